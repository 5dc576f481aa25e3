"""Track the nine facial contours through a sequence (004 V-C).

Each frame's contours start from the previous frame's equilibrium and slide downhill
in the new potential until the root-mean-square node displacement in a step falls
below ``tol`` pixels (equilibrium by a movement threshold, never a fixed number of
iterations; ``max_iter`` is only a safety cap). On the first frame the largest
node displacement must fall below ``tol``. All nine
contours form one :class:`~trackers.snakes.ContourSystem`, separated by
``a_i = b_i = 0``, whose matrix is factored once for the whole sequence.

Per frame and per contour the tracker reports a quality:

* ``depth``: mean depth ``-P`` of the potential under the nodes, relative to the
  depth on the first frame (1 = as well anchored as at the start);
* ``stretch``: contour length relative to the first frame;
* ``shape``: change of shape since the first frame (similarity-invariant residual
  over the length);
* ``lost``: depth below ``lost_depth``, stretch outside ``stretch_range``, shape
  change above ``max_shape_change``, or nodes that left the image. A lost contour
  is re-initialised from the layout (moved with the head frame) and relaxed again
  within the same frame; it stays flagged lost only if that fails too.

Ends. A free end of a contour on a dark line creeps inward, to where the ravine
stops deepening, which leaves it short of the feature's true end by about
``2 * sigma``. For contours whose ends are fiducials (brows, furrows, upper lip)
the tracker therefore relocates each end, after relaxation, on the feature's end:
it samples the potential along the contour's end tangent and puts the end where
the ravine has risen to half its depth (the end of a blurred line), then inset by
the line's half-width measured across it (so the end lies on the centre line,
e.g. the centre of a round-capped eyebrow stroke), and redistributes the nodes
evenly. Where the ravine runs on past the line's end (the furrows' tops run into the
shading beside the nose, where the ravine of the face model's renders ran on up to
6 px) the end is instead the half-level point of the strongest step of the grey
level along the line, inset by the half-width (``ends='line'``, see
:func:`refine_end`). This is recorded in ``LayoutContour.ends`` and can be switched
off.

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

import cv2
import numba
import numpy as np

from trackers.anchors import IrisAnchors, similarity_from_pairs
from trackers.fiducials import (
    HeadFrame,
    apex_fraction,
    brow_axis_frame,
    centroid,
    fiducials,
    head_frame,
)
from trackers.head_motion import FeatureAnchors, gray_u8
from trackers.layout import CONTOUR_NAMES, FaceLayout, detect_layout
from trackers.potentials import bilinear_nb as _bil
from trackers.potentials import potentials_in_boxes, sample_or_nan, to_gray
from trackers.snakes import (
    Contour,
    ContourSystem,
    SnakeParams,
    _arc_length_nb,
    paper_equivalent_strength,
    resample_polyline,
)

#: Default arc-length fraction (from the inner end) of ``brow_mid_*`` along an eyebrow
#: contour (see :class:`Tracker`, ``brow_mid``).
BROW_MID_FRACTION = 0.556

__all__ = ["BROW_MID_FRACTION", "ContourQuality", "TrackResult", "Tracker", "mouth_corners",
           "refine_end"]


@dataclass(frozen=True)
class ContourQuality:
    """Per-frame quality of one contour (see the module docstring).

    Attributes
    ----------
    depth : float
        Mean potential depth under the nodes relative to the first frame.
    stretch : float
        Length relative to the first frame.
    lost : bool
    reinitialised : bool
        Re-placed from the layout in this frame.
    shape : float
        Change of shape since the first frame: RMS residual of the best similarity
        fit (translation, rotation, scale) of the first frame's contour onto this
        one, over the contour's length (0 = same shape).
    """

    depth: float
    stretch: float
    lost: bool
    reinitialised: bool = False
    shape: float = 0.0


def _resample_for_shape(points, closed, n=32):
    from trackers.snakes import resample_polyline as _rs

    try:
        return _rs(points, n, closed=closed)
    except ValueError:
        return np.repeat(np.asarray(points, float)[:1], n, axis=0)


def _shape_change(points, ref, closed):
    """Similarity-invariant RMS shape difference over the reference length.

    Node to node: a contour keeps its number of nodes and (tension, end relocation)
    their even spacing, so no resampling is needed.
    """
    cur = np.asarray(points, float)
    if cur.shape != ref.shape:
        cur = _resample_for_shape(cur, closed, len(ref))
    return float(_shape_nb(np.ascontiguousarray(cur), np.ascontiguousarray(ref, dtype=float),
                           bool(closed)))


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
    return float(_length_nb(np.ascontiguousarray(p, dtype=np.float64), bool(closed)))


@numba.njit(cache=True, error_model="numpy")
def _length_nb(p, closed):
    n = p.shape[0]
    total = 0.0
    for i in range(n - 1):
        total += np.sqrt((p[i + 1, 0] - p[i, 0]) ** 2 + (p[i + 1, 1] - p[i, 1]) ** 2)
    if closed and n > 1:
        total += np.sqrt((p[0, 0] - p[n - 1, 0]) ** 2 + (p[0, 1] - p[n - 1, 1]) ** 2)
    return total


@numba.njit(cache=True, error_model="numpy")
def _shape_nb(cur, ref, closed):
    n = cur.shape[0]
    cx = 0.0
    cy = 0.0
    rx = 0.0
    ry = 0.0
    for i in range(n):
        cx += cur[i, 0]
        cy += cur[i, 1]
        rx += ref[i, 0]
        ry += ref[i, 1]
    cx /= n
    cy /= n
    rx /= n
    ry /= n
    ww = 0.0
    ar = 0.0
    ai = 0.0
    for i in range(n):
        wx = ref[i, 0] - rx
        wy = ref[i, 1] - ry
        zx = cur[i, 0] - cx
        zy = cur[i, 1] - cy
        ww += wx * wx + wy * wy
        # conj(w) * z
        ar += wx * zx + wy * zy
        ai += wx * zy - wy * zx
    if ww <= 1e-12:
        return 0.0
    ar /= ww
    ai /= ww
    res = 0.0
    for i in range(n):
        wx = ref[i, 0] - rx
        wy = ref[i, 1] - ry
        ex = (cur[i, 0] - cx) - (ar * wx - ai * wy)
        ey = (cur[i, 1] - cy) - (ar * wy + ai * wx)
        res += ex * ex + ey * ey
    scale = np.sqrt(ar * ar + ai * ai)
    length = _length_nb(ref, closed) * max(scale, 1e-9)
    return np.sqrt(res / n) / max(length, 1e-9)


@numba.njit(cache=True, error_model="numpy")
def _mean_depth_nb(P, pts, ox, oy):
    total = 0.0
    cnt = 0
    for i in range(pts.shape[0]):
        v = _bil(P, pts[i, 0], pts[i, 1], ox, oy)
        if not np.isnan(v):             # nodes off the potential's box do not count
            total += v
            cnt += 1
    return -total / cnt if cnt else 0.0


@numba.njit(cache=True, error_model="numpy")
def _boxes_nb(X, starts, m, X0, Y0, gw, gh, out):
    for k in range(starts.shape[0] - 1):
        xmin = np.inf
        ymin = np.inf
        xmax = -np.inf
        ymax = -np.inf
        for i in range(starts[k], starts[k + 1]):
            xmin = min(xmin, X[i, 0])
            xmax = max(xmax, X[i, 0])
            ymin = min(ymin, X[i, 1])
            ymax = max(ymax, X[i, 1])
        out[k, 0] = max(int(np.floor(xmin - m)) - X0, 0)
        out[k, 1] = max(int(np.floor(ymin - m)) - Y0, 0)
        out[k, 2] = min(int(np.ceil(xmax + m)) + 1 - X0, gw)
        out[k, 3] = min(int(np.ceil(ymax + m)) + 1 - Y0, gh)


@numba.njit(cache=True, error_model="numpy")
def _trim_start_nb(p, s):
    """Polyline ``p`` without arc length ``s`` from its start."""
    n = p.shape[0]
    cum = _arc_length_nb(p)
    if s >= cum[n - 1]:
        return p[n - 2:].copy()
    i = 0
    while i + 1 < n and cum[i + 1] <= s:
        i += 1
    seg = np.hypot(p[i + 1, 0] - p[i, 0], p[i + 1, 1] - p[i, 1])
    t = (s - cum[i]) / max(seg, 1e-12)
    out = np.empty((n - i, 2))
    out[0, 0] = p[i, 0] + t * (p[i + 1, 0] - p[i, 0])
    out[0, 1] = p[i, 1] + t * (p[i + 1, 1] - p[i, 1])
    out[1:] = p[i + 1:]
    return out


@numba.njit(cache=True, error_model="numpy")
def _move_end_nb(ref, qx, qy, sigma, settle):
    """Contour ``ref`` (its end to move first) with that end moved to ``(qx, qy)``:
    extended along the end, or cut back where the end now lies (by at most 2 sigma a
    frame unless ``settle``). An empty array when the move is refused (too small, too
    far, or cutting away half the contour)."""
    n = ref.shape[0]
    none = np.empty((0, 2))
    dx, dy = qx - ref[0, 0], qy - ref[0, 1]
    j = min(3, n - 1)
    tx, ty = ref[0, 0] - ref[j, 0], ref[0, 1] - ref[j, 1]
    tn = max(np.hypot(tx, ty), 1e-9)
    tx /= tn
    ty /= tn
    s = dx * tx + dy * ty
    if abs(s) < 1e-3 or s > 5 * sigma:
        return none
    if s < 0:
        # retract: cut the contour where the end now lies
        arc = 0.0
        best = np.inf
        cut = 0.0
        for i in range(n):
            if i > 0:
                arc += np.hypot(ref[i, 0] - ref[i - 1, 0], ref[i, 1] - ref[i - 1, 1])
            d = np.hypot(ref[i, 0] - qx, ref[i, 1] - qy)
            if d < best:
                best = d
                cut = arc
        if cut > 0.45 * arc:
            return none
        if cut > 2.0 * sigma and not settle:
            # features shorten slowly: at most 2 sigma per frame, so that a transient
            # gap (a highlight) cannot cut a contour in half (the first frame, where
            # the layout may be far off, excepted)
            out = _trim_start_nb(ref, 2.0 * sigma)
        elif cut > 0:
            rest = _trim_start_nb(ref, cut)
            out = np.empty((rest.shape[0], 2))
            out[0, 0] = qx
            out[0, 1] = qy
            out[1:] = rest[1:]
        else:
            out = ref
    else:
        out = np.empty((n + 1, 2))
        out[0, 0] = qx
        out[0, 1] = qy
        out[1:] = ref
    if out.shape[0] < 2 or _length_nb(out, False) < 2.0:
        return none
    return out


def mouth_corners(gray, lip, *, origin=(0.0, 0.0), sigma: float = 1.0,
                  half_height: float | None = None, width: float | None = None,
                  previous=None, max_shift: float = 0.08):
    """Mouth corners as the lateral ends of the dark mouth line or cavity.

    A contour on the mouth line gives the commissures by its ends while the mouth is
    closed. When the jaw drops, the dark line becomes a cavity, the contour follows
    one of its borders (often the upper edge of the lower teeth) and its ends fall
    short of the corners, which lie higher, where the lips meet. Here the mouth is
    scanned along the chord of the contour (``lip``): at each step the darkest grey
    value (blurred by ``sigma``) across a window of ``+-half_height`` pixels around
    the chord line is taken, whichever part of the window the cavity or line is in.
    Going outward from the inner part of the mouth, the corner is where this profile
    first rises to half-way between the mouth's darkness and the skin beyond it.
    Its height is that of the darkest point of the window there.

    Parameters
    ----------
    gray : ndarray (H, W)
        Grey image (e.g. the tracker's crop).
    lip : array_like (n, 2)
        Mouth-line contour, image pixels, ordered either way.
    origin : (x, y)
        Image position of ``gray[0, 0]``.
    sigma : float
        Blur of the profile, pixels.
    half_height : float, optional
        Half-height of the window across the chord (default 15 % of ``width``).
    width : float, optional
        Expected mouth width, pixels (default: the chord's length). The scan
        reaches 30 % of it beyond the ends, plus half of what the contour is short
        of it (a contour on a cavity's border shrinks).
    previous : pair of (2,) arrays or None, optional
        The corners found on the previous frame (moved with the head), at the contour's
        first and last end. Where given, the window across the chord is narrowed to
        ``+-max_shift * width`` around that corner's height: corners move little from one
        frame to the next, while something dark beside the mouth (a furrow crossing the
        window when the upper lip lifts off the teeth) would otherwise win.
    max_shift : float
        Half-height of that narrowed window, as a fraction of the mouth width.

    Returns
    -------
    list of two ndarray (2,) or None
        The corners at the contour's first and last end (None where no clear end of
        the dark region is found).

    Examples
    --------
    >>> import numpy as np, cv2
    >>> img = np.full((60, 100), 200, np.uint8)
    >>> _ = cv2.line(img, (16, 30), (84, 30), 40, 2)  # where the lips meet (caps: 15..85)
    >>> _ = cv2.ellipse(img, (50, 30), (24, 6), 0, 0, 360, 30, -1)  # the open mouth
    >>> lip = np.c_[np.linspace(34, 66, 15), np.full(15, 34.0)]     # on its lower border
    >>> [np.round(c).tolist() for c in mouth_corners(img, lip, width=68)]
    [[15.0, 30.0], [85.0, 30.0]]
    """
    p = np.asarray(lip, float)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 3:
        raise ValueError(f"lip must have shape (n >= 3, 2), got {p.shape}")
    g = np.asarray(gray, np.float32)
    if g.ndim != 2:
        raise ValueError(f"gray must be 2-D, got shape {g.shape}")
    chord = p[-1] - p[0]
    L = float(np.hypot(*chord))
    if L < 4:
        return [None, None]
    u = chord / L
    nrm = np.array([-u[1], u[0]])
    wid = L if width is None else max(float(width), L)
    h = 0.15 * wid if half_height is None else float(half_height)
    # the window is centred on the chord line through the middle of the contour's
    # height: an arched lip line or a cavity hangs below its chord
    mid = p.mean(axis=0)
    off = float((mid - p[0]) @ nrm)
    step = 0.5
    vs = np.arange(-h, h + 1e-9, 1.0) + 0.5 * off
    # blur only the part of the image the scan samples
    across = h + abs(off)
    for last, end in zip(previous if previous is not None else (), (p[0], p[-1])):
        if last is not None and np.isfinite(last).all():
            across = max(across, abs(float((np.asarray(last, float) - end) @ nrm))
                         + max(max_shift * wid, 2.0))
    pad = 0.3 * wid + 0.5 * (wid - L) + across + 4.0 * max(sigma, 0.5) + 2.0
    x0 = max(int(np.floor(p[:, 0].min() - pad - origin[0])), 0)
    y0 = max(int(np.floor(p[:, 1].min() - pad - origin[1])), 0)
    x1 = min(int(np.ceil(p[:, 0].max() + pad - origin[0])) + 1, g.shape[1])
    y1 = min(int(np.ceil(p[:, 1].max() + pad - origin[1])) + 1, g.shape[0])
    if x1 - x0 < 4 or y1 - y0 < 4:
        return [None, None]
    g = g[y0:y1, x0:x1]
    origin = (origin[0] + x0, origin[1] + y0)
    if sigma > 0:
        g = cv2.GaussianBlur(g, (0, 0), float(sigma))
    out = []
    prev = [None, None] if previous is None else list(previous)
    if len(prev) != 2:
        raise ValueError(f"previous must hold two corners (or None), got {len(prev)}")
    for end, direction, last in ((p[0], -u, prev[0]), (p[-1], u, prev[1])):
        ss = np.arange(-0.35 * L, 0.3 * wid + 0.5 * (wid - L) + 1e-9, step)
        vs_end = vs
        if last is not None and np.isfinite(last).all():
            centre = float((np.asarray(last, float) - end) @ nrm)
            reach = max(max_shift * wid, 2.0)
            vs_end = np.arange(centre - reach, centre + reach + 1e-9, 1.0)
        base = end + ss[:, None, None] * direction + vs_end[None, :, None] * nrm
        mx = (base[..., 0] - origin[0]).astype(np.float32)
        my = (base[..., 1] - origin[1]).astype(np.float32)
        vals = cv2.remap(g, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=np.nan)
        bad = np.isnan(vals).any(axis=1)
        if bad.any():
            # the scan left the image: keep what lies before
            first_bad = int(np.argmax(bad))
            if ss[first_bad] <= 0.05 * L:
                out.append(None)
                continue
            ss, vals = ss[:first_bad], vals[:first_bad]
        k = np.argmin(vals, axis=1)
        prof = vals[np.arange(len(ss)), k]
        inner = np.median(prof[ss <= -0.15 * L])
        beyond = prof[ss >= min(0.15 * L + 0.5 * (wid - L), ss[-1] - 2.0)]
        outer = np.median(beyond)
        if outer - inner < 8.0:
            out.append(None)
            continue
        half = 0.5 * (inner + outer)
        i0 = int(np.searchsorted(ss, -0.15 * L))
        found = None
        for i in range(max(i0, 1), len(ss)):
            if prof[i] > half >= prof[i - 1]:
                # an end: the profile stays up for 2 sigma (a highlight is no end)
                stay = prof[i:i + int(np.ceil(2 * max(sigma, 1.0) / step)) + 1]
                if (stay > half).all():
                    f = (half - prof[i - 1]) / (prof[i] - prof[i - 1])
                    found = i - 1 + f
                    break
        if found is None:
            out.append(None)
            continue
        i = int(found)
        t = found - i
        j = min(i + 1, len(ss) - 1)
        # height: where the window is darkest, just inside the end
        col = vals[max(i - 1, 0)]
        kk = int(k[max(i - 1, 0)])
        v = vs_end[kk]
        if 0 < kk < len(vs_end) - 1:
            den = col[kk - 1] - 2 * col[kk] + col[kk + 1]
            if den > 0:
                v += float(np.clip(0.5 * (col[kk - 1] - col[kk + 1]) / den, -0.5, 0.5)) \
                    * (vs_end[1] - vs_end[0])
        pt = end + ((1 - t) * ss[i] + t * ss[j]) * direction + v * nrm
        out.append(pt)
    return out


#: While the features give the head frame, the irises are searched for on every
#: this many frames only.
IRIS_RETRY_EVERY = 4

#: A contour lost on many consecutive frames is re-placed at least this often (frames).
REINIT_EVERY = 16

# half-angle of the fan of directions searched for an open mouth's corner (radians)
_CORNER_FAN = float(np.deg2rad(45.0))


def _retry_now(streak: int) -> bool:
    """Re-place a contour lost for ``streak`` consecutive frames now? On the 1st, 2nd,
    4th, 8th... lost frame, then every :data:`REINIT_EVERY` frames."""
    if streak <= 0:
        return False
    if streak <= REINIT_EVERY:
        return streak & (streak - 1) == 0
    return streak % REINIT_EVERY == 0


def _similarity_between(h0: HeadFrame, h1: HeadFrame):
    """Similarity (complex a, b: z -> a z + b) carrying head frame ``h0`` onto ``h1``."""
    a = (h1.scale / h0.scale) * np.exp(1j * (h1.roll - h0.roll))
    return complex(a), complex((h1.x + 1j * h1.y) - a * (h0.x + 1j * h0.y))


def _brow_angle(system, names):
    """Image angle of the line from the right to the left eyebrow's centroid."""
    cl = centroid(system.contour_points(names.index("brow_l")))
    cr = centroid(system.contour_points(names.index("brow_r")))
    return float(np.arctan2(cl[1] - cr[1], cl[0] - cr[0]))


def _apply_similarity(h: HeadFrame, a, b) -> HeadFrame:
    """Head frame ``h`` moved by the similarity z -> a z + b."""
    z = a * (h.x + 1j * h.y) + b
    return HeadFrame(float(z.real), float(z.imag), float(h.scale * abs(a)),
                     float(h.roll + np.angle(a)))


def _sample_safe(P, pts, origin):
    return sample_or_nan(P, pts, origin)


def refine_end(points, potential, sigma: float, *, origin=(0.0, 0.0), end: int = 0,
               gray=None, gray_origin=None, inset: bool = True, fan: float = 0.0,
               step: bool = False):
    """Relocate one end of an open contour on the end of the dark line it follows.

    The potential is sampled along the contour (inside) and along its end tangent
    (outside); the end is put where the ravine has risen to half its reference
    depth, provided the ravine then fades out (to a quarter of that depth within
    ``3 * sigma``; a line that merely weakens has no end there).

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
        Grey image; with ``inset`` the end is moved back by the line's half-width,
        measured across the line from ``gray``.
    gray_origin : (x, y), optional
        Image position of ``gray[0, 0]`` (default: ``origin``).
    inset : bool
        Treat the feature as a band: reference depth taken just inside the end and
        the end moved back by the half-width (needs ``gray``). Otherwise a thin line:
        reference depth = deepest point inside, no inset.
    fan : float
        Half-angle in degrees of a fan of search directions around the end tangent;
        the farthest end found wins (the corner of an open mouth lies off the
        tangent of a contour that follows the mouth's lower border). 0: tangent only.
    step : bool
        Locate a thin line's end on the grey level instead (needs ``gray``, excludes
        ``inset``): the half-level crossing of the strongest dark-to-bright step
        along the line, searched from the ravine's end (or, where the ravine runs on
        without fading, from the contour's end) back into the line over 10 sigma,
        then moved back by the line's half-width onto its centre line. A step that
        rises less than half-way from the line to the skin beside it (a line that
        merely weakens) is no end. For line ends beyond which the ravine runs on
        into shading or texture (the furrows' tops).

    Returns
    -------
    ndarray (2,) or None
        The new end, or None when no clear ravine end is found.

    Examples
    --------
    >>> import numpy as np
    >>> from trackers.potentials import valley_potential
    >>> img = np.full((40, 80), 200, np.uint8); img[19:22, 10:60] = 40
    >>> P = valley_potential(img, 1.5)
    >>> pts = np.c_[np.linspace(20, 55, 16), np.full(16, 20.0)]
    >>> refine_end(pts, P, 1.5, end=-1, inset=False).tolist()  # the band ends at x = 59.5
    [59.5, 20.0]

    A shadow prolongs a line drawn to x = 58: its ravine runs on, the grey step does not.

    >>> import cv2
    >>> img = np.full((40, 100), 200, np.uint8); img[18:23, 60:95] = 140
    >>> _ = cv2.line(img, (10, 20), (58, 20), 40, 3)
    >>> P = valley_potential(img, 1.5)
    >>> pts = np.c_[np.linspace(20, 70, 20), np.full(20, 20.0)]
    >>> refine_end(pts, P, 1.5, end=-1, inset=False) is None
    True
    >>> q = refine_end(pts, P, 1.5, end=-1, inset=False, step=True, gray=img)
    >>> bool(abs(q[0] - 58) < 1.0)
    True
    """
    p = np.asarray(points, float)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2:
        raise ValueError(f"points must have shape (n >= 2, 2), got {p.shape}")
    if end not in (0, -1):
        raise ValueError(f"end must be 0 or -1, got {end}")
    if step and (gray is None or inset):
        raise ValueError("step=True needs gray and inset=False")
    if end == -1:
        p = p[::-1]
    P = np.ascontiguousarray(potential, dtype=np.float32)
    has_gray = gray is not None
    g = np.ascontiguousarray(gray, dtype=np.float32) if has_gray else np.zeros((2, 2), np.float32)
    go = origin if gray_origin is None else gray_origin
    ok, x, y = _refine_end_nb(np.ascontiguousarray(p), P, float(origin[0]), float(origin[1]),
                              float(sigma), bool(inset), g, float(go[0]), float(go[1]),
                              has_gray, float(np.deg2rad(fan)), bool(step))
    return np.array([x, y]) if ok else None


@numba.njit(cache=True, error_model="numpy")
def _path_xy(p, arc, tx, ty, s):
    if s >= 0.0:
        return p[0, 0] + s * tx, p[0, 1] + s * ty
    d = -s
    n = p.shape[0]
    if d >= arc[n - 1]:
        return p[n - 1, 0], p[n - 1, 1]
    i = 0
    while i < n - 2 and arc[i + 1] < d:
        i += 1
    seg = arc[i + 1] - arc[i]
    f = (d - arc[i]) / seg if seg > 0 else 0.0
    return p[i, 0] + f * (p[i + 1, 0] - p[i, 0]), p[i, 1] + f * (p[i + 1, 1] - p[i, 1])


@numba.njit(cache=True, error_model="numpy")
def _half_width_nb(gray, cx, cy, tx, ty, gox, goy, sigma):
    """Half width at half depth of the dark line through (cx, cy), normal to (tx, ty)."""
    nx, ny = -ty, tx
    m = int(np.floor(5.0 * sigma / 0.25))
    cnt = 2 * m + 1
    r = np.empty(cnt)
    v = np.empty(cnt)
    for i in range(cnt):
        r[i] = (i - m) * 0.25
        v[i] = _bil(gray, cx + r[i] * nx, cy + r[i] * ny, gox, goy)
        if np.isnan(v[i]):
            return np.nan
    i0 = -1
    best = np.inf
    outer = []
    for i in range(cnt):
        if abs(r[i]) <= 1.5 * sigma and v[i] < best:
            best = v[i]
            i0 = i
        if abs(r[i]) >= 3.5 * sigma:
            outer.append(v[i])
    if i0 < 0 or len(outer) == 0:
        return np.nan
    top = np.median(np.array(outer))
    if top - best < 5.0:
        return np.nan
    half = 0.5 * (top + best)
    hi = i0
    while hi < cnt - 1 and v[hi] < half:
        hi += 1
    lo = i0
    while lo > 0 and v[lo] < half:
        lo -= 1
    if v[hi] < half or v[lo] < half:
        return np.nan
    right = r[hi - 1] + (half - v[hi - 1]) / (v[hi] - v[hi - 1]) * (r[hi] - r[hi - 1])
    left = r[lo + 1] + (half - v[lo + 1]) / (v[lo] - v[lo + 1]) * (r[lo] - r[lo + 1])
    hw = 0.5 * (right - left)
    return hw if np.isfinite(hw) else np.nan


@numba.njit(cache=True, error_model="numpy")
def _flanks_nb(gray, cx, cy, nx, ny, gox, goy, sigma):
    """Grey level beside a line through (cx, cy) running across (nx, ny): the median
    of the samples 3.5 to 5 sigma out on both sides (NaN off the image)."""
    m = int(np.floor(5.0 * sigma / 0.5))
    outer = []
    for i in range(-m, m + 1):
        r = i * 0.5
        if abs(r) >= 3.5 * sigma:
            v = _bil(gray, cx + r * nx, cy + r * ny, gox, goy)
            if np.isnan(v):
                return np.nan
            outer.append(v)
    if len(outer) == 0:
        return np.nan
    return np.median(np.array(outer))


@numba.njit(cache=True, error_model="numpy")
def _gray_step_end_nb(p, arc, tx, ty, s_coarse, sigma, gray, gox, goy, s_min):
    """Arc position of a thin dark line's end: the half-level crossing of the
    strongest dark-to-bright step of the grey level along the path, searched from
    ``s_coarse + 0.75 sigma`` back to ``10 sigma`` before ``s_coarse`` (not beyond
    ``s_min``).

    The ravine of a Hessian potential outlives the line's end: at scale sigma it
    decays over about 2 sigma, and skin texture or a shadow in the line's
    prolongation keeps it at half depth for several pixels more (on the face
    model's renders the ravine of a furrow ran on up to 6 px past the drawn line's
    top, and never faded). The grey level steps from line to skin within a pixel
    or two. Returns NaN when no step of at least 5 grey levels is found.
    """
    w = max(2.0 * sigma, 2.0)
    reach = min(10.0 * sigma, -s_min)
    lo = s_coarse - reach - w
    hi = s_coarse + 0.75 * sigma + w
    if lo < s_min:
        lo = s_min
    cnt = int(np.floor((hi - lo) / 0.25)) + 1
    k = int(round(w / 0.25))
    if cnt < 2 * k + 2:
        return np.nan
    nx, ny = -ty, tx
    g = np.empty(cnt)
    ss = np.empty(cnt)
    for i in range(cnt):
        ss[i] = lo + i * 0.25
        x, y = _path_xy(p, arc, tx, ty, ss[i])
        acc = 0.0
        for o in (-0.5 * sigma, 0.0, 0.5 * sigma):
            v = _bil(gray, x + o * nx, y + o * ny, gox, goy)
            if np.isnan(v):
                return np.nan
            acc += v
        g[i] = acc / 3.0
    csum = np.zeros(cnt + 1)
    for i in range(cnt):
        csum[i + 1] = csum[i] + g[i]
    best = 5.0
    ib = -1
    for i in range(k, cnt - k + 1):
        if ss[i] > s_coarse + 0.75 * sigma:
            break
        d = (csum[i + k] - csum[i]) / k - (csum[i] - csum[i - k]) / k
        if d > best:
            best = d
            ib = i
    if ib < 0:
        return np.nan
    # a step in a line that merely weakens (a real furrow fading out, texture) is
    # no end: it must rise at least half-way from the line to the skin beside it
    # (on the face model's renders 0.5-0.9 of the way; on real furrows mostly less)
    cx, cy = _path_xy(p, arc, tx, ty, ss[ib] - w)
    rise = (best / (_flanks_nb(gray, cx, cy, nx, ny, gox, goy, sigma)
                    - (csum[ib] - csum[ib - k]) / k))
    if not 0.5 <= rise <= 1.5:
        return np.nan
    half = 0.5 * ((csum[ib + k] - csum[ib]) / k + (csum[ib] - csum[ib - k]) / k)
    # the half-level crossing next to the step
    j = ib
    while j > ib - k + 1 and g[j - 1] >= half:
        j -= 1
    while j < ib + k - 1 and g[j] < half:
        j += 1
    if g[j] == g[j - 1]:
        return ss[j]
    f = (half - g[j - 1]) / (g[j] - g[j - 1])
    f = min(max(f, 0.0), 1.0)
    return ss[j - 1] + f * 0.25


@numba.njit(cache=True, error_model="numpy")
def _refine_end_nb(p, P, ox, oy, sigma, inset, gray, gox, goy, has_gray, fan, step):
    n = p.shape[0]
    k = min(3, n - 1)
    tx = p[0, 0] - p[k, 0]
    ty = p[0, 1] - p[k, 1]
    norm = np.sqrt(tx * tx + ty * ty)
    if norm < 1e-9:
        return False, 0.0, 0.0
    tx /= norm
    ty /= norm
    if fan <= 0.0:
        ok, s_end, x, y = _refine_dir_nb(p, P, ox, oy, sigma, inset, gray, gox, goy,
                                         has_gray, tx, ty, step)
        return ok, x, y
    # a fan of directions around the tangent: the farthest end of the dark region
    best = -np.inf
    bx = 0.0
    by = 0.0
    found = False
    m = 6
    for j in range(-m, m + 1):
        a = fan * j / m
        ca, sa = np.cos(a), np.sin(a)
        ok, s_end, x, y = _refine_dir_nb(p, P, ox, oy, sigma, inset, gray, gox, goy,
                                         has_gray, ca * tx - sa * ty, sa * tx + ca * ty, step)
        # prefer the tangent itself among (nearly) equal reaches
        score = s_end - 0.05 * abs(j)
        if ok and score > best:
            best = score
            bx = x
            by = y
            found = True
    return found, bx, by


@numba.njit(cache=True, error_model="numpy")
def _refine_dir_nb(p, P, ox, oy, sigma, inset, gray, gox, goy, has_gray, tx, ty, step):
    n = p.shape[0]
    arc = np.zeros(n)
    for i in range(1, n):
        arc[i] = arc[i - 1] + np.sqrt((p[i, 0] - p[i - 1, 0]) ** 2 + (p[i, 1] - p[i - 1, 1]) ** 2)
    length = arc[n - 1]
    s_in = 0.45 * length if not inset else min(5.0 * sigma, 0.45 * length)
    s_out = 5.0 * sigma
    i_first = -int(np.floor(s_in / 0.25))
    i_last = int(np.floor(s_out / 0.25 + 1e-9))
    cnt = i_last - i_first + 1
    s = np.empty(cnt)
    v = np.empty(cnt)
    any_inside = False
    nx = -ty
    ny = tx
    off = 1.5 * sigma
    for i in range(cnt):
        s[i] = (i_first + i) * 0.25
        x, y = _path_xy(p, arc, tx, ty, s[i])
        v[i] = _bil(P, x, y, ox, oy)
        if s[i] <= 0 and not np.isnan(v[i]):
            any_inside = True
        elif s[i] > 0 and v[i] < 0 and not inset:
            # (thin lines) beyond the end only a ravine running along the tangent counts: its
            # flanks across are shallow; a line crossing the path (a furrow next to a
            # mouth corner) is as deep on both flanks and is not a continuation
            a = _bil(P, x + off * nx, y + off * ny, ox, oy)
            b = _bil(P, x - off * nx, y - off * ny, ox, oy)
            if not (a > 0.7 * v[i] and b > 0.7 * v[i]):
                v[i] = 0.0
    if not any_inside:
        return False, 0.0, 0.0, 0.0
    if inset:
        vals = []
        i0 = -1
        for i in range(cnt):
            if s[i] <= 0 and s[i] >= -2.5 * sigma and s[i] <= -1.0 * sigma:
                i0 = i
                if not np.isnan(v[i]):
                    vals.append(v[i])
        if i0 < 0 or len(vals) == 0:
            return False, 0.0, 0.0, 0.0
        depth = np.median(np.array(vals))
    else:
        i0 = -1
        depth = np.inf
        for i in range(cnt):
            if s[i] <= 0 and not np.isnan(v[i]) and v[i] < depth:
                depth = v[i]
                i0 = i
    if not np.isfinite(depth) or depth >= -1e-3:
        return False, 0.0, 0.0, 0.0
    half = 0.5 * depth
    # the end: the first rise above half depth after which the ravine does not come
    # back within 3 sigma (a gap, a highlight on a lip, is no end) and that rises on
    # to a quarter of the depth (a line that merely weakens has no end there)
    s_end = np.nan
    for m in range(i0 + 1, cnt):
        if np.isnan(v[m]) or np.isnan(v[m - 1]):
            break
        if not (v[m] > half and v[m - 1] <= half):
            continue
        f = (half - v[m - 1]) / (v[m] - v[m - 1])
        cand = s[m - 1] + f * (s[m] - s[m - 1])
        resumes = False
        fades = False
        for i in range(m, cnt):
            if s[i] > cand + 3.0 * sigma:
                break
            if np.isnan(v[i]):
                continue
            if v[i] <= half:
                resumes = True
                break
            if v[i] >= 0.25 * depth:
                fades = True
        if resumes:
            continue
        if fades:
            s_end = cand
        break
    if step and has_gray:
        # where the ravine never fades the search starts from the contour's end: the
        # grey step only ever moves an end back along the ravine (on real furrows,
        # which fade gradually, extending on a step made the contours wander)
        s_step = _gray_step_end_nb(p, arc, tx, ty, s_end if np.isfinite(s_end) else 0.0,
                                   sigma, gray, gox, goy, s[0])
        if np.isfinite(s_step):
            s_end = s_step
        if np.isfinite(s_end):
            # the half-level point of a round-capped stroke lies one half-width
            # beyond its centre line's end (one measurement, capped: the band's
            # two-step measurement below moved the real furrows' tops more)
            cx, cy = _path_xy(p, arc, tx, ty, s_end - 2.0 * sigma)
            hw = _half_width_nb(gray, cx, cy, tx, ty, gox, goy, sigma)
            if not np.isnan(hw):
                s_end -= min(hw, 2.0 * sigma)
    if not np.isfinite(s_end):
        return False, 0.0, 0.0, 0.0
    if inset and has_gray:
        # measure the width just behind the rounded cap of the band (whose radius is
        # the half-width itself): first 2 sigma inside, then half a sigma behind
        # the cap that this first estimate implies (a tapering band is narrower
        # near its end than 2 sigma inside)
        cx, cy = _path_xy(p, arc, tx, ty, s_end - 2.0 * sigma)
        hw = _half_width_nb(gray, cx, cy, tx, ty, gox, goy, sigma)
        if not np.isnan(hw):
            cx, cy = _path_xy(p, arc, tx, ty, s_end - hw - 0.5 * sigma)
            hw2 = _half_width_nb(gray, cx, cy, tx, ty, gox, goy, sigma)
            if not np.isnan(hw2):
                hw = hw2
            s_end -= hw
    x, y = _path_xy(p, arc, tx, ty, s_end)
    return True, s_end, x, y


class _ContourHead:
    """The contours' head frame at the nodes' current positions, computed only when
    asked for: where the irises or the features give the frame it is kept only in
    case a later frame has to fall back on the contours' motion (0.2 ms a frame)."""

    __slots__ = ("_X", "_starts", "_names", "_value", "_done")

    def __init__(self, system, names):
        self._X = system.X.copy()
        self._starts, self._names = system.starts, names
        self._done = False
        self._value = None

    @property
    def value(self) -> HeadFrame | None:
        if not self._done:
            self._value = _contours_head(self._X, self._starts, self._names)
            self._done = True
            self._X = None
        return self._value


def _contours_head(X, starts, names) -> HeadFrame | None:
    """:func:`~trackers.fiducials.head_frame` of the contours whose nodes are ``X``, or
    None where it cannot be computed."""
    try:
        return head_frame({n: X[starts[k]:starts[k + 1]] for k, n in enumerate(names)})
    except ValueError:
        return None


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
        Movement threshold that defines equilibrium: root-mean-square node
        displacement in a step, pixels.
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
    max_shape_change : float
        Largest change of shape (see :class:`ContourQuality`) before a contour is lost.
    brow_mid : float or 'apex'
        Where ``brow_mid_*`` sits along each eyebrow contour, as an arc-length
        fraction from the inner end (default :data:`BROW_MID_FRACTION` = 0.556).
        One definition for everyone: the brow's centre is the top of its arch,
        where the frontalis major lifts it; the face model puts its ``brow_mid``
        landmark there (the apex of the brow curve, about midway between the ends
        along the face's surface), which on its renders lies at 0.556 +- 0.01 of the
        brow's *image* arc length (five identities; the outer brow turns away from
        the camera and is foreshortened). Finding that apex on every face instead
        ('apex': a parabola fitted to the contour on the first frame, its fraction
        kept afterwards) is ill-conditioned on a flat arch: on the model's renders
        it lands 1.6-3.5 px away (mean 2.5 px over six expression sequences,
        against 1.1 px for the fixed fraction). A fixed fraction also follows the
        same piece of brow whatever the expression does to the arch.
    channel_order : {'rgb', 'bgr'}
    mouth_corner : {'profile', 'ends'}
        'profile' (default): ``mouth_corner_*`` are the lateral ends of the dark
        mouth line or cavity found by :func:`mouth_corners` around the upper-lip
        contour (with the mouth open the contour follows a border of the cavity and
        its ends fall short of the corners); where no clear end is found the last
        corner is kept, moved with the head frame. 'ends': the contour's ends (004).
    redetect : bool
        When three or more contours have been lost for three frames in a row, detect
        the face again (:func:`~trackers.layout.detect_layout`, at most every
        ``redetect_interval`` frames) and place all contours from it; kept only if
        fewer contours are lost afterwards. The head frame stays the irises' or the
        features' when they give it on that frame; otherwise it is the first frame's
        moved by the similarity between the two detections' eyes
        (``extra['head_source'] == 'detection'``).
    redetect_interval : int
        Least number of frames between two detections; doubled (up to 16 times)
        after each detection that finds no face or does not help.
    head_anchor : {'auto', 'eyes', 'features', 'contours'}
        How the head frame follows the head after the first frame. The first frame's
        frame is always :func:`~trackers.fiducials.head_frame` of the contours (004:
        hairline and nose). 'contours' recomputes it from the contours on every
        frame, as 004 does; but expressions move the hairline and the nostrils (in
        the face model the frontalis lifts the hairline ~2 mm in surprise, the
        nostrils move ~3 mm), so that frame moves with the expression and biases
        every fiducial displacement measured in it, and a contour that slides onto
        another feature (a hand) swings it. 'eyes' moves the first frame's frame by
        a similarity: scale and translation from the two irises
        (:class:`~trackers.anchors.IrisAnchors`; eyeballs sit in the skull),
        rotation from the turn of the line between the eyebrows' centroids (level
        under symmetric expressions; the irises' own line when a brow is lost). On
        frames where an iris is not found (closed eyes, occlusion) corner features
        on the eyes and nose take over (:class:`~trackers.head_motion.
        FeatureAnchors`, seeded on the last frame the irises gave; the irises are
        then looked for every :data:`IRIS_RETRY_EVERY` frames); where those do not
        agree either, the contours' frame-to-frame motion is chained on to the last
        frame the irises or features gave. 'features': the features alone, from the
        first frame on. 'auto' (default): 'eyes' when the layout has eye centres and
        both irises are found on the first frame, else 'features' when it has eye
        centres, else 'contours'. ``TrackResult.extra['head_source']`` says which
        was used per frame ('eyes', 'features', 'contours' or 'detection').

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
                 max_iter: int = 100, first_max_iter: int = 2000, lost_depth: float = 0.3,
                 stretch_range=(0.6, 1.6), refine_ends: bool = True,
                 max_step: float = 1.0, brow_mid=BROW_MID_FRACTION, max_shape_change: float = 0.15,
                 channel_order: str = "rgb", head_anchor: str = "auto",
                 mouth_corner: str = "profile", redetect: bool = True,
                 redetect_interval: int = 15):
        if not isinstance(layout, FaceLayout):
            raise ValueError(f"layout must be a FaceLayout, got {type(layout).__name__}")
        if params is None:
            params = SnakeParams()
        ok = strength in ("auto", "paper") or (
            isinstance(strength, int | float | np.floating | np.integer)
            and not isinstance(strength, bool) and np.isfinite(strength) and strength > 0)
        if not ok:
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
        if not (isinstance(brow_mid, str) and brow_mid == "apex") and not (
                isinstance(brow_mid, int | float) and 0.0 <= brow_mid <= 1.0):
            raise ValueError(f"brow_mid must be 'apex' or a fraction in [0, 1], got "
                             f"{brow_mid!r}")
        self.brow_mid = brow_mid
        if head_anchor not in ("auto", "eyes", "features", "contours"):
            raise ValueError(f"head_anchor must be 'auto', 'eyes', 'features' or 'contours', "
                             f"got {head_anchor!r}")
        if head_anchor in ("eyes", "features") and layout.eyes is None:
            raise ValueError(f"head_anchor={head_anchor!r} needs a layout with eye centres")
        self.head_anchor = head_anchor
        if mouth_corner not in ("profile", "ends"):
            raise ValueError(f"mouth_corner must be 'profile' or 'ends', got {mouth_corner!r}")
        self.mouth_corner_mode = mouth_corner
        self.mouth_width: float | None = None
        if int(redetect_interval) < 1:
            raise ValueError(f"redetect_interval must be >= 1, got {redetect_interval}")
        self.redetect = bool(redetect)
        self.redetect_interval = int(redetect_interval)
        self._failing = 0
        self._last_detect = 0
        self._redetect_wait = self.redetect_interval
        self._sim_cache: tuple | None = None
        self._corners_head: dict[str, np.ndarray] = {}
        self._corner_misses: dict[str, int] = {}
        self.anchors = None
        self.features: FeatureAnchors | None = None
        self._feature_base: HeadFrame | None = None
        self._last_gray: np.ndarray | None = None
        self._last_gray_index = -1
        self._feature_index = -1
        self._feature_cache: tuple = (-1, None)
        # the contours' head frame (a _ContourHead) on the last frame whose head frame
        # came from elsewhere, and that head frame: where the contours' motion is
        # chained on from
        self._anchor_base: tuple[_ContourHead, HeadFrame] | None = None
        self._ref_brow_angle: float | None = None
        self._brows_lost = False
        self._head_contours_lost = False
        self._held = 0
        self.head_source = "contours"
        if not np.isfinite(max_shape_change) or max_shape_change <= 0:
            raise ValueError(f"max_shape_change must be positive, got {max_shape_change}")
        self.max_shape_change = float(max_shape_change)
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
        self._lost_streak = dict.fromkeys(self.names, 0)
        self.specs = [(layout.contours[n].kind, float(layout.contours[n].sigma))
                      for n in self.names]
        contours = []
        for name in self.names:
            c = layout.contours[name]
            p0 = paper_equivalent_strength(c.sigma, params.p) if strength in ("auto", "paper") \
                else float(strength)
            contours.append(Contour(c.points, closed=c.closed, params=params, p=p0,
                                    field=len(contours), name=name, normal_forces=True))
        self.system = ContourSystem(contours, params, max_step=max_step)
        self.sigma_max = max(sig for _, sig in self.specs)
        self.index = 0
        self.ref_depth: dict[str, float] = {}
        self.ref_length: dict[str, float] = {}
        self.ref_shape: dict[str, np.ndarray] = {}
        self.ref_head: HeadFrame | None = None
        self.brow_fraction: dict[str, float] | None = None
        self.last_head: HeadFrame | None = None
        self.frame_size = tuple(layout.image_size)
        self._clipped: set[int] = set()
        iod = layout.inter_eye
        self.motion_margin = max(6.0, 0.08 * iod) + 2.0 * self.sigma_max

    # ------------------------------------------------------------------ helpers
    def _fields(self, frame):
        """Per-contour potentials (each in a box around its contour) and their origins."""
        img = np.asarray(frame)
        if img.ndim < 2:
            raise ValueError(f"frame {self.index}: must be 2-D or 3-D, got shape {img.shape}")
        H, W = img.shape[:2]
        if self.frame_size != (W, H):
            raise ValueError(f"frame {self.index} is {W}x{H} but the layout was made for "
                             f"{self.frame_size[0]}x{self.frame_size[1]}")
        X = self.system.X
        # nodes pushed out of the frame (by the image force or a re-initialisation)
        # are put back on its border; their contour is reported lost this frame
        out = (X[:, 0] < 0) | (X[:, 1] < 0) | (X[:, 0] > W - 1) | (X[:, 1] > H - 1)
        self._clipped = set()
        if out.any():
            for k in np.unique(self.system.node_contour[out]):
                self._clipped.add(int(k))
            np.clip(X[:, 0], 0, W - 1, out=X[:, 0])
            np.clip(X[:, 1], 0, H - 1, out=X[:, 1])
        m = self.motion_margin
        lo = np.floor(X.min(0) - m).astype(int)
        hi = np.ceil(X.max(0) + m).astype(int) + 1
        pad = int(np.ceil(3 * self.sigma_max)) + 3
        X0, Y0 = max(lo[0] - pad, 0), max(lo[1] - pad, 0)
        X1, Y1 = min(hi[0] + pad, W), min(hi[1] + pad, H)
        try:
            gray = to_gray(img[Y0:Y1, X0:X1], channel_order=self.channel_order)
        except ValueError as exc:
            raise ValueError(f"frame {self.index}: {exc}") from None
        gh, gw = gray.shape
        bx = np.empty((len(self.names), 4), np.int64)
        _boxes_nb(X, self.system.starts, float(m), int(X0), int(Y0), gw, gh, bx)
        boxes = [tuple(int(v) for v in b) for b in bx]
        origins = np.c_[bx[:, 0] + X0, bx[:, 1] + Y0].astype(np.float64)
        Ps = potentials_in_boxes(gray, self.specs, boxes)
        return Ps, origins, gray, (float(X0), float(Y0))

    def _depths(self, Ps, origins):
        out = {}
        X, st = self.system.X, self.system.starts
        for k, name in enumerate(self.names):
            pts = X[st[k]:st[k + 1]]
            out[name] = float(_mean_depth_nb(Ps[k], pts, float(origins[k][0]),
                                             float(origins[k][1])))
        return out

    def _auto_strength(self, Ps, origins):
        gdt = self.params.gamma / self.params.dt
        for k, name in enumerate(self.names):
            c = self.layout.contours[name]
            pts = self.system.X[self.system.contour_slice(k)]
            P, origin = Ps[k], origins[k]
            tang = np.gradient(pts, axis=0)
            tang /= np.maximum(np.hypot(*tang.T), 1e-9)[:, None]
            nrm = np.c_[-tang[:, 1], tang[:, 0]]
            # the curvature at the bottom of the ravine each node lies in (down its
            # normal profile, at most 3 sigma): a contour that stopped on the
            # ravine's flank (the first relaxation stops each contour on its own
            # slow step) would measure a flatter curvature there and get a
            # strength that oscillates once it reaches the bottom
            h = max(0.5 * c.sigma, 0.75)
            m = max(int(np.ceil(3.0 * c.sigma / h)), 1)
            t = np.arange(-m - 1, m + 2) * h
            prof = _sample_safe(P, (pts[:, None, :] + t[None, :, None] * nrm[:, None, :])
                                .reshape(-1, 2), origin).reshape(len(pts), len(t))
            rows = np.arange(len(pts))
            mid = np.full(len(pts), m + 1)
            vals = np.where(np.isfinite(prof), prof, np.inf)
            for _ in range(m):
                # down the profile to the bottom of the ravine the node lies in
                lo, hi = vals[rows, mid - 1], vals[rows, mid + 1]
                here = vals[rows, mid]
                step = np.where((lo < here) & (lo <= hi), -1, np.where(hi < here, 1, 0))
                step[(mid + step < 1) | (mid + step > 2 * m + 1)] = 0
                mid = mid + step
            curv = (prof[rows, mid + 1] + prof[rows, mid - 1] - 2 * prof[rows, mid]) / h**2
            curv = curv[np.isfinite(curv) & (curv > 0)]
            p_paper = paper_equivalent_strength(c.sigma, self.params.p)
            if len(curv) < 3:
                p = p_paper
            else:
                # the steep end of the distribution sets the rate: stability first
                p = self.descent_rate * gdt / float(np.percentile(curv, 90))
                p = float(np.clip(p, 0.1 * p_paper, 100 * p_paper))
            self.system.set_strength(k, p)

    def _refine(self, Ps, origins, gray, gorigin, settle=False):
        if not self.refine_ends:
            return
        X, st = self.system.X, self.system.starts
        g = np.ascontiguousarray(gray, dtype=np.float32)
        gox, goy = float(gorigin[0]), float(gorigin[1])
        for k, name in enumerate(self.names):
            c = self.layout.contours[name]
            if c.ends == "free":
                continue
            pts = X[st[k]:st[k + 1]]
            n = len(pts)
            new = pts
            P = np.ascontiguousarray(Ps[k], dtype=np.float32)
            ox, oy = origins[k]
            sigma = float(c.sigma)
            for end in (0, -1):
                mode = c.end_modes[0 if end == 0 else 1]
                if mode == "free":
                    continue
                # refine_end without its checks: same kernel, same arguments
                ref = np.ascontiguousarray(new if end == 0 else new[::-1])
                ok, x, y = _refine_end_nb(ref, P, float(ox), float(oy), sigma,
                                          mode == "centre", g, gox, goy, True,
                                          _CORNER_FAN if mode == "corner" else 0.0,
                                          mode == "line")
                if not ok:
                    continue
                ref = _move_end_nb(ref, x, y, sigma, bool(settle))
                if ref.shape[0] == 0:
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

    def _redetect(self, frame, n_lost, anchored=None):
        """Place all contours again from a new face detection (many contours lost for
        several frames: a turned head, a hand over the face). Kept only when fewer
        contours are lost afterwards; returns (quality, head, iterations) or None.
        ``anchored``: this frame's head frame when the irises or the features gave it;
        it is kept rather than replaced by the detection's."""
        # faces much smaller than the tracked one are not searched for (the Haar
        # cascade's cost is in its small scales); the contours' own relaxation then
        # fits the template, so the detector's grid refinement is skipped
        iod = self.layout.inter_eye
        if self.last_head is not None and self.ref_head is not None:
            iod *= self.last_head.scale / self.ref_head.scale
        try:
            new = detect_layout(frame, frame_index=self.index,
                                channel_order=self.channel_order, refine=True,
                                min_face=max(40, int(1.2 * iod)))
        except ValueError:
            self._redetect_wait = min(2 * self._redetect_wait, 16 * self.redetect_interval)
            return None
        if new.eyes is None or self.layout.eyes is None or self.ref_head is None:
            return None
        saved = [self.system.contour_points(k).copy() for k in range(len(self.names))]
        for k, name in enumerate(self.names):
            c = new.contours[name]
            n = self.system.contour_slice(k).stop - self.system.contour_slice(k).start
            self.system.set_contour(k, resample_polyline(c.points, n, closed=c.closed),
                                    reset_rest=True)
        Ps, origins, gray, gorigin = self._fields(frame)
        r = self.system.relax(potentials=Ps, origin=origins, tol=self.tol,
                              max_iter=self.max_iter, criterion="rms")
        self._refine(Ps, origins, gray, gorigin, settle=True)
        depths = self._depths(Ps, origins)
        quality = self._quality(depths, r.outside, set(self.names))
        if sum(q.lost for q in quality.values()) >= n_lost:
            for k, pts in enumerate(saved):
                self.system.set_contour(k, pts, reset_rest=True)
            # no better: try again later, less and less often
            self._redetect_wait = min(2 * self._redetect_wait, 16 * self.redetect_interval)
            return None
        self._redetect_wait = self.redetect_interval
        if anchored is not None:
            # the irises or features followed the head through whatever lost the
            # contours; two detections' eyes (Haar boxes, or where the face box puts
            # them) turned WolfgangLanger's frame by 5 and 3.5 degrees at frames 136
            # and 231, for the rest of the video
            head = anchored
        else:
            # the first frame's moved by the similarity between the eyes of the two
            # detections; the features are seeded again on this frame from it
            a, b = similarity_from_pairs(self.layout.eyes, new.eyes)
            head = _apply_similarity(self.ref_head, a, b)
            self.head_source = "detection"
            if self.anchors is not None:
                self._move_iris_search(head)
            self.features = None
            self._feature_cache = (self.index, head)
            self._keep_gray(frame)
        # the contours' later motion is chained on from here
        self._anchor_base = (_ContourHead(self.system, self.names), head)
        self._held = 0
        self._brows_lost = quality["brow_l"].lost or quality["brow_r"].lost
        self._head_contours_lost = quality["hairline"].lost or quality["nose_tip"].lost
        return quality, head, r.iterations

    def _quality(self, depths, outside, reinit=()):
        q = {}
        X, st = self.system.X, self.system.starts
        for k, name in enumerate(self.names):
            pts = X[st[k]:st[k + 1]]
            closed = self.layout.contours[name].closed
            depth = depths[name] / max(self.ref_depth.get(name, depths[name]), 1e-9)
            stretch = _polyline_length(pts, closed) / max(self.ref_length.get(
                name, _polyline_length(pts, closed)), 1e-9)
            shape = _shape_change(pts, self.ref_shape[name], closed) \
                if name in self.ref_shape else 0.0
            lost = (not np.isfinite(pts).all() or depth < self.lost_depth
                    or not self.stretch_range[0] <= stretch <= self.stretch_range[1]
                    or shape > self.max_shape_change
                    or bool(outside[k]) or k in self._clipped)
            q[name] = ContourQuality(float(depth), float(stretch), bool(lost), name in reinit,
                                     float(shape))
        return q

    def _head(self, frame, first=False):
        """Head frame of this frame (see the class docstring, ``head_anchor``)."""
        hc = _ContourHead(self.system, self.names)
        if first:
            self.head_source = "contours"
            if self.head_anchor in ("auto", "eyes") and self.layout.eyes is not None:
                try:
                    self.anchors = IrisAnchors(frame, self.layout.eyes,
                                               channel_order=self.channel_order)
                except ValueError:
                    if self.head_anchor == "eyes":
                        raise
                    self.anchors = None
            if hc.value is not None:
                self._anchor_base = (hc, hc.value)
            self._ref_brow_angle = _brow_angle(self.system, self.names)
            self._keep_gray(frame)
            return hc.value if hc.value is not None else self.last_head
        # the irises first; while the features stand in for them, searched for only
        # every few frames (a search that fails costs as much as the features)
        if self.anchors is not None and self.ref_head is not None and (
                self.features is None or self.index % IRIS_RETRY_EVERY == 0):
            head = self._iris_head(frame, hc)
            if head is not None:
                self.head_source = "eyes"
                self._anchor_base = (hc, head)
                self.features = None  # seeded again from here when the irises go
                self._keep_gray(frame)
                return head
        head = self._feature_head(frame)
        if head is not None:
            self.head_source = "features"
            self._anchor_base = (hc, head)
            if self.anchors is not None:
                self._move_iris_search(head)
            return head
        fallback = self._chained(hc)
        if fallback is not None and self.anchors is not None:
            self._move_iris_search(fallback)
        self.head_source = "contours"
        self._keep_gray(frame)
        return fallback

    def _keep_gray(self, frame):
        """Keep this frame's 8-bit grey while the features may be seeded on it."""
        if self._features_wanted():
            self._last_gray = gray_u8(frame, self.channel_order)
            self._last_gray_index = self.index

    def _features_wanted(self):
        return self.head_anchor != "contours" and self.layout.eyes is not None

    def _move_iris_search(self, head):
        """Search the irises next where ``head`` puts them."""
        self.anchors.last = head.to_image(self.ref_head.to_head(self.anchors.centres))

    def _iris_head(self, frame, hc):
        """Head frame from the irises, or None (not found, or implausible)."""
        # search around the irises last found (a wider window after a miss)
        wide = self.head_source != "eyes"
        if self._sim_cache is not None and self._sim_cache[0] == self.index:
            sim = self._sim_cache[1]  # the irises do not depend on the contours
        else:
            sim = self.anchors.similarity(
                frame, None, search=3.0 * self.anchors.radius if wide else None)
            self._sim_cache = (self.index, sim)
        if sim is not None and self._ref_brow_angle is not None and not self._brows_lost:
            # the brow line's turn, unless it disagrees with the irises' (a brow
            # contour that slid away)
            rot = _brow_angle(self.system, self.names) - self._ref_brow_angle
            rot = (rot + np.pi) % (2 * np.pi) - np.pi
            if abs(rot - np.angle(sim[0])) < 0.05:
                sim = self.anchors.similarity_with_rotation(sim, rot)
        if sim is None:
            return None
        head = _apply_similarity(self.ref_head, *sim)
        return head if self._plausible(head, hc) else None

    def _feature_head(self, frame):
        """Head frame from the features on the eyes and nose (:class:`~trackers.
        head_motion.FeatureAnchors`), seeded on the last frame whose head frame came
        from elsewhere; None when they do not agree or the frame jumps."""
        if not self._features_wanted() or self.last_head is None or self.ref_head is None:
            return None
        if self._feature_cache[0] == self.index:
            return self._feature_cache[1]  # asked again after contours were re-placed
        head = self._follow_features(frame)
        self._feature_cache = (self.index, head)
        return head

    def _follow_features(self, frame):
        if self.features is None or self._feature_index != self.index - 1:
            if self._last_gray is None or self._last_gray_index != self.index - 1:
                return None
            eyes = self.last_head.to_image(self.ref_head.to_head(self.layout.eyes))
            try:
                self.features = FeatureAnchors(self._last_gray, eyes)
            except ValueError:
                self.features = None
                return None
            self._feature_base = self.last_head
        self._feature_index = self.index
        self._last_gray = None
        sim = self.features.similarity(gray_u8(frame, self.channel_order))
        if sim is None:
            self.features = None
            return None
        head = _apply_similarity(self._feature_base, *sim)
        if not self._plausible(head, None):
            self.features = None
            return None
        return head

    def _plausible(self, head, hc):
        """Whether a head frame from the irises agrees with the contours' frame (``hc``,
        a :class:`_ContourHead`, or None to skip that check: scale, roll) and with the
        last frame (a drifted iris match jumps)."""
        def turn(a, b):
            return abs((a - b + np.pi) % (2 * np.pi) - np.pi)

        hc = hc.value if hc is not None and not self._head_contours_lost else None
        if hc is not None and (
                abs(head.scale / hc.scale - 1) > 0.12 or turn(head.roll, hc.roll) > 0.1):
            # expressions change the contours' scale by a few per cent, no more
            return False
        last = self.last_head
        if last is not None:
            tight = self.head_source == "eyes"
            ds, dp, dr = (0.04, 0.1, 0.05) if tight else (0.1, 0.2, 0.1)
            if (abs(head.scale / last.scale - 1) > ds or turn(head.roll, last.roll) > dr
                    or np.hypot(head.x - last.x, head.y - last.y) > dp * last.scale):
                return False
        return True

    def _chained(self, lazy):
        """Fallback frame: the contours' motion (``lazy``, this frame's
        :class:`_ContourHead`) since the last frame the irises or features gave."""
        hc = lazy.value
        if hc is None or self._head_contours_lost:
            # the frame's own contours are unreliable: hold the last frame
            return self.last_head if self.last_head is not None else hc
        hc0 = self._anchor_base[0].value if self._anchor_base is not None else None
        if hc0 is None:
            return hc
        # the contours' motion since the last frame whose frame the irises gave
        h0 = self._anchor_base[1]
        a, b = _similarity_between(hc0, hc)
        moved = _apply_similarity(h0, a, b)
        # a contour frame that jumped (a hairline contour on a hand, the nose contour
        # on a nostril's edge) is not followed: the last frame is held instead
        if abs(abs(a) - 1) > 0.08 or abs(np.angle(a)) > 0.1 \
                or np.hypot(moved.x - h0.x, moved.y - h0.y) > 0.25 * h0.scale:
            self._held += 1
            if self._held <= 5 and self.last_head is not None:
                return self.last_head
            # the contours have settled elsewhere for good: start over from them
            self._anchor_base = (lazy, hc)
            self._held = 0
            return hc
        self._held = 0
        return moved

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
        Ps, origins, gray, gorigin = self._fields(frame)
        cap = self.first_max_iter if first else self.max_iter

        def relax():
            # the first frame settles each contour strictly (its largest move): a
            # contour stops at its own equilibrium instead of creeping along its
            # feature until the slowest one stops, which made where it ended depend
            # on all the others. Later frames stop on the root-mean-square move,
            # which a few nodes creeping along a weak feature cannot hold up
            return self.system.relax(potentials=Ps, origin=origins, tol=self.tol,
                                     max_iter=cap, criterion="each" if first else "rms")

        res = relax()
        iters = res.iterations
        if first and self.strength_mode == "auto":
            self._auto_strength(Ps, origins)
            if self.system.outside_fields([P.shape for P in Ps], origins).any():
                # the first frame's long settling carried nodes out of their boxes,
                # where the next relaxation would refuse to start: new boxes
                Ps, origins, gray, gorigin = self._fields(frame)
            res = relax()
            iters += res.iterations
        self._refine(Ps, origins, gray, gorigin, settle=first)
        if first and self.refine_ends:
            # the first frame moves the ends farthest: settle and relocate once more
            # (on fields around the relocated contours)
            Ps, origins, gray, gorigin = self._fields(frame)
            iters += relax().iterations
            self._refine(Ps, origins, gray, gorigin, settle=True)
        outside = res.outside
        depths = self._depths(Ps, origins)
        if first:
            for k, name in enumerate(self.names):
                self.ref_depth[name] = depths[name]
                self.ref_length[name] = _polyline_length(
                    self.system.contour_points(k), self.layout.contours[name].closed)
                self.ref_shape[name] = self.system.contour_points(k)
        quality = self._quality(depths, outside)
        self._brows_lost = quality["brow_l"].lost or quality["brow_r"].lost
        self._head_contours_lost = quality["hairline"].lost or quality["nose_tip"].lost
        head = self._head(frame, first)
        lost = [k for k, n in enumerate(self.names) if quality[n].lost]
        for n in self.names:
            self._lost_streak[n] = self._lost_streak[n] + 1 if quality[n].lost else 0
        # a contour lost frame after frame (the chin below the picture, a hand held over
        # the mouth) is re-placed on its 1st, 2nd, 4th, 8th... lost frame, at least every
        # REINIT_EVERY frames: each re-placement costs a second relaxation of all contours
        lost = [k for k in lost if _retry_now(self._lost_streak[self.names[k]])]
        reinit = set()
        if lost and not first:
            base = self.last_head if quality["hairline"].lost or quality["nose_tip"].lost \
                else head
            for k in lost:
                self.system.set_contour(k, self._layout_points(k, base), reset_rest=True)
                reinit.add(self.names[k])
            # the new positions need their own boxes
            Ps, origins, gray, gorigin = self._fields(frame)
            r3 = relax()
            iters += r3.iterations
            self._refine(Ps, origins, gray, gorigin, settle=True)
            outside = r3.outside
            depths = self._depths(Ps, origins)
            quality = self._quality(depths, outside, reinit)
            self._brows_lost = quality["brow_l"].lost or quality["brow_r"].lost
            self._head_contours_lost = quality["hairline"].lost or quality["nose_tip"].lost
            head = self._head(frame)
        if not first:
            n_lost = sum(q.lost for q in quality.values())
            self._failing = self._failing + 1 if n_lost >= 3 else 0
            if (self.redetect and self._failing >= 3
                    and self.index - self._last_detect >= self._redetect_wait):
                self._last_detect = self.index
                got = self._redetect(frame, n_lost, head if self.head_source in (
                    "eyes", "features") else None)
                if got is not None:
                    quality, head, more = got
                    iters += more
        if first and head is not None:
            self.ref_head = head
            self.brow_fraction = {}
            cont = {n: self.system.contour_points(k) for k, n in enumerate(self.names)}
            axis = brow_axis_frame(cont, head)
            for side in ("l", "r"):
                b = cont[f"brow_{side}"]
                if abs(head.to_head(b[:1])[0, 0]) > abs(head.to_head(b[-1:])[0, 0]):
                    b = b[::-1]
                self.brow_fraction[side] = apex_fraction(b, axis) \
                    if self.brow_mid == "apex" else float(self.brow_mid)
        if head is None:
            raise ValueError(f"frame {self.index}: no head frame could be computed")
        self.last_head = head
        contours = {n: self.system.contour_points(k) for k, n in enumerate(self.names)}
        fids = fiducials(contours, head, brow_mid_fraction=self.brow_fraction)
        if self.mouth_corner_mode == "profile" and not quality["upper_lip"].lost:
            lip = contours["upper_lip"]
            width = None
            if self.mouth_width is not None and self.ref_head is not None:
                width = self.mouth_width * head.scale / self.ref_head.scale
            ex = np.array(head.axes[0])
            names = ["mouth_corner_l" if (e - lip.mean(axis=0)) @ ex > 0 else "mouth_corner_r"
                     for e in (lip[0], lip[-1])]
            # a corner narrows the next search only while it is fresh: one carried on
            # for frames (a hand over the mouth) would hold the search at a height
            # where the mouth no longer is, and no corner would be found again
            previous = [None if self._corners_head.get(n) is None
                        or self._corner_misses.get(n, 0) > 1
                        else head.to_image(self._corners_head[n][None])[0] for n in names]
            corners = mouth_corners(gray, lip, origin=gorigin, width=width, previous=previous,
                                    sigma=0.5 * float(self.layout.contours["upper_lip"].sigma))
            reach = 0.25 * max(_polyline_length(lip), width or 0.0)
            for c, e, name in zip(corners, (lip[0], lip[-1]), names):
                if c is None or np.hypot(*(c - e)) > reach:
                    # no clear end of the mouth this frame (a highlight, a lip pressed
                    # on the teeth): keep the last corner, moved with the head (the
                    # contour's end can be far off: 35 px on a rendered AU 15)
                    self._corner_misses[name] = self._corner_misses.get(name, 0) + 1
                    last = self._corners_head.get(name)
                    if last is not None:
                        q = head.to_image(last[None])[0]
                        fids[name] = (float(q[0]), float(q[1]))
                    continue
                self._corner_misses[name] = 0
                fids[name] = (float(c[0]), float(c[1]))
                self._corners_head[name] = head.to_head(np.asarray(c, float)[None])[0]
            if first:
                self.mouth_width = float(np.hypot(*np.subtract(fids["mouth_corner_l"],
                                                               fids["mouth_corner_r"])))
        elif self.mouth_corner_mode == "profile":
            for name in ("mouth_corner_l", "mouth_corner_r"):
                self._corner_misses[name] = self._corner_misses.get(name, 0) + 1
        out = TrackResult(self.index, contours, quality, int(iters), bool(res.converged),
                          head, fids, {"head_source": self.head_source})
        self.index += 1
        return out

    def run(self, frames):
        """Generator of :class:`TrackResult` for an iterable of frames."""
        for frame in frames:
            yield self.track(frame)
