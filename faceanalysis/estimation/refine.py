"""Refine contractions through the face model itself (the ``joint`` estimator's last step).

The tabulated response (:mod:`faceanalysis.estimation.response`) is a fast surrogate of the
model, but muscles interact beyond its pairwise terms (the lip contact, biphasic
stiffening, the jaw carrying the lower lip). This step closes the gap: for each
frame it equilibrates the model at the current estimate, measures the difference
between the observed and the *model's own* fiducial displacements, and corrects the
estimate by a bounded Gauss-Newton step that uses the surrogate's Jacobian (a
defect-correction iteration; its fixed points are exact fits through the model).
Frames are visited in order and the model is warm-started from the previous
frame's equilibrium, which makes each equilibrium cheap.
"""

from __future__ import annotations

import numpy as np

from faceanalysis.estimation.estimators import box_qp
from faceanalysis.estimation.model_response import equilibrium_points
from faceanalysis.estimation.response import FiducialResponse


def refine_through_model(displacements: np.ndarray, response: FiducialResponse, model,
                         initial: np.ndarray, *, iterations: int = 3,
                         regularization: float = 1e-2, tol: float = 1e-3,
                         progress=None) -> np.ndarray:
    """Defect-correction refinement of contraction estimates through ``model``.

    Parameters
    ----------
    displacements : ndarray, shape (T, F, 2)
        Observed displacements of ``response.fiducials`` from neutral, model units.
    response : FiducialResponse
        Supplies the controls, the bounds and the (approximate) Jacobian.
    model : synth.FaceModel
        The face model; its state is changed (and reset at the end).
    initial : ndarray, shape (T, M)
        Starting estimate (e.g. :func:`~faceanalysis.estimation.estimators.estimate_joint`); NaN
        rows (lost frames) are passed through.
    iterations : int, keyword-only
        Model equilibria per frame at most.
    regularization : float, keyword-only
        As in :func:`~faceanalysis.estimation.estimators.estimate_joint`.
    tol : float, keyword-only
        Stop a frame when no control changes by more than ``tol`` (relative to its bound).
    progress : callable(int), optional
        Called with 1 after each frame.

    Returns
    -------
    ndarray, shape (T, M)
    """
    d = np.asarray(displacements, dtype=float)
    c_all = np.array(initial, dtype=float, copy=True)
    if d.ndim != 3 or c_all.shape != (d.shape[0], len(response.muscles)):
        raise ValueError(f"initial must have shape (T={d.shape[0]}, M={len(response.muscles)})")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    n_f = len(response.fiducials)
    upper = response.upper
    scale = np.mean(response.displacement[:, -1].reshape(len(upper), -1) ** 2) * n_f * 2
    lam = regularization * scale / upper**2
    model.reset()
    rest = equilibrium_points(model, response.muscles, np.zeros(len(upper)),
                              response.fiducials)
    for t in range(d.shape[0]):
        c = c_all[t]
        if not (np.isfinite(c).all() and np.isfinite(d[t]).all()):
            if progress is not None:
                progress(1)
            continue
        for _ in range(iterations):
            predicted = equilibrium_points(model, response.muscles, c,
                                           response.fiducials) - rest
            res = (d[t] - predicted).reshape(-1)
            jac = response.jacobian(c[None])[0]                       # (K, M)
            hess = (jac.T @ jac + np.diag(lam))[None]
            grad0 = (jac.T @ res - lam * c)[None]
            step = box_qp(hess, grad0, -c[None], (upper - c)[None], iterations=200,
                          precondition=False)[0]
            c = np.clip(c + step, 0.0, upper)
            if np.max(np.abs(step) / upper) < tol:
                break
        c_all[t] = c
        if progress is not None:
            progress(1)
    model.reset()
    return c_all
