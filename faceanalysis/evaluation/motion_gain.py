"""How much of the skin's motion a tracker reports, point by point.

A rendered sequence knows where every point of the face model's skin is on every frame.
A tracked point (a contour's fiducial, a face-mesh landmark) is put on the skin point under
it on the neutral frame (:func:`~faceanalysis.estimation.mesh_points.mesh_correspondence`);
if the tracker followed that skin, its displacement from the neutral frame would be the
skin point's. :func:`motion_gain` measures what share of it the tracker reports: the
least-squares gain ``g`` of the tracked displacements ``m`` on the exact ones ``e`` over the
frames, ``g = sum <m, e> / sum |e|^2``. 1 follows the skin, 0 stands still while the skin
moves (a landmark placed from the face's outline, not from what lies under it), and an
estimator that reads such points as skin reads the contractions too small by about as
much. :func:`exact_displacements` gives ``e`` for a sequence's contractions, calibrated
as an analysis's neutral frame is.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from faceanalysis.estimation.response import FiducialResponse

__all__ = ["exact_displacements", "motion_gain", "pool_gains", "sequence_gain"]


def _check_displacements(name: str, a) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim != 3 or a.shape[2] != 2:
        raise ValueError(f"{name} must have shape (T, P, 2), got {a.shape}")
    return a


def motion_gain(measured, exact, *, min_motion: float = 1e-3) -> tuple[np.ndarray,
                                                                        np.ndarray]:
    """Per point, the share of its exact motion that the tracked point reports.

    Parameters
    ----------
    measured : array_like, shape (T, P, 2)
        Tracked displacements from the neutral frame (any unit; NaN where not measured).
    exact : array_like, shape (T, P, 2)
        The exact displacements of the same points, in the same unit.
    min_motion : float, keyword-only
        A point whose exact motion (root of the summed squares over the frames it was
        measured on) is under this has no gain (NaN): it did not move.

    Returns
    -------
    gain : ndarray, shape (P,)
        ``sum_t <m_t, e_t> / sum_t |e_t|^2`` over the frames where the point was
        measured; NaN where it was never measured or did not move.
    motion : ndarray, shape (P,)
        ``sqrt(sum_t |e_t|^2)`` over the same frames: how much there was to follow (a
        weight when gains are pooled over points or sequences).

    Raises
    ------
    ValueError
        Shapes that differ or are not (T, P, 2), NaN in ``exact``, or a negative
        ``min_motion``.

    Examples
    --------
    >>> e = np.zeros((3, 2, 2)); e[1:, :, 0] = [[1.0, 2.0], [2.0, 4.0]]
    >>> g, motion = motion_gain(0.5 * e * [[[1], [0]]] + e * [[[0], [1]]], e)
    >>> np.round(g, 3)
    array([0.5, 1. ])
    """
    m = _check_displacements("measured", measured)
    e = _check_displacements("exact", exact)
    if m.shape != e.shape:
        raise ValueError(f"measured and exact must have the same shape, got {m.shape} "
                         f"and {e.shape}")
    if not np.isfinite(e).all():
        raise ValueError("exact displacements must be finite")
    if not (np.isfinite(min_motion) and min_motion >= 0):
        raise ValueError(f"min_motion must be a non-negative number, got {min_motion}")
    seen = np.isfinite(m).all(axis=2)
    dot = np.where(seen, (np.nan_to_num(m) * e).sum(axis=2), 0.0).sum(axis=0)
    energy = np.where(seen, (e * e).sum(axis=2), 0.0).sum(axis=0)
    motion = np.sqrt(energy)
    gain = np.full(m.shape[1], np.nan)
    moved = motion >= max(min_motion, 1e-12)
    gain[moved] = dot[moved] / energy[moved]
    return gain, motion


def exact_displacements(model, contractions: pd.DataFrame, response: FiducialResponse, *,
                        calibrate_on: int | None = None) -> np.ndarray:
    """The exact displacements (model cm) of ``response``'s points under ``contractions``,
    through the neutral frame's calibration as an analysis makes it.

    Parameters
    ----------
    model : synth.model.FaceModel
        The face the sequence was rendered from (its state is reset afterwards).
    contractions : DataFrame
        One row per frame, the first the neutral one; its columns that name a muscle of
        the model or ``jaw_rotation`` are applied.
    response : FiducialResponse
        Whose points (``response.fiducials``) and rest positions the calibration maps to.
    calibrate_on : int, optional, keyword-only
        Calibrate on the first this many points only (the 16 contour points, as an
        analysis that also reads the face mesh does) and apply the map to all.

    Returns
    -------
    ndarray, shape (T, P, 2)
        x = the subject's left, y up; the first row is zero.
    """
    from faceanalysis.evaluation.ceiling import _displacements, perfect_measurements

    if calibrate_on is not None and not 3 <= calibrate_on <= len(response.fiducials):
        raise ValueError(f"calibrate_on must lie in 3..{len(response.fiducials)}, got "
                         f"{calibrate_on}")
    points = perfect_measurements(model, contractions, response.fiducials)
    return _displacements(points, response, calibrate_on=calibrate_on)


def sequence_gain(folder, model, **options) -> tuple[np.ndarray, np.ndarray, object]:
    """Gain of each point an analysis reads on one rendered sequence.

    Parameters
    ----------
    folder : path
        A rendered sequence (``video.mp4`` and ``truth.csv``, as
        :func:`synth.render.sequence.render_sequence` writes them), starting at rest.
    model : synth.model.FaceModel
        The face it was rendered from.
    **options
        Passed to :func:`~faceanalysis.analysis.pipeline.analyze` (default: its defaults),
        e.g. ``tracker="snakes"``.

    Returns
    -------
    gain, motion : ndarray, shape (P,)
        :func:`motion_gain` of the points the analysis's estimator read (NaN gains where
        the first frame was not the neutral one: the exact motion is from frame 0).
    analysis : Analysis
        The analysis (its ``estimate.response.fiducials`` name the points).
    """
    from pathlib import Path

    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.estimation.model_response import MEASUREMENT_POINTS

    folder = Path(folder)
    truth = pd.read_csv(folder / "truth.csv")
    analysis = analyze(folder / "video.mp4", **options)
    est = analysis.estimate
    n = len(est.response.fiducials)
    if analysis.metadata["parameters"]["neutral_frame"] != 0:
        return np.full(n, np.nan), np.zeros(n), analysis
    controls = [c for c in truth.columns if c in model.muscle_names or c == "jaw_rotation"]
    calibrate_on = len(MEASUREMENT_POINTS) if n > len(MEASUREMENT_POINTS) else None
    exact = exact_displacements(model, truth[controls].iloc[:len(analysis.table)],
                                est.response, calibrate_on=calibrate_on)
    gain, motion = motion_gain(est.displacements, exact)
    return gain, motion, analysis


def pool_gains(gains, motions) -> tuple[np.ndarray, np.ndarray]:
    """Gains of the same points over several sequences, pooled as one least-squares gain
    (each sequence weighted by its exact motion squared): (gain, motion)."""
    g = np.asarray(gains, dtype=float)
    e2 = np.asarray(motions, dtype=float) ** 2
    energy = e2.sum(axis=0)
    dot = np.where(np.isfinite(g), g * e2, 0.0).sum(axis=0)
    pooled = np.full(energy.shape, np.nan)
    pooled[energy > 0] = dot[energy > 0] / energy[energy > 0]
    return pooled, np.sqrt(energy)

