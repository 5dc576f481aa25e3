"""Polylines resampled at equal arc length.

:func:`resample_polyline` and its Numba kernels (arc length, interpolation at an arc
position, value for value as ``np.interp``). The snakes' initial contours, the layout,
the tracker (which resamples every contour whose end moved, several times a frame) and
the fiducials (points at an arc-length fraction) all use them.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["resample_polyline"]


def resample_polyline(points, n: int | None = None, *, spacing: float | None = None,
                      closed: bool = False) -> np.ndarray:
    """Resample a polyline at equal arc-length steps.

    Parameters
    ----------
    points : array_like, (m, 2)
    n : int, optional
        Number of output nodes.
    spacing : float, optional
        Desired node spacing in pixels (used when ``n`` is None).
    closed : bool
        Treat the polyline as closed (the output does not repeat the first node).

    Returns
    -------
    ndarray of float64, (n, 2)

    Examples
    --------
    >>> resample_polyline([[0, 0], [10, 0]], 6)[:, 0]
    array([ 0.,  2.,  4.,  6.,  8., 10.])
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ValueError(f"points must have shape (m >= 2, 2), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points contain NaN or infinite coordinates")
    if closed:
        pts = np.vstack([pts, pts[:1]])
    s = _arc_length_nb(pts)
    total = s[-1]
    if total <= 0:
        raise ValueError("polyline has zero length")
    if n is None:
        if spacing is None or spacing <= 0:
            raise ValueError("give n or a positive spacing")
        n = max(int(round(total / spacing)) + (0 if closed else 1), 3)
    n = int(n)
    if n < 2:
        raise ValueError(f"n must be >= 2, got {n}")
    out = np.empty((n, 2))
    _resample_nb(pts, s, n, closed, out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _arc_length_nb(pts):
    s = np.empty(pts.shape[0])
    s[0] = 0.0
    for i in range(pts.shape[0] - 1):
        s[i + 1] = s[i] + np.hypot(pts[i + 1, 0] - pts[i, 0], pts[i + 1, 1] - pts[i, 1])
    return s


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _interp_at_nb(pts, s, t, j, out, row):
    """``out[row] = np.interp(t, s, pts[:, c])`` for both columns, value for value; the
    search for ``t``'s segment starts at ``j`` (the segment is returned, so that
    increasing ``t`` walk the polyline once)."""
    m = s.shape[0]
    if m == 1:
        out[row, 0] = pts[0, 0]
        out[row, 1] = pts[0, 1]
        return j
    if t != t:
        out[row, 0] = np.nan
        out[row, 1] = np.nan
        return j
    if t >= s[m - 1]:
        out[row, 0] = pts[m - 1, 0]
        out[row, 1] = pts[m - 1, 1]
        return j
    if t < s[0]:
        out[row, 0] = pts[0, 0]
        out[row, 1] = pts[0, 1]
        return j
    while j + 1 < m and s[j + 1] <= t:
        j += 1
    if s[j] == t:
        out[row, 0] = pts[j, 0]
        out[row, 1] = pts[j, 1]
        return j
    ds = s[j + 1] - s[j]
    for c in range(2):
        slope = (pts[j + 1, c] - pts[j, c]) / ds
        v = slope * (t - s[j]) + pts[j, c]
        if np.isnan(v):
            v = slope * (t - s[j + 1]) + pts[j + 1, c]
            if np.isnan(v) and pts[j, c] == pts[j + 1, c]:
                v = pts[j, c]
        out[row, c] = v
    return j


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _resample_nb(pts, s, n, closed, out):
    # at np.linspace(0, s[-1], n (+1 closed)), as np.interp would: the tracker
    # resamples every contour whose end moved, several times a frame
    total = s[s.shape[0] - 1]
    step = total / ((n + 1 if closed else n) - 1)
    j = 0
    for i in range(n):
        t = total if not closed and i == n - 1 else i * step + 0.0
        j = _interp_at_nb(pts, s, t, j, out, i)
