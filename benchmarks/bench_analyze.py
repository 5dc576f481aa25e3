"""Analysis: frames per second of `faceanalysis analyze` on 640x360 video.

Tracking and estimation run on one thread (OpenCV limited to one thread); decoding
runs ahead in a second thread (:func:`faceanalysis.io.video.read_ahead`), so the end to
end figure uses up to two cores.

Two figures per video, from the same run of :func:`faceanalysis.analysis.pipeline.analyze`:

* ``analysis``: tracking (potentials, snake relaxation, fiducials) + calibration +
  estimation, decode excluded: frames / (tracking time + estimation time);
* ``end to end``: the wall time of the whole call (decode + tracking + estimation
  + table), no overlay; decoding overlaps with tracking. The model's response table
  is built beforehand (it is cached on disk once per model).

Cases: a rendered 640x360 happiness sequence of the project's face model (with head
motion and noise), and ``WolfgangLanger_Pexels.mp4`` from ``../shared/data/real``
when present.

Peer, measured in the same run where it is installed: MediaPipe's face mesh (the
landmark tracker the issue names: 3.7 ms per frame, 270 frames/s, decode excluded, on
the machine it was written on) on the same frames, decode excluded
(``peers/mediapipe_face_mesh.py``). MediaPipe pins its own OpenCV and protobuf, so it
runs in its own interpreter: ``MEDIAPIPE_PYTHON=/path/to/python`` (a virtual
environment with ``pip install mediapipe==0.10.14``, whose wheel still carries the face
mesh model), or this interpreter if it can import MediaPipe. The ratio is our analysis
figure over MediaPipe's, the median of turns in which each runs once (so that a slow
spell of a shared machine weighs on both); the issue's 300 frames/s against
MediaPipe's 270 is a ratio of 1.11.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure  # noqa: E402

REAL = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "real"
PEER = Path(__file__).resolve().parent / "peers" / "mediapipe_face_mesh.py"


def _mediapipe_python() -> str | None:
    """The interpreter that runs the MediaPipe peer, or None (with the reason on stderr)."""
    given = os.environ.get("MEDIAPIPE_PYTHON")
    if given:
        exe = shutil.which(given) or given
        if not Path(exe).is_file():
            print(f"MEDIAPIPE_PYTHON={given}: no such interpreter; peer not measured",
                  file=sys.stderr)
            return None
        return exe
    # the face mesh is an attribute of the package (there is no mediapipe.solutions
    # module to import), and 1.x wheels lack it
    probe = subprocess.run([sys.executable, "-c",
                            "import mediapipe as mp; mp.solutions.face_mesh"],
                           capture_output=True)
    if probe.returncode == 0:
        return sys.executable
    print("MediaPipe not measured: set MEDIAPIPE_PYTHON to a Python with mediapipe 0.10.x "
          "(see this benchmark's docstring)", file=sys.stderr)
    return None


def _mediapipe_fps(python: str, video: Path, end: int | None) -> dict | None:
    """One timed pass of the peer over ``video`` (after its own untimed one)."""
    cmd = [python, str(PEER), str(video), "--repeat", "1"]
    if end is not None:
        cmd += ["--end", str(end)]
    run = subprocess.run(cmd, capture_output=True, text=True)
    lines = [ln for ln in run.stdout.splitlines() if ln.startswith("{")]
    if run.returncode != 0 or not lines:
        tail = run.stderr.strip().splitlines()[-1:] or ["no output"]
        print(f"MediaPipe peer failed on {video.name}: {tail[0]}", file=sys.stderr)
        return None
    return json.loads(lines[-1])


def _measure(video: Path, **options) -> tuple[float, float, int]:
    """One analysis: (analysis frames/s, end-to-end frames/s, frames)."""
    from faceanalysis.analysis.pipeline import analyze

    t0 = time.perf_counter()
    result = analyze(video, **options)
    wall = time.perf_counter() - t0
    frames = result.timings["frames"]
    work = result.timings["track_s"] + result.timings["estimate_s"]
    return frames / work, frames / wall, frames


def run(quick: bool = False) -> list[Figure]:
    from faceanalysis.estimation.model_response import model_response
    from synth.render.sequence import render_sequence

    cv2.setNumThreads(1)
    from faceanalysis.analysis.pipeline import analyze

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
        peer_python = _mediapipe_python()
        for name, video, options in cases:
            analyze(video, end=3)         # warm-up: compiled kernels load from the cache
            # ours and the peer in turns, so that a slow spell of this shared machine
            # weighs on both; the ratio is the median of the per-turn ratios
            ours, peers, ratios = [], [], []
            for _ in range(repeat):
                ours.append(_measure(video, **options))
                if peer_python is not None:
                    peer = _mediapipe_fps(peer_python, video, options.get("end"))
                    if peer is not None:
                        peers.append(peer)
                        ratios.append(ours[-1][0] / peer["fps"])
            a = statistics.median(o[0] for o in ours)
            e = statistics.median(o[1] for o in ours)
            extra = {"frames": ours[0][2], "runs": [round(o[0], 1) for o in ours]}
            label = None
            if peers:
                label = f"MediaPipe face mesh {peers[0]['version']}"
                extra.update(peer_fps=statistics.median(p["fps"] for p in peers),
                             peer_runs=[round(p["fps"], 1) for p in peers],
                             peer_faces_found=peers[0]["found"],
                             peer_cpu_per_wall=statistics.median(p["cpu_per_wall"]
                                                                 for p in peers))
            figures.append(Figure(
                "analyze", name, "analysis (track + estimate)", a, "frames/s", True,
                target=300.0, peer=label,
                ratio=statistics.median(ratios) if ratios else None, extra=extra))
            figures.append(Figure("analyze", name, "end to end (decode + analysis)", e,
                                  "frames/s", True, target=150.0,
                                  extra={"frames": ours[0][2]}))
    return figures
