"""Calibration on the neutral frame: map model space into the tracked head frame.

004 (V-D) calibrates on an image of the neutral face: the head reference frame's
origin comes from the hairline, and the muscle vectors are placed relative to it
from the fiducial points. Here the map is an affine transform fitted by least
squares from the model's rest fiducials (cm, y up) to the neutral fiducials
expressed in the head frame, so that face proportions that differ from the model
(width, length) are absorbed, and fiducial motion in later frames can be taken
back into model units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from faceanalysis.tracking import to_head_frame

#: A neutral point this far (head-frame units) from the calibrated model's is suspect
#: (:func:`find_suspect`): on 77 rendered sequences of 7 faces the farthest point was
#: 0.051 away, while the contours that settled on the wrong feature on the real clips
#: (the mouth line on the lower lip, a furrow's top on the mouth) put points 0.08-0.17
#: away.
MAX_POINT_RESIDUAL = 0.08


@dataclass(frozen=True)
class Calibration:
    """Affine map from model space (cm, y up) to head-frame coordinates of the neutral face.

    Attributes
    ----------
    matrix : ndarray, shape (2, 2)
        Linear part: head-frame displacement = ``matrix @ model displacement``.
    offset : ndarray, shape (2,)
    neutral : ndarray, shape (F, 2)
        Neutral fiducials in head-frame coordinates.
    residual : float
        RMS fit residual of the neutral fiducials, in head-frame units.
    point_residuals : ndarray, shape (F,), optional
        Each fiducial's distance from the fitted map of its model position, head-frame
        units (NaN for those not seen). Faces of other proportions fit within a few
        hundredths; a point much farther out sits on the wrong feature (see
        :func:`find_suspect`).
    """

    matrix: np.ndarray
    offset: np.ndarray
    neutral: np.ndarray
    residual: float
    point_residuals: np.ndarray | None = None

    def model_displacements(self, fiducials: np.ndarray, head: np.ndarray) -> np.ndarray:
        """Fiducial displacements from neutral, in model cm, for tracked frames.

        Parameters
        ----------
        fiducials : ndarray, shape (T, F, 2)
            Tracked image fiducials.
        head : ndarray, shape (T, 4)
            Tracked head frames.
        """
        q = to_head_frame(fiducials, head)
        return (q - self.neutral) @ np.linalg.inv(self.matrix).T

    def to_model(self, points: np.ndarray) -> np.ndarray:
        """Head-frame positions (..., 2) in model cm: the inverse of the map."""
        return (np.asarray(points, dtype=float) - self.offset) @ np.linalg.inv(self.matrix).T


def calibrate(neutral_fiducials: np.ndarray, neutral_head: np.ndarray,
              model_rest: np.ndarray, *, valid: np.ndarray | None = None) -> Calibration:
    """Fit the model-to-head-frame map on the neutral frame.

    Parameters
    ----------
    neutral_fiducials : ndarray, shape (F, 2)
        Image fiducials of the neutral frame, pixels.
    neutral_head : ndarray, shape (4,)
        Head frame of the neutral frame (x, y, scale, roll).
    model_rest : ndarray, shape (F, 2)
        The same fiducials on the model at rest (cm, x = subject's left, y up).
    valid : ndarray of bool, shape (F,), optional
        Fiducials seen on the neutral frame (default: all). The map is fitted on these;
        the others have no neutral position, so their displacements stay NaN.

    Returns
    -------
    Calibration

    Raises
    ------
    ValueError
        If shapes disagree, values are not finite, or the fiducials are degenerate
        (collinear), so that no affine map is defined.

    Examples
    --------
    >>> import numpy as np
    >>> rest = np.array([[-3., 4.], [3., 4.], [0., -5.], [-2., -3.]])
    >>> image = np.c_[100 + 10 * rest[:, 0], 120 - 10 * rest[:, 1]]
    >>> cal = calibrate(image, np.array([100., 120., 10., 0.]), rest)
    >>> np.round(cal.matrix, 6) + 0.0
    array([[ 1.,  0.],
           [ 0., -1.]])
    """
    p = np.asarray(neutral_fiducials, dtype=float)
    r = np.asarray(model_rest, dtype=float)
    head = np.asarray(neutral_head, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or r.shape != p.shape:
        raise ValueError(f"neutral fiducials {p.shape} and model fiducials {r.shape} must both "
                         "have shape (F, 2)")
    if head.shape != (4,):
        raise ValueError(f"neutral head frame must have 4 values, got shape {head.shape}")
    seen = np.ones(len(p), bool) if valid is None else np.asarray(valid, bool)
    if seen.shape != (len(p),):
        raise ValueError(f"valid must have one flag per fiducial ({len(p)})")
    if not (np.isfinite(p[seen]).all() and np.isfinite(r).all() and np.isfinite(head).all()):
        raise ValueError("calibration needs finite neutral fiducials and head frame")
    if head[2] <= 0:
        raise ValueError(f"head scale must be positive, got {head[2]}")
    q = to_head_frame(np.where(seen[:, None], p, np.nan), head)
    design = np.c_[r, np.ones(len(r))][seen]
    if len(design) < 3:
        raise ValueError("calibration needs at least 3 fiducials on the neutral frame")
    if np.linalg.matrix_rank(design) < 3:
        raise ValueError("neutral fiducials are degenerate (collinear): cannot calibrate")
    coef, *_ = np.linalg.lstsq(design, q[seen], rcond=None)
    matrix, offset = coef[:2].T, coef[2]
    residual = float(np.sqrt(np.mean(np.sum((design @ coef - q[seen]) ** 2, axis=1))))
    points = np.linalg.norm(r @ matrix.T + offset - q, axis=1)      # NaN where not seen
    return Calibration(matrix=matrix, offset=offset, neutral=q, residual=residual,
                       point_residuals=points)


def find_suspect(neutral_fiducials: np.ndarray, neutral_head: np.ndarray,
                 model_rest: np.ndarray, *, valid: np.ndarray | None = None,
                 limit: float = MAX_POINT_RESIDUAL) -> np.ndarray:
    """Neutral points that the calibration cannot place: contours on the wrong feature.

    One misplaced point pulls the affine map towards itself and pushes the others off,
    so the points are not judged on one fit: the worst point farther than ``limit``
    from the map is set aside and the map refitted, until every remaining point lies
    within ``limit`` (or only four remain).

    Parameters
    ----------
    neutral_fiducials, neutral_head, model_rest, valid
        As for :func:`calibrate`.
    limit : float
        Largest distance (head-frame units) of a point from the fitted map.

    Returns
    -------
    ndarray of bool, shape (F,)
        True for the points set aside.

    Examples
    --------
    >>> import numpy as np
    >>> rest = np.array([[-3., 4.], [3., 4.], [0., 0.], [0., -5.], [-2., -3.], [2., -3.]])
    >>> image = np.c_[100 + 10 * rest[:, 0], 120 - 10 * rest[:, 1]]
    >>> image[4, 1] += 25                    # one point 2.5 units from where it belongs
    >>> find_suspect(image, np.array([100., 120., 10., 0.]), rest, limit=0.8)
    array([False, False, False, False,  True, False])
    """
    p = np.asarray(neutral_fiducials, dtype=float)
    keep = np.isfinite(p).all(axis=1) if valid is None else np.asarray(valid, bool).copy()
    out = np.zeros(len(p), bool)
    while keep.sum() > 4:
        cal = calibrate(p, neutral_head, model_rest, valid=keep)
        res = np.where(keep, np.nan_to_num(cal.point_residuals, nan=0.0), 0.0)
        worst = int(np.argmax(res))
        if res[worst] <= limit:
            break
        keep[worst] = False
        out[worst] = True
    return out
