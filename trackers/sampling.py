"""What a contour reads from a potential: force fields and bilinear samples.

:func:`force_field` turns a potential of :mod:`trackers.potentials` into the image force
``-p * grad P`` on the pixel grid (see the sign convention there); :func:`sample_bilinear`
interpolates a scalar or vector field at sub-pixel points, checked, and
:func:`sample_or_nan` / ``bilinear_nb`` are the unchecked, compiled samplers that the
trackers' kernels share (NaN outside the field).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["force_field", "sample_bilinear", "sample_or_nan"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _force_nb(P, p, F):
    H, W = P.shape
    for y in range(H):
        y0 = y - 1 if y > 0 else 0
        y1 = y + 1 if y < H - 1 else H - 1
        for x in range(W):
            x0 = x - 1 if x > 0 else 0
            x1 = x + 1 if x < W - 1 else W - 1
            F[y, x, 0] = -p * (P[y, x1] - P[y, x0]) / (x1 - x0)
            F[y, x, 1] = -p * (P[y1, x] - P[y0, x]) / (y1 - y0)


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def bilinear_nb(P, x, y, ox, oy):  # pragma: no cover
    """Bilinear sample of the 2-D array ``P`` at image point (x, y), ``P[0, 0]`` being at
    (ox, oy); NaN outside (compiled helper shared by the trackers' kernels)."""
    H, W = P.shape
    xf = x - ox
    yf = y - oy
    if not (xf >= 0.0 and yf >= 0.0 and xf <= W - 1 and yf <= H - 1):
        return np.nan
    x0 = min(int(xf), W - 2)
    y0 = min(int(yf), H - 2)
    tx = xf - x0
    ty = yf - y0
    return ((1 - ty) * ((1 - tx) * P[y0, x0] + tx * P[y0, x0 + 1])
            + ty * ((1 - tx) * P[y0 + 1, x0] + tx * P[y0 + 1, x0 + 1]))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _sample_nb(P, pts, ox, oy, out):
    """Bilinear samples of P at (x, y) - (ox, oy); NaN outside."""
    for i in range(pts.shape[0]):
        out[i] = bilinear_nb(P, pts[i, 0], pts[i, 1], ox, oy)


def sample_or_nan(P, points, origin=(0.0, 0.0)) -> np.ndarray:
    """Bilinear samples of a 2-D field at (x, y) points, NaN where a point is outside.

    The unchecked, compiled counterpart of :func:`sample_bilinear` for inner loops.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
    out = np.empty(len(pts))
    _sample_nb(np.ascontiguousarray(P), pts, float(origin[0]), float(origin[1]), out)
    return out


def force_field(potential, p: float = 1.0) -> np.ndarray:
    """Image force ``-p * grad P`` on the pixel grid (central differences).

    Parameters
    ----------
    potential : array_like, (H, W)
        A potential such as :func:`gaussian_potential` returns.
    p : float
        Image-force strength (eq. 12). The default 1 gives the bare gradient so
        that per-node strengths can be applied later (the snake kernel does).

    Returns
    -------
    F : ndarray of float32, (H, W, 2)
        ``F[..., 0]`` is the x (column) component, ``F[..., 1]`` the y (row) one.

    Examples
    --------
    >>> import numpy as np
    >>> P = -np.exp(-((np.arange(9) - 4.0) ** 2))[None, :].repeat(5, 0)
    >>> F = force_field(P)
    >>> bool(F[2, 2, 0] > 0 and F[2, 6, 0] < 0)  # pushes toward the ravine at x=4
    True
    """
    P = np.asarray(potential, dtype=np.float32)
    if P.ndim != 2 or P.shape[0] < 2 or P.shape[1] < 2:
        raise ValueError(f"potential must be a 2-D array at least 2x2, got shape {P.shape}")
    if not np.isfinite(P).all():
        raise ValueError("potential has NaN or infinite values")
    p = float(p)
    if not np.isfinite(p):
        raise ValueError(f"p must be finite, got {p}")
    F = np.empty(P.shape + (2,), np.float32)
    _force_nb(np.ascontiguousarray(P), np.float32(p), F)
    return F


def sample_bilinear(field, points, *, origin=(0.0, 0.0)) -> np.ndarray:
    """Bilinear interpolation of a scalar or vector field at sub-pixel points.

    Parameters
    ----------
    field : array_like, (H, W) or (H, W, K)
    points : array_like, (N, 2)
        (x, y) positions in image pixels (x right, y down, origin at the centre of
        the top-left pixel).
    origin : (x, y)
        Image position of ``field[0, 0]`` (the ``roi`` corner of a cropped field).

    Returns
    -------
    values : ndarray of float64, (N,) or (N, K)

    Raises
    ------
    ValueError
        If a point is not finite or lies outside the field.

    Examples
    --------
    >>> import numpy as np
    >>> f = np.arange(12.0).reshape(3, 4)
    >>> sample_bilinear(f, [[1.5, 1.0], [0.0, 0.5]])
    array([5.5, 2. ])
    """
    f = np.asarray(field, dtype=np.float64)
    if f.ndim not in (2, 3) or f.shape[0] < 1 or f.shape[1] < 1:
        raise ValueError(f"field must be (H, W) or (H, W, K), got shape {f.shape}")
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"points must have shape (N, 2), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points contain NaN or infinite coordinates")
    x = pts[:, 0] - float(origin[0])
    y = pts[:, 1] - float(origin[1])
    H, W = f.shape[:2]
    out = (x < 0) | (y < 0) | (x > W - 1) | (y > H - 1)
    if out.any():
        i = int(np.argmax(out))
        raise ValueError(f"point {i} at (x={pts[i, 0]:.2f}, y={pts[i, 1]:.2f}) lies outside "
                         f"the field (x in [{origin[0]}, {origin[0] + W - 1}], "
                         f"y in [{origin[1]}, {origin[1] + H - 1}])")
    x0 = np.minimum(np.floor(x).astype(np.intp), max(W - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.intp), max(H - 2, 0))
    fx = x - x0
    fy = y - y0
    x1 = np.minimum(x0 + 1, W - 1)
    y1 = np.minimum(y0 + 1, H - 1)
    if f.ndim == 3:
        fx = fx[:, None]
        fy = fy[:, None]
    return ((1 - fy) * ((1 - fx) * f[y0, x0] + fx * f[y0, x1])
            + fy * ((1 - fx) * f[y1, x0] + fx * f[y1, x1]))
