"""What the tracker reports per frame, and the measures behind a contour's quality.

:class:`ContourQuality` holds one contour's depth, stretch and shape change on one frame
(see :mod:`trackers.tracking` for when a contour counts as lost) and :class:`TrackResult`
everything the :class:`~trackers.tracking.Tracker` knows about a frame. The Numba kernels
that measure a contour's length and its similarity-invariant change of shape live here
too, next to the quality they define; the end relocation
(:mod:`trackers.contour_ends`) reuses the length.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from trackers.fiducials import HeadFrame

__all__ = ["ContourQuality", "TrackResult"]


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
    from trackers.polyline import resample_polyline as _rs

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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _length_nb(p, closed):
    n = p.shape[0]
    total = 0.0
    for i in range(n - 1):
        total += np.sqrt((p[i + 1, 0] - p[i, 0]) ** 2 + (p[i + 1, 1] - p[i, 1]) ** 2)
    if closed and n > 1:
        total += np.sqrt((p[0, 0] - p[n - 1, 0]) ** 2 + (p[0, 1] - p[n - 1, 1]) ** 2)
    return total


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
