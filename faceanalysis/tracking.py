"""The one loop over a video's frames: contours, points and head frame per frame.

:func:`track` streams a video (file, image folder or single image) through the nine
snakes of :mod:`trackers` and returns :class:`Tracks`: per frame the head reference
frame, the 11 fiducials, the measurement points an estimator reads, the tracker's
confidence and the contours. Everything above it (calibration, estimators, the flow
pass, validation, recognition) starts from a :class:`Tracks` or its table, so every
command sees the same frames succeed and fail.

Frames are streamed: memory holds the per-frame measurements (a few hundred bytes a
frame) and the contours, never the frames.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from contextlib import closing
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.errors import FaceAnalysisError
from faceanalysis.io.cuts import frame_changes, shot_cuts
from faceanalysis.io.report import (
    LOST_REASONS,
    input_metadata,
    input_name,
    lost_reasons_text,
)
from faceanalysis.io.table import FIDUCIALS, HEAD_COLUMNS, POSE_COLUMNS
from faceanalysis.io.video import MIN_FACE_SIZE, Frames, as_video, open_video, read_ahead
from trackers.torch_backend import check_backend, make_tracker

log = logging.getLogger(__name__)

__all__ = [
    "CURVE_POINTS",
    "HIDDEN_REASONS",
    "MIN_FURROW_STRETCH",
    "MIN_POINTS",
    "POINT_CONTOUR",
    "DEFAULT_TRACKER",
    "FADE_RISE",
    "TRACKERS",
    "Tracks",
    "faded_furrow_ends",
    "find_face",
    "hidden_frames",
    "lost_reason_counts",
    "measure_frame",
    "progress_bar",
    "resolve_tracker",
    "thread_budget",
    "to_head_frame",
    "track",
]

#: Measurement points read off a contour instead of a landmark: name -> (contour, fraction
#: of its arc length from its first end). The contour names are shared by the trackers
#: (:data:`trackers.layout.CONTOUR_NAMES`) and the face mesh's feature curves
#: (:attr:`synth.face_mesh.FaceMesh.feature_curves`); both run from the furrow's top down.
#: The middle and lower end of each nasolabial furrow follow the cheek where the
#: zygomaticus, the levators, risorius and the jaw pull it, which is what tells those
#: controls apart from the mouth corners alone.
CURVE_POINTS: dict[str, tuple[str, float]] = {
    **{f"furrow_mid_{s}": (f"furrow_{s}", 0.5) for s in "lr"},
    **{f"furrow_bottom_{s}": (f"furrow_{s}", 1.0) for s in "lr"},
}

# How a measurement point that is not one of the 11 fiducials is read off the contours.
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

#: On this many frames before one where a hand covers contours (the landmark tracker's
#: hand detector), those contours are taken as covered too: a hand moving over the face
#: arrives fingers first, and the palm detector finds it only once its palm is in view.
#: On ``WolfgangLanger_Pexels.mp4`` the hand is first found on frame 60; on frame 58 its
#: fingers lie over the chin and the analysis read zygomaticus major 1.0 and orbicularis
#: oris 0.78 on a crying face, on frame 59 over the mouth (0.94, 0.98). On cap12 a hand
#: found on the chin on frame 1185 had deepened the chin's edges from 1.4 to 2.3 times
#: their first frame's two frames before.
HAND_LEAD = 2

#: Until a face is first found, a frame of a video is lost (``'fading'``, not shown to the
#: tracker) where the next frame is brighter than it by more than this factor (the mean of
#: its grey levels): a video that fades in from black, a camera's exposure still settling.
#: The first frame with a face is the one the contours are placed on, whose edges every
#: later frame's are judged against, and by default the analysis's neutral frame: cap13 faded
#: in over its first 20 frames had its face found on the second, at a tenth of the light, and
#: lost 199 of its 200 frames. Frames one by one from an image folder (photographs, often
#: under other light) are not held to it. The real clips' frames change by at most 1.5 %.
FADE_RISE = 1.03


#: A furrow's lower end (``furrow_bottom_*``) is measured only on frames where the
#: tracked furrow is at least this long relative to the neutral frame. The face model
#: never shortens a nasolabial furrow by more than 1.4 % (risorius at full contraction)
#: and opening the jaw lengthens it by 18 %; a tracked furrow that got shorter ends
#: where its line faded out (the stretched lower furrow fades as the jaw opens), not
#: where the model's furrow ends, and its end would read as a jaw that did not open.
MIN_FURROW_STRETCH = 0.98

# The measurement points at a contour's lower end: name -> contour.
_END_POINTS = {name: contour for name, (contour, fraction) in CURVE_POINTS.items()
               if fraction == 1.0}


def to_head_frame(points: np.ndarray, head: np.ndarray) -> np.ndarray:
    """Express image points in the head reference frame.

    Parameters
    ----------
    points : ndarray, shape (..., F, 2)
        Image points (x right, y down, pixels).
    head : ndarray, shape (..., 4)
        Head frame per frame: origin x, origin y, scale (px per unit), roll (radians):
        the angle of the head's x axis in image coordinates, ``atan2(dy, dx)`` with y
        down, so a positive roll is clockwise on screen.

    Returns
    -------
    ndarray, shape (..., F, 2)
        ``R(-roll) (p - origin) / scale``: translation, in-plane rotation and scale removed.

    Examples
    --------
    >>> to_head_frame([[12.0, 20.0]], [10.0, 20.0, 2.0, 0.0]).tolist()
    [[1.0, 0.0]]
    """
    points = np.asarray(points, dtype=float)
    head = np.asarray(head, dtype=float)
    rel = points - head[..., None, 0:2]
    cos, sin = np.cos(head[..., 3])[..., None], np.sin(head[..., 3])[..., None]
    x = cos * rel[..., 0] + sin * rel[..., 1]
    y = -sin * rel[..., 0] + cos * rel[..., 1]
    return np.stack([x, y], axis=-1) / head[..., 2, None, None]


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


def progress_bar(total, enabled: bool, desc: str, *, unit: str = "frame"):
    """A tqdm bar on stderr, or None when ``enabled`` is false (the library's default)."""
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False,
                dynamic_ncols=True)


def load_layout(layout, frame_size):
    """A :class:`trackers.FaceLayout` from a layout, a JSON file of one, or None."""
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


@dataclass
class Tracks:
    """What :func:`track` saw in a video, frame by frame.

    Attributes
    ----------
    video : str or Frames
        The input's path, or the frames in memory (:class:`~faceanalysis.io.video.Frames`).
    input : dict
        The input's metadata (:func:`faceanalysis.io.report.input_metadata`).
    frames, timestamps : ndarray, shape (T,)
        Absolute frame numbers and their times in seconds.
    success : ndarray of bool, shape (T,)
        Head frame known and at least :data:`MIN_POINTS` points measured.
    confidence : ndarray, shape (T,)
        The tracker's confidence (smallest relative potential depth of the contours
        that are held), 0 on lost frames.
    heads : ndarray, shape (T, 4)
        Head frame (origin x, y, scale, roll); NaN on lost frames.
    fiducials : ndarray, shape (T, 11, 2)
        The 11 fiducials in pixels (:data:`~faceanalysis.io.table.FIDUCIALS` order);
        NaN on lost frames and where the fiducial's contour is lost.
    point_names : tuple of str
        The measurement points.
    points : ndarray, shape (T, len(point_names), 2)
        Measurement points in pixels, NaN as for ``fiducials``.
    stretch : ndarray, shape (T, len(point_names))
        Length of each point's contour relative to the tracker's first frame.
    contours : list
        Per frame, contour name -> (n, 2) nodes (None for frames that did not decode).
    pose : ndarray, shape (T, 2)
        Head pitch and yaw in degrees relative to the tracker's first frame (landmark
        tracker); NaN on lost frames and with the snakes tracker.
    eyes : ndarray, shape (T, 2)
        Each eye's lid gap (the subject's left, then right) over the inter-ocular
        distance, traced by the iris model (landmark tracker,
        :mod:`trackers.landmarks.eyes`); NaN on lost frames and with the snakes tracker.
    tracker : str
        Which tracker ran (:data:`TRACKERS`).
    landmarks : list
        Per frame, the landmark tracker's 468 face-mesh points as a (468, 3) float32
        array (x, y in pixels, z in pixels of depth, toward the camera negative) for
        the estimators that read more than the fiducials (index map:
        :mod:`trackers.landmark_contours`); None on lost frames and with the snakes
        tracker.
    timings : dict
        ``track_s`` (time in the tracker), ``cpu_s`` (CPU time of the process, all
        threads, over the tracking loop: decoding included) and ``frames``.
    mirrored : bool
        Whether the video was tracked mirrored (:func:`track`'s ``mirror``).
    lost_reasons : list
        Per frame, why it was lost (a code of
        :data:`~faceanalysis.io.report.LOST_REASONS`); None where it was
        tracked (or, for tracks not made by :func:`track`, where the reason is not known).
    cuts : list of int
        Frame numbers where a new shot begins (:func:`faceanalysis.io.cuts.shot_cuts`);
        empty for tracks not made by :func:`track`.
    """

    video: str | Frames
    input: dict
    frames: np.ndarray
    timestamps: np.ndarray
    success: np.ndarray
    confidence: np.ndarray
    heads: np.ndarray
    fiducials: np.ndarray
    point_names: tuple
    points: np.ndarray
    stretch: np.ndarray
    contours: list
    pose: np.ndarray | None = None
    eyes: np.ndarray | None = None
    tracker: str = "snakes"
    landmarks: list | None = None
    timings: dict = field(default_factory=dict)
    mirrored: bool = False
    lost_reasons: list | None = None
    cuts: list = field(default_factory=list)

    def __post_init__(self):
        if self.pose is None:
            self.pose = np.full((len(self.frames), 2), np.nan)
        if self.eyes is None:
            self.eyes = np.full((len(self.frames), 2), np.nan)
        if self.landmarks is None:
            self.landmarks = [None] * len(self.frames)
        if self.lost_reasons is None:
            self.lost_reasons = [None] * len(self.frames)       # not known

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        # a summary, not the fields: the per-frame contours and landmarks print about
        # 10 kB a frame
        n, tracked = len(self.frames), int(np.count_nonzero(self.success))
        lost = f"{n - tracked} lost"
        reasons = lost_reason_counts(self.lost_reasons or ())
        if reasons:
            lost += f" ({lost_reasons_text(reasons)})"
        name = (self.video.name if isinstance(self.video, Frames)
                else input_name(self.input) if self.input else Path(str(self.video)).name)
        return (f"<Tracks of {name}: {n} frame{'' if n == 1 else 's'}, {tracked} tracked, "
                f"{lost}; {self.tracker} tracker{', mirrored' if self.mirrored else ''}>")

    @property
    def table(self) -> pd.DataFrame:
        """``frame, timestamp, success``, the head columns and ``fid_<name>_x/_y``:
        the tracking part of ``contractions.csv``."""
        out = {"frame": self.frames.astype(np.int64), "timestamp": self.timestamps,
               "success": self.success.astype(np.int64)}
        for j, col in enumerate(HEAD_COLUMNS):
            out[col] = self.heads[:, j]
        for j, col in enumerate(POSE_COLUMNS):
            out[col] = self.pose[:, j]
        for j, name in enumerate(FIDUCIALS):
            out[f"fid_{name}_x"] = self.fiducials[:, j, 0]
            out[f"fid_{name}_y"] = self.fiducials[:, j, 1]
        return pd.DataFrame(out)


def _detect(image, frame_index: int, video):
    from trackers import detect_layout

    try:
        return detect_layout(image, frame_index=frame_index, channel_order="bgr")
    except ValueError as exc:
        # the detector names the frame; the user needs the file too
        raise ValueError(f"{video}: {exc}") from None


#: The trackers :func:`track` can run: 'landmarks' (snakes placed and held by MediaPipe's
#: face mesh, :class:`trackers.AnchoredTracker`) and 'snakes' (004: Haar cascades, the
#: template layout and free snakes).
TRACKERS = ("landmarks", "snakes")

#: The tracker used when none is named (and no layout places the snakes): the landmark
#: tracker, which finds and holds real faces and loses frames without one, where the free
#: snakes of 004 slide onto other features (docs/accuracy.md). On the toolkit's rendered
#: faces, which are drawn for them, the snakes are the more precise (0.79 px mean fiducial
#: error against 1.44 px): the standard suite runs them.
DEFAULT_TRACKER = "landmarks"


def resolve_tracker(tracker: str | None, layout=None) -> str:
    """The tracker :func:`track` runs for ``tracker`` (None: :data:`DEFAULT_TRACKER`, or
    the snakes where a ``layout`` places them).

    Examples
    --------
    >>> resolve_tracker(None), resolve_tracker(None, layout="face.json")
    ('landmarks', 'snakes')
    """
    if tracker is None:
        return "snakes" if layout is not None else DEFAULT_TRACKER
    return tracker


def track(video: str | os.PathLike, *, points: tuple[str, ...] = tuple(FIDUCIALS),
          fps: float | None = None, start: int = 0, end: int | None = None, layout=None,
          tracker: str | None = None, tracker_options: dict | None = None,
          backend: str = "numpy", device: str | None = None, redetect: bool = False,
          overlay: str | os.PathLike | None = None, progress: bool = False,
          keep_contours: bool = True, mirror: bool = False) -> Tracks:
    """Track the face in a video: head frame, fiducials and measurement points per frame.

    Parameters
    ----------
    video : path-like, Frames or array_like
        Video file, folder of images, a single image, or frames in memory (an array
        ``(T, H, W[, 3])`` or a sequence of arrays, RGB; :class:`~faceanalysis.io.video.Frames`).
    points : tuple of str, keyword-only
        Measurement points to read: fiducials (:data:`~faceanalysis.io.table.FIDUCIALS`),
        ``lip_lower_centre`` and the :data:`CURVE_POINTS`. A frame succeeds when at
        least :data:`MIN_POINTS` of them are measured.
    fps : float, optional
        Frame rate, overriding the container's.
    start, end : int, optional
        Frame range ``[start, end)``.
    layout : FaceLayout or path-like, optional
        Initial contours (e.g. corrected by hand and saved with ``FaceLayout.to_json``)
        for ``tracker='snakes'``; by default they are placed by OpenCV's face and eye
        detectors on the first frame.
    tracker : {'landmarks', 'snakes'}, optional
        'landmarks' (default, :data:`DEFAULT_TRACKER`, unless ``layout`` is given): a
        learned landmark model (MediaPipe's face mesh) finds the face on every frame, places
        the contours and holds them with springs (:class:`trackers.AnchoredTracker`); a
        frame without a face is lost and the analysis starts on the first frame with one.
        What a hand covers is lost, on the frame where it is found and on the
        :data:`HAND_LEAD` frames before it (the overlay is drawn that many frames behind).
        'snakes': the method of 004 (Haar cascades, the template layout and free snakes),
        which needs no model.
    tracker_options : dict, optional
        Keyword arguments for :class:`trackers.Tracker` or, with 'landmarks',
        :class:`trackers.AnchoredTracker` (e.g. ``{"brow_mid": 0.556}``).
    backend : {'numpy', 'torch'}, keyword-only
        Where the snakes relax: compiled NumPy/Numba (default) or batched torch (the
        ``[torch]`` extra; same contours within 1e-6 px).
    device : str, optional
        Torch device with ``backend='torch'``.
    redetect : bool, keyword-only
        With ``tracker='snakes'``. Frames before the first one with a face are lost
        either way. False (default): once the face is found, the snakes follow it to the
        end. True: a frame
        where the face is not found or the contours leave the image is lost, the face is
        looked for again on the next frame, and fresh contours get two more relaxations
        to settle.
    overlay : path-like, optional
        Write the frames with contours, fiducials and head frame drawn to this video.
    progress : bool
        Progress bar on stderr.
    keep_contours : bool, keyword-only
        Keep every frame's contours in :attr:`Tracks.contours` (a few kB a frame); False
        leaves None there, for callers that only read the measurements, whose memory then
        does not grow with the contours.
    mirror : bool, keyword-only
        Track the video mirrored left to right (each frame flipped before the tracker sees
        it): every position is in the mirrored frame's pixels, and what is named ``_l`` is
        the subject's right (the mirrored face's left). The analysis's reproducibility
        check reads it (``analyze(..., mirror_check=True)``).

    Returns
    -------
    Tracks

    Raises
    ------
    FileNotFoundError
        If the video (or layout file) does not exist.
    ValueError
        Unreadable video, an empty frame range, no face in any frame, unknown points or
        bad parameters.
    """
    video = as_video(video)         # frames in memory: messages name them, not their pixels
    points = tuple(points)
    unknown = [p for p in points if p not in POINT_CONTOUR]
    if unknown:
        raise ValueError(f"unknown measurement points {unknown}; choose from "
                         f"{', '.join(POINT_CONTOUR)}")
    check_backend(backend, device)
    tracker = resolve_tracker(tracker, layout)
    if tracker not in TRACKERS:
        raise ValueError(f"unknown tracker {tracker!r}; choose from {', '.join(TRACKERS)}")
    if tracker == "landmarks" and layout is not None:
        raise ValueError("a layout places the snakes of tracker='snakes'; the landmark "
                         "tracker places its own")
    if tracker == "landmarks":
        from trackers.landmarks import ensure_models

        try:
            ensure_models()   # before any frame: a missing model is one clear error
        except RuntimeError as exc:
            raise FaceAnalysisError(str(exc)) from None
    # frames are read at 8 bits: the same picture at any bit depth gives the same tracks
    source = open_video(video, fps=fps, start=start, end=end, min_size=MIN_FACE_SIZE,
                        eight_bit=True)
    if mirror and (tracker_options or {}).get("start_near") is not None:
        # the point that picks the face is the unmirrored frame's
        x, y = tracker_options["start_near"]
        tracker_options = {**tracker_options, "start_near": [source.size[0] - 1 - x, y]}
    n_fid = len(FIDUCIALS)
    fid_of_point = [points.index(n) if n in points else None for n in FIDUCIALS]
    point_contours = [POINT_CONTOUR[p] for p in points]   # once, not per frame
    nan_fid = np.full((n_fid, 2), np.nan)
    nan_pts = np.full((len(points), 2), np.nan)
    nan_stretch = np.full(len(points), np.nan)
    nan_head = np.full(4, np.nan)
    frames, stamps, ok, conf, poses, mesh, reasons = [], [], [], [], [], [], []
    lids = []
    fid_rows, pt_rows, head_rows, stretch_rows, contours = [], [], [], [], []
    under_hand: list[set] = []           # per row, the contours a hand covers there
    fid_contour = [POINT_CONTOUR[n] for n in FIDUCIALS]
    pending: list = []                   # overlay frames held back HAND_LEAD frames
    late_cover: dict[int, set] = {}      # rows a hand found later covers (drawn as lost)

    def cover(r: int, covered: set) -> None:
        """Row ``r`` with the contours ``covered`` by a hand found a frame or two later."""
        if overlay is not None:
            late_cover[r] = covered
        pts = pt_rows[r].copy()
        pts[[j for j, c in enumerate(point_contours) if c in covered]] = np.nan
        if np.isfinite(pts).all(axis=1).sum() >= MIN_POINTS:
            pt_rows[r] = pts
            fids = fid_rows[r].copy()
            fids[[j for j, c in enumerate(fid_contour) if c in covered]] = np.nan
            fid_rows[r] = fids
            return
        ok[r], reasons[r], conf[r] = False, "hand", 0.0
        fid_rows[r], pt_rows[r], head_rows[r] = nan_fid, nan_pts, nan_head
        poses[r], lids[r], mesh[r] = nan_pose, nan_pose, None

    def draw(frame, res, r: int) -> None:
        nonlocal writer
        if writer is None:
            from synth.render.video import VideoWriter

            # photographs are shown a second each, not at the frame rate assumed for them
            rate = 1.0 if source.photographs else source.fps
            writer = VideoWriter(overlay, rate, source.size, channel_order="bgr")
        shown = None if res is None else res.contours
        hands = None if res is None else res.extra.get("hands")
        eyelids = None if not ok[r] else res.extra.get("eyelids")
        why = reasons[r] and LOST_REASONS[reasons[r]][0]
        muted = set() if res is None else {n for n, q in res.quality.items() if q.lost}
        muted |= late_cover.pop(r, set())
        writer.write(_draw(frame, shown, fid_rows[r], head_rows[r] if ok[r] else None,
                           why or not ok[r], hands, eyelids, muted))
    kind, tracker = tracker, None
    # frames of a video, in time: a fade-in there holds the tracker back (FADE_RISE), and
    # the landmark tracker evens their light out and waits for an entering face
    fades, faced = source.kind != "images", False
    waiting = _Waiting()
    nan_pose = np.full(2, np.nan)
    writer = None
    t_track = 0.0
    c_start = time.process_time()
    bar = progress_bar(source.n_frames, progress, "track")
    try:
        # decoding runs ahead in a thread; closing() stops it before the source closes
        # (frames are flipped in the decoding thread, not on the tracker's time)
        changes: dict[int, float] = {}
        with source, closing(read_ahead(_with_changes(
                _mirrored(source) if mirror else source, changes))) as decoded:
            upcoming = next(decoded, None)
            while upcoming is not None:
                frame = upcoming
                frames.append(frame.index)
                stamps.append(frame.timestamp)
                res = None
                t0 = time.perf_counter()
                upcoming = next(decoded, None)
                fading = (fades and not faced and frame.ok and upcoming is not None
                          and upcoming.ok and _brightening(frame.image, upcoming.image))
                if kind != "landmarks":
                    t0 = time.perf_counter()
                # else the landmark tracker works on this frame (prefetched) while the
                # next one is decoded: the wait counts as tracking time, so that no
                # landmark work hides outside the timed span
                if frame.ok and not fading:
                    if kind == "landmarks":
                        if tracker is None:
                            tracker = _anchored(backend, device, tracker_options,
                                                video=fades,
                                                photographs=source.photographs)
                        ahead = (upcoming.image if upcoming is not None and upcoming.ok
                                 else None)
                        res = tracker.track(frame.image, next_frame=ahead)
                    else:
                        tracker, res = _track_frame(tracker, frame, video, layout,
                                                    source.size, redetect, backend, device,
                                                    tracker_options,
                                                    waiting=None if any(ok) else waiting)
                    t_track += time.perf_counter() - t0
                    faced = faced or res is not None
                if res is None:
                    good, c = False, 0.0
                    fids, pts, head, stretch = nan_fid, nan_pts, nan_head, nan_stretch
                else:
                    head, pts, good = measure_frame(res, points)
                    c = _confidence(res)
                    fids = np.array([res.fiducials[n] for n in FIDUCIALS], float)
                    for j, p in enumerate(fid_of_point):
                        if p is not None and not np.isfinite(pts[p]).all():
                            fids[j] = np.nan
                    stretch = np.array([res.quality[c_].stretch for c_ in point_contours])
                    if not good:
                        fids, pts, head = nan_fid, nan_pts, nan_head
                pose = nan_pose
                if good and "head_pitch" in res.extra:
                    pose = np.array([res.extra["head_pitch"], res.extra["head_yaw"]])
                    c = min(c, float(res.extra["presence"]))
                poses.append(pose)
                lids.append(res.extra.get("eye_gaps", nan_pose) if good else nan_pose)
                mesh.append(_mesh(res) if good else None)
                ok.append(good)
                reasons.append(None if good else "fading" if fading
                               else _lost_reason(frame.ok, res, getattr(tracker, "others", 0)))
                conf.append(c)
                fid_rows.append(fids)
                pt_rows.append(pts)
                head_rows.append(head)
                stretch_rows.append(stretch)
                contours.append(None if res is None or not keep_contours else res.contours)
                covered = _under_hand(res)
                under_hand.append(covered)
                if covered:
                    # the frames just before, which no hand covered yet, as far as the
                    # hand's arrival can reach
                    for r in range(len(ok) - 2, max(len(ok) - 2 - HAND_LEAD, -1), -1):
                        if under_hand[r] or not ok[r]:
                            break
                        cover(r, covered)
                if overlay is not None and frame.ok:
                    pending.append((frame, res, len(ok) - 1))
                    if len(pending) > HAND_LEAD:
                        draw(*pending.pop(0))
                if bar is not None:
                    bar.update(1)
        for held in pending:
            draw(*held)
        if frames and not any(ok) and layout is None:
            # before the overlay is finished: a failed run leaves no file behind
            if set(lost_reason_counts(reasons)) - {"no_face", "undecodable"}:
                # a face was found, and lost for what covered it or the contours it lost
                raise ValueError(lost_everywhere(video, reasons))
            hint = ""
            if kind == "landmarks" and getattr(getattr(tracker, "landmarks", None),
                                               "full_range", True) is False:
                hint = (" (with OpenCV's TFLite reader a face narrower than about a "
                        "twentieth of the frame is not found; the full-range detector, which "
                        "finds it, runs with LiteRT: pip install ai-edge-litert)")
            raise ValueError(f"{video}: no face found in any of the {len(frames)} "
                             f"frames{hint}")
        if writer is not None:
            writer.close()
            writer = None
    finally:
        if bar is not None:
            bar.close()
        if writer is not None:
            writer.abort()
        if kind == "landmarks" and tracker is not None:
            tracker.close()
    if not frames:
        raise ValueError(f"{video}: no frames in the requested range")
    return Tracks(video=video if isinstance(video, Frames) else str(video),
                  input=input_metadata(source), frames=np.array(frames),
                  timestamps=np.array(stamps, float), success=np.array(ok, bool),
                  confidence=np.where(ok, conf, 0.0), heads=np.stack(head_rows),
                  pose=np.stack(poses), eyes=np.stack(lids).astype(float), tracker=kind,
                  landmarks=mesh, mirrored=bool(mirror),
                  lost_reasons=reasons,
                  fiducials=np.stack(fid_rows), point_names=points,
                  points=np.stack(pt_rows), stretch=np.stack(stretch_rows),
                  contours=contours, timings={"track_s": t_track, "frames": len(frames),
                                              "cpu_s": time.process_time() - c_start},
                  cuts=shot_cuts([changes[i] for i in frames], frames))


def find_face(video: str | os.PathLike, *, fps: float | None = None, start: int = 0,
              end: int | None = None, max_frames: int | None = 250) -> dict | None:
    """The first frame of ``video`` with a face, as the landmark tracker finds it.

    A quick look before an analysis: whether the face will be found, where it starts,
    and how large it is (under :data:`faceanalysis.analysis.pipeline.SMALL_FACE_IOD`
    pixels between the eyes the contractions are noisy).

    Parameters
    ----------
    video : path-like
        Video file, folder of images, or a single image.
    fps, start, end
        As for :func:`track`.
    max_frames : int or None, keyword-only
        Look at most at this many frames from ``start`` (None: to ``end``).

    Returns
    -------
    dict or None
        ``frame`` (its number), ``interocular_px`` (the distance between the eye centres),
        ``box`` (x0, y0, x1, y1 of the face mesh, pixels) and ``detector``: ``'short'``
        where MediaPipe's short-range detector finds the face on the whole frame,
        ``'full'`` where only the full-range one does (a face far from the camera);
        ``faces``: the boxes of every face the short-range detector finds on that frame
        (None where it finds none), for picking one with ``analyze(face=...)``.
        None where no face is found in the frames looked at.

    Raises
    ------
    FileNotFoundError, ValueError
        As :func:`track`; FaceAnalysisError where the face models cannot be obtained.
    """
    from trackers.landmark_contours import interocular_distance
    from trackers.landmarks import LandmarkTracker, detect_faces, ensure_models

    if max_frames is not None and (isinstance(max_frames, bool) or int(max_frames) != max_frames
                                   or max_frames < 1):
        raise ValueError(f"max_frames must be a positive integer or None, got {max_frames!r}")
    try:
        ensure_models()
    except RuntimeError as exc:
        raise FaceAnalysisError(str(exc)) from None
    source = open_video(video, fps=fps, start=start, end=end, min_size=MIN_FACE_SIZE,
                        eight_bit=True)
    tracker = LandmarkTracker(channel_order="bgr")
    with source, closing(read_ahead(source)) as frames:
        for n, frame in enumerate(frames):
            if max_frames is not None and n >= max_frames:
                break
            if not frame.ok:
                continue
            lm = tracker.track(frame.image)
            if lm is None:
                continue
            near = detect_faces(frame.image, channel_order="bgr")
            return {"frame": int(frame.index),
                    "interocular_px": round(interocular_distance(lm.points), 1),
                    "box": [round(v, 1) for v in lm.box],
                    "detector": "short" if near else "full",
                    "faces": [[round(v, 1) for v in f.box] for f in near] or None}
    return None


def lost_reason_counts(reasons) -> dict[str, int]:
    """How many frames were lost for each reason (codes of
    :data:`~faceanalysis.io.report.LOST_REASONS`, in its order; reasons not known left out).

    Examples
    --------
    >>> lost_reason_counts([None, "hand", "no_face", "hand", None])
    {'no_face': 1, 'hand': 2}
    """
    counts = {code: sum(r == code for r in reasons) for code in LOST_REASONS}
    return {code: n for code, n in counts.items() if n}


def lost_everywhere(video, reasons) -> str:
    """The message for a video whose every frame was lost, each for its reason (codes of
    :data:`~faceanalysis.io.report.LOST_REASONS`), with how many were lost for which.

    Examples
    --------
    >>> print(lost_everywhere("clip.mp4", ["hand", "hand", "no_face"]))
    ... # doctest: +NORMALIZE_WHITESPACE
    clip.mp4: the face was lost in every one of the 3 frames (1 without a face,
    2 under a hand); nothing to analyse
    """
    counts = lost_reason_counts(reasons)
    why = f" ({lost_reasons_text(counts)})" if counts else ""
    return f"{video}: the face was lost in every one of the {len(reasons)} frames{why}; " \
           "nothing to analyse"


#: Lost-frame reasons (:data:`~faceanalysis.io.report.LOST_REASONS`) that leave nothing of
#: the face to see: no face found, a hand over it, no picture at all. (A frame lost for
#: ``'contours'`` still shows the face.)
HIDDEN_REASONS = ("no_face", "other_face", "hand", "undecodable", "fading")


def hidden_frames(frames, lost_reasons) -> np.ndarray:
    """The frame numbers on which the face cannot be seen: lost for one of
    :data:`HIDDEN_REASONS` (``frames`` and ``lost_reasons`` as in :class:`Tracks`; no
    reasons, None: none known).

    Examples
    --------
    >>> hidden_frames([10, 11, 12, 13], [None, "hand", "contours", "no_face"]).tolist()
    [11, 13]
    """
    frames = np.asarray(frames, dtype=int)
    if lost_reasons is None:
        return frames[:0]
    if len(lost_reasons) != len(frames):
        raise ValueError(f"lost_reasons has {len(lost_reasons)} entries for {len(frames)} "
                         "frames")
    return frames[np.array([r in HIDDEN_REASONS for r in lost_reasons], bool)]


def _under_hand(result) -> set:
    """The contours the landmark tracker lost under a hand on ``result``'s frame (its
    ``occluded`` contours where it found a hand), empty where it found none."""
    if result is None or not result.extra.get("hands"):
        return set()
    return set(result.extra.get("occluded", ()))


def _lost_reason(decoded: bool, result, others: int = 0) -> str:
    """Why a frame that was not tracked is lost (a code of
    :data:`~faceanalysis.io.report.LOST_REASONS`); ``others``: faces the tracker found
    on it and took for someone else's."""
    if not decoded:
        return "undecodable"
    if result is None:
        return "other_face" if others else "no_face"
    if result.extra.get("edge"):
        return "edge"
    return "hand" if result.extra.get("hands") else "contours"


def _brightening(image, following) -> bool:
    """Whether ``following`` is brighter than ``image`` by more than :data:`FADE_RISE`."""
    import cv2

    level = float(np.mean(cv2.mean(image)[:3 if np.ndim(image) == 3 else 1]))
    after = float(np.mean(cv2.mean(following)[:3 if np.ndim(following) == 3 else 1]))
    return after > FADE_RISE * max(level, 0.5)


def _with_changes(frames, changes: dict):
    """``frames`` as they are; each one's :func:`~faceanalysis.io.cuts.frame_changes`
    change goes into ``changes`` (frame number -> change), in the thread that decodes them."""
    for frame, change in frame_changes(frames):
        changes[frame.index] = change
        yield frame


def _mirrored(frames):
    """``frames`` flipped left to right (undecoded frames as they are)."""
    import cv2

    for frame in frames:
        yield (replace(frame, image=cv2.flip(frame.image, 1)) if frame.ok
               and frame.image is not None else frame)


def _mesh(res):
    """The landmark tracker's 468 points (x, y, z) of a tracked frame, float32; None
    with the snakes tracker."""
    pts = res.extra.get("landmarks")
    if pts is None:
        return None
    z = res.extra.get("landmarks_z")
    z = np.zeros(len(pts)) if z is None else z
    return np.c_[pts, z].astype(np.float32)


def _anchored(backend, device, tracker_options, *, video: bool = False,
              photographs: bool = False):
    from trackers.anchored import AnchoredTracker

    # the landmarks' thread only pays where a core is free for it: not in a batch worker
    # given one core of many; frames in time (a video) have their light evened out and an
    # entering face waited for, photographs one by one not
    options = {"prefetch": thread_budget() > 1, "video": video, "photographs": photographs,
               **(tracker_options or {})}
    return AnchoredTracker(channel_order="bgr", backend=backend, device=device, **options)


def available_cores() -> int:
    """The number of cores the operating system lets this process run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1   # pragma: no cover - not Linux


def thread_budget() -> int:
    """The threads one analysis may run at once: ``FACEANALYSIS_WORKER_THREADS`` where the
    batch runner set it (its workers share the machine's cores), else every core this
    process may run on."""
    budget = os.environ.get("FACEANALYSIS_WORKER_THREADS", "")
    return max(int(budget), 1) if budget.isdigit() else available_cores()


#: After a stretch of at least this many frames without a face (a title card, the sky),
#: a face box in which the eye detector finds no eyes starts the snakes only once it has
#: held its place for as many frames: the face cascade fires on such frames too (on
#: ``noface_face.mov``, on 3 consecutive frames at most), and the contours would then track
#: a face that is not there. A video that starts with a face, or has only a few frames
#: without one, starts at once (the eye cascade finds no eyes on the toolkit's rendered
#: faces).
START_FRAMES = 5


@dataclass
class _Waiting:
    """Before the first face: frames without any face so far, and the last eyeless
    face boxes at one place."""

    empty: int = 0
    boxes: list = field(default_factory=list)

    def trusts(self, box) -> bool:
        if self.empty < START_FRAMES:
            return True
        if self.boxes and _box_overlap(self.boxes[-1], box) < 0.5:
            self.boxes = []
        self.boxes.append(box)
        return len(self.boxes) >= START_FRAMES


def _box_overlap(a, b) -> float:
    """Intersection over union of two (x, y, w, h) boxes."""
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[0] + a[2], b[0] + b[2]), min(a[1] + a[3], b[1] + b[3])
    inter = max(0, x1 - x0) * max(0, y1 - y0)
    return inter / float(a[2] * a[3] + b[2] * b[3] - inter)


def _track_frame(tracker, frame, video, layout, size, redetect, backend, device,
                 tracker_options, waiting=None):
    """(tracker, result) for one decoded frame; result None when the frame is lost.

    ``waiting``: a :class:`_Waiting` while no face has been found yet (see
    :data:`START_FRAMES`); a frame without a face is then lost, not an error (the
    analysis starts on the first frame with a face)."""
    fresh = tracker is None
    try:
        if fresh:
            lay = load_layout(layout, size)
            if lay is None:
                try:
                    lay = _detect(frame.image, frame.index, video)
                except ValueError:
                    if waiting is None:
                        raise
                    waiting.empty += 1
                    waiting.boxes = []
                    log.debug("%s: frame %d: no face yet", video, frame.index)
                    return None, None
                if (waiting is not None and lay.meta.get("placement") == "face box"
                        and not waiting.trusts(lay.face_box)):
                    log.debug("%s: frame %d: a face box without eyes, not yet trusted",
                              video, frame.index)
                    return None, None
            tracker = make_tracker(lay, backend=backend, device=device, channel_order="bgr",
                                   **(tracker_options or {}))
        res = tracker.track(frame.image)
        for _ in range(2 if fresh and redetect else 0):   # let fresh contours settle
            if res.success:
                break
            res = tracker.track(frame.image)
    except ValueError as exc:
        if not redetect:
            raise
        # no face, or contours off the image: this frame is lost
        log.warning("%s: frame %d lost (%s)", video, frame.index, exc)
        if layout is None:
            tracker = None          # look for the face again on the next frame
        return tracker, None
    return tracker, res


def _draw(frame, contours, fids, head, lost, hands=None, eyelids=None, lost_contours=()):
    from faceanalysis.viz.overlay import draw_overlay

    return draw_overlay(frame.image, contours=contours,
                        fiducials=dict(zip(FIDUCIALS, fids.tolist())), head=head, lost=lost,
                        label=f"frame {frame.index}  {frame.timestamp:.2f} s", hands=hands,
                        eyelids=eyelids, lost_contours=lost_contours)
