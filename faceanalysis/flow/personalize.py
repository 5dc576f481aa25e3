"""Flow templates for one subject: the generic face's templates warped onto a subject's
neutral fiducials (a thin-plate spline in the head's frame), and the check that refuses
fiducials too far from the face model to warp to."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from faceanalysis.flow.grid import FaceGrid, rigid_basis
from faceanalysis.flow.templates import FlowTemplates
from faceanalysis.io.table import FIDUCIALS

log = logging.getLogger(__name__)

__all__ = ["SubjectWarp", "implausible_fiducials", "personalize", "personalize_from_table"]


def _tps_warp(src: np.ndarray, dst: np.ndarray):
    """Thin-plate spline mapping src points -> dst points (2-D), and its affine part."""
    from scipy.interpolate import RBFInterpolator

    rbf = RBFInterpolator(src, dst, kernel="thin_plate_spline", smoothing=1e-4, degree=1)
    design = np.c_[src, np.ones(len(src))]
    coef, *_ = np.linalg.lstsq(design, dst, rcond=None)
    return rbf, coef[:2].T


class SubjectWarp:
    """2-D landmark-driven warp from the model's face onto a subject's, on the face grid.

    A thin-plate spline maps each grid point of the subject's face to the corresponding
    point of the model's (driven by the 11 fiducials and five rigid anchors: the head origin
    and the grid corners); fields are resampled there and vectors mapped by the inverse of
    the warp's affine part.

    Parameters
    ----------
    grid : FaceGrid
    model_fiducials, subject_fiducials : (11, 2) array_like
        Head coordinates of the model's rest fiducials and of the subject's neutral ones.
    """

    def __init__(self, grid: FaceGrid, model_fiducials, subject_fiducials):
        q = np.asarray(subject_fiducials, dtype=float)
        p = np.asarray(model_fiducials, dtype=float)
        if q.shape != p.shape or q.ndim != 2 or q.shape[1] != 2 or not np.isfinite(q).all():
            raise ValueError(f"subject fiducials must be {p.shape} finite values, "
                             f"got shape {q.shape}")
        self.grid = grid
        anchors = np.array([[0.0, 0.0], [grid.u[0], grid.v[0]], [grid.u[1], grid.v[0]],
                            [grid.u[0], grid.v[1]], [grid.u[1], grid.v[1]]])
        rbf, lin = _tps_warp(np.vstack([q, anchors]), np.vstack([p, anchors]))
        pts = grid.points
        self.back = rbf(pts.reshape(-1, 2)).reshape(pts.shape)
        self.jac = np.linalg.inv(lin)

    def scalars(self, stack: np.ndarray) -> np.ndarray:
        """Warp scalar fields (..., rows, cols)."""
        stack = np.asarray(stack, dtype=float)
        lead = stack.shape[:-2]
        flat = stack.reshape(-1, *self.grid.shape)
        out = self.grid.sample(np.moveaxis(flat, 0, -1), self.back)
        return np.moveaxis(out.reshape(*self.grid.shape, -1), -1, 0).reshape(*lead,
                                                                           *self.grid.shape)

    def vectors(self, stack: np.ndarray) -> np.ndarray:
        """Warp vector fields (..., rows, cols, 2)."""
        stack = np.asarray(stack, dtype=float)
        lead = stack.shape[:-3]
        flat = stack.reshape(-1, *self.grid.shape, 2)
        chans = np.moveaxis(flat, 0, 2).reshape(*self.grid.shape, -1)      # (r, c, K*2)
        out = self.grid.sample(chans, self.back).reshape(*self.grid.shape, len(flat), 2)
        out = out @ self.jac.T
        return np.moveaxis(out, 2, 0).reshape(*lead, *self.grid.shape, 2)

    def mask(self, mask: np.ndarray) -> np.ndarray:
        return self.grid.sample(np.asarray(mask, dtype=np.float32), self.back) > 0.99


def personalize(templates: FlowTemplates, fiducials_head) -> FlowTemplates:
    """Warp generic templates onto a subject's face (2-D landmark-driven warp).

    Parameters
    ----------
    templates : FlowTemplates
        Generic (model) templates.
    fiducials_head : (11, 2) array_like
        The subject's neutral fiducials in head coordinates (e.g.
        :func:`faceanalysis.tracking.to_head_frame` of the neutral frame's fiducials and
        head frame), in :data:`~faceanalysis.io.table.FIDUCIALS` order.

    Returns
    -------
    FlowTemplates
        Templates on the same grid, whose features sit where the subject's are.
    """
    q = np.asarray(fiducials_head, dtype=float)
    warp = SubjectWarp(templates.grid, templates.fiducials, q)
    mask_w = warp.mask(templates.mask)
    near = warp.scalars(templates.region.astype(float))
    region = np.where(np.abs(near - np.rint(near)) < 1e-3, np.rint(near), -1).astype(np.int8)
    region[~mask_w] = -1
    control = warp.vectors(templates.control)
    nuis = np.array([*rigid_basis(templates.grid), *warp.vectors(templates.nuisance[4:])])
    expr = warp.vectors(templates.expression)
    energy = warp.scalars(templates.energy)
    for arr in (control, nuis, expr):
        arr[..., ~mask_w, :] = 0.0
    energy[:, ~mask_w] = 0.0
    meta = dict(templates.meta, personalised=True)
    return replace(templates, control=control, nuisance=nuis, mask=mask_w, region=region,
                   expression=expr, energy=energy, fiducials=q.copy(), meta=meta)


#: Largest distance, in head units, between a subject's neutral fiducial and the
#: model's after the best similarity: the synthetic suite's identities reach 0.075;
#: on a real video whose furrow contours had slid onto the mouth line, 0.12-0.16.
MAX_FIDUCIAL_RESIDUAL = 0.1


def implausible_fiducials(templates: FlowTemplates, fiducials_head) -> list[str]:
    """Names of the fiducials that a similarity (translation, rotation, scale) of the
    templates' own fiducials leaves more than :data:`MAX_FIDUCIAL_RESIDUAL` head units
    away: a contour tracked onto the wrong feature, not a face of another shape.

    Examples
    --------
    >>> import numpy as np
    >>> from faceanalysis.flow.templates import default_templates
    >>> from faceanalysis.io.table import FIDUCIALS
    >>> t = default_templates()
    >>> q = 1.1 * t.fiducials + [0.02, -0.03]            # another scale, another place
    >>> implausible_fiducials(t, q)
    []
    >>> q[FIDUCIALS.index("furrow_top_l"), 1] += 0.25    # the furrow's top at the mouth
    >>> implausible_fiducials(t, q)
    ['furrow_top_l']
    """
    q = np.asarray(fiducials_head, dtype=float)
    g = np.asarray(templates.fiducials, dtype=float)
    if q.shape != g.shape:
        raise ValueError(f"fiducials must have shape {g.shape}, got {q.shape}")
    zg = (g - g.mean(0)) @ [1, 1j]
    zq = (q - q.mean(0)) @ [1, 1j]
    a = (np.conj(zg) @ zq) / (np.conj(zg) @ zg)
    far = np.abs(zq - a * zg) > MAX_FIDUCIAL_RESIDUAL
    return [n for n, f in zip(FIDUCIALS, far) if f]


def personalize_from_table(templates: FlowTemplates, table, neutral: int) -> FlowTemplates:
    """Templates warped onto the subject's neutral fiducials of ``table`` (frame ``neutral``);
    the generic ones when the fiducials are missing or implausible
    (:func:`implausible_fiducials`: warping the templates onto a mistracked feature
    would move the expressions' flow onto the wrong part of the face)."""
    from faceanalysis.io.table import heads_from_table
    from faceanalysis.tracking import to_head_frame

    cols = [c for n in FIDUCIALS for c in (f"fid_{n}_x", f"fid_{n}_y")]
    if any(c not in table.columns for c in cols):
        return templates
    row = np.flatnonzero(table["frame"].to_numpy(int) == neutral)
    if row.size == 0:
        raise ValueError(f"neutral frame {neutral} is not in the table")
    fid = table[cols].to_numpy(float)[row[0]].reshape(len(FIDUCIALS), 2)
    head = heads_from_table(table)[row[0]]
    if not (np.isfinite(fid).all() and np.isfinite(head).all()):
        return templates
    q = to_head_frame(fid, head)
    bad = implausible_fiducials(templates, q)
    if bad:
        log.warning("neutral frame %d: %s too far from where the face model puts %s; the "
                    "templates are not personalised", neutral, ", ".join(bad),
                    "it" if len(bad) == 1 else "them")
        return templates
    return personalize(templates, q)
