"""The accuracy ceiling of the fiducial estimators: estimation from perfect measurements.

The closed-loop suite (:func:`faceanalysis.evaluation.suite.run_suite`) scores the whole
pipeline: rendering, tracking, calibration and estimation together. This module
takes tracking out. For every identity and sequence of a suite, the identity's own
face model is equilibrated at the true contractions of every frame and the
measurement points (:data:`faceanalysis.estimation.model_response.MEASUREMENT_POINTS`) are
read off it exactly: orthographic, no camera, no head motion, no noise. The
estimator then inverts them as it would a tracked video (calibration on the first
frame, the generic face's response table by default).

What is left is the error of the estimator itself: the response table's
approximation of the model (pairwise interactions only), the difference between
the subject's face and the generic one, and, above all, how far the points can tell
the muscles apart. No tracker of these points can do better on average, so a
per-muscle target that the ceiling misses needs more measurements (the ``flow``
estimator's dense motion), not a better tracker.
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd

from faceanalysis.estimation.calibration import calibrate
from faceanalysis.estimation.estimators import POINT_ESTIMATORS, estimate
from faceanalysis.estimation.model_fit import (
    fit_through_model,
    mesh_fit_keywords,
    personal_model,
)
from faceanalysis.estimation.model_response import MEASUREMENT_POINTS
from faceanalysis.estimation.registry import mesh_fit, mesh_response
from faceanalysis.estimation.response import FiducialResponse
from faceanalysis.evaluation.scores import pool, public
from faceanalysis.evaluation.suite import SuiteConfig, script_kwargs
from faceanalysis.io.table import JAW, MUSCLES
from faceanalysis.tracking import to_head_frame

__all__ = ["perfect_measurements", "measurement_ceiling"]

#: The equilibrium solver's tolerance (cm) for the perfect measurements: the points then
#: lie within about 1e-5 cm of the equilibrium whatever frame the solver starts from.
EXACT_TOL = 1e-6


def perfect_measurements(model, contractions: pd.DataFrame, points) -> np.ndarray:
    """Exact model-space positions of ``points`` on ``model`` at each row of ``contractions``.

    Parameters
    ----------
    model : synth.FaceModel
        The face (its state is reset afterwards).
    contractions : DataFrame
        One row per frame; the columns that name a muscle of the model or
        ``jaw_rotation`` are applied (others are ignored).
    points : sequence of str
        Measurement point names (see :func:`faceanalysis.estimation.model_response.model_points`).

    Returns
    -------
    ndarray, shape (T, P, 2)
        Orthographic x-y in cm (x = subject's left, y up).
    """
    from faceanalysis.estimation.model_response import equilibrium_points

    controls = [c for c in contractions.columns if c in model.muscle_names or c == JAW]
    if not controls:
        raise ValueError("contractions has no column naming a muscle of the model or "
                         f"{JAW!r}")
    values = contractions[controls].to_numpy(float)
    if not np.isfinite(values).all():
        raise ValueError("contractions must be finite")
    model.reset()
    try:
        # frames in order: each equilibrium starts from the last, which makes it cheap;
        # solved tightly, since the solver's default tolerance leaves points a few
        # hundredths of a millimetre from the equilibrium, depending on the last frame
        return np.stack([equilibrium_points(model, controls, v, points, tol=EXACT_TOL)
                         for v in values])
    finally:
        model.reset()


def _displacements(points: np.ndarray, response: FiducialResponse,
                   calibrate_on: int | None = None) -> np.ndarray:
    """Calibrate as an analysis does (first frame = neutral) and return model-space
    displacements. The points go in as an image would (y down, one pixel per cm,
    head frame at the origin): the calibration's affine map then absorbs the
    difference between this face and the generic one exactly as on a video. With
    ``calibrate_on``, only the first that many points are calibrated on (the contour
    points, as an analysis with face-mesh points does) and the map applied to all."""
    image = points * np.array([1.0, -1.0])
    heads = np.tile([0.0, 0.0, 1.0, 0.0], (len(points), 1))
    n = len(response.fiducials) if calibrate_on is None else calibrate_on
    cal = calibrate(image[0, :n], heads[0], response.rest[:n])
    return (image - image[0]) @ np.linalg.inv(cal.matrix).T


def _neutral(points: np.ndarray, response: FiducialResponse, calibrate_on: int) -> np.ndarray:
    """The first frame's ``points`` in model cm through the calibration of
    :func:`_displacements`: what an analysis's neutral frame gives
    (:func:`~faceanalysis.estimation.registry.mesh_neutral`)."""
    image = points[0] * np.array([1.0, -1.0])
    head = np.array([0.0, 0.0, 1.0, 0.0])
    cal = calibrate(image[:calibrate_on], head, response.rest[:calibrate_on])
    return cal.to_model(to_head_frame(image, head))


def measurement_ceiling(config: SuiteConfig | None = None, *,
                        estimators=("joint", "tw93"),
                        response: FiducialResponse | None = None,
                        own_response: bool = False, personalize: bool = False,
                        progress: bool = False) -> dict:
    """Score the fiducial estimators on perfect measurements of the suite's faces.

    Parameters
    ----------
    config : SuiteConfig, optional
        Identities, frames and sequences (default: the standard suite's; rendering
        options are not used).
    estimators : sequence of {'joint', 'mesh', 'model', 'tw93'}, keyword-only
        ``mesh`` reads the 16 contour points and the skin under the face-mesh landmarks
        (:func:`~faceanalysis.estimation.registry.mesh_response`), calibrated on the 16 as
        an analysis is: the ceiling of that observation set. ``model``: the ``mesh`` fit,
        then each frame fitted through the face model's own equilibrium
        (:func:`~faceanalysis.estimation.model_fit.fit_through_model`): the generic face's,
        or with ``own_response`` the identity's own.
    response : FiducialResponse, optional
        Response table to invert (default: the generic face's, as an analysis uses).
    own_response : bool, keyword-only
        Invert each identity's own response table instead (tabulated here, about 10 s
        per identity), and fit ``model`` through the identity's own model: what is left is
        the table's approximation (none for ``model``) and what the points cannot tell
        apart.
    personalize : bool, keyword-only
        Fit ``model`` through the generic face personalised to each sequence's neutral
        frame (:func:`~faceanalysis.estimation.model_fit.personal_model` of its exact
        points), as ``estimate_model(personalize=True)`` does. Not with ``own_response``.
    progress : bool
        Progress bar on stderr.

    Returns
    -------
    dict
        Estimator name -> the pooled report of :func:`faceanalysis.evaluation.scores.pool`
        (JSON-ready: ``controls`` name -> ``rmse``, ``r``, ``truth_max``,
        ``estimate_max``; ``jaw_rmse_deg``; ``frames``; ``sequences``), with
        ``points`` (the measurement points used). Fiducial errors are ``None``: the
        points are exact.

    Examples
    --------
    A smile with the mouth opened (AU 12 + 26) on one unseen face: from exact points
    the jaw is followed within 0.3 degree and the zygomaticus in step (r 1.0) within
    0.1; through the generic face's table its peak reads 0.82 for 0.7 on this face:

    >>> from faceanalysis.evaluation.suite import SuiteConfig
    >>> rep = measurement_ceiling(SuiteConfig(identities=1, frames=10,
    ...                                       sequences=(("au", "12:0.7,26:0.6"),)))
    >>> round(rep["joint"]["jaw_rmse_deg"], 1)
    0.5
    >>> zyg = rep["joint"]["controls"]["zygomaticus_major_l"]
    >>> round(zyg["r"], 3), zyg["truth_max"], round(zyg["rmse"], 2) <= 0.1
    (1.0, 0.7, True)
    >>> round(zyg["estimate_max"], 2)
    0.82
    """
    from faceanalysis.estimation.model_response import model_response, tabulate_response
    from synth.face_shape import FaceShape
    from synth.model import FaceModel
    from synth.render.sequence import contraction_timeline

    estimators = tuple(estimators)
    choices = (*POINT_ESTIMATORS, "mesh", "model")
    bad = [e for e in estimators if e not in choices]
    if bad or not estimators:
        raise ValueError(f"unknown estimators {bad} for the ceiling; choose from "
                         f"{', '.join(choices)}")
    if personalize and (own_response or "model" not in estimators):
        raise ValueError("personalize goes with the model estimator and without own_response "
                         "(each face's own model needs no personalising)")
    if config is None:
        config = SuiteConfig()
    if response is None:
        response = model_response()
    mesh_table = None
    if "mesh" in estimators or "model" in estimators:
        mesh_table = mesh_response()
    generic = FaceModel.default() if "model" in estimators and not own_response else None
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=config.identities * len(config.sequences), desc="ceiling",
                   unit="seq", file=sys.stderr, leave=False)
    reports: dict[str, list] = {e: [] for e in estimators}
    try:
        for i in range(config.identities):
            seed = config.seed_start + i
            model = FaceModel.build(FaceShape.random(seed))
            table, mtable = response, mesh_table
            if own_response:
                table = tabulate_response(model, response.muscles,
                                          n_levels=len(response.levels))
                if mesh_table is not None:
                    mtable = tabulate_response(model, mesh_table.muscles,
                                               n_levels=len(mesh_table.levels),
                                               points=mesh_table.fiducials)
            for kind, spec in config.sequences:
                truth = contraction_timeline(list(model.muscle_names), frames=config.frames,
                                             **script_kwargs(kind, spec))
                exact = perfect_measurements(model, truth, table.fiducials)
                disp = _displacements(exact, table)
                if mtable is not None:
                    mexact = perfect_measurements(model, truth, mtable.fiducials)
                    mdisp = _displacements(mexact, mtable, calibrate_on=len(MEASUREMENT_POINTS))
                mesh_values = None
                if mtable is not None:
                    mesh_values, mesh_options = mesh_fit(mdisp, mtable)
                for est in estimators:
                    if est == "mesh":
                        values = dict(zip(mtable.muscles, mesh_values.T))
                    elif est == "model":
                        through = model if own_response else generic
                        if personalize:
                            through, _ = personal_model(
                                _neutral(mexact, mtable, len(MEASUREMENT_POINTS)), mtable,
                                generic)
                        fitted = fit_through_model(mdisp, mtable, through, mesh_values,
                                                   **mesh_fit_keywords(mesh_options))
                        values = dict(zip(mtable.muscles, fitted.T))
                    else:
                        values = dict(zip(table.muscles,
                                          estimate(disp, table, estimator=est).T))
                    pairs = {c: (truth[c].to_numpy(float), np.nan_to_num(values[c]))
                             for c in (*MUSCLES, JAW) if c in truth and c in values}
                    reports[est].append({"_pairs": pairs, "frames": len(truth),
                                         "frames_compared": len(truth)})
                if bar is not None:
                    bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    out = {}
    for est, reps in reports.items():
        out[est] = public(pool(reps))
        points = mesh_table.fiducials if est in ("mesh", "model") else response.fiducials
        out[est].update(points=list(points), own_response=bool(own_response))
        if est == "model":
            out[est]["personalized"] = bool(personalize)
    return out
