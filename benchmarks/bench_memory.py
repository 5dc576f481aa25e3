"""Memory: peak resident memory of `faceanalysis analyze` and its growth per frame.

A long recording (a 30-minute interview at 30 frames/s is 54,000 frames) must fit in a
laptop's memory. Decoding streams (``bench_io``); what grows with the video's length is
what the analysis keeps per frame (the tracks: contours, face-mesh landmarks) and the
estimation's arrays. Each length is analysed in a fresh interpreter (default tracker and
estimator) and its peak resident set size read from ``/proc/self/status`` (``VmHWM``;
Linux only); the growth per frame
is the difference between two lengths over the frames between them, so that the
interpreter, the libraries and the models (some 300 MB) cancel out. A peak varies by some
tens of MB from run to run (threads, the allocator), so each length is analysed twice and
the lower peak kept, and the lengths lie thousands of frames apart.

Cases: a rendered 640x360 happiness sequence (120 frames, with head motion and noise),
played forward and back to 600 and 6,000 frames (quick: 300 and 2,400); and
``cap13_edit2.mp4`` (400x300, a real talking face, 765 frames) played forward and back
to 765 and 6,120 frames from ``../shared/data/real`` (or ``$FACEANALYSIS_REAL_DATA``)
when present.

No peer: MediaPipe's face mesh keeps nothing per frame.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure  # noqa: E402

REAL = Path(os.environ.get("FACEANALYSIS_REAL_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))

_CHILD = """
import json, sys
from faceanalysis.analysis.pipeline import analyze
result = analyze(sys.argv[1], end=int(sys.argv[2]))
# VmHWM: this process's own high-water mark (getrusage's ru_maxrss keeps the parent's
# across the fork and exec that started it)
with open("/proc/self/status") as status:
    peak = next(int(line.split()[1]) for line in status if line.startswith("VmHWM"))
print(json.dumps({"peak_kb": peak,
                  "frames": result.timings["frames"],
                  "tracked": int(result.tracks.success.sum())}))
"""


def _looped(source: Path, target: Path, frames: int) -> Path:
    """``source`` played forward and back until ``frames`` frames, written to ``target``."""
    cap = cv2.VideoCapture(str(source))
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    clip = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        clip.append(frame)
    cap.release()
    h, w = clip[0].shape[:2]
    out = cv2.VideoWriter(str(target), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    written, forward = 0, True
    while written < frames:
        for frame in (clip if forward else clip[::-1]):
            if written == frames:
                break
            out.write(frame)
            written += 1
        forward = not forward
    out.release()
    return target


def _peak(video: Path, frames: int) -> dict:
    run = subprocess.run([sys.executable, "-c", _CHILD, str(video), str(frames)],
                         capture_output=True, text=True)
    lines = [ln for ln in run.stdout.splitlines() if ln.startswith("{")]
    if run.returncode != 0 or not lines:
        tail = run.stderr.strip().splitlines()[-1:] or ["no output"]
        raise RuntimeError(f"analysis of {video.name} ({frames} frames) failed: {tail[0]}")
    return json.loads(lines[-1])


def run(quick: bool = False) -> list[Figure]:
    from synth.render.sequence import render_sequence

    if not Path("/proc/self/status").is_file():
        print("# memory: reads /proc/self/status (Linux); not measured here", file=sys.stderr)
        return []

    figures = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        files = render_sequence(tmp / "seq", expression="happiness", frames=120,
                                size=(640, 360), seed=11, head_motion=0.3, noise=2.0,
                                flow=False)
        short, long = (300, 2400) if quick else (600, 6000)
        cases = [("synthetic 640x360 happiness, looped", Path(files["video"]), short, long)]
        real = REAL / "cap13_edit2.mp4"
        if real.is_file():
            cases.append(("real cap13 400x300, looped", real, 765, 6120))
        else:
            print(f"# {real} is absent: the real clip is skipped", file=sys.stderr)
        for name, source, n1, n2 in cases:
            video = _looped(source, tmp / f"looped_{len(figures)}.mp4", n2)
            a, b = (min((_peak(video, n) for _ in range(2)), key=lambda r: r["peak_kb"])
                    for n in (n1, n2))
            growth = (b["peak_kb"] - a["peak_kb"]) / (n2 - n1)
            extra = {"frames": [n1, n2], "tracked": [a["tracked"], b["tracked"]],
                     "peak_mb": [round(a["peak_kb"] / 1024), round(b["peak_kb"] / 1024)]}
            figures.append(Figure("memory", name, f"peak resident memory, {n2} frames",
                                  b["peak_kb"] / 1024, "MB", False, extra=extra))
            figures.append(Figure("memory", name, "peak memory growth per frame", growth,
                                  "kB/frame", False, extra=extra))
            figures.append(Figure("memory", name,
                                  "peak memory of a 30-minute 30 f/s video (extrapolated)",
                                  (b["peak_kb"] + growth * (54_000 - n2)) / 1024**2, "GB",
                                  False, extra=extra))
    return figures
