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
``tw93``
    The paper's per-muscle inversion (:func:`~faceanalysis.estimation.estimators.estimate_tw93`).
``flow``
    Bounded least squares of the dense face flow on the model's flow templates
    (:func:`~faceanalysis.estimation.flow.estimate_flow`); reads the video a second time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from faceanalysis.estimation.estimators import estimate_joint, estimate_tw93
from faceanalysis.estimation.response import FiducialResponse
from faceanalysis.tracking import Tracks

__all__ = ["ESTIMATORS", "Observations", "run_estimator"]


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
    """

    tracks: Tracks
    response: FiducialResponse
    displacements: np.ndarray
    neutral: int
    options: dict = field(default_factory=dict)


def _in_response_order(values: np.ndarray, obs: Observations) -> pd.DataFrame:
    return pd.DataFrame(values, columns=list(obs.response.muscles))


def _joint(obs: Observations, *, refine: bool = False) -> pd.DataFrame:
    values = estimate_joint(obs.displacements, obs.response)
    if refine:
        from faceanalysis.estimation.refine import refine_through_model
        from synth.model import FaceModel

        values = refine_through_model(obs.displacements, obs.response, FaceModel.default(),
                                      values)
    return _in_response_order(values, obs)


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
#: estimated control (muscles, ``jaw_rotation``) and one row per frame of the tracks; a
#: control it does not estimate is absent or NaN throughout.
ESTIMATORS: dict[str, Callable[..., pd.DataFrame]] = {
    "joint": _joint,
    "tw93": _tw93,
    "flow": _flow,
}


def run_estimator(name: str, obs: Observations, **options) -> pd.DataFrame:
    """Run the estimator ``name`` (see :data:`ESTIMATORS`) on ``obs``.

    Raises
    ------
    ValueError
        For an unknown name (the message lists the valid ones).
    """
    if name not in ESTIMATORS:
        raise ValueError(f"unknown estimator {name!r}; choose from {', '.join(ESTIMATORS)}")
    return ESTIMATORS[name](obs, **options)
