"""Track the nine facial contours through a sequence (004 V-C).

Each frame's contours start from the previous frame's equilibrium and slide downhill
in the new potential until no node moves more than ``tol`` pixels in a step
(equilibrium by a movement threshold, never a fixed number of iterations). All nine
contours form one :class:`~trackers.snakes.ContourSystem`, separated by
``a_i = b_i = 0``, whose matrix is factored once for the whole sequence.

Per frame and per contour the tracker reports a quality:

* ``depth``: mean depth ``-P`` of the potential under the nodes, relative to the
  depth on the first frame (1 = as well anchored as at the start);
* ``stretch``: contour length relative to the first frame;
* ``lost``: depth below ``lost_depth``, stretch outside ``stretch_range``, or nodes
  that left the image. A lost contour is re-initialised from the layout (moved with
  the head frame) and relaxed again within the same frame; it stays flagged lost only
  if that fails too.

Ends. A free end of a contour on a dark line creeps inward, to where the ravine
stops deepening, which leaves it short of the feature's true end by about
``2 * sigma``. For contours whose ends are fiducials (brows, furrows, upper lip)
the tracker therefore relocates each end, after relaxation, on the feature's end:
it samples the potential along the contour's end tangent and puts the end where
the ravine has risen to half its depth (the end of a blurred line), then inset by
the line's half-width measured across it (so the end lies on the centre line,
e.g. the centre of a round-capped eyebrow stroke), and redistributes the nodes
evenly. This is recorded in ``LayoutContour.ends`` and can be switched off.

Image forces act along the contour normal only (``Contour.normal_forces``): along
an uneven ravine (a tapering eyebrow) the tangential part of eq. 12 would slide the
nodes toward its deepest spot and, rest lengths being viscoelastic, shrink the contour.

Image-force strength. ``strength='auto'`` (default) keeps the paper's parameters for
tension, rigidity, viscoelasticity and damping, and sets each contour's ``p`` on
the first frame so that a node descends its ravine at a fixed fraction
(``descent_rate``) of the remaining distance per step (from the ravine's measured
curvature). The paper's ``p = 0.001`` was tuned for its own ~1-pixel filter;
``strength='paper'`` uses that value scaled to each contour's ``sigma`` with
:func:`~trackers.snakes.paper_equivalent_strength`, and a float sets ``p`` directly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trackers.fiducials import (
    HeadFrame,
    apex_fraction,
    brow_axis_frame,
    fiducials,
    head_frame,
)
from trackers.layout import CONTOUR_NAMES, FaceLayout
from trackers.potentials import force_field, potential_from_gray, sample_bilinear, to_gray
from trackers.snakes import (
    Contour,
    ContourSystem,
    SnakeParams,
    paper_equivalent_strength,
    resample_polyline,
)

__all__ = ["ContourQuality", "TrackResult", "Tracker", "refine_end"]


@dataclass(frozen=True)
class ContourQuality:
    """Per-frame quality of one contour (see the module docstring)."""

    depth: float
    stretch: float
    lost: bool
    reinitialised: bool = False


@dataclass
class TrackResult:
    """Everything the tracker knows about one frame.

    Attributes
    ----------
    index : int
        Frame index (0 for the first frame given to the tracker).
    contours : dict name -> ndarray (n, 2)
        Equilibrium node positions, image pixels.
    quality : dict name -> ContourQuality
    iterations : int
        Time steps used for this frame (all relaxations together).
    converged : bool
        Whether the last relaxation reached the movement threshold.
    head : HeadFrame
    fiducials : dict name -> (x, y)
    """

    index: int
    contours: dict
    quality: dict
    iterations: int
    converged: bool
    head: HeadFrame
    fiducials: dict
    extra: dict = field(default_factory=dict)

    @property
    def success(self) -> bool:
        """No contour is lost."""
        return not any(q.lost for q in self.quality.values())

    @property
    def confidence(self) -> float:
        """Smallest relative depth over the contours, clipped to [0, 1]."""
        return float(np.clip(min(q.depth for q in self.quality.values()), 0.0, 1.0))


def _polyline_length(p, closed=False):
    d = np.diff(np.vstack([p, p[:1]]) if closed else p, axis=0)
    return float(np.hypot(*d.T).sum())


def _trim_start(p, s):
    """Drop arc length ``s`` from the start of polyline ``p``."""
    seg = np.hypot(*np.diff(p, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if s >= cum[-1]:
        return p[-2:]
    i = int(np.searchsorted(cum, s, side="right")) - 1
    t = (s - cum[i]) / max(seg[i], 1e-12)
    first = p[i] + t * (p[i + 1] - p[i])
    return np.vstack([first, p[i + 1:]])


def _sample_safe(P, pts, origin):
    H, W = P.shape
    q = np.asarray(pts, float) - origin
    ok = (q[:, 0] >= 0) & (q[:, 1] >= 0) & (q[:, 0] <= W - 1) & (q[:, 1] <= H - 1)
    out = np.full(len(q), np.nan)
    if ok.any():
        out[ok] = sample_bilinear(P, q[ok])
    return out


def refine_end(points, potential, sigma: float, *, origin=(0.0, 0.0), end: int = 0,
               gray=None, inset: bool = True):
    """Relocate one end of an open contour on the end of the dark line it follows.

    Parameters
    ----------
    points : array_like (n, 2)
        Contour nodes (x, y).
    potential : ndarray (H, W)
        Valley (or edge) potential the contour lies in.
    sigma : float
        Width of that potential, pixels.
    origin : (x, y)
        Image position of ``potential[0, 0]``.
    end : {0, -1}
        Which end.
    gray : ndarray (H, W), optional
        Grey image on the same grid; with ``inset`` the end is moved back by the
        line's half-width, measured across the line from ``gray``.
    inset : bool
        Treat the feature as a band: reference depth taken just inside the end and
        the end moved back by the half-width (needs ``gray``). Otherwise a thin line:
        reference depth = deepest point inside, no inset.

    Returns
    -------
    ndarray (2,) or None
        The new end, or None when no clear ravine end is found.
    """
    p = np.asarray(points, float)
    if end not in (0, -1):
        raise ValueError(f"end must be 0 or -1, got {end}")
    if end == -1:
        p = p[::-1]
    n = len(p)
    k = min(3, n - 1)
    t = p[0] - p[k]
    norm = float(np.hypot(*t))
    if norm < 1e-9:
        return None
    t /= norm
    length = _polyline_length(p)
    s_in = 0.45 * length if not inset else min(5.0 * sigma, 0.45 * length)
    s_out = 5.0 * sigma
    s = np.arange(-s_in, s_out + 1e-9, 0.25)
    # inside: along the contour itself; outside: along the end tangent
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    path = p[0] + np.maximum(s, 0.0)[:, None] * t
    neg = s < 0
    path[neg, 0] = np.interp(-s[neg], arc, p[:, 0])
    path[neg, 1] = np.interp(-s[neg], arc, p[:, 1])
    v = _sample_safe(potential, path, np.asarray(origin, float))
    inside = s <= 0
    if np.isnan(v[inside]).all():
        return None
    if inset:
        # a band: reference depth just inside the end (a tapering band is shallower
        # near its end than in its middle, and its end is where *that* depth halves)
        near = inside & (s >= -2.5 * sigma) & (s <= -1.0 * sigma)
        if not near.any() or np.isnan(v[near]).all():
            return None
        depth = float(np.nanmedian(v[near]))
        i0 = int(np.nonzero(near)[0][-1])
    else:
        # a line: the deepest point inside, so that a faint continuation is no end
        i0 = int(np.nanargmin(np.where(inside, v, np.inf)))
        depth = float(v[i0])
    if not np.isfinite(depth) or depth >= -1e-3:
        return None
    half = 0.5 * depth
    j = None
    for m in range(i0 + 1, len(s)):
        if np.isnan(v[m]):
            break
        if v[m] > half:
            j = m
            break
    if j is None:
        return None
    f = (half - v[j - 1]) / (v[j] - v[j - 1])
    s_end = s[j - 1] + f * (s[j] - s[j - 1])
    # a real end: the ravine must fade out (not just weaken) within 3 sigma beyond
    beyond = v[(s > s_end) & (s <= s_end + 3.0 * sigma)]
    if len(beyond) == 0 or np.isnan(beyond).all() or np.nanmax(beyond) < 0.25 * depth:
        return None
    if inset and gray is not None:
        hw = _half_width(gray, _path_point(p, arc, t, s_end - 2.0 * sigma), t,
                         np.asarray(origin, float), sigma)
        if hw is not None:
            s_end -= hw
    return _path_point(p, arc, t, s_end)


def _path_point(p, arc, t, s):
    if s >= 0:
        return p[0] + s * t
    return np.array([np.interp(-s, arc, p[:, 0]), np.interp(-s, arc, p[:, 1])])


def _half_width(gray, centre, tangent, origin, sigma):
    """Half width at half depth of the dark line crossing ``centre`` (normal to ``tangent``)."""
    nrm = np.array([-tangent[1], tangent[0]])
    r = np.arange(-5.0 * sigma, 5.0 * sigma + 1e-9, 0.25)
    v = _sample_safe(gray, centre + r[:, None] * nrm, origin)
    if np.isnan(v).any():
        return None
    c = len(r) // 2
    win = np.abs(r) <= 1.5 * sigma
    i0 = int(np.argmin(np.where(win, v, np.inf)))
    bottom = v[i0]
    outer = np.abs(r) >= 3.5 * sigma
    top = float(np.median(v[outer]))
    if top - bottom < 5.0:
        return None
    half = 0.5 * (top + bottom)
    hi = i0
    while hi < len(r) - 1 and v[hi] < half:
        hi += 1
    lo = i0
    while lo > 0 and v[lo] < half:
        lo -= 1
    if v[hi] < half or v[lo] < half:
        return None

    def cross(a, b):
        return r[a] + (half - v[a]) / (v[b] - v[a]) * (r[b] - r[a])

    right = cross(hi - 1, hi)
    left = cross(lo + 1, lo)
    del c
    return 0.5 * (right - left)


class Tracker:
    """Track a :class:`~trackers.layout.FaceLayout` through frames.

    Parameters
    ----------
    layout : FaceLayout
        Contours placed on the first frame to be tracked.
    params : SnakeParams, optional
        Tension, rigidity, viscoelasticity, damping (004 V-E values by default).
    strength : 'auto', 'paper' or float
        Image-force strength (see the module docstring).
    descent_rate : float
        Fraction of the distance to the ravine bottom covered per step with
        ``strength='auto'``.
    tol : float
        Movement threshold (pixels per step) that defines equilibrium.
    max_iter : int
        Safety cap on steps per frame.
    first_max_iter : int
        Cap on the first frame, where the contours move farthest.
    lost_depth : float
        Relative depth under which a contour is lost.
    stretch_range : (float, float)
        Relative lengths outside which a contour is lost.
    refine_ends : bool
        Relocate ends on feature ends for the contours whose layout asks for it.
    max_step : float
        Cap on a node's move per step, pixels (a guard against a too strong image
        force; it does not change equilibria).
    channel_order : {'rgb', 'bgr'}

    Examples
    --------
    >>> import numpy as np, cv2
    >>> from trackers.layout import layout_from_eyes
    >>> img = np.full((256, 256), 200, np.uint8)
    >>> lay = layout_from_eyes((96, 105), (159, 105), (256, 256))
    >>> for c in lay.contours.values():
    ...     _ = cv2.polylines(img, [np.round(c.points).astype(np.int32)], c.closed, 60, 3)
    >>> res = Tracker(lay).track(img)
    >>> sorted(res.fiducials)[:2], res.success
    (['brow_inner_l', 'brow_inner_r'], True)
    """

    def __init__(self, layout: FaceLayout, *, params: SnakeParams | None = None,
                 strength="auto", descent_rate: float = 0.3, tol: float = 0.01,
                 max_iter: int = 300, first_max_iter: int = 2000, lost_depth: float = 0.3,
                 stretch_range=(0.6, 1.6), refine_ends: bool = True,
                 max_step: float = 1.0, channel_order: str = "rgb"):
        if not isinstance(layout, FaceLayout):
            raise ValueError(f"layout must be a FaceLayout, got {type(layout).__name__}")
        if params is None:
            params = SnakeParams()
        if not (strength in ("auto", "paper") or (np.isscalar(strength)
                                                  and float(strength) > 0)):
            raise ValueError(f"strength must be 'auto', 'paper' or a positive number, got "
                             f"{strength!r}")
        if not 0 < descent_rate < 1.5:
            raise ValueError(f"descent_rate must be in (0, 1.5), got {descent_rate}")
        if not 0 <= lost_depth < 1:
            raise ValueError(f"lost_depth must be in [0, 1), got {lost_depth}")
        lo, hi = stretch_range
        if not 0 < lo < 1 < hi:
            raise ValueError(f"stretch_range must be (lo < 1 < hi), got {stretch_range}")
        if channel_order not in ("rgb", "bgr"):
            raise ValueError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")
        self.layout = layout
        self.params = params
        self.strength_mode = strength
        self.descent_rate = float(descent_rate)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.first_max_iter = int(first_max_iter)
        self.lost_depth = float(lost_depth)
        self.stretch_range = (float(lo), float(hi))
        self.refine_ends = bool(refine_ends)
        self.channel_order = channel_order
        self.names = list(CONTOUR_NAMES)
        # one force field per (kind, sigma)
        self.field_keys: list[tuple[str, float]] = []
        fidx = {}
        for name in self.names:
            c = layout.contours[name]
            key = (c.kind, round(float(c.sigma), 4))
            if key not in self.field_keys:
                self.field_keys.append(key)
            fidx[name] = self.field_keys.index(key)
        self.field_of = fidx
        contours = []
        for name in self.names:
            c = layout.contours[name]
            p0 = paper_equivalent_strength(c.sigma, params.p) if strength in ("auto", "paper") \
                else float(strength)
            contours.append(Contour(c.points, closed=c.closed, params=params, p=p0,
                                    field=fidx[name], name=name, normal_forces=True))
        self.system = ContourSystem(contours, params, max_step=max_step)
        self.sigma_max = max(s for _, s in self.field_keys)
        self.index = 0
        self.ref_depth: dict[str, float] = {}
        self.ref_length: dict[str, float] = {}
        self.ref_head: HeadFrame | None = None
        self.brow_fraction: dict[str, float] | None = None
        self.last_head: HeadFrame | None = None
        self.frame_size = tuple(layout.image_size)
        iod = layout.inter_eye
        self.motion_margin = max(6.0, 0.12 * iod)

    # ------------------------------------------------------------------ helpers
    def _roi(self, W, H):
        X = self.system.X
        m = self.motion_margin + 3.0 * self.sigma_max
        x0 = int(max(np.floor(X[:, 0].min() - m), 0))
        y0 = int(max(np.floor(X[:, 1].min() - m), 0))
        x1 = int(min(np.ceil(X[:, 0].max() + m) + 1, W))
        y1 = int(min(np.ceil(X[:, 1].max() + m) + 1, H))
        return x0, y0, x1, y1

    def _fields(self, frame):
        img = np.asarray(frame)
        if img.ndim < 2:
            raise ValueError(f"frame {self.index}: must be 2-D or 3-D, got shape {img.shape}")
        H, W = img.shape[:2]
        if self.frame_size != (W, H):
            raise ValueError(f"frame {self.index} is {W}x{H} but the layout was made for "
                             f"{self.frame_size[0]}x{self.frame_size[1]}")
        x0, y0, x1, y1 = self._roi(W, H)
        pad = int(np.ceil(3 * self.sigma_max)) + 3
        X0, Y0 = max(x0 - pad, 0), max(y0 - pad, 0)
        X1, Y1 = min(x1 + pad, W), min(y1 + pad, H)
        try:
            gray = to_gray(img[Y0:Y1, X0:X1], channel_order=self.channel_order)
        except ValueError as exc:
            raise ValueError(f"frame {self.index}: {exc}") from None
        roi = (x0 - X0, y0 - Y0, x1 - X0, y1 - Y0)
        Ps = [potential_from_gray(gray, kind, sig, roi=roi) for kind, sig in self.field_keys]
        F = np.stack([force_field(P) for P in Ps])
        g_roi = gray[roi[1]:roi[3], roi[0]:roi[2]]
        return F, Ps, g_roi, (float(x0), float(y0))

    def _depths(self, Ps, origin):
        out = {}
        for k, name in enumerate(self.names):
            pts = self.system.X[self.system.contour_slice(k)]
            v = _sample_safe(Ps[self.field_of[name]], pts, np.asarray(origin))
            out[name] = float(-np.nanmean(v)) if np.isfinite(v).any() else 0.0
        return out

    def _auto_strength(self, Ps, origin):
        gdt = self.params.gamma / self.params.dt
        for k, name in enumerate(self.names):
            c = self.layout.contours[name]
            pts = self.system.X[self.system.contour_slice(k)]
            P = Ps[self.field_of[name]]
            tang = np.gradient(pts, axis=0)
            tang /= np.maximum(np.hypot(*tang.T), 1e-9)[:, None]
            nrm = np.c_[-tang[:, 1], tang[:, 0]]
            h = max(0.5 * c.sigma, 0.75)
            v0 = _sample_safe(P, pts, origin)
            vp = _sample_safe(P, pts + h * nrm, origin)
            vm = _sample_safe(P, pts - h * nrm, origin)
            curv = (vp + vm - 2 * v0) / h**2
            curv = curv[np.isfinite(curv) & (curv > 0)]
            p_paper = paper_equivalent_strength(c.sigma, self.params.p)
            if len(curv) < 3:
                p = p_paper
            else:
                # the steep end of the distribution sets the rate: stability first
                p = self.descent_rate * gdt / float(np.percentile(curv, 90))
                p = float(np.clip(p, 0.1 * p_paper, 100 * p_paper))
            self.system.set_strength(k, p)

    def _refine(self, Ps, gray, origin):
        if not self.refine_ends:
            return
        for k, name in enumerate(self.names):
            c = self.layout.contours[name]
            if c.ends == "free":
                continue
            pts = self.system.contour_points(k)
            n = len(pts)
            P = Ps[self.field_of[name]]
            new = pts
            for end in (0, -1):
                q = refine_end(new, P, c.sigma, origin=origin, end=end, gray=gray,
                               inset=c.ends == "centre")
                if q is None:
                    continue
                e = new[0] if end == 0 else new[-1]
                d = q - e
                ref = new if end == 0 else new[::-1]
                t = ref[0] - ref[min(3, len(ref) - 1)]
                t /= max(np.hypot(*t), 1e-9)
                s = float(d @ t)
                if abs(s) < 1e-3 or s > 5 * c.sigma:
                    continue
                if s < 0:
                    # retract: cut the contour where the end now lies
                    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(ref, axis=0).T))])
                    cut = arc[np.argmin(np.hypot(*(ref - q).T))]
                    if cut > 0.45 * arc[-1]:
                        continue
                    ref = np.vstack([q, _trim_start(ref, cut)[1:]]) if cut > 0 else ref
                else:
                    ref = np.vstack([q, ref])
                if len(ref) < 2 or _polyline_length(ref) < 2.0:
                    continue
                new = ref if end == 0 else ref[::-1]
            if new is not pts:
                self.system.set_contour(k, resample_polyline(new, n), reset_rest=True)

    def _layout_points(self, k, head):
        """Layout contour ``k`` moved by the similarity between the first and this frame."""
        name = self.names[k]
        c = self.layout.contours[name]
        n = self.system.contour_slice(k).stop - self.system.contour_slice(k).start
        pts = resample_polyline(c.points, n, closed=c.closed)
        if self.ref_head is not None and head is not None:
            pts = head.to_image(self.ref_head.to_head(pts))
        W, H = self.frame_size
        return np.clip(pts, 0, [W - 1, H - 1])

    def _quality(self, depths, outside, reinit=()):
        q = {}
        for k, name in enumerate(self.names):
            pts = self.system.X[self.system.contour_slice(k)]
            closed = self.layout.contours[name].closed
            depth = depths[name] / max(self.ref_depth.get(name, depths[name]), 1e-9)
            stretch = _polyline_length(pts, closed) / max(self.ref_length.get(
                name, _polyline_length(pts, closed)), 1e-9)
            lost = (not np.isfinite(pts).all() or depth < self.lost_depth
                    or not self.stretch_range[0] <= stretch <= self.stretch_range[1]
                    or bool(outside[k]))
            q[name] = ContourQuality(float(depth), float(stretch), bool(lost), name in reinit)
        return q

    def _head(self):
        cont = {n: self.system.contour_points(k) for k, n in enumerate(self.names)}
        try:
            return head_frame(cont)
        except ValueError:
            return self.last_head

    # ------------------------------------------------------------------ public
    def track(self, frame) -> TrackResult:
        """Relax the contours on ``frame`` (starting from the last equilibrium).

        Raises
        ------
        ValueError
            When the frame's size differs from the layout's or its pixels are bad
            (the message names the frame index).
        """
        first = self.index == 0
        F, Ps, gray, origin = self._fields(frame)
        cap = self.first_max_iter if first else self.max_iter
        res = self.system.relax(F, origin=origin, tol=self.tol, max_iter=cap)
        iters = res.iterations
        if first and self.strength_mode == "auto":
            self._auto_strength(Ps, origin)
            res = self.system.relax(F, origin=origin, tol=self.tol, max_iter=cap)
            iters += res.iterations
        self._refine(Ps, gray, origin)
        if self.refine_ends:
            r2 = self.system.relax(F, origin=origin, tol=self.tol, max_iter=cap)
            iters += r2.iterations
            self._refine(Ps, gray, origin)
        outside = res.outside
        depths = self._depths(Ps, origin)
        if first:
            for k, name in enumerate(self.names):
                self.ref_depth[name] = depths[name]
                self.ref_length[name] = _polyline_length(
                    self.system.contour_points(k), self.layout.contours[name].closed)
        quality = self._quality(depths, outside)
        head = self._head()
        lost = [k for k, n in enumerate(self.names) if quality[n].lost]
        reinit = set()
        if lost and not first:
            base = self.last_head if quality["hairline"].lost or quality["nose_tip"].lost \
                else head
            for k in lost:
                self.system.set_contour(k, self._layout_points(k, base), reset_rest=True)
                reinit.add(self.names[k])
            # the new positions must lie inside the fields' ROI
            F, Ps, gray, origin = self._fields(frame)
            r3 = self.system.relax(F, origin=origin, tol=self.tol, max_iter=cap)
            iters += r3.iterations
            self._refine(Ps, gray, origin)
            outside = r3.outside
            depths = self._depths(Ps, origin)
            quality = self._quality(depths, outside, reinit)
            head = self._head()
        if first and head is not None:
            self.ref_head = head
            self.brow_fraction = {}
            cont = {n: self.system.contour_points(k) for k, n in enumerate(self.names)}
            axis = brow_axis_frame(cont, head)
            for side in ("l", "r"):
                b = cont[f"brow_{side}"]
                if abs(head.to_head(b[:1])[0, 0]) > abs(head.to_head(b[-1:])[0, 0]):
                    b = b[::-1]
                self.brow_fraction[side] = apex_fraction(b, axis)
        if head is None:
            raise ValueError(f"frame {self.index}: no head frame could be computed")
        self.last_head = head
        contours = {n: self.system.contour_points(k) for k, n in enumerate(self.names)}
        fids = fiducials(contours, head, brow_mid_fraction=self.brow_fraction)
        out = TrackResult(self.index, contours, quality, int(iters), bool(res.converged),
                          head, fids)
        self.index += 1
        return out

    def run(self, frames):
        """Generator of :class:`TrackResult` for an iterable of frames."""
        for frame in frames:
            yield self.track(frame)
