"""Video in, muscle contractions out: the analysis pipeline (004, section V).

:func:`analyze` tracks the video (:func:`faceanalysis.tracking.track`), calibrates the
face model into the head frame on the neutral frame
(:mod:`faceanalysis.estimation.calibration`), takes the points' motion back into model
units and runs one of the estimators of :mod:`faceanalysis.estimation.registry`. Every
estimator's result then goes through the same checks: the face model's prediction at
the estimate against the measured points (the fit residual), which caps the frame's
confidence, and the head's turn out of the image plane since the neutral frame, which caps
it too.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.analysis.eyes import eye_closures, eye_openness
from faceanalysis.analysis.neutral import NeutralCheck, check_neutral, mouth_measures
from faceanalysis.analysis.results import Analysis, OutputFolder
from faceanalysis.errors import FaceAnalysisError
from faceanalysis.estimation.calibration import MAX_POINT_RESIDUAL, calibrate, find_suspect
from faceanalysis.estimation.estimators import check_temporal, fit_residual
from faceanalysis.estimation.identifiability import (
    MIRROR_GAP,
    MIRROR_R,
    assess,
    mirror_agreement,
)
from faceanalysis.estimation.pose import correct_pose, head_frame_points, rest_points_3d
from faceanalysis.estimation.registry import (
    ESTIMATORS,
    MESH_ESTIMATORS,
    TEMPORAL,
    TEMPORAL_ESTIMATORS,
    VIDEO_ESTIMATORS,
    Observations,
    run_estimator,
)
from faceanalysis.estimation.response import FiducialResponse
from faceanalysis.io.report import (
    analysis_metadata,
    frame_ranges,
    quality_summary,
)
from faceanalysis.io.table import (
    EYE_COLUMNS,
    FIDUCIALS,
    HEAD_COLUMNS,
    JAW,
    MUSCLES,
    POSE_COLUMNS,
    empty_table,
    head_turn,
    with_au_columns,
    with_identifiable_columns,
)
from faceanalysis.io.video import Frames, as_video, is_photographs
from faceanalysis.tracking import (
    Tracks,
    faded_furrow_ends,
    hidden_frames,
    lost_everywhere,
    lost_reason_counts,
    resolve_tracker,
    track,
)
from trackers.fiducials import HeadFrame
from trackers.landmark_contours import interocular_distance

log = logging.getLogger(__name__)

#: A frame whose measured points lie farther than this from the estimate's prediction
#: (root mean square, model cm) is one the face model does not explain, and its
#: ``confidence`` is lowered to ``MAX_FIT_RESIDUAL / residual``. On the 110 rendered
#: sequences of the standard suite (10 faces) the worst frame is 0.41 cm away and the
#: median 0.05; on real clips heads that turn out of the image plane and contours on
#: other features put frames beyond it.
MAX_FIT_RESIDUAL = 0.5

#: A frame whose head is turned out of the image plane by more than this from the neutral
#: frame's pose (degrees, the hypotenuse of the differences in ``head_pitch`` and
#: ``head_yaw``) reads the turn partly as muscles, and its ``confidence`` is lowered to
#: ``MAX_HEAD_TURN / turn``. On the IMM photographs (20 people), a second neutral photograph
#: up to 9 degrees from the first reads like a frontal one (largest muscle a median 0.12);
#: from 17.5 degrees on, none of the 40 turned ones reads rest (median 0.35).
MAX_HEAD_TURN = 15.0

#: The neutral frame's eyes narrower than this share of their median gap: a warning (their
#: openness is relative to the neutral frame's).
NEUTRAL_EYES = 0.75

#: Outer eye corners closer than this (pixels, on the neutral frame): a warning that eye
#: closures may be missed. On cap13 shrunk to 51 px both blinks are found, to 41 px the one
#: caught half-shut on a single frame is not, to 21 px neither.
SMALL_EYES_PX = 45.0

#: Eye centres closer than this (pixels, the median over the tracked frames of the landmark
#: tracker): a warning that the contractions are noisy. Measured on WolfgangLanger and cap13
#: shrunk into a 1920x1080 frame, against each clip as given: the median |difference| of
#: zygomaticus major (WolfgangLanger) / frontalis major (cap13) is 0.05 / 0.04 at 70 px
#: between the eyes, 0.04 / 0.04 at 44 px (cap13's own size), 0.09 / 0.04 at 33 px and
#: 0.11 / 0.09 at 26 px; WolfgangLanger's laugh reads 0.19 / 0.18 / 0.09 / 0.03 more
#: zygomaticus major than its crying (0.22 as given).
SMALL_FACE_IOD = 36.0

#: A neutral frame more than this many times as blocky as the frames of the two seconds after
#: it (:func:`faceanalysis.io.picture.blockiness`, relative to their median): a warning. Where
#: the neutral frame was the default, it names the first tracked frame of the next second
#: that is coded like the rest: its blockiness at most :data:`CLEAN_BLOCKS` times the median
#: and its sharpness (:func:`faceanalysis.io.picture.sharpness`) at least
#: :data:`SHARP_ENOUGH` of theirs. cap12 and cap13 of the real clips start at 1.45 and 1.47
#: (the frames named: 11 and 12, against which their muscles' medians over the clip sum to
#: 0.00 and 0.03 instead of 0.23 and 0.36; the least blocky frame of cap13's first half
#: second, 11, still gave 0.32: the encoder's next key picture, 12, is the first sharp one);
#: the other three real clips start at 1.02-1.05 and the rendered suite's MPEG-4 videos at
#: 1.04-1.16. Measured round the face (a square three times its size, at most 512 px).
BLOCKY_NEUTRAL = 1.3
CLEAN_BLOCKS = 1.1
SHARP_ENOUGH = 0.8

__all__ = ["Analysis", "ESTIMATORS", "MAX_FIT_RESIDUAL", "MAX_HEAD_TURN", "analyze",
           "analyze_to_folder", "default_estimator", "reestimate"]


def default_estimator(tracker: str | None = None, *, layout=None, refine: bool = False) -> str:
    """The estimator :func:`analyze` runs when none is named.

    ``mesh`` where the landmark tracker runs (the default tracker): on real faces it reads
    the whole face mesh, and of the estimators it is the one whose smiles and rests the
    photographs and clips of ``benchmarks/run.py estimation`` bear out; ``joint`` with
    the snakes (``tracker='snakes'`` or a ``layout``, which places them), whose points are
    the only ones there are, and with ``refine``, which refines the ``joint`` fit.

    Examples
    --------
    >>> default_estimator(), default_estimator("snakes"), default_estimator(refine=True)
    ('mesh', 'joint', 'joint')
    """
    if refine:
        return "joint"
    return "mesh" if resolve_tracker(tracker, layout) == "landmarks" else "joint"


def analyze(video: str | os.PathLike, *, estimator: str | None = None, fps: float | None = None,
            start: int = 0, end: int | None = None, neutral: int | str | None = None,
            layout=None, response: FiducialResponse | None = None, refine: bool = False,
            personalize: bool = False, eyes: bool = False, face=None,
            tracker: str | None = None, tracker_options: dict | None = None,
            backend: str = "numpy",
            device: str | None = None, suspect_points: str = "exclude",
            pose_correction: bool = True, temporal: float | None = None,
            mirror_check: bool = False, overlay: str | os.PathLike | None = None,
            progress: bool = False) -> Analysis:
    """Analyse a face video into muscle contractions.

    Parameters
    ----------
    video : path-like, Frames or array_like
        Video file, folder of images, a single image, or frames in memory (an array
        ``(T, H, W[, 3])`` or a sequence of arrays, RGB, as imageio reads them: give their
        ``fps``; :class:`~faceanalysis.io.video.Frames`, whose ``channel_order='bgr'``
        takes OpenCV's frames as they are).
    estimator : {'joint', 'mesh', 'model', 'fused', 'tw93', 'flow'}, optional
        ``joint``: bounded least squares of all contractions through the model's
        fiducial response on the contours' points; ``mesh``: the same on the contour
        points and the landmark tracker's face mesh (implies ``tracker='landmarks'``);
        default :func:`default_estimator`: ``mesh`` with the landmark tracker, ``joint``
        with the snakes (and with ``refine``); ``model``: the ``mesh`` fit, then each
        frame fitted through the face model's own equilibrium (about 0.1 s a frame);
        ``fused``:
        ``mesh`` with the dense flow in the same fit (a second pass over the video);
        ``tw93``: the paper's per-muscle inversion;
        ``flow``: bounded least squares of the dense face flow on the model's flow
        templates (a second pass over the video). See
        :mod:`faceanalysis.estimation.registry`.
    fps : float, optional
        Frame rate, overriding the container's.
    start, end : int, optional
        Frame range ``[start, end)``.
    neutral : int or 'auto', optional
        Frame (absolute index) showing the neutral face, used for calibration;
        default: the first tracked frame (with the snakes, the first tracked frame that
        sees every measurement point within :data:`LATE_REFERENCE_S` seconds of it, if
        any); a point it misses takes its neutral position from the first frame within
        that time that sees it. ``'auto'``: the default, unless it is coarsely coded, has
        the brows raised or the mouth open or widened
        (:mod:`faceanalysis.analysis.neutral`); then the frame nearest it that is none of
        these (``calibration.auto_neutral`` in the metadata says from which frame and why).
    layout : FaceLayout or path-like, optional
        Initial contours (e.g. corrected by hand and saved with
        ``FaceLayout.to_json``) for the snakes tracker.
    tracker : {'landmarks', 'snakes'}, optional
        'landmarks' (default, unless ``layout`` is given): MediaPipe's face mesh finds
        the face on every frame and holds the snakes (:class:`trackers.AnchoredTracker`);
        frames without a face are lost; the model files come from PyPI on first use.
        'snakes': 004's Haar cascades, template layout and free snakes, no model needed.
        See :func:`faceanalysis.tracking.track`.
    response : FiducialResponse, optional
        Model response to invert (default: the generic face model's, cached).
    refine : bool, keyword-only
        With ``estimator='joint'``, refine every frame through the face model itself
        (:func:`faceanalysis.estimation.refine.refine_through_model`); about ten times
        slower.
    personalize : bool, keyword-only
        With ``estimator='model'``, fit through the generic face warped onto the
        subject's neutral frame (:func:`faceanalysis.estimation.model_fit.personal_model`)
        instead of the generic face itself.
    eyes : bool, keyword-only
        Trace both eyes' lids on every frame with MediaPipe's iris model (landmark
        tracker; about 2.5 ms a frame): ``eye_openness_l`` / ``_r`` in the table (each eye's
        lid gap over the neutral frame's) and the eye closures and blinks in
        ``analysis.json`` (``eyes``, :func:`faceanalysis.analysis.eyes.eye_closures`).
        Without it those columns are empty.
    face : (float, float), keyword-only
        A point (x, y, pixels of the first frame with a face) on or near the face to
        analyse, where the video shows several (landmark tracker): that face is followed
        instead of the largest.
    tracker_options : dict, optional
        Keyword arguments for :class:`trackers.Tracker` (e.g. ``{"brow_mid": 0.556}``).
    backend : {'numpy', 'torch'}, keyword-only
        Where the snakes relax: compiled NumPy/Numba (default) or batched torch
        (the ``[torch]`` extra; same contours within 1e-6 px).
    device : str, optional
        Torch device (``'cpu'``, ``'cuda'``, ``'cuda:N'``) with ``backend='torch'``.
    suspect_points : {'exclude', 'keep'}, keyword-only
        What to do with measurement points that the neutral frame puts more than
        :data:`~faceanalysis.estimation.calibration.MAX_POINT_RESIDUAL` head units from
        where the calibrated face model has them (a contour on the wrong feature).
        They are named in a warning and in ``analysis.json``
        (``calibration.suspect_points``) either way; ``'exclude'`` (default) also
        leaves them out of the calibration and the estimation.
    pose_correction : bool, keyword-only
        Where the tracker measures the head's pitch and yaw (``tracker='landmarks'``),
        take the apparent motion of the head's rotation since the neutral frame out of
        the points' displacements (:func:`~faceanalysis.estimation.pose.correct_pose`),
        so that a bowed or turned head is not read as an expression. Whether it was
        applied is recorded in ``analysis.json`` (``parameters.pose_correction``).
    temporal : float, keyword-only, optional
        Weight of the prior that draws each frame's contractions toward its neighbours'
        (``joint``, ``mesh`` and ``fused``; default
        :data:`~faceanalysis.estimation.registry.TEMPORAL`, see
        :func:`~faceanalysis.estimation.estimators.estimate_joint`); 0 fits every frame on
        its own, for frames that are not a sequence. A folder of images analysed without
        ``fps`` is taken as photographs and gets 0 unless ``temporal`` is given; with
        ``fps``, as the frames of a video. Recorded in ``analysis.json``
        (``parameters.temporal``).
    mirror_check : bool, keyword-only
        Track and estimate the video a second time mirrored left to right, and flag what
        does not come back on it
        (:func:`~faceanalysis.estimation.identifiability.mirror_agreement`): on a video,
        a moving control whose series its mirrored partner's does not follow is not
        identifiable; on fewer than
        :data:`~faceanalysis.estimation.identifiability.MIRROR_FRAMES` frames (photographs),
        a value its partner's differs from is flagged on its frame (``<control>_identifiable``
        0). ``analysis.json`` reports it (``identifiability.mirror``; where the mirrored
        video cannot be tracked, or not on the neutral frame, ``skipped`` says so and
        nothing is flagged). Doubles the tracking time; not with the ``fused`` and ``flow``
        estimators, which read the frames again, nor with a ``layout``.
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
        Unreadable video, no face in any frame, a neutral frame outside the range or
        not tracked, bad parameters.
    """
    from trackers.torch_backend import check_backend

    video = as_video(video)         # frames in memory: messages name them, not their pixels
    if estimator is None:
        estimator = default_estimator(tracker, layout=layout, refine=refine)
    if estimator not in ESTIMATORS:
        raise ValueError(f"unknown estimator {estimator!r}; choose from {', '.join(ESTIMATORS)}")
    if suspect_points not in ("exclude", "keep"):
        raise ValueError(f"suspect_points must be 'exclude' or 'keep', got {suspect_points!r}")
    if refine and estimator != "joint":
        raise ValueError(f"refine works with the joint estimator, not {estimator!r}")
    if personalize and estimator != "model":
        raise ValueError(f"personalize works with the model estimator, not {estimator!r}")
    if mirror_check and estimator in VIDEO_ESTIMATORS:
        raise ValueError(f"mirror_check works with the "
                         f"{', '.join(e for e in ESTIMATORS if e not in VIDEO_ESTIMATORS)} "
                         f"estimators, not {estimator!r} (it reads the video's frames again)")
    if mirror_check and layout is not None:
        raise ValueError("mirror_check does not go with a layout: the layout places the "
                         "contours on the video as it is, not mirrored")
    if eyes:
        if resolve_tracker(tracker, layout) != "landmarks":
            raise ValueError("eyes works with the landmark tracker, not the snakes (the iris "
                             "model is placed from the face mesh)")
        tracker_options = {**(tracker_options or {}), "eyes": True}
    if face is not None:
        from trackers.landmarks.tracker import check_point

        if resolve_tracker(tracker, layout) != "landmarks":
            raise ValueError("face works with the landmark tracker, not the snakes (they "
                             "start on the largest face the cascades find)")
        face = [float(v) for v in check_point(face, "face")]
        tracker_options = {**(tracker_options or {}), "start_near": face}
    est_options = _fit_options(estimator, refine, temporal, personalize)
    if estimator == "model" and progress:
        est_options["progress"] = True     # its fit takes about 0.1 s a frame
    if estimator in MESH_ESTIMATORS:
        # they read the landmark tracker's face mesh
        if tracker not in (None, "landmarks"):
            raise ValueError(f"the {estimator} estimator reads the landmark tracker's face "
                             f"mesh; it does not work with tracker={tracker!r}")
        tracker = "landmarks"
    try:
        check_backend(backend, device)
    except ImportError as exc:
        raise FaceAnalysisError(str(exc)) from None
    t_start = time.perf_counter()
    if response is None:
        from faceanalysis.estimation.model_response import model_response

        response = model_response()
    auto = _check_neutral_option(neutral)
    given_frame = None if auto else neutral
    if given_frame is not None or face is not None:
        _check_input_points(video, given_frame, face, fps=fps, start=start, end=end)
    track_options = {"points": response.fiducials, "fps": fps, "start": start, "end": end,
                     "layout": layout, "tracker": tracker, "tracker_options": tracker_options,
                     "backend": backend, "device": device, "progress": progress}
    tracks = track(video, overlay=overlay, **track_options)
    t_track = tracks.timings["track_s"]
    log.debug("%s: tracked %d frames (%d lost) with the %s tracker in %.2f s (%.1f ms a frame)",
              video, len(tracks), int((~tracks.success).sum()), tracks.tracker, t_track,
              1e3 * t_track / len(tracks))
    if not tracks.success.any():
        raise FaceAnalysisError(lost_everywhere(video, tracks.lost_reasons))
    if len(tracks) == 1:
        log.warning("%s: one frame has no expression to measure: its contractions are 0 "
                    "by definition (the neutral frame is the frame itself)", video)
    if len(tracks) >= 2 and is_photographs(tracks.input):
        log.info("%s: a folder of images without a frame rate is taken as photographs, each "
                 "read and fitted on its own; for the frames of a video give --fps", video)
        if temporal is None and "temporal" in est_options and len(tracks) >= 3:
            # as the tracker takes them: each fitted on its own, not drawn toward its
            # neighbours' fits
            est_options["temporal"] = 0.0
    k = _neutral_row(tracks, given_frame)
    calib_options = {"suspect_points": suspect_points, "pose_correction": pose_correction,
                     "options": {"fps": fps, "start": start, "end": end}}
    t0, c0 = time.perf_counter(), time.process_time()
    meas, cal, calib, pose_applied, est = _estimate(tracks, k, response, estimator,
                                                    est_options, video, **calib_options)
    mouth = mouth_measures(tracks)          # the clip's, whichever frame is neutral
    neutral_check = _check_neutral_frame(video, est, tracks, k, fps, mouth,
                                         default=given_frame is None)
    moved = None
    if auto and neutral_check.reasons and neutral_check.advice is not None:
        # the frame every warning would offer: estimate again from it
        moved = {"from_frame": int(tracks.frames[k]), "because": neutral_check.reasons}
        k = int(np.flatnonzero(tracks.frames == neutral_check.advice[0])[0])
        log.info("%s: neutral frame %d instead of %d (%s there)", video,
                 int(tracks.frames[k]), moved["from_frame"], ", ".join(moved["because"]))
        meas, cal, calib, pose_applied, est = _estimate(tracks, k, response, estimator,
                                                        est_options, video, **calib_options)
        neutral_check = _check_neutral_frame(video, est, tracks, k, fps, mouth, default=True)
    # (said once the neutral frame is settled)
    _warn_suspect(video, tracks, k, calib["suspect_points"], calib["excluded_points"])
    mirrored = check = None
    t_estimate = time.perf_counter() - t0
    c_estimate = time.process_time() - c0
    log.debug("%s: neutral frame %d; the %s estimator took %.2f s (%.1f ms a frame)", video,
              int(tracks.frames[k]), estimator, t_estimate, 1e3 * t_estimate / len(tracks))
    if mirror_check:
        t1 = time.perf_counter()
        try:
            with _quiet_tracking():
                options = track_options
                if eyes:
                    # the check compares the controls: the mirrored eyes would go unread
                    options = {**track_options, "tracker_options": {
                        k: v for k, v in tracker_options.items() if k != "eyes"}}
                mirrored = track(video, mirror=True, keep_contours=False, **options)
        except (ValueError, FaceAnalysisError) as exc:
            # (the snakes' face detector may find no face in the mirrored frames)
            check = _skipped(f"the mirrored video could not be tracked ({exc})")
        else:
            check = _mirror_check(est, mirrored, k, tracks, response, estimator, est_options,
                                  video, calib_options)
        t_mirror = time.perf_counter() - t1
    t0, c0 = time.perf_counter(), time.process_time()

    parameters = {
        "estimator": estimator, "fps": fps, "start": start, "end": end,
        "temporal": est_options.get("temporal"),
        "neutral_frame": int(tracks.frames[k]),
        "neutral": neutral if neutral is None or auto else int(neutral),
        "tracker": tracks.tracker,
        "layout": None if layout is None else str(layout),
        "refine": bool(refine), "personalize": bool(personalize), "eyes": bool(eyes),
        "face": face,
        "tracker_options": dict(tracker_options or {}),
        "backend": backend, "device": device,
        "measurement_points": list(response.fiducials),
        "single_frame": len(tracks) == 1,
        "pose_correction": pose_applied,
    }
    table = _tracking_table(tracks, k)
    eye_summary = _eye_summary(table, tracks, k, video)
    parameters["measurement_points"] = list(est.response.fiducials)
    parameters["mirror_check"] = bool(mirror_check)
    parameters["suspect_points"] = suspect_points
    ident = _assess(est, tracks.input)
    ident, unreproduced = _with_mirror(ident, check, tracks.frames)
    table, residual, fit = _contractions(table, est.values, est.displacements, est.response,
                                         tracks.confidence, parameters, ident, unreproduced,
                                         est.residual)
    # estimation: the fit, what the points can tell apart, the model's fit residual
    t_estimate += time.perf_counter() - t0
    c_estimate += time.process_time() - c0
    if fit["frames_over_limit"] > 0.1 * max(int(tracks.success.sum()), 1):
        log.warning("%s: on %d of %d tracked frames the face model does not explain the "
                    "tracked points (fit residual over %.2f cm, median %.2f; rendered faces "
                    "stay under 0.41): a head turned out of the image plane, contours on "
                    "other features or motion beyond the model's. Their confidence is "
                    "lowered; check the overlay (--overlay)%s", video, fit["frames_over_limit"],
                    int(tracks.success.sum()), MAX_FIT_RESIDUAL, fit["median_cm"],
                    _LANDMARK_HINT if tracks.tracker == "snakes" else "")
    turned = fit["head_turn"]["frames_over_limit"] or 0
    if turned > 0.1 * max(int(tracks.success.sum()), 1):
        log.warning("%s: on %d of %d tracked frames the head is turned more than %.0f degrees "
                    "out of the image plane from the neutral frame's pose (up to %.0f): a "
                    "turned head reads partly as muscles, so their confidence is lowered; "
                    "compare frames of similar pose (head_pitch, head_yaw)", video, turned,
                    int(tracks.success.sum()), MAX_HEAD_TURN, fit["head_turn"]["max_deg"])
    _warn_identifiability(video, ident)
    _warn_cuts(video, tracks, k)
    calib.update(neutral_check.calibration())
    calib["auto_neutral"] = moved
    neutral_check.warn(video, tracks, how="chosen" if moved is not None
                       else "given" if given_frame is not None else "default")
    iod = _interocular_px(tracks)
    if iod is not None and iod < SMALL_FACE_IOD:
        log.warning("%s: the face is small, %.0f px between the eyes (median): under %.0f the "
                    "contours hold the features only loosely and the contractions are noisy; "
                    "film closer or at a higher resolution", video, iod, SMALL_FACE_IOD)
    elapsed = time.perf_counter() - t_start
    metadata = analysis_metadata(tracks.input, table, parameters=parameters, elapsed_s=elapsed,
                                 extra={"calibration": calib, "model_fit": fit,
                                        "identifiability": ident, "eyes": eye_summary})
    if metadata.get("quality") is not None:
        metadata["quality"]["lost_reasons"] = lost_reason_counts(tracks.lost_reasons)
        metadata["quality"]["hidden_ranges"] = frame_ranges(
            hidden_frames(tracks.frames, tracks.lost_reasons))
        metadata["quality"]["shot_cuts"] = list(tracks.cuts)
        metadata["quality"]["interocular_px"] = None if iod is None else round(iod, 1)
    timings = {"track_s": tracks.timings["track_s"], "estimate_s": t_estimate,
               "total_s": elapsed, "frames": len(tracks),
               "track_cpu_s": tracks.timings["cpu_s"], "estimate_cpu_s": c_estimate}
    if mirror_check:
        timings["mirror_check_s"] = t_mirror
    return Analysis(table=table, contours=tracks.contours, metadata=metadata, calibration=cal,
                    response=response, measurements=meas, timings=timings,
                    fit_residual=residual, track_confidence=tracks.confidence, tracks=tracks,
                    mirrored_tracks=mirrored, estimate=est)


def _estimate(tracks: Tracks, k: int, response: FiducialResponse, estimator: str,
              est_options: dict, video, *, suspect_points: str, pose_correction: bool,
              options: dict):
    """Calibrate ``tracks`` on row ``k`` and run ``estimator``: the measurements, the
    calibration, its ``analysis.json`` section, whether the pose correction was applied,
    and the :class:`~faceanalysis.estimation.registry.Estimate`."""
    meas, cal, calib = _calibrate(tracks, k, response, suspect_points)
    disp = cal.model_displacements(meas, tracks.heads)
    disp, pose_applied = _correct_pose(disp, tracks.pose, k, response, pose_correction)
    obs = Observations(tracks=tracks, response=response, displacements=disp, neutral=k,
                       options=options, calibration=cal)
    return meas, cal, calib, pose_applied, run_estimator(estimator, obs, **est_options)


class _quiet_tracking:
    """Within it, the tracking's and the decoder's warnings are not logged: the mirror
    check's second pass over the video would repeat the first pass's."""

    _names = ("faceanalysis.tracking", "faceanalysis.io.video")

    def filter(self, record) -> bool:
        return record.levelno > logging.WARNING

    def __enter__(self):
        for name in self._names:
            logging.getLogger(name).addFilter(self)
        return self

    def __exit__(self, *exc):
        for name in self._names:
            logging.getLogger(name).removeFilter(self)
        return False


def _mirror_check(est, mirrored: Tracks, k: int, tracks: Tracks, response: FiducialResponse,
                  estimator: str, est_options: dict, video, calib_options: dict) -> dict:
    """:func:`~faceanalysis.estimation.identifiability.mirror_agreement` of ``est`` with the
    same estimator on ``mirrored`` (the video tracked mirrored), calibrated on the same
    frame. Where that frame was not tracked in the mirrored video, nothing is compared and
    the result says why (``skipped``)."""
    rows = np.flatnonzero(mirrored.frames == tracks.frames[k])
    if len(mirrored) != len(tracks) or not rows.size or not mirrored.success[rows[0]]:
        return _skipped(f"the neutral frame {int(tracks.frames[k])} was not tracked in the "
                        "mirrored video")
    *_, mest = _estimate(mirrored, int(rows[0]), response, estimator, est_options, video,
                         **calib_options)
    return mirror_agreement(_response_array(est.values, est.response),
                            _response_array(mest.values, est.response),
                            est.response.muscles, upper=est.response.upper)


def _skipped(why: str) -> dict:
    """A mirror check that compared nothing, and why."""
    return {"frames": 0, "rule": None, "controls": {}, "not_reproduced": [], "mask": None,
            "skipped": why}


def _with_mirror(ident: dict, check: dict | None, frames: np.ndarray):
    """``ident`` with the mirror check's section (``mirror``) and, by the series rule, its
    not reproduced controls not identifiable; and the per-frame mask of the values not
    reproduced (None without a check)."""
    if check is None:
        return ident, None
    ident = {**ident, "controls": {n: dict(e) for n, e in ident["controls"].items()}}
    section = {"frames": check["frames"], "rule": check["rule"],
               "not_reproduced": list(check["not_reproduced"])}
    if "skipped" in check:
        section["skipped"] = check["skipped"]
    elif check["rule"] == "series":
        section.update(min_r=MIRROR_R, controls=check["controls"])
        for name in check["not_reproduced"]:
            ident["controls"][name]["identifiable"] = False
    else:
        mask = check["mask"]
        section["frames_not_reproduced"] = {
            n: [int(f) for f in frames[mask[:, j]]]
            for j, n in enumerate(check["controls"]) if mask[:, j].any()}
    for name, entry in ident["controls"].items():
        entry["mirror_reproduced"] = check["controls"].get(name, {}).get("reproduced")
    ident["mirror"] = section
    ident["not_identifiable"] = [n for n, e in ident["controls"].items() if not e["identifiable"]]
    return ident, check["mask"] if check["rule"] == "frames" else None


def _response_array(values: pd.DataFrame, response: FiducialResponse) -> np.ndarray:
    """An estimator's values as an array of ``response.muscles`` (NaN for a control it
    does not estimate), shape (T, M)."""
    return np.column_stack([
        values[m].to_numpy(float) if m in values.columns else np.full(len(values), np.nan)
        for m in response.muscles])


def _assess(est, input_meta=None) -> dict:
    """:func:`~faceanalysis.estimation.identifiability.assess` of an estimate: at the
    tracking noise, and from the estimates themselves (controls that trade places); of
    photographs (``input_meta``), at the reference noise and without trading."""
    return assess(est.response, est.displacements, fit_options=est.fit_options,
                  values=_response_array(est.values, est.response),
                  sequence=not is_photographs(input_meta))


def _warn_identifiability(video, ident: dict) -> None:
    """One warning for the controls the noise hides, one for those the mirror check finds
    not reproduced, one for those that trade places."""
    elsewhere = {n for p in ident.get("traded", []) for n in p["controls"]}
    mirror = ident.get("mirror")
    if mirror and mirror.get("rule") == "series":
        # named in the mirror's warning, unless the noise hides them too
        elsewhere |= {n for n in mirror["not_reproduced"]
                      if ident["controls"][n]["rmse"] is not None
                      and ident["controls"][n]["rmse"] <= ident["limit"]}
    noisy = [n for n in ident["not_identifiable"] if n not in elsewhere]
    if noisy:
        log.warning("%s: at the tracking noise of %.3f cm (%s), the seen points cannot tell "
                    "%s from the other controls: their values lean on the prior that "
                    "muscles rest (analysis.json: identifiability)", video, ident["noise_cm"],
                    ident["noise_source"], ", ".join(noisy))
    if mirror and mirror.get("skipped"):
        log.warning("%s: mirror check skipped: %s", video, mirror["skipped"])
    elif mirror and mirror["rule"] == "series" and mirror["not_reproduced"]:
        log.warning("%s: analysed mirrored, %s do%s not come back (their series and their "
                    "mirrored partners' correlate under r = %.1f): flagged 0 in "
                    "<control>_identifiable (analysis.json: identifiability.mirror)", video,
                    ", ".join(mirror["not_reproduced"]),
                    "es" if len(mirror["not_reproduced"]) == 1 else "", MIRROR_R)
    elif mirror and mirror.get("frames_not_reproduced"):
        log.warning("%s: analysed mirrored, %s differ%s from the mirrored partner's value on "
                    "some frames (by over %.1f of the range and half the larger): flagged 0 "
                    "in <control>_identifiable there (analysis.json: identifiability.mirror)",
                    video, ", ".join(mirror["frames_not_reproduced"]),
                    "s" if len(mirror["frames_not_reproduced"]) == 1 else "", MIRROR_GAP)
    if ident.get("traded"):
        pairs = ", ".join(f"{a} / {b} ({r:.2f})" for (a, b), r in
                          ((p["controls"], p["correlation"]) for p in ident["traded"]))
        log.warning("%s: these controls trade places from frame to frame (their "
                    "frame-to-frame jitter correlates as given): %s; a pair's sum is "
                    "measured, not its split, and both are flagged 0 in "
                    "<control>_identifiable (analysis.json: identifiability)", video, pairs)


def _fit_options(estimator: str, refine: bool, temporal, personalize: bool = False) -> dict:
    """The options of ``estimator``'s fit: ``refine``, ``personalize``, and the temporal
    prior's weight (checked; the default where the estimator has the prior)."""
    options = {"refine": True} if refine else {}
    if personalize:
        options["personalize"] = True
    if temporal is not None:
        temporal = check_temporal(temporal)
        if estimator not in TEMPORAL_ESTIMATORS:
            raise ValueError(f"temporal works with the {', '.join(TEMPORAL_ESTIMATORS)} "
                             f"estimators, not {estimator!r}")
    if estimator in TEMPORAL_ESTIMATORS:
        options["temporal"] = TEMPORAL if temporal is None else temporal
    return options


def _check_neutral_option(neutral) -> bool:
    """Whether ``neutral`` asks for the neutral frame to be chosen (``"auto"``); refuse
    anything but None, a frame index and ``"auto"``."""
    if isinstance(neutral, str):
        if neutral != "auto":
            raise ValueError(f"neutral={neutral!r}: give a frame index, 'auto' or None")
        return True
    if neutral is not None and (isinstance(neutral, bool) or not isinstance(
            neutral, (int, np.integer)) or neutral < 0):
        raise ValueError(f"neutral={neutral!r}: give a frame index (0 or more), 'auto' "
                         "or None")
    return False


def _check_neutral_frame(video, est, tracks: Tracks, k: int, fps, mouth, *,
                         default: bool) -> NeutralCheck:
    """:func:`~faceanalysis.analysis.neutral.check_neutral` of row ``k`` with the clip's
    ``mouth`` (:func:`~faceanalysis.analysis.neutral.mouth_measures`), its coding measured
    (judged only for a neutral frame not given, ``default``)."""
    blocky = _blocky_neutral(video, tracks, k, fps)
    coarse = default and blocky is not None and blocky[0] > BLOCKY_NEUTRAL
    return check_neutral(est, tracks, k, blocky=blocky, coarse=coarse, mouth=mouth)


def _check_input_points(video, neutral: int | None, face, *, fps, start: int,
                        end: int | None) -> None:
    """Refuse, before any frame is tracked, a neutral frame outside the analysed range and
    a face point outside the picture (coordinates from a scaled display or another video
    would otherwise quietly pick whichever face lies nearest)."""
    from faceanalysis.io.video import MIN_FACE_SIZE, open_video

    with open_video(video, fps=fps, start=start, end=end, min_size=MIN_FACE_SIZE) as src:
        n, (w, h) = src.n_frames, src.size
    last = None if n is None else start + n - 1
    if neutral is not None and (neutral < start or (last is not None and neutral > last)):
        raise ValueError(f"{video}: neutral frame {neutral} is outside the analysed range "
                         f"{start}..{'end' if last is None else last}")
    if face is not None and not (0 <= face[0] <= w and 0 <= face[1] <= h):
        raise ValueError(f"{video}: face point ({face[0]:g}, {face[1]:g}) lies outside the "
                         f"{w}x{h} picture (x 0..{w}, y 0..{h} pixels)")


#: Added to the warnings that say the snakes did not hold the face: on real faces the
#: landmark tracker places and holds them (docs/accuracy.md).
_LANDMARK_HINT = ("; for a real face, use the landmark tracker (the default without "
                  "--tracker snakes or --layout), which holds the contours on their features")

#: The default neutral frame waits at most this many seconds after the first tracked frame
#: for one that sees every point (:func:`_neutral_row`); a point the neutral frame does not
#: see takes its neutral position from the first tracked frame within this many seconds
#: after it that sees it (:func:`_late_references`).
LATE_REFERENCE_S = 1.0


def _neutral_row(tracks: Tracks, neutral: int | None) -> int:
    """Row of the neutral frame: the given one; else, with the landmark tracker, the first
    tracked frame; else the first tracked frame that sees every point within
    :data:`LATE_REFERENCE_S` of the first tracked frame, else the first tracked frame.

    The snakes settle on their features over the first frames, so a complete frame soon
    after the first is taken. The wait is short: a frame that sees every point much later
    could be an expression, which would bias every value; a point the neutral frame misses
    takes its neutral position from a frame just after it instead
    (:func:`_late_references`), which biases that point at most. The landmark tracker
    places its contours from the first frame, and what it misses there is mostly a feature
    the face does not show at rest: a furrow that a smile deepens (on two of 20 IMM
    neutral-then-smile pairs, the smile was the first complete frame and read as neutral).
    """
    if neutral is None:
        first = int(np.flatnonzero(tracks.success)[0])
        if tracks.tracker == "landmarks":
            return first
        complete = tracks.success & np.isfinite(tracks.points).all(axis=(1, 2))
        rows = np.flatnonzero(complete & _within(tracks, first, inclusive=True))
        return int(rows[0]) if rows.size else first
    hits = np.flatnonzero(tracks.frames == neutral)
    if hits.size == 0:
        raise ValueError(f"neutral frame {neutral} is outside the analysed range "
                         f"{tracks.frames[0]}..{tracks.frames[-1]}")
    k = int(hits[0])
    if not tracks.success[k]:
        from faceanalysis.io.report import LOST_REASONS

        reason = (tracks.lost_reasons or [None] * len(tracks))[k]
        why = f"lost: {LOST_REASONS[reason][0]}" if reason in LOST_REASONS else "face lost"
        tracked = np.flatnonzero(tracks.success)
        nearest = [*tracked[tracked < k][-1:], *tracked[tracked > k][:1]]
        near = [str(int(tracks.frames[r])) for r in nearest]
        hint = (f"; the nearest tracked frame{'s are' if len(near) > 1 else ' is'} "
                f"{' and '.join(near)}" if near else "")
        raise ValueError(f"{tracks.video}: neutral frame {neutral} was not tracked ({why})"
                         f"{hint}; choose another with --neutral")
    return k


def _warn_suspect(video, tracks: Tracks, k: int, suspect: list, excluded: list) -> None:
    """The warning about the neutral frame's (row ``k``) suspect points, if any."""
    if suspect:
        log.warning("%s: on the neutral frame %d, %s lie%s more than %.2f head units from "
                    "where the face model puts %s (a contour on the wrong feature?); %s. "
                    "Check the overlay (--overlay), or give another --neutral frame%s",
                    video, int(tracks.frames[k]), ", ".join(suspect),
                    "s" if len(suspect) == 1 else "", MAX_POINT_RESIDUAL,
                    "it" if len(suspect) == 1 else "them",
                    "left out of the estimation" if excluded else "kept",
                    # a layout places only the snakes' contours
                    " or a corrected --layout" + _LANDMARK_HINT if tracks.tracker == "snakes"
                    else "")


def _calibrate(tracks: Tracks, k: int, response: FiducialResponse, suspect_points: str):
    """Measurements the estimators may read, the calibration, and its ``analysis.json``
    section. Suspect points (:func:`~faceanalysis.estimation.calibration.find_suspect`)
    are left out with ``suspect_points='exclude'`` (:func:`_warn_suspect` says so); faded
    furrow ends always are."""
    meas = tracks.points
    late = _late_references(tracks, k)
    neutral_points = meas[k].copy()
    for j, row in late.items():
        # the point where that frame puts it relative to the head, placed in this frame
        neutral_points[j] = HeadFrame(*tracks.heads[k]).to_image(
            HeadFrame(*tracks.heads[row]).to_head(meas[row, j][None]))[0]
    seen = np.isfinite(neutral_points).all(axis=1)
    drop = find_suspect(neutral_points, tracks.heads[k], response.rest, valid=seen)
    suspect = [n for n, d in zip(response.fiducials, drop) if d]
    excluded: list[str] = []
    if suspect and suspect_points == "exclude":
        meas = meas.copy()
        meas[:, drop] = np.nan
        seen = seen & ~drop
        excluded = suspect
    cal = calibrate(neutral_points, tracks.heads[k], response.rest, valid=seen)
    # (counted only where the point would have been measured)
    faded = (faded_furrow_ends(tracks.stretch, k, response.fiducials)
             & np.isfinite(meas).all(axis=2))
    if faded.any():
        meas = np.where(faded[..., None], np.nan, meas)
    calib = {"neutral_frame": int(tracks.frames[k]), "residual": cal.residual,
             "matrix": cal.matrix.tolist(), "offset": cal.offset.tolist(),
             "suspect_points": suspect, "excluded_points": excluded,
             "late_references": {response.fiducials[j]: int(tracks.frames[row])
                                 for j, row in late.items()},
             "faded_furrow_ends": {n: int(c) for n, c in zip(response.fiducials,
                                                             faded.sum(axis=0)) if c}}
    return meas, cal, calib


def _late_references(tracks: Tracks, k: int) -> dict[int, int]:
    """For each point the neutral frame ``k`` does not see, the first tracked row within
    :data:`LATE_REFERENCE_S` after it that sees it: point index -> row. A point seen
    nowhere in that time is left without a neutral position (not measured), and so is one
    of photographs (the photograph after the neutral one shows another expression)."""
    if is_photographs(tracks.input):
        return {}
    pts = tracks.points
    missing = np.flatnonzero(~np.isfinite(pts[k]).all(axis=1))
    if not missing.size:
        return {}
    rows = np.flatnonzero(_within(tracks, k, inclusive=False) & tracks.success)
    out = {}
    for j in missing:
        hit = rows[np.isfinite(pts[rows, j]).all(axis=1)]
        if hit.size:
            out[int(j)] = int(hit[0])
    return out


def _within(tracks: Tracks, k: int, *, inclusive: bool) -> np.ndarray:
    """Rows at most :data:`LATE_REFERENCE_S` after row ``k`` (30 frames where the frames
    have no time stamps), ``k`` itself if ``inclusive``."""
    t = np.asarray(tracks.timestamps, dtype=float)
    rows = np.arange(len(t))
    after = rows >= k if inclusive else rows > k
    if np.isfinite(t[k]):
        return after & np.isfinite(t) & (t - t[k] <= LATE_REFERENCE_S)
    return after & (rows <= k + 30)


def _correct_pose(disp: np.ndarray, pose: np.ndarray, k: int, response: FiducialResponse,
                  enabled: bool) -> tuple[np.ndarray, bool]:
    """``disp`` less the apparent motion of the head's rotation since the neutral frame
    (:func:`~faceanalysis.estimation.pose.correct_pose`), and whether any frame was
    corrected: not without a pose on the neutral frame (the snakes tracker), nor for a
    response whose points the generic face model does not have (their depth is its)."""
    pose = np.asarray(pose, dtype=float)
    if not enabled or pose.shape != (len(disp), 2) or not np.isfinite(pose[k]).all():
        return disp, False
    try:
        rest = rest_points_3d(response.fiducials)
    except ValueError as exc:
        log.warning("no head pose correction: %s", exc)
        return disp, False
    # the model's x-y, which the calibration was fitted to, with the generic face's depth
    rest[:, :2] = response.rest
    return correct_pose(disp, pose, k, rest, reference=head_frame_points()), True


def _blocky_neutral(video, tracks: Tracks, k: int, fps) -> tuple[float, int | None] | None:
    """The neutral frame's (row ``k``) blockiness over the median of the frames of the two
    seconds after it (at least :data:`~faceanalysis.io.cuts.MIN_SHOT` frames), and the first
    tracked frame of the next second coded like them (:data:`CLEAN_BLOCKS`,
    :data:`SHARP_ENOUGH`; None where none is); None where fewer frames follow or they cannot
    be read again."""
    from faceanalysis.io.cuts import MIN_SHOT
    from faceanalysis.io.picture import blockiness, sharpness
    from faceanalysis.io.video import open_video

    rate = float(tracks.input.get("fps") or 0) if isinstance(tracks.input, dict) else 0.0
    if not rate > 0:
        return None
    first = int(tracks.frames[k])
    stop = min(first + max(MIN_SHOT, round(2 * rate)), int(tracks.frames[-1]) + 1)
    if np.count_nonzero((tracks.frames >= first) & (tracks.frames < stop)) < MIN_SHOT:
        return None
    # measured round the face, on the frame's own block grid (the crop starts on it): a
    # large frame's measures would cost more than the rest of the analysis's start
    mesh = tracks.landmarks[k] if tracks.landmarks is not None else None
    if mesh is not None:
        lo, hi = np.asarray(mesh, float)[:, :2].min(0), np.asarray(mesh, float)[:, :2].max(0)
    else:
        x, y, scale = (float(v) for v in tracks.heads[k][:3])
        lo, hi = np.array([x - scale, y - scale]), np.array([x + scale, y + 2 * scale])
    half = min(256.0, max(32.0, 1.5 * float((hi - lo).max())))
    x0, y0 = (int(max(0.0, c - half)) // 8 * 8 for c in (lo + hi) / 2)
    side = int(2 * half)
    blocks, sharp = {}, {}
    try:
        with open_video(video, fps=fps, start=first, end=stop, eight_bit=True) as source:
            for frame in source:
                if frame.ok:
                    crop = frame.image[y0:y0 + side, x0:x0 + side]
                    blocks[frame.index] = blockiness(crop)
                    sharp[frame.index] = sharpness(crop)
    except (OSError, ValueError):
        return None
    measured = [b for b in blocks.values() if np.isfinite(b)]    # (a flat crop has none)
    typical = float(np.median(measured)) if measured else np.nan
    own = blocks.get(first, np.nan)
    if not (np.isfinite(own) and np.isfinite(typical) and typical > 0):
        return None
    crisp = SHARP_ENOUGH * float(np.median(list(sharp.values())))
    clean = [int(f) for f, ok in zip(tracks.frames, tracks.success)
             if ok and first < f <= first + round(rate)
             and blocks.get(int(f), np.inf) <= CLEAN_BLOCKS * typical
             and sharp.get(int(f), -1.0) >= crisp]
    return own / typical, clean[0] if clean else None


def _interocular_px(tracks: Tracks) -> float | None:
    """The median distance between the eye centres (pixels) over the tracked frames with
    the landmark tracker's face mesh; None without one."""
    gaps = [interocular_distance(np.asarray(m, float)[:, :2])
            for m, ok in zip(tracks.landmarks or (), tracks.success) if ok and m is not None]
    return float(np.median(gaps)) if gaps else None


def _warn_cuts(video, tracks: Tracks, k: int) -> None:
    """A warning for each shot cut (:attr:`Tracks.cuts`) with tracked frames on both
    sides: the face after it may be another person or another view, measured against the
    neutral frame of another shot."""
    tracked = tracks.frames[tracks.success]
    across = [c for c in tracks.cuts if (tracked < c).any() and (tracked >= c).any()]
    if across:
        log.warning("%s: a shot cut at frame%s %s, with a face on both sides: the face "
                    "after a cut can be another person or seen from another camera, and is "
                    "measured against the neutral frame %d all the same; analyse each shot "
                    "on its own (--start, --end; 'faceanalysis probe --decode' lists them)",
                    video, "s" if len(across) > 1 else "",
                    ", ".join(map(str, across)), int(tracks.frames[k]))


def _tracking_table(tracks: Tracks, k: int) -> pd.DataFrame:
    """The tracking columns of ``contractions.csv`` (the controls follow); the eyes'
    openness relative to row ``k``, the neutral frame."""
    table = empty_table(len(tracks), frames=tracks.frames.tolist(),
                        timestamps=tracks.timestamps.tolist())
    table["success"] = tracks.success.astype(np.int64)
    table["confidence"] = tracks.confidence
    table[list(HEAD_COLUMNS)] = tracks.heads
    table[list(POSE_COLUMNS)] = tracks.pose
    table[list(EYE_COLUMNS)] = eye_openness(tracks.eyes, k)
    for j, name in enumerate(FIDUCIALS):
        table[f"fid_{name}_x"] = tracks.fiducials[:, j, 0]
        table[f"fid_{name}_y"] = tracks.fiducials[:, j, 1]
    return table


def _eye_summary(table: pd.DataFrame, tracks: Tracks, k: int, video) -> dict | None:
    """``analysis.json``'s ``eyes``: the neutral frame's lid gaps and outer eye corners'
    distance, and the closures of :func:`~faceanalysis.analysis.eyes.eye_closures`; None
    without measured eyes. Warns when the neutral frame's eyes are narrower than usual (the
    openness is relative to them) or smaller than :data:`SMALL_EYES_PX`."""
    # photographs last no time: their closures have no duration, none is a blink
    times = (np.full(len(tracks.frames), np.nan) if is_photographs(tracks.input)
             else tracks.timestamps)
    summary = eye_closures(table[list(EYE_COLUMNS)].to_numpy(float), tracks.frames, times)
    if summary is None:
        return None
    neutral = tracks.eyes[k]
    typical = np.nanmedian(tracks.eyes[tracks.success], axis=0)
    mesh = tracks.landmarks[k]
    corners = None if mesh is None else float(np.hypot(*(mesh[33, :2] - mesh[263, :2])))
    if corners is not None and corners < SMALL_EYES_PX:
        log.warning("%s: the outer eye corners lie %.0f px apart on the neutral frame: at "
                    "under %.0f px the lids are too small to read reliably, and eye closures "
                    "(blinks most) may be missed", video, corners, SMALL_EYES_PX)
    if (neutral < NEUTRAL_EYES * typical).any():
        log.warning("%s: on the neutral frame %d the eyes are narrower than on most frames "
                    "(lid gaps %.2f and %.2f of their median): eye_openness is relative to "
                    "them; give another --neutral frame", video, int(tracks.frames[k]),
                    *(neutral / typical))
    return {"source": "MediaPipe iris landmark model", "neutral_lid_gap_iod":
            [round(float(g), 4) for g in neutral],
            "eye_corner_distance_px": None if corners is None else round(corners, 1),
            **summary}


def _contractions(table: pd.DataFrame, values: pd.DataFrame, disp: np.ndarray,
                  response: FiducialResponse, track_conf: np.ndarray, parameters: dict,
                  ident: dict, unreproduced: np.ndarray | None = None,
                  model_residual: np.ndarray | None = None):
    """``table`` with the estimate's controls, its confidence, AU and identifiability
    columns; the per-frame fit residual and its summary. ``parameters`` gains the
    estimated and resting controls.

    A frame's value of a control is flagged measured (``<control>_identifiable``) when
    ``ident`` (:func:`~faceanalysis.estimation.identifiability.assess`) finds the control
    identifiable and the estimator observed it on that frame, and where the mirror check
    compared frame by frame, its value came back on the mirrored frame (``unreproduced``,
    shape (T, len(response.muscles)): the values that did not).

    Controls the estimator did not estimate are reported at rest (0) on tracked frames
    and listed in ``parameters['controls_at_rest']``; lost frames are NaN. A tracked
    frame has a value for every control: one that the frame's points do not observe
    (NaN from the estimator) is held (:func:`_hold_unobserved`), counted in
    ``parameters['controls_held']`` and lowers the frame's confidence. So do a fit residual
    over :data:`MAX_FIT_RESIDUAL` and a head turned more than :data:`MAX_HEAD_TURN` from
    the neutral frame's pose (``fit['head_turn']``).
    """
    table = table.copy()
    success = table["success"].to_numpy() == 1
    estimated = [c for c in values.columns
                 if c in (*MUSCLES, JAW) and np.isfinite(values[c].to_numpy(float)).any()]
    observed = np.ones(len(table), dtype=float)
    held: dict[str, int] = {}
    controls = (*MUSCLES, JAW)
    measured = np.zeros((len(table), len(controls)), dtype=bool)
    if estimated:
        v, seen = _hold_unobserved(values[estimated].to_numpy(float), success)
        observed = seen.mean(axis=1)
        held = {c: int(n) for c, n in zip(estimated, (~seen & success[:, None]).sum(axis=0))
                if n}
        for j, c in enumerate(estimated):
            measured[:, controls.index(c)] = seen[:, j]
    for col in controls:
        col_v = v[:, estimated.index(col)] if col in estimated else np.zeros(len(table))
        table[col] = np.where(success, col_v, np.nan)
    # the model's prediction at the estimate, whichever estimator made it
    in_response = _response_array(values, response)
    turn = head_turn(table, parameters.get("neutral_frame"))
    with np.errstate(divide="ignore"):
        track_conf = np.fmin(track_conf, MAX_HEAD_TURN / turn)   # fmin: no pose, no cap
    residual, confidence, fit = _model_fit(disp, response, in_response, success, track_conf,
                                           model_residual)
    fit["head_turn"] = _turn_summary(turn[success])
    table["confidence"] = confidence * observed
    parameters["estimated_controls"] = estimated
    parameters["controls_at_rest"] = [m for m in controls if m not in estimated]
    parameters["controls_held"] = held
    if unreproduced is not None:
        for j, c in enumerate(response.muscles):
            if c in controls:
                measured[:, controls.index(c)] &= ~unreproduced[:, j]
    identifiable = [c for c, entry in ident["controls"].items() if entry["identifiable"]]
    table = with_identifiable_columns(with_au_columns(table), identifiable, observed=measured)
    return table, residual, fit


def _hold_unobserved(values: np.ndarray, success: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill the controls a tracked frame does not observe; say which were observed.

    An estimator leaves a control NaN on a tracked frame when none of the frame's
    visible points moves with it (a brow or the mouth contour lost: 3-8 % of the
    frames of the real test clips). Such a control takes its last observed value
    (rest, 0, before the first), so that a tracked frame (``success = 1``) has a value
    for every control and every reader of ``contractions.csv`` accepts it; the frame
    stays tracked because its other controls are measured. Measured on the rendered
    surprise (24 frames, seed 5) with the left brow hidden on 3 to 5 frames, the RMSE
    of the five left-brow controls on those frames is 0.14-0.17 held, 0.70-0.73 at
    rest, 0.16-0.31 interpolated between the observed neighbours (which also needs the
    future), against 0.11-0.14 with the brow visible.

    Parameters
    ----------
    values : ndarray, shape (T, C)
        Estimated controls; NaN where not observed.
    success : ndarray of bool, shape (T,)
        Tracked frames.

    Returns
    -------
    filled : ndarray, shape (T, C)
        ``values`` with every NaN of a tracked frame filled.
    observed : ndarray of bool, shape (T, C)
        Where the estimator gave a value (False on lost frames): the frame's
        confidence is multiplied by its fraction of observed controls.

    Examples
    --------
    >>> v = np.array([[np.nan], [0.5], [np.nan], [np.nan]])
    >>> filled, seen = _hold_unobserved(v, np.array([True, True, False, True]))
    >>> filled[:, 0].tolist(), seen[:, 0].tolist()
    ([0.0, 0.5, nan, 0.5], [False, True, False, False])
    """
    observed = np.isfinite(values) & success[:, None]
    rows = np.arange(len(values))[:, None]
    last = np.maximum.accumulate(np.where(observed, rows, -1), axis=0)       # (T, C)
    cols = np.arange(values.shape[1])[None, :]
    held = np.where(last >= 0, values[np.maximum(last, 0), cols], 0.0)
    filled = np.where(observed, values, np.where(success[:, None], held, np.nan))
    return filled, observed


def _turn_summary(turn: np.ndarray) -> dict:
    """``model_fit.head_turn`` of ``analysis.json``: the limit, the tracked frames beyond
    it and the largest turn (both None without a pose: the snakes tracker's)."""
    t = turn[np.isfinite(turn)]
    if not t.size:
        return {"limit_deg": MAX_HEAD_TURN, "frames_over_limit": None, "max_deg": None}
    return {"limit_deg": MAX_HEAD_TURN, "frames_over_limit": int((t > MAX_HEAD_TURN).sum()),
            "max_deg": float(t.max())}


def _model_fit(disp, response, values, success, track_conf, model_residual=None):
    """Per-frame fit residual (``model_residual``, the estimator's own through the model,
    where it has one; else through the response table), the confidence it allows, and
    their summary for ``analysis.json`` (``model_fit``)."""
    if model_residual is None:
        model_residual = fit_residual(disp, response, values)
    residual = np.where(success, model_residual, np.nan)
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


def reestimate(analysis: Analysis, estimator: str, *, refine: bool = False,
               temporal: float | None = None, personalize: bool = False) -> Analysis:
    """The same tracking and calibration, another estimator: a new :class:`Analysis`.

    Tracking dominates the cost of an analysis, so comparing estimators this way
    costs only the estimation (and, for ``flow``, the flow pass over the video).
    ``temporal`` as in :func:`analyze`; by default the analysis's own (its
    ``parameters.temporal``), else the estimator's default; ``personalize`` as in
    :func:`analyze`. An analysis made with
    ``mirror_check`` repeats the check with the new estimator on its mirrored tracks
    (not with ``fused`` and ``flow``, which read the frames again: there the new
    analysis has no check, and ``parameters.mirror_check`` says so).
    """
    if estimator not in ESTIMATORS:
        raise ValueError(f"unknown estimator {estimator!r}; choose from {', '.join(ESTIMATORS)}")
    if temporal is None and estimator in TEMPORAL_ESTIMATORS:
        temporal = analysis.metadata.get("parameters", {}).get("temporal")
    if refine and estimator != "joint":
        raise ValueError(f"refine works with the joint estimator, not {estimator!r}")
    if personalize and estimator != "model":
        raise ValueError(f"personalize works with the model estimator, not {estimator!r}")
    est_options = _fit_options(estimator, refine, temporal, personalize)
    if analysis.calibration is None or analysis.response is None:
        raise ValueError("this analysis has no calibration/response to re-estimate from")
    if estimator == "flow" and analysis.tracks is None:
        raise ValueError("the flow estimator needs the tracks of the video; this analysis "
                         "has none (analyse the video again)")
    table = analysis.table.copy()
    heads = table[list(HEAD_COLUMNS)].to_numpy(float)
    points = analysis.fiducials if analysis.measurements is None else analysis.measurements
    disp = analysis.calibration.model_displacements(points, heads)
    params = analysis.metadata.get("parameters", {})
    tracks = analysis.tracks
    k = 0 if tracks is None else int(np.flatnonzero(
        tracks.frames == params.get("neutral_frame", tracks.frames[0]))[0])
    if params.get("pose_correction"):
        # the same correction as the analysis's, from the pose columns of its table
        rows = np.flatnonzero(table["frame"].to_numpy() == params.get("neutral_frame"))
        if rows.size:
            disp, _ = _correct_pose(disp, table[list(POSE_COLUMNS)].to_numpy(float),
                                    int(rows[0]), analysis.response, True)
    obs = Observations(tracks=tracks, response=analysis.response, displacements=disp,
                       neutral=k, options={n: params.get(n) for n in ("fps", "start", "end")},
                       calibration=analysis.calibration)
    est = run_estimator(estimator, obs, **est_options)
    track_conf = analysis.track_confidence
    if track_conf is None:
        track_conf = table["confidence"].to_numpy(float)
    parameters = {**params, "estimator": estimator, "refine": bool(refine),
                  "personalize": bool(personalize), "temporal": est_options.get("temporal"),
                  "measurement_points": list(est.response.fiducials)}
    check = None
    mirrored = analysis.mirrored_tracks
    parameters["mirror_check"] = (bool(params.get("mirror_check"))
                                  and estimator not in VIDEO_ESTIMATORS)
    if parameters["mirror_check"] and mirrored is None:
        check = _skipped("this analysis holds no tracks of the mirrored video")
    elif parameters["mirror_check"]:
        calib_options = {"suspect_points": params.get("suspect_points", "exclude"),
                         "pose_correction": bool(params.get("pose_correction")),
                         "options": obs.options}
        check = _mirror_check(est, mirrored, k, tracks, analysis.response, estimator,
                              est_options, mirrored.video, calib_options)
    ident, unreproduced = _with_mirror(_assess(est, analysis.metadata.get("input")), check,
                                       tracks.frames
                                       if tracks is not None else table["frame"].to_numpy())
    table, residual, fit = _contractions(table, est.values, est.displacements, est.response,
                                         track_conf, parameters, ident, unreproduced,
                                         est.residual)
    metadata = dict(analysis.metadata)
    metadata["parameters"] = parameters
    metadata["model_fit"] = fit
    metadata["identifiability"] = ident
    if "quality" in metadata:
        # the confidence changed with the estimate: so do its mean and minimum
        q = quality_summary(table, frames_missing=metadata["quality"].get("frames_missing", 0))
        metadata["quality"] = {**metadata["quality"], "mean_confidence": q["mean_confidence"],
                               "min_confidence": q["min_confidence"]}
    return Analysis(table=table, contours=analysis.contours, metadata=metadata,
                    calibration=analysis.calibration, response=analysis.response,
                    measurements=analysis.measurements, timings=dict(analysis.timings),
                    fit_residual=residual, track_confidence=track_conf, tracks=tracks,
                    mirrored_tracks=mirrored, estimate=est)


def analyze_to_folder(video: str | os.PathLike, output: str | os.PathLike, *,
                      overwrite: bool = False, overlay: bool = False, quiet: bool = True,
                      **options) -> Analysis:
    """Run :func:`analyze` and write its results into the folder ``output``.

    The folder is checked before any work (a non-empty folder needs
    ``overwrite=True``); each file is written atomically. Writes
    ``contractions.csv``, ``analysis.json``, ``contractions.png`` and, with
    ``overlay=True``, ``overlay.mp4``. Other keyword arguments go to :func:`analyze`.
    A folder created for the run is removed again if the run fails before writing
    anything; after a run with ``overwrite``, the toolkit's files of an earlier run that
    it did not write again (an overlay, ``validation.*``) are removed
    (see :class:`~faceanalysis.analysis.results.OutputFolder`).
    """
    video = as_video(video)
    if (not isinstance(video, Frames) and Path(video).is_dir()
            and Path(output).resolve() == Path(video).resolve()):
        # the plot written there would be read as one more picture by the next analysis
        raise ValueError(f"{output} is the folder of images being analysed: write the "
                         "results to another folder (its contractions.png would be read as "
                         "a picture)")
    with OutputFolder(output, overwrite=overwrite) as folder:
        result = analyze(video, overlay=folder.overlay_mp4 if overlay else None,
                         progress=not quiet, **options)
        folder.write(result.table, result.metadata,
                     title=video.name if isinstance(video, Frames) else Path(video).name)
    return result
