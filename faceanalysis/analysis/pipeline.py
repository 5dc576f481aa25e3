"""Video in, muscle contractions out: the analysis pipeline (004, section V).

For every frame the nine snakes of :mod:`trackers` relax from the previous
frame's equilibrium; the 11 fiducial points and the head reference frame come out.
After the pass, the neutral frame calibrates the face model into the head frame
(:mod:`faceanalysis.estimation.calibration`), the fiducial motion is taken back into model
units, and an estimator (:mod:`faceanalysis.estimation.estimators`) inverts the model's
fiducial response (:mod:`faceanalysis.estimation.response`) into contractions.

Frames are streamed: memory holds the per-frame measurements (a few hundred
bytes a frame), never the frames.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.estimation.calibration import (
    MAX_POINT_RESIDUAL,
    Calibration,
    calibrate,
    find_suspect,
)
from faceanalysis.errors import FaceAnalysisError
from faceanalysis.estimation.estimators import ESTIMATORS, estimate, fit_residual
from faceanalysis.estimation.model_response import CURVE_POINTS
from faceanalysis.estimation.response import FiducialResponse
from faceanalysis.io.table import (
    FIDUCIALS,
    HEAD_COLUMNS,
    JAW,
    MUSCLES,
    empty_table,
    with_au_columns,
)
from faceanalysis.io.video import MIN_FACE_SIZE, open_video, read_ahead

log = logging.getLogger(__name__)

#: A frame whose measured points lie farther than this from the estimate's prediction
#: (root mean square, model cm) is one the face model does not explain, and its
#: ``confidence`` is lowered to ``MAX_FIT_RESIDUAL / residual``. On 110 rendered
#: sequences of the standard suite (10 faces) the worst frame was 0.41 cm away and the
#: median 0.05; on the three real clips the median frame is 0.7-1.0 cm away (heads that
#: turn out of the image plane, contours on other features).
MAX_FIT_RESIDUAL = 0.5

__all__ = ["Analysis", "analyze", "analyze_to_folder", "reestimate", "ESTIMATORS"]


@dataclass
class Analysis:
    """The result of :func:`analyze`.

    Attributes
    ----------
    table : DataFrame
        One row per frame, the columns of ``contractions.csv`` (see
        :func:`faceanalysis.io.table.contraction_columns`).
    contours : list of dict or None
        Per frame, contour name -> (n, 2) node positions in pixels (None for frames
        that could not be decoded).
    metadata : dict
        The content of ``analysis.json``.
    calibration : Calibration
        The neutral-frame calibration.
    response : FiducialResponse
        The model response the estimate inverted.
    measurements : ndarray, shape (T, P, 2)
        Image positions of the response's measurement points (the 11 fiducials and
        the lower lip's centre) per frame; NaN for lost frames.
    fit_residual : ndarray, shape (T,)
        Per frame, the root-mean-square distance in model cm between the measured
        point displacements and the face model's prediction at the estimate (see
        :data:`MAX_FIT_RESIDUAL`); NaN for lost frames.
    track_confidence : ndarray, shape (T,)
        The tracker's confidence alone; the table's ``confidence`` is its minimum with
        ``MAX_FIT_RESIDUAL / fit_residual``.
    """

    table: pd.DataFrame
    contours: list
    metadata: dict
    calibration: Calibration | None = None
    response: FiducialResponse | None = None
    measurements: np.ndarray | None = None
    timings: dict = field(default_factory=dict)
    fit_residual: np.ndarray | None = None
    track_confidence: np.ndarray | None = None

    @property
    def fiducials(self) -> np.ndarray:
        """Tracked fiducials, shape (T, 11, 2), pixels; NaN for lost frames."""
        cols = [c for name in FIDUCIALS for c in (f"fid_{name}_x", f"fid_{name}_y")]
        return self.table[cols].to_numpy(float).reshape(len(self.table), len(FIDUCIALS), 2)

    @property
    def contractions(self) -> pd.DataFrame:
        """Muscle columns and ``jaw_rotation``, indexed by frame."""
        return self.table.set_index("frame")[[*MUSCLES, JAW]]

    def plot(self, path: str | os.PathLike | None = None, **kwargs):
        """The time-series plot (like Fig. 8 of 004); saved to ``path`` if given."""
        from faceanalysis.viz.plots import plot_contractions

        return plot_contractions(self.table, path, **kwargs)

    def save(self, output: str | os.PathLike, *, overwrite: bool = False) -> dict[str, Path]:
        """Write ``contractions.csv``, ``analysis.json`` and ``contractions.png`` to ``output``."""
        from faceanalysis.analysis.results import OutputFolder

        folder = OutputFolder(output, overwrite=overwrite)
        return folder.write(self.table, self.metadata, title=self.metadata.get("input", {})
                            .get("name"))


def _load_layout(layout, frame_size):
    from trackers import FaceLayout

    if layout is None or isinstance(layout, FaceLayout):
        return layout
    path = Path(layout)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such layout file")
    lay = FaceLayout.from_json(path)
    if tuple(lay.image_size) != tuple(frame_size):
        raise ValueError(f"{path}: layout is for {lay.image_size[0]}x{lay.image_size[1]} frames, "
                         f"the video has {frame_size[0]}x{frame_size[1]}")
    return lay


#: How a measurement point that is not one of the 11 fiducials is read off the contours:
#: name -> (contour, fraction of its arc length).
_CONTOUR_POINTS = {"lip_lower_centre": ("lower_lip", 0.5), **CURVE_POINTS}

#: The contour each measurement point comes from: a point is missing on a frame where
#: its contour is lost (e.g. the chin below the bottom of the frame), while the points
#: of the other contours still count.
POINT_CONTOUR = {
    **{f"brow_{p}_{s}": f"brow_{s}" for p in ("inner", "mid", "outer") for s in "lr"},
    "mouth_corner_l": "upper_lip", "mouth_corner_r": "upper_lip",
    "furrow_top_l": "furrow_l", "furrow_top_r": "furrow_r",
    "chin": "chin_boss", "lip_lower_centre": "lower_lip",
    **{name: contour for name, (contour, _) in CURVE_POINTS.items()},
}

#: A frame is tracked (``success = 1``) when its head frame is known and at least this
#: many measurement points are; controls that only the missing points observe are NaN.
MIN_POINTS = 7

#: A furrow's lower end (``furrow_bottom_*``) is measured only on frames where the
#: tracked furrow is at least this long relative to the neutral frame. The face model
#: never shortens a nasolabial furrow by more than 1.4 % (risorius at full contraction)
#: and opening the jaw lengthens it by 18 % (the generic face's response, each control
#: at its bound, along the furrow's top, middle and lower end); a tracked furrow that
#: got shorter ends where its line faded out (the stretched lower furrow fades as the
#: jaw opens), not where the model's furrow ends, and its end would read as a jaw that
#: did not open.
#: On the demo's sequence this took the jaw error from 2.57 to 0.89 degrees; on the
#: standard suite from 0.60 to 0.54 (median joint RMSE 0.121 -> 0.119).
MIN_FURROW_STRETCH = 0.98

#: The measurement points at a contour's lower end: name -> contour.
_END_POINTS = {name: contour for name, (contour, fraction) in CURVE_POINTS.items()
               if fraction == 1.0}


def faded_furrow_ends(stretch, neutral: int, names) -> np.ndarray:
    """Where a furrow's lower end is not measured (see :data:`MIN_FURROW_STRETCH`).

    Parameters
    ----------
    stretch : array_like, shape (T, len(names))
        Per frame, the length of the contour each point lies on relative to the
        tracker's first frame (:attr:`trackers.ContourQuality.stretch`); NaN where the
        frame was not tracked.
    neutral : int
        Row of ``stretch`` of the neutral frame.
    names : sequence of str
        Measurement points.

    Returns
    -------
    ndarray of bool, shape (T, len(names))
        True for a ``furrow_bottom_*`` point on a frame where its furrow is shorter
        than :data:`MIN_FURROW_STRETCH` of its length on the neutral frame.

    Examples
    --------
    >>> faded_furrow_ends([[1.0, 1.0], [np.nan, np.nan], [0.9, 0.9]], 0,
    ...                   ["furrow_top_l", "furrow_bottom_l"])
    array([[False, False],
           [False, False],
           [False,  True]])
    """
    s = np.asarray(stretch, dtype=float)
    if s.ndim != 2 or s.shape[1] != len(names):
        raise ValueError(f"stretch must have shape (T, {len(names)}), got {s.shape}")
    if not 0 <= neutral < len(s):
        raise ValueError(f"neutral must be a row of stretch (0..{len(s) - 1}), got {neutral}")
    ends = np.array([name in _END_POINTS for name in names])
    with np.errstate(invalid="ignore"):
        return ends & (s < MIN_FURROW_STRETCH * s[neutral])


def _measure(result, names: tuple[str, ...]) -> np.ndarray:
    from trackers.fiducials import arc_point

    out = np.empty((len(names), 2))
    lost = {name for name, q in result.quality.items() if q.lost}
    for j, name in enumerate(names):
        if POINT_CONTOUR.get(name) in lost:
            out[j] = np.nan
        elif name in result.fiducials:
            out[j] = result.fiducials[name]
        elif name in _CONTOUR_POINTS:
            contour, fraction = _CONTOUR_POINTS[name]
            out[j] = arc_point(result.contours[contour], fraction)
        else:
            raise ValueError(f"the tracker cannot measure the point {name!r}")
    return out


def measure_frame(result, names: tuple[str, ...]):
    """Head frame (4,), points (len(names), 2) and success of one tracked frame.

    A point is NaN when the contour it lies on is lost; the frame succeeds when its
    head frame is finite and at least :data:`MIN_POINTS` points are known.
    """
    head = result.head
    head_row = np.array([head.x, head.y, head.scale, head.roll], float)
    points = _measure(result, names)
    good = bool(np.isfinite(head_row).all()
                and np.isfinite(points).all(axis=1).sum() >= MIN_POINTS)
    return head_row, points, good


def _confidence(result) -> float:
    """Smallest relative potential depth over the contours that are not lost, in [0, 1]."""
    depths = [q.depth for q in result.quality.values() if not q.lost]
    return float(np.clip(min(depths), 0.0, 1.0)) if depths else 0.0


def _progress(total, enabled: bool, desc: str):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="frame", file=sys.stderr, leave=False,
                dynamic_ncols=True)


def analyze(video: str | os.PathLike, *, estimator: str = "joint", fps: float | None = None,
            start: int = 0, end: int | None = None, neutral: int | None = None,
            layout=None, response: FiducialResponse | None = None, refine: bool = False,
            tracker_options: dict | None = None, backend: str = "numpy",
            device: str | None = None, suspect_points: str = "exclude",
            overlay: str | os.PathLike | None = None, progress: bool = False) -> Analysis:
    """Analyse a face video into muscle contractions.

    Parameters
    ----------
    video : path-like
        Video file, folder of images, or a single image.
    estimator : {'joint', 'tw93', 'flow'}, keyword-only
        ``joint`` (default): bounded least squares of all contractions through the
        model's fiducial response; ``tw93``: the paper's per-muscle inversion;
        ``flow``: bounded least squares of the dense face flow on the model's flow
        templates (a second pass over the video).
    fps : float, optional
        Frame rate, overriding the container's.
    start, end : int, optional
        Frame range ``[start, end)``.
    neutral : int, optional
        Frame (absolute index) showing the neutral face, used for calibration;
        default: the first frame tracked successfully.
    layout : FaceLayout or path-like, optional
        Initial contours (e.g. corrected by hand and saved with
        ``FaceLayout.to_json``); by default they are placed by OpenCV's face and
        eye detectors on the first frame.
    response : FiducialResponse, optional
        Model response to invert (default: the generic face model's, cached).
    refine : bool, keyword-only
        With ``estimator='joint'``, refine every frame through the face model itself
        (:func:`faceanalysis.estimation.refine.refine_through_model`): more accurate where muscles
        interact, about ten times slower.
    tracker_options : dict, optional
        Keyword arguments for :class:`trackers.Tracker` (e.g. ``{"brow_mid": 0.556}``).
    backend : {'numpy', 'torch'}, keyword-only
        Where the snakes relax: compiled NumPy/Numba (default) or batched torch
        (the ``[torch]`` extra; same contours within 1e-6 px).
    device : str, optional
        Torch device (``'cpu'``, ``'cuda'``, ``'cuda:N'``) with ``backend='torch'``.
    suspect_points : {'exclude', 'keep'}, keyword-only
        What to do with measurement points that the neutral frame puts more than
        :data:`~faceanalysis.estimation.calibration.MAX_POINT_RESIDUAL` head units from where the
        calibrated face model has them (a contour on the wrong feature: the mouth line
        on the lower lip, a furrow's top on the mouth). They are named in a warning and
        in ``analysis.json`` (``calibration.suspect_points``) either way; ``'exclude'``
        (default) also leaves them out of the calibration and the estimation (their
        :attr:`Analysis.measurements` are NaN), since their motion is not the motion the
        model predicts for them. No point of the rendered test faces comes near the
        limit.
    overlay : path-like, optional
        Write the frames with contours and fiducials drawn to this video file.
    progress : bool
        Progress bar on stderr.

    Returns
    -------
    Analysis

    Raises
    ------
    FileNotFoundError
        If the video (or layout file) does not exist.
    ValueError
        Unreadable video, no face in the first frame, a neutral frame outside the
        range or not tracked, bad parameters.
    """
    from faceanalysis.viz.overlay import draw_overlay
    from faceanalysis.io.video_writer import VideoWriter
    from trackers import detect_layout
    from trackers.torch_backend import check_backend, make_tracker

    if estimator not in ESTIMATORS:
        raise ValueError(f"unknown estimator {estimator!r}; choose from {', '.join(ESTIMATORS)}")
    if suspect_points not in ("exclude", "keep"):
        raise ValueError(f"suspect_points must be 'exclude' or 'keep', got {suspect_points!r}")
    try:
        check_backend(backend, device)
    except ImportError as exc:
        raise FaceAnalysisError(str(exc)) from None
    t_start = time.perf_counter()
    if response is None:
        from faceanalysis.estimation.model_response import model_response

        response = model_response()

    source = open_video(video, fps=fps, start=start, end=end, min_size=MIN_FACE_SIZE)
    frames: list[int] = []
    stamps: list[float] = []
    ok: list[bool] = []
    conf: list[float] = []
    fid_rows: list[np.ndarray] = []
    meas_rows: list[np.ndarray] = []
    head_rows: list[np.ndarray] = []
    contours: list = []
    stretch_rows: list[np.ndarray] = []
    nan_fid = np.full((len(FIDUCIALS), 2), np.nan)
    nan_meas = np.full((len(response.fiducials), 2), np.nan)
    nan_stretch = np.full(len(response.fiducials), np.nan)
    point_contours = [POINT_CONTOUR[p] for p in response.fiducials]   # once, not per frame
    nan_head = np.full(4, np.nan)
    tracker = None
    writer = None
    t_track = 0.0
    bar = _progress(source.n_frames, progress, "analyze")
    try:
        # decoding runs ahead in a thread; closing() stops it before the source closes
        with source, closing(read_ahead(source)) as decoded:
            for frame in decoded:
                frames.append(frame.index)
                stamps.append(frame.timestamp)
                if not frame.ok:
                    ok.append(False)
                    conf.append(0.0)
                    fid_rows.append(nan_fid)
                    meas_rows.append(nan_meas)
                    head_rows.append(nan_head)
                    contours.append(None)
                    stretch_rows.append(nan_stretch)
                else:
                    t0 = time.perf_counter()
                    if tracker is None:
                        lay = _load_layout(layout, source.size)
                        if lay is None:
                            try:
                                lay = detect_layout(frame.image, frame_index=frame.index,
                                                    channel_order="bgr")
                            except ValueError as exc:
                                # the detector names the frame; the user needs the file too
                                raise ValueError(f"{video}: {exc}") from None
                        tracker = make_tracker(lay, backend=backend, device=device,
                                               channel_order="bgr", **(tracker_options or {}))
                    res = tracker.track(frame.image)
                    t_track += time.perf_counter() - t0
                    head_row, points, good = measure_frame(res, response.fiducials)
                    ok.append(good)
                    conf.append(_confidence(res))
                    fids = np.array([res.fiducials[n] for n in FIDUCIALS], float)
                    fids[~np.isfinite(points[:len(FIDUCIALS)]).all(axis=1)] = np.nan
                    fid_rows.append(fids if good else nan_fid)
                    meas_rows.append(points if good else nan_meas)
                    head_rows.append(head_row if good else nan_head)
                    contours.append(res.contours)
                    stretch_rows.append(np.array(
                        [res.quality[c].stretch for c in point_contours]))
                if overlay is not None and frame.ok:
                    if writer is None:
                        writer = VideoWriter(overlay, source.fps, source.size)
                    i = len(frames) - 1
                    writer.write(draw_overlay(
                        frame.image, contours=contours[i],
                        fiducials=dict(zip(FIDUCIALS, fid_rows[i].tolist())),
                        head=head_rows[i] if ok[i] else None, lost=not ok[i],
                        label=f"frame {frame.index}  {frame.timestamp:.2f} s"))
                if bar is not None:
                    bar.update(1)
        if writer is not None:
            writer.close()
            writer = None
    finally:
        if bar is not None:
            bar.close()
        if writer is not None:
            writer.abort()

    n = len(frames)
    if n == 0:
        raise ValueError(f"{video}: no frames in the requested range")
    fid = np.stack(fid_rows)
    meas = np.stack(meas_rows)
    heads = np.stack(head_rows)
    success = np.array(ok)
    if not success.any():
        raise FaceAnalysisError(f"{video}: the face was lost in every frame; nothing to analyse")

    frame_arr = np.array(frames)
    n_valid = np.isfinite(meas).all(axis=2).sum(axis=1)
    if neutral is None:
        # the first tracked frame that sees every point, else the one that sees the most
        k = int(np.argmax(np.where(success, n_valid, -1)))
        complete = np.flatnonzero(success & (n_valid == meas.shape[1]))
        if complete.size:
            k = int(complete[0])
    else:
        hits = np.flatnonzero(frame_arr == neutral)
        if hits.size == 0:
            raise ValueError(f"neutral frame {neutral} is outside the analysed range "
                             f"{frames[0]}..{frames[-1]}")
        k = int(hits[0])
        if not success[k]:
            raise ValueError(f"neutral frame {neutral} was not tracked (face lost); "
                             "choose another with --neutral")
    seen = np.isfinite(meas[k]).all(axis=1)
    drop = find_suspect(meas[k], heads[k], response.rest, valid=seen)
    suspect = [n for n, d in zip(response.fiducials, drop) if d]
    excluded_names: list[str] = []
    if suspect and suspect_points == "exclude":
        meas = meas.copy()
        meas[:, drop] = np.nan
        seen = seen & ~drop
        excluded_names = suspect
    cal = calibrate(meas[k], heads[k], response.rest, valid=seen)
    # (counted only where the point would have been measured)
    faded = (faded_furrow_ends(np.stack(stretch_rows), k, response.fiducials)
             & np.isfinite(meas).all(axis=2))
    if faded.any():
        meas = np.where(faded[..., None], np.nan, meas)
    if suspect:
        log.warning("%s: on the neutral frame %d, %s lie%s more than %.2f head units from "
                    "where the face model puts %s (a contour on the wrong feature?); %s. "
                    "Check the overlay (--overlay), or give another --neutral frame or a "
                    "corrected --layout", video, int(frame_arr[k]), ", ".join(suspect),
                    "s" if len(suspect) == 1 else "", MAX_POINT_RESIDUAL,
                    "it" if len(suspect) == 1 else "them",
                    "left out of the estimation" if excluded_names else "kept")
    t0 = time.perf_counter()
    disp = cal.model_displacements(meas, heads)
    values = _estimate(disp, response, "joint" if estimator == "flow" else estimator, refine)
    t_estimate = time.perf_counter() - t0
    track_conf = np.where(success, conf, 0.0)
    residual, confidence, fit = _model_fit(disp, response, values, success, track_conf)
    if fit["frames_over_limit"] > 0.1 * max(int(success.sum()), 1):
        log.warning("%s: on %d of %d tracked frames the face model does not explain the "
                    "tracked points (fit residual over %.2f cm, median %.2f; rendered faces "
                    "stay under 0.41): a head turned out of the image plane, contours on "
                    "other features or motion beyond the model's. Their confidence is "
                    "lowered; check the overlay (--overlay)", video, fit["frames_over_limit"],
                    int(success.sum()), MAX_FIT_RESIDUAL, fit["median_cm"])

    table = empty_table(n, frames=frames, timestamps=stamps)
    table["success"] = success.astype(np.int64)
    table["confidence"] = confidence
    table[list(HEAD_COLUMNS)] = heads
    for j, name in enumerate(FIDUCIALS):
        table[f"fid_{name}_x"] = fid[:, j, 0]
        table[f"fid_{name}_y"] = fid[:, j, 1]
    estimated = _fill_contractions(table, values, response, success)
    table = with_au_columns(table)

    from faceanalysis.io.report import analysis_metadata

    elapsed = time.perf_counter() - t_start
    parameters = {
        "estimator": estimator, "fps": fps, "start": start, "end": end,
        "neutral_frame": int(frame_arr[k]), "layout": None if layout is None else str(layout),
        "refine": bool(refine), "tracker_options": dict(tracker_options or {}),
        "backend": backend, "device": device,
        "measurement_points": list(response.fiducials),
        "estimated_controls": estimated,
        "controls_at_rest": [m for m in (*MUSCLES, JAW) if m not in estimated],
    }
    calib = {"neutral_frame": int(frame_arr[k]), "residual": cal.residual,
             "matrix": cal.matrix.tolist(), "offset": cal.offset.tolist(),
             "suspect_points": suspect, "excluded_points": excluded_names,
             "faded_furrow_ends": {n: int(c) for n, c in zip(response.fiducials,
                                                             faded.sum(axis=0)) if c}}
    metadata = analysis_metadata(source, table, parameters=parameters, elapsed_s=elapsed,
                                 extra={"calibration": calib, "model_fit": fit})
    timings = {"track_s": t_track, "estimate_s": t_estimate, "total_s": elapsed, "frames": n}
    result = Analysis(table=table, contours=contours, metadata=metadata, calibration=cal,
                      response=response, measurements=meas, timings=timings,
                      fit_residual=residual, track_confidence=track_conf)
    if estimator == "flow":
        from faceanalysis.estimation.flow import reestimate_flow

        t0 = time.perf_counter()
        result = reestimate_flow(result, video, fps=fps)
        result.timings["estimate_s"] = time.perf_counter() - t0
    return result


def _estimate(disp, response, estimator: str, refine: bool) -> np.ndarray:
    values = estimate(disp, response, estimator=estimator)
    if refine and estimator == "joint":
        from faceanalysis.estimation.refine import refine_through_model
        from synth import FaceModel

        values = refine_through_model(disp, response, FaceModel.default(), values)
    return values


def _model_fit(disp, response, values, success, track_conf):
    """Per-frame fit residual, the confidence it allows, and their summary for
    ``analysis.json`` (``model_fit``)."""
    residual = np.where(success, fit_residual(disp, response, values), np.nan)
    with np.errstate(divide="ignore"):
        # fmin skips NaN: a frame without a residual keeps the tracker's confidence
        allowed = np.fmin(1.0, MAX_FIT_RESIDUAL / residual)
    confidence = np.where(success, np.minimum(track_conf, allowed), 0.0)
    r = residual[np.isfinite(residual)]
    summary = {"limit_cm": MAX_FIT_RESIDUAL,
               "median_cm": float(np.median(r)) if r.size else None,
               "p90_cm": float(np.percentile(r, 90)) if r.size else None,
               "max_cm": float(r.max()) if r.size else None,
               "frames_over_limit": int((r > MAX_FIT_RESIDUAL).sum())}
    return residual, confidence, summary


def _fill_contractions(table: pd.DataFrame, values: np.ndarray, response: FiducialResponse,
                       success: np.ndarray) -> list[str]:
    """Write estimated controls into ``table`` in place; returns the estimated names.

    Muscles the fiducials do not observe are reported at rest (0) on tracked frames
    and listed in ``analysis.json``; lost frames are NaN.
    """
    estimated = [m for j, m in enumerate(response.muscles) if np.isfinite(values[:, j]).any()]
    for col in (*MUSCLES, JAW):
        table[col] = np.where(success, 0.0, np.nan)
    for j, name in enumerate(response.muscles):
        if name in estimated:
            table[name] = np.where(success, values[:, j], np.nan)
    return estimated


def reestimate(analysis: Analysis, estimator: str, *, refine: bool = False) -> Analysis:
    """The same tracking and calibration, another estimator: a new :class:`Analysis`.

    Tracking dominates the cost of an analysis, so comparing estimators this way
    costs only the estimation.
    """
    if estimator == "flow":
        raise ValueError("the flow estimator needs the video: use "
                         "faceanalysis.estimation.flow.reestimate_flow(analysis, video)")
    if analysis.calibration is None or analysis.response is None:
        raise ValueError("this analysis has no calibration/response to re-estimate from")
    table = analysis.table.copy()
    success = table["success"].to_numpy() == 1
    heads = table[list(HEAD_COLUMNS)].to_numpy(float)
    points = analysis.fiducials if analysis.measurements is None else analysis.measurements
    disp = analysis.calibration.model_displacements(points, heads)
    values = _estimate(disp, analysis.response, estimator, refine)
    estimated = _fill_contractions(table, values, analysis.response, success)
    track_conf = analysis.track_confidence
    if track_conf is None:
        track_conf = table["confidence"].to_numpy(float)
    residual, table["confidence"], fit = _model_fit(disp, analysis.response, values, success,
                                                    track_conf)
    table = with_au_columns(table)
    metadata = dict(analysis.metadata)
    metadata["parameters"] = {**metadata.get("parameters", {}), "estimator": estimator,
                              "refine": bool(refine), "estimated_controls": estimated}
    metadata["model_fit"] = fit
    if "quality" in metadata:
        # the confidence changed with the estimate: so do its mean and minimum
        from faceanalysis.io.report import quality_summary

        q = quality_summary(table, frames_missing=metadata["quality"].get("frames_missing", 0))
        metadata["quality"] = {**metadata["quality"], "mean_confidence": q["mean_confidence"],
                               "min_confidence": q["min_confidence"]}
    return Analysis(table=table, contours=analysis.contours, metadata=metadata,
                    calibration=analysis.calibration, response=analysis.response,
                    measurements=analysis.measurements, timings=dict(analysis.timings),
                    fit_residual=residual, track_confidence=track_conf)


def analyze_to_folder(video: str | os.PathLike, output: str | os.PathLike, *,
                      overwrite: bool = False, overlay: bool = False, quiet: bool = True,
                      **options) -> Analysis:
    """Run :func:`analyze` and write its results into the folder ``output``.

    The folder is checked before any work (a non-empty folder needs
    ``overwrite=True``); each file is written atomically. Writes
    ``contractions.csv``, ``analysis.json``, ``contractions.png`` and, with
    ``overlay=True``, ``overlay.mp4``. Other keyword arguments go to :func:`analyze`.
    """
    from faceanalysis.analysis.results import OutputFolder

    folder = OutputFolder(output, overwrite=overwrite)
    result = analyze(video, overlay=folder.overlay_mp4 if overlay else None,
                     progress=not quiet, **options)
    folder.write(result.table, result.metadata, title=Path(video).name)
    return result
