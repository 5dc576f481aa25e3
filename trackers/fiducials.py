"""Head reference frame and the 11 fiducial points of 004 (V-D), from the contours.

All points are image pixels (x right, y down, origin at the top-left pixel's
centre); ``_l`` is the subject's left, which is on the image's right in an unmirrored
frontal view.

Head frame (004: "a head reference frame from the average position of the hairline
contour"):

* origin: the arc-length centroid of the hairline contour, moved along the head's
  x axis onto the face's midline (the head-vertical line through the midpoints of
  the brows, of the furrows and of the mouth corners, where it crosses the
  hairline). A contour on an edge cannot see motion along the edge, so the
  hairline's own centroid would not follow a sideways head motion; its height does;
* roll: the mean direction of the line from the right to the left eyebrow's
  centroid and of the line joining the mouth corners (both pointing to the
  subject's left, image right when upright), as ``atan2(dy, dx)`` in image
  coordinates (0 for an upright face, positive when the subject's left side is lower
  in the image). The hairline's principal axis is used only when those contours are
  absent: it tilts when the contour slides along the hairline (free ends);
* scale: the distance in pixels from the origin to the centroid of the nose-tip
  contour (hairline and nose barely move with expressions). It is a length in
  pixels, not a physical unit; divide positions by it to factor out zoom.

Fiducials:

* ``brow_inner_*`` / ``brow_outer_*``: the ends of each eyebrow contour nearer to /
  farther from the facial midline (measured along the head frame's x axis);
* ``brow_mid_*``: the eyebrow's centre point, taken as the apex of its arch (the top
  of a parabola fitted to the contour in the head frame) on the reference (neutral)
  frame, and then as the point at the same fraction of the contour's arc length on
  later frames, so that it follows the same piece of brow when the arch changes
  shape (pass ``brow_mid_fraction``; :class:`~trackers.tracking.Tracker` does).
  Without a fraction the apex of the current frame is used; a brow without an arch
  falls back to its arc-length middle;
* ``mouth_corner_*``: the two ends of the upper-lip contour;
* ``furrow_top_*``: the upper end (in the head frame) of each nasolabial furrow contour;
* ``chin``: the centroid of the chin-boss contour (area centroid when closed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from trackers.polyline import _arc_length_nb, _interp_at_nb

__all__ = ["FIDUCIAL_NAMES", "HeadFrame", "head_frame", "fiducials", "arc_point",
           "centroid", "apex_fraction", "brow_axis_frame"]

FIDUCIAL_NAMES = ("brow_inner_l", "brow_mid_l", "brow_outer_l", "brow_inner_r", "brow_mid_r",
                  "brow_outer_r", "mouth_corner_l", "mouth_corner_r", "furrow_top_l",
                  "furrow_top_r", "chin")


@dataclass(frozen=True)
class HeadFrame:
    """Head reference frame in the image.

    Attributes
    ----------
    x, y : float
        Origin, pixels.
    scale : float
        Reference length, pixels (hairline-to-nose distance).
    roll : float
        In-plane rotation, radians (0 upright).
    """

    x: float
    y: float
    scale: float
    roll: float

    @property
    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors (image coordinates) of the head's x (subject's left) and y (down)."""
        c, s = math.cos(self.roll), math.sin(self.roll)
        return np.array([c, s]), np.array([-s, c])

    def to_head(self, points) -> np.ndarray:
        """Image points (N, 2) -> head coordinates in units of ``scale``."""
        p = np.asarray(points, float) - [self.x, self.y]
        ex, ey = self.axes
        return np.stack([p @ ex, p @ ey], axis=-1) / self.scale

    def to_image(self, points) -> np.ndarray:
        """Head coordinates (N, 2) in units of ``scale`` -> image points."""
        q = np.asarray(points, float) * self.scale
        ex, ey = self.axes
        return q[..., :1] * ex + q[..., 1:2] * ey + [self.x, self.y]

    def as_dict(self) -> dict:
        """``head_x, head_y, head_scale, head_roll`` as in contractions.csv."""
        return {"head_x": self.x, "head_y": self.y, "head_scale": self.scale,
                "head_roll": self.roll}


def _points(contours, name):
    if name not in contours:
        raise ValueError(f"contours lack {name!r} (have {sorted(contours)})")
    p = np.asarray(contours[name], float)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2:
        raise ValueError(f"contour {name!r} must have shape (n >= 2, 2), got {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError(f"contour {name!r} has NaN or infinite coordinates")
    return p


def centroid(points, *, closed: bool = False) -> np.ndarray:
    """Arc-length centroid of a polyline, or area centroid of a closed polygon.

    Examples
    --------
    >>> centroid([[0, 0], [2, 0], [2, 2], [0, 2]], closed=True)
    array([1., 1.])
    >>> centroid([[0, 0], [1, 0], [4, 0]])
    array([2., 0.])
    """
    p = np.asarray(points, float)
    if closed:
        q = np.roll(p, -1, axis=0)
        cross = p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]
        area = cross.sum() / 2
        if abs(area) > 1e-9:
            return np.array([((p[:, 0] + q[:, 0]) * cross).sum(),
                             ((p[:, 1] + q[:, 1]) * cross).sum()]) / (6 * area)
        p = np.vstack([p, p[:1]])
    seg = np.hypot(*np.diff(p, axis=0).T)
    if seg.sum() <= 0:
        return p.mean(axis=0)
    mid = 0.5 * (p[1:] + p[:-1])
    return (mid * seg[:, None]).sum(axis=0) / seg.sum()


def arc_point(points, fraction: float) -> np.ndarray:
    """Point at ``fraction`` (0..1) of a polyline's arc length.

    Examples
    --------
    >>> arc_point([[0, 0], [1, 0], [4, 0]], 0.5)
    array([2., 0.])
    """
    p = np.ascontiguousarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 1:
        raise ValueError(f"points must have shape (n >= 1, 2), got {p.shape}")
    out = np.empty((1, 2))
    _arc_point_nb(p, float(fraction), out)
    return out[0]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _arc_point_nb(p, fraction, out):
    # np.interp(fraction * length, arc, p[:, c]), value for value (the fiducials and
    # the extra measurement points take a few of these a frame)
    s = _arc_length_nb(p)
    _interp_at_nb(p, s, fraction * s[s.shape[0] - 1], 0, out, 0)


def apex_fraction(points, head: HeadFrame) -> float:
    """Arc-length fraction (0..1) of the top of a contour's arch in the head frame.

    A parabola ``v = a u**2 + b u + c`` is fitted to the nodes in head coordinates
    (u along the head's x axis, v down) and refitted twice on the nodes nearer to its
    apex ``u = -b / 2a``, which is then located on the contour. Returns 0.5 when the
    contour does not arch upward.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.linspace(0, 30, 31)  # an arch whose top is at x = 10 (y down)
    >>> round(apex_fraction(np.c_[x, 0.02 * (x - 10) ** 2], HeadFrame(0, 0, 1, 0)), 2)
    0.32
    """
    p = np.asarray(points, float)
    q = head.to_head(p)
    u, v = q[:, 0], q[:, 1]
    if len(p) < 3 or np.ptp(u) <= 0:
        return 0.5
    ustar = None
    sel = np.ones(len(u), bool)
    half_range = 0.5 * np.ptp(u)
    for _ in range(3):
        # refit around the current apex: a projected arch is not a symmetric parabola
        if sel.sum() < 5:
            break
        um = u[sel].mean()
        a, b, _ = np.polyfit(u[sel] - um, v[sel], 2)
        if a <= 1e-12:
            break
        cand = -b / (2 * a) + um
        if not u.min() < cand < u.max():
            break
        ustar = cand
        half_range *= 0.7
        sel = np.abs(u - ustar) <= half_range
    if ustar is None:
        return 0.5
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    # first crossing of u = ustar along the contour
    d = u - ustar
    for i in range(len(d) - 1):
        if d[i] == 0 or d[i] * d[i + 1] < 0:
            t = 0.0 if d[i] == 0 else d[i] / (d[i] - d[i + 1])
            return float((s[i] + t * (s[i + 1] - s[i])) / s[-1])
    return 0.5


def brow_axis_frame(contours, head: HeadFrame) -> HeadFrame:
    """``head`` turned so that its x axis runs from the right to the left brow centroid.

    The apex of an eyebrow's arch is measured in this frame: it is symmetric for a
    symmetric face whatever the free ends of the hairline did.
    """
    d = centroid(_points(contours, "brow_l")) - centroid(_points(contours, "brow_r"))
    return HeadFrame(head.x, head.y, head.scale, math.atan2(d[1], d[0]))


def head_frame(contours) -> HeadFrame:
    """Head reference frame from the hairline and nose-tip contours.

    Parameters
    ----------
    contours : mapping name -> (n, 2) array
        Needs ``hairline`` and ``nose_tip``; the brows, furrows and ``upper_lip`` are
        used for the midline and the roll when present.

    Returns
    -------
    HeadFrame

    Examples
    --------
    >>> import numpy as np
    >>> x = np.linspace(-40, 40, 21)
    >>> hf = head_frame({"hairline": np.c_[100 + x, 50 + 0.01 * x**2],
    ...                  "nose_tip": np.c_[np.linspace(90, 110, 5), np.full(5, 150.0)]})
    >>> round(hf.roll, 6), round(hf.x, 6), round(hf.scale) > 90
    (0.0, 100.0, True)
    """
    hair = _points(contours, "hairline")
    nose = _points(contours, "nose_tip")
    origin = centroid(hair)
    # principal axis of the hairline nodes, weighted by arc length
    seg = np.hypot(*np.diff(hair, axis=0).T)
    mid = 0.5 * (hair[1:] + hair[:-1]) - origin
    w = seg / max(seg.sum(), 1e-12)
    cov = (mid * w[:, None]).T @ mid
    evals, evecs = np.linalg.eigh(cov)
    axis = evecs[:, np.argmax(evals)]
    nose_c = centroid(nose)
    down = nose_c - origin
    # orient the x axis so that the nose is below (+y) in the head frame
    if axis[0] * down[1] - axis[1] * down[0] < 0:
        axis = -axis
    angles = [math.atan2(axis[1], axis[0])]
    mids = []
    for a_name, b_name, kind in (("brow_l", "brow_r", "centroid"),
                                 ("furrow_l", "furrow_r", "centroid"),
                                 ("upper_lip", None, "ends")):
        if a_name not in contours or (b_name is not None and b_name not in contours):
            continue
        if kind == "centroid":
            pl = centroid(_points(contours, a_name))
            pr = centroid(_points(contours, b_name))
        else:
            lip = _points(contours, a_name)
            pl, pr = (lip[-1], lip[0]) if (lip[-1] - lip[0]) @ axis > 0 else (lip[0], lip[-1])
        d = pl - pr
        if a_name.startswith("brow") or kind == "ends":
            angles.append(math.atan2(d[1], d[0]))
        mids.append(0.5 * (pl + pr))
    if len(angles) > 1:
        angles = angles[1:]  # the hairline's axis tilts when the contour slides along it
    roll = math.atan2(sum(math.sin(a) for a in angles), sum(math.cos(a) for a in angles))
    ex = np.array([math.cos(roll), math.sin(roll)])
    # along the hairline the contour cannot see motion (an edge has no texture along
    # it), so its x is taken where the face's midline crosses it: the head-vertical
    # line through the midpoints of the paired features (brows, furrows, mouth
    # corners), which are tracked in both directions thanks to their ends
    centre = np.mean(mids, axis=0) if mids else nose_c
    u = (hair - centre) @ ex
    for i in range(len(u) - 1):
        if u[i] == 0 or u[i] * u[i + 1] < 0:
            t = 0.0 if u[i] == 0 else u[i] / (u[i] - u[i + 1])
            cross = hair[i] + t * (hair[i + 1] - hair[i])
            origin = origin + ((cross - origin) @ ex) * ex
            break
    down = nose_c - origin
    scale = float(np.hypot(*down))
    if scale <= 1e-6:
        raise ValueError("nose_tip contour coincides with the hairline origin")
    return HeadFrame(float(origin[0]), float(origin[1]), scale, float(roll))


def fiducials(contours, head: HeadFrame | None = None, *,
              brow_mid_fraction: dict | None = None) -> dict[str, tuple[float, float]]:
    """The 11 fiducial points of 004 from the contours.

    Parameters
    ----------
    contours : mapping name -> (n, 2) array
        Needs the nine contours of :data:`trackers.layout.CONTOUR_NAMES` that the
        fiducials use (brows, furrows, upper_lip, chin_boss; hairline and nose_tip
        when ``head`` is not given).
    head : HeadFrame, optional
        Frame that decides left/right and up; computed from the contours if absent.
    brow_mid_fraction : dict {'l': f, 'r': f}, optional
        Arc-length fractions (from the inner end) of the brow centre points; default:
        the apex of each brow on this frame (:func:`apex_fraction`).

    Returns
    -------
    dict name -> (x, y)
        In :data:`FIDUCIAL_NAMES` order, image pixels.
    """
    if head is None:
        head = head_frame(contours)
    ex, ey = head.axes
    o = np.array([head.x, head.y])

    def hx(p):
        return float((np.asarray(p) - o) @ ex)

    def hy(p):
        return float((np.asarray(p) - o) @ ey)

    out: dict[str, tuple[float, float]] = {}
    for side in ("l", "r"):
        b = _points(contours, f"brow_{side}")
        if abs(hx(b[0])) > abs(hx(b[-1])):
            b = b[::-1]  # inner end first
        inner, outer = b[0], b[-1]
        out[f"brow_inner_{side}"] = (float(inner[0]), float(inner[1]))
        if brow_mid_fraction is not None and side in brow_mid_fraction:
            f = float(brow_mid_fraction[side])
            if not 0.0 <= f <= 1.0:
                raise ValueError(f"brow_mid_fraction[{side!r}] must be in [0, 1], got {f}")
        else:
            f = apex_fraction(b, brow_axis_frame(contours, head))
        m = arc_point(b, f)
        out[f"brow_mid_{side}"] = (float(m[0]), float(m[1]))
        out[f"brow_outer_{side}"] = (float(outer[0]), float(outer[1]))
    lip = _points(contours, "upper_lip")
    right, left = sorted((lip[0], lip[-1]), key=hx)
    out["mouth_corner_l"] = (float(left[0]), float(left[1]))
    out["mouth_corner_r"] = (float(right[0]), float(right[1]))
    for side in ("l", "r"):
        f = _points(contours, f"furrow_{side}")
        top = min((f[0], f[-1]), key=hy)
        out[f"furrow_top_{side}"] = (float(top[0]), float(top[1]))
    c = centroid(_points(contours, "chin_boss"), closed=True)
    out["chin"] = (float(c[0]), float(c[1]))
    return {n: out[n] for n in FIDUCIAL_NAMES}
