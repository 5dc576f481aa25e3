"""Analysis: frames per second of `faceanalysis analyze` on 640x360 video.

Tracking and estimation run on one thread (OpenCV limited to one thread); decoding
runs ahead in a second thread (:func:`faceanalysis.video.read_ahead`), so the end to
end figure uses up to two cores.

Two figures per video, from the same run of :func:`faceanalysis.analysis.analyze`:

* ``analysis``: tracking (potentials, snake relaxation, fiducials) + calibration +
  estimation, decode excluded: frames / (tracking time + estimation time);
* ``end to end``: the wall time of the whole call (decode + tracking + estimation
  + table), no overlay; decoding overlaps with tracking. The model's response table
  is built beforehand (it is cached on disk once per model).

Cases: a rendered 640x360 happiness sequence of the project's face model (with head
motion and noise), and ``WolfgangLanger_Pexels.mp4`` from ``../shared/data/real``
when present. For reference (not measured here): the issue quotes MediaPipe's face
mesh at about 3.7 ms per frame (270 frames/s) on this machine, decode excluded.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure  # noqa: E402

REAL = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "real"


def _measure(video: Path, repeat: int, **options) -> tuple[float, float, int]:
    from faceanalysis.analysis import analyze

    analysis_fps, e2e_fps = [], []
    frames = 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = analyze(video, **options)
        wall = time.perf_counter() - t0
        frames = result.timings["frames"]
        work = result.timings["track_s"] + result.timings["estimate_s"]
        analysis_fps.append(frames / work)
        e2e_fps.append(frames / wall)
    return statistics.median(analysis_fps), statistics.median(e2e_fps), frames


def run(quick: bool = False) -> list[Figure]:
    from faceanalysis.model_response import model_response
    from synth.render.sequence import render_sequence

    cv2.setNumThreads(1)
    from faceanalysis.analysis import analyze

    model_response()                      # build or load the cached table first
    repeat = 1 if quick else 3
    figures = []
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        frames = 40 if quick else 120
        files = render_sequence(Path(tmp) / "seq", expression="happiness", frames=frames,
                                size=(640, 360), seed=11, head_motion=0.3, noise=2.0,
                                flow=False)
        cases.append(("synthetic 640x360 happiness", Path(files["video"]), {}))
        real = REAL / "WolfgangLanger_Pexels.mp4"
        if real.is_file():
            cases.append(("real WolfgangLanger 640x360", real, {"end": 160 if quick else None}))
        for name, video, options in cases:
            analyze(video, end=3)         # warm-up: compiled kernels load from the cache
            a, e, n = _measure(video, repeat, **options)
            figures.append(Figure("analyze", name, "analysis (track + estimate)", a, "frames/s",
                                  True, target=300.0, extra={"frames": n}))
            figures.append(Figure("analyze", name, "end to end (decode + analysis)", e,
                                  "frames/s", True, target=150.0, extra={"frames": n}))
    return figures
