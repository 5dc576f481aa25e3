"""The face grid: fixed sample points in the head's frame, and the maps between image
pixels and head units that every flow field of :mod:`faceanalysis.flow` is expressed in,
with the rigid-motion basis that is removed from flow on the grid."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["FaceGrid", "head_array", "grid_image_points", "vectors_to_head",
           "image_flow_to_grid", "rigid_basis", "remove_rigid"]


# ---------------------------------------------------------------------------- grid
@dataclass(frozen=True)
class FaceGrid:
    """A fixed grid of points in head-frame coordinates (units of the head scale).

    Parameters
    ----------
    rows, cols : int
        Grid size (default 64 x 48).
    u : (float, float)
        Range of the head x coordinate (toward the subject's left), centre of the first and
        last column.
    v : (float, float)
        Range of the head y coordinate (down), centre of the first and last row. The head
        origin (0, 0) is the hairline; the nose tip lies near ``v = 1``.

    Examples
    --------
    >>> g = FaceGrid()
    >>> g.points.shape, round(g.cell, 4)
    ((64, 48, 2), 0.0267)
    """

    rows: int = 64
    cols: int = 48
    u: tuple = (-0.63, 0.63)
    v: tuple = (-0.10, 1.58)

    def __post_init__(self):
        if int(self.rows) < 2 or int(self.cols) < 2:
            raise ValueError(f"grid size {self.rows}x{self.cols} must be at least 2x2")
        if not (self.u[1] > self.u[0] and self.v[1] > self.v[0]):
            raise ValueError(f"grid ranges u={self.u}, v={self.v} must be increasing")

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.rows), int(self.cols))

    @property
    def points(self) -> np.ndarray:
        """Head coordinates ``(rows, cols, 2)`` of the grid points, ``[..., 0] = u``."""
        uu = np.linspace(self.u[0], self.u[1], self.cols)
        vv = np.linspace(self.v[0], self.v[1], self.rows)
        U, V = np.meshgrid(uu, vv)
        return np.stack([U, V], axis=-1)

    @property
    def cell(self) -> float:
        """Mean spacing of the grid points, head units."""
        return 0.5 * ((self.u[1] - self.u[0]) / (self.cols - 1)
                      + (self.v[1] - self.v[0]) / (self.rows - 1))

    @property
    def centre(self) -> np.ndarray:
        return np.array([0.5 * (self.u[0] + self.u[1]), 0.5 * (self.v[0] + self.v[1])])

    def as_dict(self) -> dict:
        return {"rows": int(self.rows), "cols": int(self.cols),
                "u": [float(x) for x in self.u], "v": [float(x) for x in self.v]}

    @classmethod
    def from_dict(cls, d) -> FaceGrid:
        return cls(int(d["rows"]), int(d["cols"]), tuple(float(x) for x in d["u"]),
                   tuple(float(x) for x in d["v"]))

    def sample(self, field_: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Bilinear sample of a grid field ``(rows, cols, ...)`` at head points ``(..., 2)``;
        points outside the grid take the nearest border value."""
        f = np.asarray(field_, dtype=np.float32)
        p = np.asarray(points, dtype=np.float64)
        cx = (p[..., 0] - self.u[0]) / (self.u[1] - self.u[0]) * (self.cols - 1)
        cy = (p[..., 1] - self.v[0]) / (self.v[1] - self.v[0]) * (self.rows - 1)
        extra = f.shape[2:]
        flat = f.reshape(f.shape[0], f.shape[1], -1)
        out = np.stack([cv2.remap(np.ascontiguousarray(flat[..., k]), cx.astype(np.float32),
                                  cy.astype(np.float32), cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REPLICATE)
                        for k in range(flat.shape[-1])], axis=-1)
        return out.reshape(*cx.shape, *extra)


def head_array(head) -> np.ndarray:
    """A head frame as ``array([x, y, scale, roll])``; accepts a HeadFrame, a mapping with
    ``head_x``... keys or a sequence of four numbers."""
    if hasattr(head, "scale") and hasattr(head, "roll"):
        h = np.array([head.x, head.y, head.scale, head.roll], dtype=float)
    elif isinstance(head, dict):
        h = np.array([head["head_x"], head["head_y"], head["head_scale"], head["head_roll"]],
                     dtype=float)
    else:
        h = np.asarray(head, dtype=float)
    if h.shape[-1:] != (4,):
        raise ValueError(f"a head frame has 4 values (x, y, scale, roll), got shape {h.shape}")
    return h


def grid_image_points(grid: FaceGrid, head) -> np.ndarray:
    """Image positions (px) ``(rows, cols, 2)`` of the grid points under head frame ``head``."""
    x, y, s, r = head_array(head)
    if not s > 0:
        raise ValueError(f"head scale must be positive, got {s}")
    p = grid.points * s
    c, sn = math.cos(r), math.sin(r)
    return np.stack([x + c * p[..., 0] - sn * p[..., 1], y + sn * p[..., 0] + c * p[..., 1]],
                    axis=-1)


def vectors_to_head(vectors: np.ndarray, head) -> np.ndarray:
    """Image displacement vectors (px, ``(..., 2)``) into head units: ``R(-roll) v / scale``."""
    _, _, s, r = head_array(head)
    v = np.asarray(vectors, dtype=np.float64)
    c, sn = math.cos(r), math.sin(r)
    return np.stack([c * v[..., 0] + sn * v[..., 1], -sn * v[..., 0] + c * v[..., 1]],
                    axis=-1) / s


def smoothing_sigma(grid: FaceGrid, px_per_unit: float) -> float:
    """Gaussian sigma (px) that smooths an image flow to the grid's cell size."""
    return 0.5 * grid.cell * px_per_unit


def image_flow_to_grid(flow: np.ndarray, head, grid: FaceGrid | None = None, *,
                       smooth: bool = True, valid: np.ndarray | None = None) -> np.ndarray:
    """Resample an image flow field onto the face grid, in head units.

    Parameters
    ----------
    flow : (H, W, 2) array
        Displacement in px of the pixels of an image whose head frame is ``head``.
    head : head frame (see :func:`head_array`)
    grid : FaceGrid, optional
    smooth : bool
        Average over about one grid cell (Gaussian) before sampling.
    valid : (H, W) bool, optional
        Pixels whose flow is meaningful; the average is normalised over them (cells with
        no valid pixel get NaN).

    Returns
    -------
    ndarray (rows, cols, 2), float64, head units.
    """
    grid = grid or FaceGrid()
    fl = np.asarray(flow, dtype=np.float32)
    if fl.ndim != 3 or fl.shape[2] != 2:
        raise ValueError(f"flow must have shape (H, W, 2), got {fl.shape}")
    h = head_array(head)
    pts = grid_image_points(grid, h).astype(np.float32)
    w = None if valid is None else np.asarray(valid, dtype=np.float32)
    if w is not None and w.shape != fl.shape[:2]:
        raise ValueError(f"valid mask {w.shape} does not match the flow {fl.shape[:2]}")
    if w is not None:
        fl = fl * w[..., None]
    if smooth:
        sig = smoothing_sigma(grid, h[2])
        if sig > 0.3:
            fl = cv2.GaussianBlur(fl, (0, 0), sig)
            if w is not None:
                w = cv2.GaussianBlur(w, (0, 0), sig)
    out = np.stack([cv2.remap(np.ascontiguousarray(fl[..., k]), pts[..., 0], pts[..., 1],
                              cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=np.nan) for k in range(2)], axis=-1).astype(np.float64)
    if w is not None:
        ws = cv2.remap(w, pts[..., 0], pts[..., 1], cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=0.0).astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(ws[..., None] > 0.05, out / ws[..., None], np.nan)
    return vectors_to_head(out, h)


# ---------------------------------------------------------------------------- rigid motion
def rigid_basis(grid: FaceGrid | None = None) -> np.ndarray:
    """Unit similarity motions on the grid, ``(4, rows, cols, 2)``: translation u, translation
    v, rotation and scaling about the grid centre (rotation/scale per head unit of radius)."""
    grid = grid or FaceGrid()
    p = grid.points - grid.centre
    b = np.zeros((4, *grid.shape, 2))
    b[0, ..., 0] = 1.0
    b[1, ..., 1] = 1.0
    b[2, ..., 0], b[2, ..., 1] = -p[..., 1], p[..., 0]
    b[3] = p
    return b


def remove_rigid(displacement: np.ndarray, mask: np.ndarray, basis: np.ndarray | None = None
                 ) -> np.ndarray:
    """Subtract the least-squares fit of the nuisance ``basis`` (default: similarity) on
    ``mask`` from each frame's displacement.

    Parameters
    ----------
    displacement : (..., rows, cols, 2)
    mask : (rows, cols) bool
    basis : (K, rows, cols, 2), optional

    Returns
    -------
    ndarray, same shape (NaN stays NaN)

    Examples
    --------
    >>> g = FaceGrid(rows=8, cols=6)
    >>> d = 0.3 * rigid_basis(g)[2]
    >>> float(np.abs(remove_rigid(d, np.ones(g.shape, bool))).max()) < 1e-12
    True
    """
    d = np.asarray(displacement, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)
    if d.shape[-1] != 2 or d.shape[-3:-1] != m.shape:
        raise ValueError(f"displacement {d.shape} does not match the mask {m.shape}")
    if basis is None:
        basis = rigid_basis(FaceGrid(m.shape[0], m.shape[1]))
    B = np.asarray(basis, dtype=np.float64)
    A = B[:, m].reshape(len(B), -1).T                       # (2n, K)
    lead = d.shape[:-3]
    flat = d.reshape(-1, *d.shape[-3:])
    obs = flat[:, m].reshape(len(flat), -1)                 # (T, 2n)
    ok = np.isfinite(obs).all(axis=1)
    out = flat.copy()
    if ok.any():
        coef, *_ = np.linalg.lstsq(A, obs[ok].T, rcond=None)  # (K, T)
        fit = np.tensordot(coef.T, B, axes=1)               # (T, rows, cols, 2)
        out[ok] = flat[ok] - fit
    return out.reshape(*lead, *d.shape[-3:])
