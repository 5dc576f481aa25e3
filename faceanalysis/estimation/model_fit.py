"""Contractions fitted through the face model's own equilibrium (the ``model`` estimator).

The ``mesh`` fit inverts a response table: each control's motion of the points tabulated at
six levels, plus pairwise interaction terms. The model itself is more than that (biphasic
springs that stiffen, the lips' contact, the jaw carrying the lower face), so where several
muscles act together the table's prediction departs from the model's. This fit removes the
table: for each frame it equilibrates the model at the current contractions, compares the
model's own points with the tracked ones, and takes a Gauss-Newton step whose Jacobian is
the equilibrium's quasi-static sensitivity ``dx/dc = K^{-1} df/dc``
(:func:`synth.sensitivity.equilibrium_sensitivity`, as Sifakis et al. 2005 fit activations
to markers), mapped onto the measurement points. The objective is the ``mesh`` fit's last
stage (:data:`~faceanalysis.estimation.registry.MESH_FIT`): per-point weights, a Huber
reweighting of points the model cannot explain, the sparsity prior weighed by the minimax
concave penalty's slope at the current values, the bounds, and each frame drawn toward its
neighbours' first fits. The table's fit is the first guess; frames are visited in order and
the model is warm-started from the previous frame's equilibrium.
"""

from __future__ import annotations

import numpy as np

from faceanalysis.estimation.estimators import _one_blas_thread, box_qp
from faceanalysis.estimation.mesh_points import MESH_POINT_PREFIX, surface_points
from faceanalysis.estimation.model_response import model_points
from faceanalysis.estimation.response import FiducialResponse
from faceanalysis.io.table import JAW

__all__ = ["fit_through_model", "mesh_fit_keywords", "personal_model", "point_jacobian"]

#: Gauss-Newton iterations per frame at most (each one equilibrium, more when a step is
#: halved). On exact points of the first standard-suite identity a fourth changes nothing.
ITERATIONS = 3

#: A frame stops when no control's step exceeds this fraction of its range.
TOLERANCE = 2e-3

#: Convergence tolerance of each equilibrium, cm (the solver's largest update): the
#: solver's default (3e-4) leaves a warm-started equilibrium up to 0.1 mm from the one a
#: tight solve reaches, which the fit would read as muscle; at 1e-4 it is 0.02-0.03 mm
#: (3e-5 reads exact points of the first standard-suite identity the same, 30 % slower).
EQUILIBRIUM_TOL = 1e-4

#: The personalisation's warp carries every this many face-mesh points (of some 330 seen):
#: the warp interpolates its landmarks exactly, so each one adds the tracker's noise on
#: it to the face's shape.
WARP_EVERY = 4

#: Landmarks of the warp closer than this (cm) on the model are one: the first carries it.
WARP_SPACING = 0.1


def mesh_fit_keywords(options: dict) -> dict:
    """The keywords of :func:`fit_through_model` that carry over the ``mesh`` fit's
    ``options`` (:func:`~faceanalysis.estimation.registry.mesh_fit`): the same point
    weights, prior, Huber threshold, concave knee, temporal pull and inner iterations."""
    return {"weights": options["weights"], "sparsity": options["sparsity"],
            "robust": options["robust"], "knee": options["debias"],
            "temporal": options["temporal"], "inner_iterations": options["inner_iterations"]}


def personal_model(neutral: np.ndarray, response: FiducialResponse, model, *,
                   every: int = WARP_EVERY):
    """``model`` personalised to a subject's neutral face seen at ``neutral``.

    Kähler's landmark warp (:func:`synth.personalize.personalize_in_plane`) takes the
    model's skin points under the seen face-mesh points (every ``every``-th) and the
    mesh's landmarks among ``response.fiducials`` onto their neutral x-y, their depth the
    model's scaled as the face; where the warp folds the face it is blended toward its
    affine part.

    Parameters
    ----------
    neutral : ndarray, shape (P, 2)
        Positions of ``response.fiducials`` on the neutral frame, model cm (x = the
        subject's left, y up); NaN where not seen.
    response : FiducialResponse
        Names the points.
    model : synth.FaceModel
        The model to personalise (not modified).
    every : int, keyword-only
        Every how many seen face-mesh points one carries the warp.

    Returns
    -------
    personal : synth.FaceModel
    blend : float
        The share of the warp beyond its affine part that was kept (1: all of it).

    Raises
    ------
    ValueError
        For a ``neutral`` of the wrong shape, ``every`` < 1, fewer than 10 seen points, or
        no warp down to an affine one that gives a valid model.
    """
    from synth.personalize import personalize_in_plane

    names = list(response.fiducials)
    xy = np.asarray(neutral, dtype=float)
    if xy.shape != (len(names), 2):
        raise ValueError(f"neutral must have shape ({len(names)}, 2), got {xy.shape}")
    if isinstance(every, bool) or int(every) != every or every < 1:
        raise ValueError(f"every must be a positive integer, got {every!r}")
    seen = np.isfinite(xy).all(axis=1)
    mesh = [j for j, n in enumerate(names) if n.startswith(MESH_POINT_PREFIX) and seen[j]]
    mesh = mesh[::int(every)]
    marks = [j for j, n in enumerate(names)
             if n in model.mesh.landmarks and not n.startswith(MESH_POINT_PREFIX) and seen[j]]
    use = mesh + marks
    if len(use) < 10:
        raise ValueError(f"personalising the model needs at least 10 seen points, got {len(use)}")
    v = model.surface_vertices
    table = surface_points([names[j] for j in mesh])
    src = np.array([table[names[j]][1] @ v[table[names[j]][0]] for j in mesh]
                   + [v[model.mesh.landmarks[names[j]]] for j in marks])
    # face-mesh points that share a skin point (or nearly) would make the warp's system
    # singular: the first of them carries it
    near = np.linalg.norm(src[:, None] - src[None], axis=2) < WARP_SPACING
    keep = ~np.triu(near, 1).any(axis=0)
    src, dst = src[keep], xy[use][keep]
    personal, _, blend = personalize_in_plane(model, src, dst)
    return personal, blend


def _split(points) -> tuple[list, list, list]:
    """Indices of the face-mesh points, the mesh's landmarks and the feature-curve points."""
    from faceanalysis.tracking import CURVE_POINTS

    mesh = [j for j, n in enumerate(points) if n.startswith(MESH_POINT_PREFIX)]
    curve = [j for j, n in enumerate(points) if n in CURVE_POINTS]
    taken = set(mesh) | set(curve)
    other = [j for j in range(len(points)) if j not in taken]
    return mesh, other, curve


def point_jacobian(model, vertices: np.ndarray, points, motion: np.ndarray, *,
                   step: float = 1e-3) -> np.ndarray:
    """How the orthographic x-y of ``points`` (:func:`model_points`) move per unit of each
    of the skin motions ``motion`` (C, N, 3) at ``vertices``, shape (C, P, 2).

    The face-mesh points and the mesh's landmarks follow the skin linearly; the points on
    feature curves (at a fraction of the curve's length) are differenced with a motion
    scaled to at most ``step`` cm.
    """
    from faceanalysis.tracking import CURVE_POINTS
    from trackers.fiducials import arc_point

    points = list(points)
    mesh, other, curve = _split(points)
    out = np.zeros((len(motion), len(points), 2))
    if mesh:
        names = [points[j] for j in mesh]
        table = surface_points(names)
        verts = np.stack([table[n][0] for n in names])            # (Pm, 3)
        bary = np.stack([table[n][1] for n in names])             # (Pm, 3)
        out[:, mesh] = np.einsum("pk,cpkd->cpd", bary, motion[:, verts, :2])
    for j in other:
        out[:, j] = motion[:, model.mesh.landmarks[points[j]], :2]
    if curve:
        by_curve: dict[str, list[int]] = {}
        for j in curve:
            by_curve.setdefault(CURVE_POINTS[points[j]][0], []).append(j)
        for name, rows in by_curve.items():
            base = model.mesh.curve_positions(name, vertices)[:, :2]
            at = np.array([arc_point(base, CURVE_POINTS[points[j]][1]) for j in rows])
            for i in range(len(motion)):
                size = np.abs(motion[i]).max()
                if size == 0:
                    continue
                h = step / size
                moved = model.mesh.curve_positions(name, vertices + h * motion[i])[:, :2]
                out[i, rows] = (np.array([arc_point(moved, CURVE_POINTS[points[j]][1])
                                          for j in rows]) - at) / h
    return out


class _Prior:
    """A frame's priors: the sparsity prior ``2 mu s(c) . c`` weighed by the concave
    penalty's slope ``s(c) = max(0, 1 - c / knee)`` at the current values, and the pull
    ``nu |c - centre|^2`` toward the neighbours' first fits."""

    def __init__(self, mu, knee, nu, centre):
        self.mu, self.knee, self.nu, self.centre = mu, knee, nu, centre

    def slope(self, c):
        return self.mu * np.clip(1.0 - c / self.knee, 0.0, 1.0)

    def objective(self, c, r, pw, mu_t) -> float:
        """The weighted squares of the residuals ``r`` (P, 2) with the priors at ``c``."""
        return (float(np.sum(pw[:, None] * r**2)) + 2.0 * float(mu_t @ c)
                + float(self.nu @ (c - self.centre) ** 2))


def fit_through_model(displacements: np.ndarray, response: FiducialResponse, model,
                      initial: np.ndarray, *, weights: np.ndarray | None = None,
                      sparsity: float = 2e-2, robust: float | None = 0.1, knee: float = 0.2,
                      temporal: float = 0.0, iterations: int = ITERATIONS,
                      tol: float = TOLERANCE, inner_iterations: int = 400,
                      return_residual: bool = False, progress=None):
    """Fit every frame's contractions through ``model``'s own equilibrium.

    Minimises, per frame, ``sum_p w_p h_p |d_p - x_p(c) + x_p(0)|^2
    + 2 mu sum_m s_m c_m / upper_m + nu sum_m ((c_m - n_m) / upper_m)^2`` over
    ``0 <= c <= upper``, ``x(c)`` the model's points at its equilibrium under ``c``, ``h_p``
    the Huber weight ``min(1, robust / residual)``, ``s_m = max(0, 1 - c_m / (knee upper_m))``
    the concave prior's slope at the current values, ``n`` the mean of the neighbouring
    frames' ``initial`` values, by Gauss-Newton steps with the Jacobian of the equilibrium
    (:func:`synth.sensitivity.equilibrium_sensitivity`), each step solved with the bounds
    (:func:`~faceanalysis.estimation.estimators.box_qp`) and halved (twice at most) until
    the objective falls. The scales ``mu`` and ``nu`` are those of
    :func:`~faceanalysis.estimation.estimators.estimate_joint` (relative to the table's mean
    squared full-contraction response), so that ``sparsity`` and ``temporal`` mean what
    they mean there.

    Parameters
    ----------
    displacements : ndarray, shape (T, P, 2)
        Observed displacements of ``response.fiducials`` from neutral, model cm (NaN:
        not seen).
    response : FiducialResponse
        The points, the controls and their bounds (its table sets the prior's scale only).
    model : synth.FaceModel
        The face to fit through (its state is changed, and reset at the end).
    initial : ndarray, shape (T, M)
        First guess, e.g. the ``mesh`` fit; a NaN row is a frame not fitted (left NaN), a
        NaN value a control not observed on that frame (held at rest, left NaN).
    weights : ndarray, shape (P,), optional
        Per-point weights (default 1).
    sparsity, robust, knee, temporal : float, keyword-only
        The prior's weight, the Huber threshold (cm; None: plain least squares), the
        concave prior's knee (a fraction of the range), the pull toward the neighbours.
    iterations : int, keyword-only
        Gauss-Newton steps per frame at most.
    tol : float, keyword-only
        Stop a frame when no step exceeds ``tol`` of its control's range.
    inner_iterations : int, keyword-only
        Projected-gradient iterations of each step's bounded solve.
    return_residual : bool, keyword-only
        Also return each frame's fit residual through the model.
    progress : callable(int), optional
        Called with 1 after each frame.

    Returns
    -------
    values : ndarray, shape (T, M)
    residual : ndarray, shape (T,)
        With ``return_residual``: the RMS distance over the points seen between the
        observed displacements and the model's at ``values``, model cm (NaN where no frame
        was fitted).
    """
    from synth.sensitivity import equilibrium_sensitivity, stiffness_factor

    d_all = np.asarray(displacements, dtype=float)
    n_p = len(response.fiducials)
    n_m = len(response.muscles)
    c_init = np.array(initial, dtype=float)
    if d_all.ndim != 3 or d_all.shape[1:] != (n_p, 2):
        raise ValueError(f"displacements must have shape (T, {n_p}, 2), got {d_all.shape}")
    if c_init.shape != (len(d_all), n_m):
        raise ValueError(f"initial must have shape ({len(d_all)}, {n_m}), got {c_init.shape}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    if robust is not None and not (np.isfinite(robust) and robust > 0):
        raise ValueError(f"robust must be a positive threshold or None, got {robust}")
    if not (0 < knee <= 1):
        raise ValueError(f"knee must be in (0, 1], got {knee}")
    w = np.ones(n_p) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (n_p,) or np.any(w < 0) or not np.isfinite(w).all():
        raise ValueError(f"weights must be {n_p} finite non-negative values")
    names = list(model.muscle_names)
    unknown = [m for m in response.muscles if m != JAW and m not in names]
    if unknown:
        raise ValueError(f"the model has no control {unknown}")
    upper = response.upper
    full = response.displacement[:, -1].reshape(n_m, -1)
    scale = np.mean((full * np.repeat(np.sqrt(w), 2)) ** 2) * n_p * 2
    mu = sparsity * scale / upper
    nu_all = temporal * scale / upper**2
    # the neighbours' first fits, where both are known
    centre = np.full_like(c_init, np.nan)
    centre[1:-1] = 0.5 * (c_init[:-2] + c_init[2:])
    points = list(response.fiducials)
    controls = list(response.muscles)

    linear = None   # (controls, nodes, sensitivity) of the last linearisation

    def equilibrium(c):
        values = {m: float(v) for m, v in zip(controls, c) if m != JAW}
        jaw = float(c[controls.index(JAW)]) if JAW in controls else 0.0
        model.set_contractions(values, jaw_rotation=jaw)
        start = None
        if linear is not None:
            # started where the linearisation puts it: a few solver iterations from it
            start = linear[1] + np.tensordot(c - linear[0], linear[2], axes=1)
        skin = model.equilibrate(tol=EQUILIBRIUM_TOL, max_iter=20000, start=start)
        return skin, model_points(model, skin, points)

    out = np.full_like(c_init, np.nan)
    residual = np.full(len(d_all), np.nan)
    # the stiffness's solves and the small products gain nothing from more BLAS threads
    with _one_blas_thread():
        model.reset()
        try:
            _, rest = equilibrium(np.zeros(n_m))
            for t in range(len(d_all)):
                d = d_all[t]
                seen = np.isfinite(d).all(axis=1)
                if seen.sum() >= 3 and np.isfinite(c_init[t]).any():
                    observed = np.isfinite(c_init[t])
                    hi = np.where(observed, upper, 0.0)
                    c = np.clip(np.nan_to_num(c_init[t]), 0.0, hi)
                    prior = _Prior(mu, knee * upper, np.where(
                        np.isfinite(centre[t]) & observed, nu_all, 0.0), np.nan_to_num(centre[t]))
                    skin, p = equilibrium(c)
                    # the Jacobian once per frame, at its first guess (its steps change the
                    # stiffness little; the residuals are always the model's own, so the
                    # optimum is the same)
                    sens = equilibrium_sensitivity(model, controls, factor=stiffness_factor(
                        model.system, model.node_positions))
                    jac = point_jacobian(model, skin, points, sens[:, :len(skin)])
                    jac = jac.reshape(n_m, -1).T                                  # (2P, M)
                    for _ in range(iterations):
                        r = np.where(seen[:, None], d - (p - rest), 0.0)
                        pw = w * seen
                        if robust is not None:
                            pw = pw * np.minimum(1.0, robust / np.maximum(
                                np.linalg.norm(r, axis=1), 1e-12))
                        mu_t = prior.slope(c)
                        current = prior.objective(c, r, pw, mu_t)
                        sw = np.repeat(pw, 2)
                        hess = (jac.T * sw) @ jac + np.diag(prior.nu)
                        grad0 = (jac.T * sw) @ r.ravel() - mu_t - prior.nu * (c - prior.centre)
                        # the truncated solve damps the step where the points barely
                        # determine a direction, which the model's nonlinearity punishes
                        step = box_qp(hess[None], grad0[None], -c[None], (hi - c)[None],
                                      iterations=inner_iterations, precondition=False)[0]
                        for frac in (1.0, 0.5, 0.25):
                            trial = np.clip(c + frac * step, 0.0, hi)
                            t_skin, t_p = equilibrium(trial)
                            t_r = np.where(seen[:, None], d - (t_p - rest), 0.0)
                            if prior.objective(trial, t_r, pw, mu_t) < current:
                                c, skin, p = trial, t_skin, t_p
                                break
                        else:
                            skin, p = equilibrium(c)   # back to the frame's best, for the next
                            break
                        if np.max(np.abs(frac * step) / upper) < tol:
                            break
                    out[t] = np.where(observed, c, np.nan)
                    r = d[seen] - (p - rest)[seen]
                    residual[t] = float(np.sqrt(np.mean(np.sum(r**2, axis=1))))
                if progress is not None:
                    progress(1)
        finally:
            model.reset()
    return (out, residual) if return_residual else out
