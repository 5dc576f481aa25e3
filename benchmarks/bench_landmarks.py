"""Landmarks: MediaPipe face detector and 468-point mesh, speed per runtime.

Speed: ms per call on one core of the detector (whole frame) and of the landmark model in
tracking mode (the crop from the previous landmarks), and of ``LandmarkTracker.track`` in
tracking mode, on a 640x360 frame: the first frame of ``../shared/data/real/cap13_edit2.mp4``
scaled to 360 rows and padded (a rendered face when the file is absent), for each runtime
installed (OpenCV's dnn always; LiteRT with ``pip install ai-edge-litert``).

Accuracy on photographs and real clips: ``bench_landmark_tracking.py``.
"""

from __future__ import annotations

import logging
import os
import sys
from functools import partial
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure, median_time  # noqa: E402

from trackers.landmarks import (  # noqa: E402
    LandmarkTracker,
    detect_faces,
    ensure_models,
    face_landmarks,
    litert_available,
)

log = logging.getLogger("bench_landmarks")
ROOT = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("FACEANALYSIS_REAL_DATA",
                           ROOT.parent / "shared" / "data" / "real")).parent
NAME = "landmarks"
EYES_MESH = ([33, 133, 159, 145], [362, 263, 386, 374])   # subject's right, left


def _frame() -> tuple[np.ndarray, str]:
    cap = cv2.VideoCapture(str(DATA / "real" / "cap13_edit2.mp4"))
    ok, bgr = cap.read()
    cap.release()
    if ok:
        h, w = bgr.shape[:2]
        bgr = cv2.resize(bgr, (round(w * 360 / h), 360), interpolation=cv2.INTER_AREA)
        pad = (640 - bgr.shape[1]) // 2
        bgr = cv2.copyMakeBorder(bgr, 0, 0, pad, 640 - bgr.shape[1] - pad, cv2.BORDER_REPLICATE)
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), "cap13 640x360"
    print("cap13_edit2.mp4 not found: timing on a rendered face", file=sys.stderr)
    from synth.render.sequence import synthesize

    face = synthesize(frames=1, size=256, seed=3, flow=False).images[0]
    frame = np.full((360, 640, 3), face[0, 0], np.uint8)
    frame[52:308, 192:448] = face
    return frame, "rendered face 640x360"


def _speed(quick: bool) -> list[Figure]:
    frame, case = _frame()
    repeat, number = (5, 10) if quick else (9, 30)
    figures = []
    for runtime in ["opencv"] + (["litert"] if litert_available() else []):
        det = detect_faces(frame, runtime=runtime)[0]
        points, _ = face_landmarks(frame, det, runtime=runtime)
        tracker = LandmarkTracker(runtime=runtime)
        tracker.track(frame)
        for metric, fn in (
                ("detection", partial(detect_faces, frame, runtime=runtime)),
                ("landmarks (tracking)", partial(face_landmarks, frame, points, runtime=runtime)),
                ("tracker.track (tracking)", partial(tracker.track, frame))):
            ms = 1e3 * median_time(fn, repeat=repeat, number=number)
            figures.append(Figure(NAME, f"{case}, {runtime}", f"{metric} time", ms, "ms/frame",
                                  higher_is_better=False))
    return figures


def run(quick: bool = False) -> list[Figure]:
    ensure_models()
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one core, as a Dask worker runs it
    try:
        return _speed(quick)
    finally:
        cv2.setNumThreads(threads)
