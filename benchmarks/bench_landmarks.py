"""Landmarks: MediaPipe face detector and 468-point mesh, speed per runtime and IMM accuracy.

Speed: ms per call on one core of the detector (whole frame) and of the landmark model in
tracking mode (the crop from the previous landmarks), and of ``LandmarkTracker.track`` in
tracking mode, on a 640x360 frame: the first frame of ``../shared/data/real/cap13_edit2.mp4``
scaled to 360 rows and padded (a rendered face when the file is absent), for each runtime
installed (OpenCV's dnn always; LiteRT with ``pip install ai-edge-litert``).

Accuracy, on ``../shared/data/annotated/imm_dev`` (20 people, hand-placed points; skipped
when absent): each photograph is a fresh track (detection, then the refining second pass).
The mouth-corner error (points 61 and 291 against the annotated corners 39 and 43) over the
inter-ocular distance (between the means of each annotated eye contour), per photo type
(1 neutral, 2 smile, 3-4 head turned, 5 side light, 6 free expression); and smile against
neutral: mouth width over the distance between the eye centres of the mesh (means of 33, 133,
159, 145 and of 362, 263, 386, 374), the number of people whose smile (type 2) reads wider
than their neutral face (type 1), and the ROC AUC of that ratio over the 40 photographs.
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


def _read_asf(path: Path, shape) -> np.ndarray:
    rows = [line.split() for line in path.read_text().splitlines()
            if line.strip() and not line.startswith("#")]
    pts = np.array([[float(r[2]), float(r[3])] for r in rows if len(r) >= 7])
    assert len(pts) == 58, path
    return pts * [shape[1], shape[0]]


def _auc(neg, pos) -> float:
    neg, pos = np.asarray(neg), np.asarray(pos)
    return float(((pos[:, None] > neg[None]) + 0.5 * (pos[:, None] == neg[None])).mean())


def _imm() -> list[Figure]:
    folder = DATA / "annotated" / "imm_dev"
    if not folder.is_dir():
        print(f"{folder} not found: the IMM accuracy figures are skipped", file=sys.stderr)
        return []
    tracker = LandmarkTracker(channel_order="bgr")
    err, ratio, hand = {}, {}, {}
    for jpg in sorted(folder.glob("*.jpg")):
        person, kind = jpg.stem.split("-")[0], int(jpg.stem.split("-")[1][0])
        img = cv2.imread(str(jpg))
        truth = _read_asf(jpg.with_suffix(".asf"), img.shape)
        iod = np.linalg.norm(truth[13:21].mean(0) - truth[21:29].mean(0))
        hand[person, kind] = np.linalg.norm(truth[39] - truth[43]) / iod
        tracker.reset()
        lm = tracker.track(img)
        if lm is None:
            log.warning("no face found in %s", jpg.name)
            err.setdefault(kind, []).append(np.nan)
            continue
        p = lm.points
        err.setdefault(kind, []).append(
            np.linalg.norm(p[[61, 291]] - truth[[39, 43]], axis=1).mean() / iod)
        eyes = [p[idx].mean(0) for idx in EYES_MESH]
        ratio[person, kind] = np.linalg.norm(p[291] - p[61]) / np.linalg.norm(eyes[1] - eyes[0])
    figures = []
    for kind in sorted(err):
        e = np.array(err[kind])
        figures.append(Figure(NAME, f"IMM type {kind} ({len(e)} photos)", "mouth-corner error",
                              float(np.nanmean(e)), "IOD", higher_is_better=False,
                              extra={"median": float(np.nanmedian(e)),
                                     "lost": int(np.isnan(e).sum())}))
    for name, values in (("mesh", ratio), ("hand-placed", hand)):
        people = sorted({p for p, k in values if (p, 1) in values and (p, 2) in values})
        wider = int(sum(values[p, 2] > values[p, 1] for p in people))
        auc = _auc([values[p, 1] for p in people], [values[p, 2] for p in people])
        case = f"IMM smile vs neutral, {name} ({len(people)} people)"
        figures.append(Figure(NAME, case, "people whose smile is wider", wider, "people",
                              higher_is_better=True))
        figures.append(Figure(NAME, case, "ROC AUC of mouth width / IOD", auc, "",
                              higher_is_better=True))
    return figures


def run(quick: bool = False) -> list[Figure]:
    ensure_models()
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one core, as a Dask worker runs it
    try:
        return _speed(quick) + _imm()
    finally:
        cv2.setNumThreads(threads)
