"""Large frames: the landmark tracker on 1920x1080 video, shrunk to its working size and not.

:class:`trackers.AnchoredTracker` tracks a face wider than ``MAX_IOD`` pixels between the
eyes on frames shrunk by a whole factor (``max_iod``); this measures what that buys on
a 1920x1080 video and what it costs in agreement:

* ``frames/s``: :meth:`AnchoredTracker.run <trackers.AnchoredTracker.run>` over frames
  decoded beforehand (landmarks, snakes, head pose; the next frame's landmarks in a
  second thread), with the default ``max_iod`` and with ``max_iod=None`` (every frame
  at its own size), in interleaved turns so that a slow spell of a shared machine weighs
  on both; the ratio is the median of the per-turn ratios. The 640x360 original is
  tracked in the same turns for reference;
* ``agreement``: the fiducials of each 1080p run against those of the 640x360 original
  (scaled by 3), median over points and frames tracked by both, in 640x360 pixels.
  Tracking a real clip is sensitive to small changes of the image: the same clip
  re-encoded as MJPEG at its own size is shown as the floor of that comparison.

Video: the first 240 frames of ``WolfgangLanger_Pexels.mp4`` (``../shared/data/real``,
or ``$FACEANALYSIS_REAL_DATA``) upscaled 3x (bicubic) to 1920x1080, its face about 300
px between the eyes; skipped when absent. No target: the figures say what large frames
cost.
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _harness import Figure, read_frames  # noqa: E402

REAL = Path(os.environ.get("FACEANALYSIS_REAL_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))


def _track(frames, **options):
    from trackers.anchored import AnchoredTracker

    tracker = AnchoredTracker(channel_order="bgr", **options)
    t0 = time.perf_counter()
    results = list(tracker.run(frames))
    return len(frames) / (time.perf_counter() - t0), results, tracker.downscale


def _fids(results):
    from trackers.fiducials import FIDUCIAL_NAMES

    out = np.full((len(results), len(FIDUCIAL_NAMES), 2), np.nan)
    for i, r in enumerate(results):
        if r is not None and r.success:
            out[i] = [r.fiducials[n] for n in FIDUCIAL_NAMES]
    return out


def _agreement(small, big, factor):
    a = _fids(small)
    b = (_fids(big) + 0.5) / factor - 0.5
    d = np.hypot(*(a - b).transpose(2, 0, 1))
    return float(np.nanmedian(d)), float(np.nanpercentile(d, 90))


def run(quick: bool = False) -> list[Figure]:
    import cv2

    if not (REAL / "WolfgangLanger_Pexels.mp4").is_file():
        print(f"# {REAL / 'WolfgangLanger_Pexels.mp4'} is absent: resolution figures skipped")
        return []
    cv2.setNumThreads(1)
    small = read_frames(REAL / "WolfgangLanger_Pexels.mp4", 120 if quick else 240)
    big = [cv2.resize(f, (1920, 1080), interpolation=cv2.INTER_CUBIC) for f in small]
    # the same frames through MJPEG at their own size: how much tracking moves when the
    # image changes by a compression's worth
    mjpeg = [cv2.imdecode(cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, 90])[1],
                          cv2.IMREAD_COLOR) for f in small]
    configs = {"640x360": (small, {}), "1920x1080, max_iod default": (big, {}),
               "1920x1080, max_iod=None": (big, {"max_iod": None})}
    turns = 2 if quick else 3
    fps = {k: [] for k in configs}
    results, factors = {}, {}
    for _ in range(turns):
        for name, (frames, options) in configs.items():
            rate, res, k = _track(frames, **options)
            fps[name].append(rate)
            results[name], factors[name] = res, k
    ratio = [a / b for a, b in zip(fps["1920x1080, max_iod default"],
                                   fps["1920x1080, max_iod=None"])]
    figs = []
    for name in configs:
        figs.append(Figure("resolution", name, "tracking (landmark tracker)",
                           statistics.median(fps[name]), "frames/s", True,
                           extra={"runs": [round(v, 1) for v in fps[name]],
                                  "frames": len(small), "downscale": factors[name]}))
    figs.append(Figure("resolution", "1920x1080", "shrunk / full size", statistics.median(ratio),
                       "x", True, extra={"turn_ratios": [round(v, 2) for v in ratio]}))
    base = results["640x360"]
    for name in ("1920x1080, max_iod default", "1920x1080, max_iod=None"):
        med, p90 = _agreement(base, results[name], 3.0)
        figs.append(Figure("resolution", name, "fiducials vs the 640x360 run, median", med,
                           "px (640x360)", False, extra={"p90": round(p90, 2)}))
    _, res, _ = _track(mjpeg)
    med, p90 = _agreement(base, res, 1.0)
    figs.append(Figure("resolution", "640x360 re-encoded (MJPEG q90)",
                       "fiducials vs the 640x360 run, median", med, "px (640x360)", False,
                       extra={"p90": round(p90, 2)}))
    return figs
