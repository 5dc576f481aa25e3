"""The estimators behind one name each: tracked points in, contractions out.

Every estimator takes the same :class:`Observations` (the tracks, the calibrated point
displacements in model units, the model response and the neutral frame) and returns a
table of controls per frame, so that :func:`faceanalysis.analysis.analyze` runs each of
them through one path: one fill of the table, one model-fit check, one confidence.

``joint`` (default)
    Bounded least squares of all controls at once through the model's fiducial
    response (:func:`~faceanalysis.estimation.estimators.estimate_joint`); with
    ``refine=True`` refined through the face model itself
    (:func:`~faceanalysis.estimation.refine.refine_through_model`).
``mesh``
    The same fit on every reliable tracked point: the 16 contour points and the landmark
    tracker's face mesh (:mod:`~faceanalysis.estimation.mesh_points`), whose motion is
    taken relative to the head by a 3-D alignment; needs ``tracker='landmarks'``
    (:func:`estimate_mesh`).
``fused``
    ``mesh`` with the video's dense flow in the same objective (:func:`estimate_fused`);
    reads the video a second time.
``tw93``
    The paper's per-muscle inversion (:func:`~faceanalysis.estimation.estimators.estimate_tw93`).
``flow``
    Bounded least squares of the dense face flow on the model's flow templates
    (:func:`~faceanalysis.estimation.flow.estimate_flow`); reads the video a second time.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from faceanalysis.estimation.estimators import estimate_joint, estimate_tw93
from faceanalysis.estimation.names import (
    ESTIMATOR_NAMES,
    MESH_ESTIMATORS,
    TEMPORAL_ESTIMATORS,
    VIDEO_ESTIMATORS,
)
from faceanalysis.estimation.response import FiducialResponse
from faceanalysis.tracking import Tracks

__all__ = ["ESTIMATORS", "MESH_ESTIMATORS", "REGIONS", "TEMPORAL_ESTIMATORS", "VIDEO_ESTIMATORS",
           "Estimate", "Observations", "estimate_fused", "estimate_mesh", "estimate_model",
           "mesh_fit", "mesh_neutral", "mesh_regions", "regions_lost", "run_estimator"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Observations:
    """What an estimator reads.

    Attributes
    ----------
    tracks : Tracks
        The tracked video.
    response : FiducialResponse
        The model response the point estimators invert.
    displacements : ndarray, shape (T, P, 2)
        Displacement of ``response.fiducials`` from the neutral frame in model cm (NaN:
        point not measured, excluded as suspect or faded, or frame lost).
    neutral : int
        Row of the neutral frame in ``tracks``.
    options : dict
        The input options (``fps``, ``start``, ``end``) for estimators that read the
        video again.
    calibration : Calibration, optional
        The model-to-head-frame map of the neutral frame, for estimators that read
        points other than ``response.fiducials``.
    """

    tracks: Tracks
    response: FiducialResponse
    displacements: np.ndarray
    neutral: int
    options: dict = field(default_factory=dict)
    calibration: object = None


@dataclass(frozen=True)
class Estimate:
    """What an estimator gives back.

    Attributes
    ----------
    values : DataFrame
        One column per estimated control, one row per frame of the tracks.
    response : FiducialResponse
        The model response of the points it read (the fit residual is measured on them).
    displacements : ndarray, shape (T, P, 2)
        Those points' displacements, model cm.
    fit_options : dict
        Options of :func:`~faceanalysis.estimation.estimators.estimate_joint` that the
        estimator used (for the identifiability simulation); empty when it is not that
        fit.
    residual : ndarray, shape (T,), optional
        The fit residual per frame (RMS over the points seen, model cm) where the
        estimator measures it itself (through the model's own equilibrium); None: through
        ``response`` (:func:`~faceanalysis.estimation.estimators.fit_residual`).
    """

    values: pd.DataFrame
    response: FiducialResponse
    displacements: np.ndarray
    fit_options: dict = field(default_factory=dict)
    residual: np.ndarray | None = None

    def __repr__(self) -> str:
        n_frames, n_controls = self.values.shape
        return (f"<Estimate: {n_controls} controls on {n_frames} "
                f"frame{'' if n_frames == 1 else 's'}, from {len(self.response.fiducials)} "
                f"points{'' if self.residual is None else '; its own fit residual'}>")


def _in_response_order(values: np.ndarray, obs: Observations) -> pd.DataFrame:
    return pd.DataFrame(values, columns=list(obs.response.muscles))


#: Weight of the temporal prior of the ``joint``, ``mesh`` and ``fused`` fits
#: (``estimate_joint``'s ``temporal``): each frame is drawn toward its neighbours' fits, so
#: that controls the points tell apart only weakly do not trade places from frame to frame.
#: ``joint`` on the real clips (landmark tracker): single-frame spikes 676 / 261 / 99
#: without, 338 / 124 / 36 with; on the standard suite (snakes, 110 sequences) its median
#: per-control RMSE 0.1105 without, 0.1117 with.
TEMPORAL = 0.01


def _joint(obs: Observations, *, refine: bool = False, temporal: float = TEMPORAL
           ) -> pd.DataFrame:
    values = estimate_joint(obs.displacements, obs.response, temporal=temporal)
    if refine:
        from faceanalysis.estimation.refine import refine_through_model
        from synth.model import FaceModel

        values = refine_through_model(obs.displacements, obs.response, FaceModel.default(),
                                      values)
    return _in_response_order(values, obs)


#: The ``mesh`` fit's settings (see :func:`~faceanalysis.estimation.estimators.estimate_joint`),
#: chosen on the 20 people of the IMM set (a neutral photograph against a second one
#: under a side light, and against a smile) and on simulated contractions of every muscle
#: pair at 0.2, 0.5 and 1.0 through the response: each contour point weighs as much as 5
#: face-mesh points (they are 16 against 356 and follow edges the mesh smooths over); the
#: sparsity prior is 5 times the ``joint`` fit's; the muscles it leaves active are
#: refitted with the prior weighed down by how far it let them off rest (gone from a
#: fifth of the range on: ``debias=0.2``), so that it chooses which muscles act and does
#: not also shrink how much, without the relaxed lasso's jump from rest to a full refit
#: that switched a muscle near its threshold on and off from frame to frame; and the
#: box-constrained steps are solved to their optimum (``precondition``: projected gradient
#: on the Jacobi-scaled problem, at most 400 iterations; unscaled, as ``joint`` solves
#: them, the steps stop short, up to 0.6 of a control's range on a real clip).
#: A stronger prior (0.025) or a tighter Huber threshold (0.02 cm) let more side-lit
#: neutrals read rest, but only by ignoring real motion (a full corrugator read 0.33).
#: On a video, each frame is drawn toward its neighbours' fits (:data:`TEMPORAL`), so that
#: muscles the points tell apart only weakly do not trade places from frame to frame; a
#: single-frame pulse of orbicularis oculi, the least observed muscle, then reads 0.8 as
#: 0.65, a three-frame one peaking at 1.0 as 0.89.
MESH_FIT = {"sparsity": 2e-2, "robust": 0.1, "debias": 0.2, "inner_iterations": 400,
            "precondition": True, "temporal": TEMPORAL}
#: Weight of each contour point against each face-mesh point in the ``mesh`` fit.
CONTOUR_WEIGHT = 5.0


def mesh_response(model=None) -> FiducialResponse:
    """The model response of the ``mesh`` estimator's points: the contour points
    (:data:`~faceanalysis.estimation.model_response.MEASUREMENT_POINTS`) then the usable
    face-mesh landmarks; cached on disk."""
    from faceanalysis.estimation.mesh_points import mesh_indices, mesh_point_names
    from faceanalysis.estimation.model_response import MEASUREMENT_POINTS, model_response

    return model_response(model, points=(*MEASUREMENT_POINTS, *mesh_point_names(mesh_indices())))


def mesh_observations(obs: Observations, response: FiducialResponse) -> np.ndarray:
    """Displacements (model cm) of ``response.fiducials``: the contour points from ``obs``,
    the face-mesh points from the tracks' landmarks, shape (T, P, 2)."""
    from faceanalysis.estimation.mesh_points import (
        DISPLACEMENT_CHUNK,
        MESH_POINT_PREFIX,
        mesh_displacements,
        to_model_units,
    )

    tracks = obs.tracks
    landmarks = None if tracks is None else tracks.landmarks
    if landmarks is None or all(lm is None for lm in landmarks):
        raise ValueError("the mesh estimator reads the landmark tracker's face mesh: analyse "
                         "with tracker='landmarks' (--tracker landmarks)")
    if obs.calibration is None:
        raise ValueError("the mesh estimator needs the neutral frame's calibration")
    names = response.fiducials
    mesh = [i for i, n in enumerate(names) if n.startswith(MESH_POINT_PREFIX)]
    idx = [int(names[i].removeprefix(MESH_POINT_PREFIX)) for i in mesh]
    d = np.full((len(tracks), len(names), 2), np.nan)
    for j, n in enumerate(names):
        if not n.startswith(MESH_POINT_PREFIX) and n in obs.response.fiducials:
            d[:, j] = obs.displacements[:, obs.response.fiducials.index(n)]
    k = obs.neutral
    ref = np.asarray(landmarks[k], dtype=float)[idx, :2]
    # a chunk of frames at a time (each frame's motion is its own): no array of the whole
    # video's pixel motion beside ``d``
    for a in range(0, len(d), DISPLACEMENT_CHUNK):
        part = [landmarks[k], *landmarks[a:a + DISPLACEMENT_CHUNK]]    # neutral first
        px = mesh_displacements(part, 0, idx)[1:]
        d[a:a + DISPLACEMENT_CHUNK, mesh] = to_model_units(px, ref, tracks.heads[k],
                                                           obs.calibration)
    # where the tracker lost a region (a brow under hair, the lower face under a hand),
    # the mesh goes on drawing a face the landmark model imagines: its points there go too
    lost = regions_lost(tracks)
    region = mesh_regions(response)
    for name, gone in lost.items():
        cols = [j for j, r in zip(mesh, region) if r == name]
        d[np.ix_(gone, cols)] = np.nan
    # a frame the tracker lost has no measurement, whatever the mesh still showed
    d[~np.asarray(tracks.success, bool)] = np.nan
    return d


def mesh_neutral(obs: Observations, response: FiducialResponse) -> np.ndarray:
    """Positions (model cm, x = the subject's left, y up) of ``response.fiducials`` on the
    neutral frame, through the calibration: the contour points as calibrated, the face-mesh
    points from the tracks' landmarks; NaN where not seen, shape (P, 2)."""
    from faceanalysis.estimation.mesh_points import MESH_POINT_PREFIX
    from faceanalysis.tracking import to_head_frame

    tracks, cal, k = obs.tracks, obs.calibration, obs.neutral
    if cal is None or tracks is None or tracks.landmarks is None or tracks.landmarks[k] is None:
        raise ValueError("the neutral positions need the neutral frame's calibration and "
                         "the landmark tracker's face mesh on it")
    names = response.fiducials
    out = np.full((len(names), 2), np.nan)
    for j, n in enumerate(names):
        if not n.startswith(MESH_POINT_PREFIX) and n in obs.response.fiducials:
            out[j] = cal.to_model(cal.neutral[obs.response.fiducials.index(n)])
    mesh = [j for j, n in enumerate(names) if n.startswith(MESH_POINT_PREFIX)]
    idx = [int(names[j].removeprefix(MESH_POINT_PREFIX)) for j in mesh]
    image = np.asarray(tracks.landmarks[k], dtype=float)[idx, :2]
    out[mesh] = cal.to_model(to_head_frame(image, tracks.heads[k]))
    return out


#: The face's regions by their contours: a region is lost on a frame where every one of
#: its contours is (:func:`regions_lost`).
REGIONS = {"brow_l": ("brow_l",), "brow_r": ("brow_r",),
           "lower_face": ("upper_lip", "lower_lip", "chin_boss", "furrow_l", "furrow_r")}


def regions_lost(tracks: Tracks) -> dict[str, np.ndarray]:
    """Per region of :data:`REGIONS`, the tracked frames on which none of its contours'
    measurement points was measured, shape (T,) each."""
    from faceanalysis.tracking import POINT_CONTOUR

    measured = np.isfinite(np.asarray(tracks.points, dtype=float)).all(axis=2)   # (T, P)
    tracked = np.asarray(tracks.success, bool)
    out = {}
    for name, contours in REGIONS.items():
        cols = [j for j, p in enumerate(tracks.point_names) if POINT_CONTOUR.get(p) in contours]
        if cols:
            out[name] = tracked & ~measured[:, cols].any(axis=1)
    return out


def mesh_regions(response: FiducialResponse) -> list[str | None]:
    """The region (:data:`REGIONS`) of each face-mesh point of ``response``: that of the
    contour point nearest to it on the model at rest (None: no contour point)."""
    from faceanalysis.estimation.mesh_points import MESH_POINT_PREFIX
    from faceanalysis.tracking import POINT_CONTOUR

    of_contour = {c: r for r, cs in REGIONS.items() for c in cs}
    names = response.fiducials
    contour = [j for j, n in enumerate(names) if POINT_CONTOUR.get(n) in of_contour]
    out: list[str | None] = []
    for j, n in enumerate(names):
        if not n.startswith(MESH_POINT_PREFIX):
            continue
        if not contour:
            out.append(None)
            continue
        dist = np.hypot(*(response.rest[contour] - response.rest[j]).T)
        out.append(of_contour[POINT_CONTOUR[names[contour[int(np.argmin(dist))]]]])
    return out


def mesh_fit(displacements: np.ndarray, response: FiducialResponse, *,
             contour_weight: float = CONTOUR_WEIGHT, **fit) -> tuple[np.ndarray, dict]:
    """The ``mesh`` fit of ``displacements`` of ``response``'s points: contour points weighed
    ``contour_weight`` to each face-mesh point, the settings of :data:`MESH_FIT` (``fit``
    adds to or overrides them, e.g. ``quadratic``). Returns the contractions and the
    options used."""
    from faceanalysis.estimation.mesh_points import MESH_POINT_PREFIX

    w = np.array([1.0 if n.startswith(MESH_POINT_PREFIX) else contour_weight
                  for n in response.fiducials])
    options = {"weights": w, **MESH_FIT, **fit}
    return estimate_joint(displacements, response, **options), options


def estimate_mesh(obs: Observations, *, contour_weight: float = CONTOUR_WEIGHT,
                  **fit) -> Estimate:
    """The ``mesh`` estimator: bounded least squares of all controls on the contour points
    and the face mesh together (see :func:`mesh_observations` and :func:`mesh_fit`)."""
    response = mesh_response()
    d = mesh_observations(obs, response)
    values, options = mesh_fit(d, response, contour_weight=contour_weight, **fit)
    return Estimate(pd.DataFrame(values, columns=list(response.muscles)), response, d, options)


def estimate_model(obs: Observations, *, contour_weight: float = CONTOUR_WEIGHT,
                   temporal: float = TEMPORAL, personalize: bool = False,
                   progress: bool = False) -> Estimate:
    """The ``model`` estimator: the ``mesh`` fit (:func:`estimate_mesh`) as the first guess,
    then every frame fitted through the face model's own equilibrium, with the
    equilibrium's sensitivity as the Jacobian
    (:func:`~faceanalysis.estimation.model_fit.fit_through_model`) and the same points,
    weights and priors. About 0.1 s a frame. The identifiability simulation runs the
    ``mesh`` fit (the table standing in for the model: the same points and priors).

    ``personalize``: fit through the generic face warped onto the subject's neutral frame
    (:func:`~faceanalysis.estimation.model_fit.personal_model` of :func:`mesh_neutral`)
    instead of the generic face itself."""
    from faceanalysis.estimation.model_fit import (
        fit_through_model,
        mesh_fit_keywords,
        personal_model,
    )
    from synth.model import FaceModel

    first = estimate_mesh(obs, contour_weight=contour_weight, temporal=temporal)
    response, d, options = first.response, first.displacements, first.fit_options
    initial = first.values[list(response.muscles)].to_numpy(float)
    model = FaceModel.default()
    if personalize:
        model, blend = personal_model(mesh_neutral(obs, response), response, model)
        if blend < 1.0:
            log.warning("the face model follows the neutral frame's points at %.0f %% of the "
                        "warp beyond its affine part only (the full warp folds the face)",
                        100 * blend)
    bar = None
    if progress:
        from faceanalysis.tracking import progress_bar

        bar = progress_bar(len(d), True, "fit")
    try:
        values, residual = fit_through_model(
            d, response, model, initial, **mesh_fit_keywords(options), return_residual=True,
            progress=None if bar is None else bar.update)
    finally:
        if bar is not None:
            bar.close()
    return Estimate(pd.DataFrame(values, columns=list(response.muscles)), response, d, options,
                    residual)


#: Weight of the dense flow's least squares against the points' in the ``fused`` fit
#: (flow in head units, points in cm). On 2 identities of the rendered suite (22
#: sequences, landmark tracker) the median per-control RMSE is 0.229 at 0 (``mesh``), 0.211
#: at 10, 0.164 at 30, 0.125 at 100, 0.117 at 1000 (the flow alone: 0.109); on the 20 IMM
#: people (a flow between two photographs, taken apart in time) the smile's AUC is 0.980,
#: 0.995, 0.988, 0.978, 0.968 and the side-lit neutral's largest muscle 0.24, 0.20, 0.27,
#: 0.39, 0.46 (median). 30 keeps the real photographs where ``mesh`` has them.
FLOW_WEIGHT = 30.0


def estimate_fused(obs: Observations, *, flow_weight: float = FLOW_WEIGHT,
                   contour_weight: float = CONTOUR_WEIGHT, **fit) -> Estimate:
    """The ``fused`` estimator: the ``mesh`` fit (:func:`estimate_mesh`) with the video's
    dense flow in the same objective (:func:`~faceanalysis.estimation.flow.flow_quadratic`,
    weighted by ``flow_weight``); reads the video a second time."""
    from faceanalysis.estimation.flow import flow_quadratic

    if not (np.isfinite(flow_weight) and flow_weight >= 0):
        raise ValueError(f"flow_weight must be a non-negative number, got {flow_weight}")
    response = mesh_response()
    d = mesh_observations(obs, response)
    o = obs.options
    h, g = flow_quadratic(obs.tracks.video, obs.tracks.table, response.muscles,
                          neutral=int(obs.tracks.frames[obs.neutral]), fps=o.get("fps"),
                          start=o.get("start") or 0, end=o.get("end"))
    values, options = mesh_fit(d, response, contour_weight=contour_weight,
                               quadratic=(flow_weight * h, flow_weight * g), **fit)
    # the identifiability simulation is of the points' fit: it has no flow to add
    options.pop("quadratic")
    return Estimate(pd.DataFrame(values, columns=list(response.muscles)), response, d, options)


def _tw93(obs: Observations) -> pd.DataFrame:
    return _in_response_order(estimate_tw93(obs.displacements, obs.response), obs)


def _flow(obs: Observations, **kwargs) -> pd.DataFrame:
    from faceanalysis.estimation.flow import estimate_flow

    o = obs.options
    est = estimate_flow(obs.tracks.video, obs.tracks.table,
                        neutral=int(obs.tracks.frames[obs.neutral]), fps=o.get("fps"),
                        start=o.get("start") or 0, end=o.get("end"), **kwargs)
    return est.reset_index(drop=True)


#: Estimator name -> function(observations, **options) -> DataFrame with one column per
#: estimated control (muscles, ``jaw_rotation``) and one row per frame of the tracks (a
#: control it does not estimate is absent or NaN throughout), or an :class:`Estimate`
#: when it reads other points than ``observations.response.fiducials``. In the order of
#: :data:`~faceanalysis.estimation.names.ESTIMATOR_NAMES`.
ESTIMATORS: dict[str, Callable[..., pd.DataFrame]] = dict(zip(ESTIMATOR_NAMES, (
    _joint, estimate_mesh, estimate_model, estimate_fused, _tw93, _flow)))


def run_estimator(name: str, obs: Observations, **options) -> Estimate:
    """Run the estimator ``name`` (see :data:`ESTIMATORS`) on ``obs``.

    An estimator that reads only ``obs.response.fiducials`` is returned with them.

    Raises
    ------
    ValueError
        For an unknown name (the message lists the valid ones), and for an estimator of
        :data:`VIDEO_ESTIMATORS` on tracks of the video mirrored (its frames are read as
        they are).
    """
    if name not in ESTIMATORS:
        raise ValueError(f"unknown estimator {name!r}; choose from {', '.join(ESTIMATORS)}")
    if name in VIDEO_ESTIMATORS and getattr(obs.tracks, "mirrored", False):
        raise ValueError(f"the {name} estimator reads the video's frames as they are; it "
                         f"does not work on tracks of the video mirrored")
    out = ESTIMATORS[name](obs, **options)
    if isinstance(out, Estimate):
        return out
    return Estimate(out, obs.response, obs.displacements)
