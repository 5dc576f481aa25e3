"""Contractions from dense face motion: bounded least squares on the per-control templates.

The observed displacement of the face from the neutral frame, on the face grid
(:func:`faceanalysis.flow.dense.video_face_flow`: flow measured directly from the neutral frame to
each frame, in the head frame), is explained per frame as

    d(g) = sum_m c_m T_m(g) + sum_k a_k N_k(g) + noise,     0 <= c_m <= upper_m,

where ``T_m`` are the model's per-control templates (motion per unit contraction, jaw per
radian) and ``N_k`` the nuisance motions (head-frame similarity jitter, out-of-plane yaw
and pitch), whose coefficients are free. The nuisance is eliminated exactly (projection on
the orthogonal complement of its span), and the box-constrained quadratic in ``c`` with a
small ridge ``lam |c / upper|^2`` is solved for all frames at once by accelerated projected
gradient (FISTA) on the shared normal matrix. Templates are linear in the contraction
(made at ``level``), so strongly non-linear muscles are under- or over-estimated at other
levels; bounds are the only thing that keeps the values in range.

By default only the controls the ``joint`` estimator reads are fitted
(:data:`FLOW_CONTROLS`): the templates of zygomaticus minor and buccinator are near twins
of zygomaticus major's and risorius's (cosine 0.94 and 0.96 on the face grid once the
nuisance is removed), so with them in the fit the motion of one muscle is shared out
among the pair at random.
"""

from __future__ import annotations

import os

import numpy as np
import pandas as pd

from faceanalysis.estimation.model_response import OBSERVED_CONTROLS
from faceanalysis.flow.templates import FlowTemplates

__all__ = ["estimate_contractions", "estimate_flow", "flow_quadratic", "reestimate_flow",
           "FlowDesign", "FLOW_CONTROLS"]

#: Controls the flow estimator fits by default: those of the ``joint`` estimator
#: (:data:`faceanalysis.estimation.model_response.OBSERVED_CONTROLS`), which leave out the
#: near twins zygomaticus minor and buccinator. The others are reported at rest, as ``joint`` does.
FLOW_CONTROLS: tuple[str, ...] = OBSERVED_CONTROLS


def _select(templates: FlowTemplates, controls) -> tuple[str, ...]:
    if controls is None:
        return tuple(templates.controls)
    controls = tuple(controls)
    unknown = [c for c in controls if c not in templates.controls]
    if unknown or not controls or len(set(controls)) != len(controls):
        raise ValueError(f"controls must be distinct names of the templates' controls "
                         f"({', '.join(templates.controls)}); got {list(controls)}")
    return controls


class FlowDesign:
    """The least-squares design of a set of templates on their face mask (reusable).

    Parameters
    ----------
    templates : FlowTemplates
    controls : sequence of str, optional
        The templates' controls to fit, in this order (default: all of them).
    regularization : float
        Ridge weight, relative to the mean squared full-range template.
    weights : (rows, cols) array, optional
        Per-cell weights on the mask (default 1).
    """

    def __init__(self, templates: FlowTemplates, *, controls=None,
                 regularization: float = 1e-3, weights: np.ndarray | None = None):
        if regularization < 0:
            raise ValueError(f"regularization={regularization} must be >= 0")
        self.templates = templates
        self.controls = _select(templates, controls)
        index = [templates.controls.index(c) for c in self.controls]
        m = templates.mask
        if not m.any():
            raise ValueError("the templates' face mask is empty")
        w = np.ones(m.shape) if weights is None else np.asarray(weights, dtype=float)
        if w.shape != m.shape or np.any(w < 0) or not np.isfinite(w).all():
            raise ValueError(f"weights must be {m.shape} finite non-negative values")
        self.sw = np.repeat(np.sqrt(w[m]), 2)                              # (2n,)
        A = templates.control[index][:, m, :].reshape(len(index), -1).T * self.sw[:, None]
        N = templates.nuisance[:, m, :].reshape(len(templates.nuisance), -1).T * self.sw[:, None]
        q, _ = np.linalg.qr(N) if N.size else (np.zeros((A.shape[0], 0)), None)
        self.q = q                                                         # nuisance basis
        self.A = A - q @ (q.T @ A)                                         # (2n, M)
        self.upper = templates.upper[index].astype(float)
        scale = np.mean((self.A * self.upper) ** 2) * self.A.shape[0]
        self.lam = regularization * scale / self.upper ** 2
        self.H = self.A.T @ self.A + np.diag(self.lam)
        self.L = float(np.linalg.eigvalsh(self.H)[-1])

    def observations(self, displacement: np.ndarray) -> np.ndarray:
        """Flatten (T, rows, cols, 2) displacement on the mask, weighted, nuisance removed."""
        d = np.asarray(displacement, dtype=float)
        y = d[:, self.templates.mask, :].reshape(len(d), -1) * self.sw
        return y - (y @ self.q) @ self.q.T

    def solve(self, y: np.ndarray, *, iterations: int = 500, tol: float = 1e-7) -> np.ndarray:
        """Box-constrained least squares for rows of ``y`` (finite rows only)."""
        b = y @ self.A                                                     # (T, M)
        c = np.zeros_like(b)
        z = c.copy()
        t = 1.0
        for _ in range(iterations):
            g = z @ self.H - b
            new = np.clip(z - g / self.L, 0.0, self.upper)
            t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
            z = new + ((t - 1.0) / t_new) * (new - c)
            done = np.abs(new - c).max() < tol if new.size else True
            c, t = new, t_new
            if done:
                break
        return c


def estimate_contractions(displacement: np.ndarray, templates: FlowTemplates, *,
                          controls=None, regularization: float = 1e-3,
                          iterations: int = 500, design: FlowDesign | None = None
                          ) -> np.ndarray:
    """Contractions per frame from the face displacement (see the module docstring).

    Parameters
    ----------
    displacement : ndarray (T, rows, cols, 2)
        Displacement from the neutral frame on the templates' grid, head units; frames with
        NaN on the mask are lost frames.
    templates : FlowTemplates
    controls : sequence of str, optional
        The templates' controls to fit, in this order (default: all of them; the others
        are taken to be at rest).
    regularization : float
        Ridge weight (relative).
    iterations : int
        Projected-gradient iterations at most.
    design : FlowDesign, optional
        A prepared design of the same templates and controls (reuse across calls).

    Returns
    -------
    ndarray (T, M)
        One column per control (``controls``, or ``templates.controls``): muscles in
        [0, 1], jaw in radians; NaN rows for lost frames.

    Examples
    --------
    >>> from faceanalysis.flow.grid import FaceGrid, rigid_basis
    >>> g = FaceGrid(rows=6, cols=5)
    >>> rng = np.random.default_rng(0)
    >>> ctrl = rng.normal(size=(2, 6, 5, 2))
    >>> tpl = FlowTemplates(g, ("a", "b"), np.ones(2), ctrl, ("tu", "tv", "rot", "scale"),
    ...                     rigid_basis(g), np.ones((6, 5), bool), np.zeros((6, 5), np.int8),
    ...                     (), np.zeros((0, 2, 6, 5, 2)), np.zeros((0, 6, 5)),
    ...                     np.zeros((11, 2)), np.zeros(4))
    >>> d = 0.3 * ctrl[0] + 0.7 * ctrl[1] + 0.05 * rigid_basis(g)[0]
    >>> np.round(estimate_contractions(d[None], tpl, regularization=0), 3)
    array([[0.3, 0.7]])

    With a near twin of ``b`` among the templates, noise shares ``b``'s motion out
    between the two; leaving the twin out of the fit gives it back to ``b``:

    >>> twin = ctrl[1] + 0.1 * rng.normal(size=(6, 5, 2))
    >>> tpl3 = FlowTemplates(g, ("a", "b", "b2"), np.ones(3), np.stack([*ctrl, twin]),
    ...                      tpl.nuisance_names, tpl.nuisance, tpl.mask, tpl.region, (),
    ...                      tpl.expression, tpl.energy, tpl.fiducials, tpl.head)
    >>> noisy = d + 0.02 * rng.normal(size=d.shape)
    >>> np.round(estimate_contractions(noisy[None], tpl3), 2)
    array([[0.3 , 0.63, 0.07]])
    >>> np.round(estimate_contractions(noisy[None], tpl3, controls=("a", "b")), 2)
    array([[0.3, 0.7]])
    """
    d = np.asarray(displacement, dtype=float)
    if d.ndim == 3:
        d = d[None]
    shape = (*templates.grid.shape, 2)
    if d.ndim != 4 or d.shape[1:] != shape:
        raise ValueError(f"displacement must have shape (T, {shape[0]}, {shape[1]}, 2), "
                         f"got {d.shape}")
    if iterations < 1:
        raise ValueError(f"iterations={iterations} must be >= 1")
    if design is None:
        design = FlowDesign(templates, controls=controls, regularization=regularization)
    elif controls is not None and tuple(controls) != design.controls:
        raise ValueError(f"controls {list(controls)} differ from the design's "
                         f"{list(design.controls)}")
    out = np.full((len(d), len(design.controls)), np.nan)
    ok = np.isfinite(d[:, templates.mask, :]).all(axis=(1, 2))
    if ok.any():
        out[ok] = design.solve(design.observations(d[ok]), iterations=iterations)
    return out


def estimate_flow(video: str | os.PathLike, table: pd.DataFrame, *,
                  neutral: int | None = None, templates: FlowTemplates | None = None,
                  method: str = "dis", fps: float | None = None, start: int = 0,
                  end: int | None = None, regularization: float = 1e-3,
                  personalised: bool = True, controls=FLOW_CONTROLS) -> pd.DataFrame:
    """The ``flow`` estimator for an analysed video: contractions per frame from its flow.

    Parameters
    ----------
    video : path-like
        The analysed video (read a second time, streamed).
    table : DataFrame
        Per-frame ``frame``, ``success``, ``head_*`` and ``fid_*`` columns (the tracking
        part of ``contractions.csv``).
    neutral : int, optional
        Neutral frame number (default: the first tracked frame).
    templates : FlowTemplates, optional
        Default: the generic face model's templates (cached).
    method : {'dis', 'farneback', 'tvl1'}
    fps, start, end
        Input options as for ``analyze``.
    regularization : float
    personalised : bool
        Warp the templates onto the subject's neutral fiducials first
        (:func:`faceanalysis.flow.personalize.personalize`).
    controls : sequence of str or None
        Controls to fit (default :data:`FLOW_CONTROLS`, less those the templates lack);
        None: every control of the templates. A name the templates lack is a
        ``ValueError``.

    Returns
    -------
    DataFrame
        Index = the table's rows; one column per fitted control (muscles,
        ``jaw_rotation``); NaN for lost frames.
    """
    # templates of a model without some of the default muscles: fit the others
    design, ff = _face_flow(video, table, neutral=neutral, templates=templates, method=method,
                            fps=fps, start=start, end=end, regularization=regularization,
                            personalised=personalised, controls=controls,
                            subset=controls is FLOW_CONTROLS)
    values = estimate_contractions(ff.displacement, design.templates, design=design)
    return pd.DataFrame(_on_table_rows(values, ff.frames, table["frame"].to_numpy(int)),
                        columns=list(design.controls), index=table.index)


def _face_flow(video, table: pd.DataFrame, *, neutral, templates, method, fps, start, end,
               regularization, personalised, controls, subset):
    """The design of ``controls`` on the (personalised) templates, and the video's face
    flow from the neutral frame. With ``subset``, ``controls`` the templates lack are
    dropped instead of refused."""
    from faceanalysis.flow.dense import video_face_flow
    from faceanalysis.flow.personalize import personalize_from_table
    from faceanalysis.io.table import heads_from_table

    if templates is None:
        from faceanalysis.flow.templates import default_templates

        templates = default_templates()
    frames = table["frame"].to_numpy(int)
    ok = np.isfinite(heads_from_table(table)).all(axis=1)
    if not ok.any():
        raise ValueError(f"{video}: no tracked frame to estimate from")
    ref = int(frames[np.argmax(ok)]) if neutral is None else int(neutral)
    if personalised:
        templates = personalize_from_table(templates, table, ref)
    if subset:
        controls = tuple(c for c in controls if c in templates.controls)
    design = FlowDesign(templates, controls=controls, regularization=regularization)
    ff = video_face_flow(video, table=table, neutral=ref, method=method, grid=templates.grid,
                         fps=fps, start=start, end=end)
    return design, ff


def _on_table_rows(values: np.ndarray, flow_frames, frames) -> np.ndarray:
    """Rows of ``values`` (one per frame of ``flow_frames``) placed on ``frames``; NaN where
    the flow has no frame."""
    pos = {int(f): i for i, f in enumerate(flow_frames)}
    out = np.full((len(frames), values.shape[1]), np.nan)
    for i, f in enumerate(frames):
        j = pos.get(int(f))
        if j is not None:
            out[i] = values[j]
    return out


def flow_quadratic(video: str | os.PathLike, table: pd.DataFrame, controls, *,
                   neutral: int | None = None, method: str = "dis", fps: float | None = None,
                   start: int = 0, end: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The dense flow's least squares in ``controls``, for a fit that also reads points.

    The video's face flow from the neutral frame (as :func:`estimate_flow` measures it, on
    the generic face's templates warped to the subject, nuisance motion projected out) is
    ``y_t ~ A c``; this returns ``H = A'A`` and ``g_t = A'y_t`` with ``A``'s columns in the
    order of ``controls`` (zero for a control without a template), for
    :func:`~faceanalysis.estimation.estimators.estimate_joint`'s ``quadratic``.

    Returns
    -------
    (ndarray (M, M), ndarray (T, M))
        ``g`` has one row per row of ``table``; NaN where the flow has no frame.
    """
    design, ff = _face_flow(video, table, neutral=neutral, templates=None, method=method,
                            fps=fps, start=start, end=end, regularization=0.0,
                            personalised=True, controls=controls, subset=True)
    fitted = design.controls
    d = np.asarray(ff.displacement, dtype=float)
    seen = np.isfinite(d[:, design.templates.mask, :]).all(axis=(1, 2))
    y = np.full((len(d), design.A.shape[0]), np.nan)
    if seen.any():
        y[seen] = design.observations(d[seen])
    A = np.zeros((design.A.shape[0], len(controls)))
    for j, c in enumerate(controls):
        if c in fitted:
            A[:, j] = design.A[:, fitted.index(c)]
    return A.T @ A, _on_table_rows(y @ A, ff.frames, table["frame"].to_numpy(int))


def reestimate_flow(analysis, video: str | os.PathLike, *,
                    templates: FlowTemplates | None = None, method: str = "dis",
                    fps: float | None = None, **kwargs):
    """The same tracking, the ``flow`` estimator: a new :class:`~faceanalysis.analysis.pipeline.
    Analysis` whose muscle, jaw and AU columns come from :func:`estimate_flow`.

    Parameters
    ----------
    analysis : Analysis
        A finished analysis of ``video`` (its table gives the head frames, fiducials and
        neutral frame).
    video : path-like
        The analysed video, read again for its flow.
    templates, method, fps, **kwargs
        Passed to :func:`estimate_flow`.
    """
    from dataclasses import replace

    from faceanalysis.io.table import (
        JAW,
        MUSCLES,
        with_au_columns,
        with_identifiable_columns,
    )

    table = analysis.table.copy()
    params = analysis.metadata.get("parameters", {})
    est = estimate_flow(video, table, neutral=params.get("neutral_frame"), templates=templates,
                        method=method, fps=fps if fps is not None else params.get("fps"),
                        start=params.get("start") or 0, end=params.get("end"), **kwargs)
    success = table["success"].to_numpy() == 1
    observed = np.zeros((len(table), len(MUSCLES) + 1), dtype=bool)
    for j, col in enumerate((*MUSCLES, JAW)):
        v = est[col].to_numpy(float) if col in est.columns else np.zeros(len(table))
        observed[:, j] = np.isfinite(v) & (col in est.columns)
        table[col] = np.where(success, v, np.nan)
    # flagged by the points' identifiability: the flow's own is not assessed
    ident = analysis.metadata.get("identifiability", {}).get("controls", {})
    table = with_identifiable_columns(
        with_au_columns(table), [c for c, e in ident.items() if e.get("identifiable")],
        observed=observed)
    metadata = dict(analysis.metadata)
    metadata["parameters"] = {**params, "estimator": "flow",
                              "estimated_controls": [c for c in est.columns
                                                     if np.isfinite(est[c]).any()],
                              "flow_method": method}
    return replace(analysis, table=table, metadata=metadata)
