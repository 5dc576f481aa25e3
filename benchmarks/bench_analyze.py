"""Analysis: frames per second of `faceanalysis analyze` on 640x360 video, both trackers.

Tracking and estimation run on one thread (OpenCV limited to one thread), except that
the landmark tracker runs the next frame's landmark model in a second thread while the
snakes relax on this frame (:meth:`trackers.AnchoredTracker.track`, ``next_frame``);
decoding runs ahead in a third (:func:`faceanalysis.io.video.read_ahead`).

Per video and tracker, each with the estimator :func:`faceanalysis.analysis.pipeline.analyze`
runs by default with it (``tracker="snakes"``: the snakes of 004, ``joint``;
``tracker="landmarks"``, the default: MediaPipe's face detector and mesh holding the snakes,
:class:`trackers.AnchoredTracker`, and the ``mesh`` fit, with LiteRT, the landmark model's
default runtime where ``ai-edge-litert`` is installed, and with ``cv2.dnn``, the runtime
everywhere else; and with LiteRT and ``eyes=True``, the iris model's eyelids on every frame
too), from the same run of :func:`~faceanalysis.analysis.pipeline.analyze`:

* ``analysis``: tracking (landmarks where used, potentials, snake relaxation, head frame
  or pose, fiducials) + calibration + estimation (the fit, the identifiability of each
  control, the model's fit residual), decode excluded:
  frames / (tracking time + estimation time); with the landmark tracker, waiting for
  the next decoded frame counts as tracking time (its landmarks are being read then);
* ``end to end``: the wall time of the whole call (decode + tracking + estimation
  + table), no overlay; decoding overlaps with tracking. The model's response table
  is built beforehand (it is cached on disk once per model).

The default once more on the same frames decoded beforehand and passed in memory
(:class:`faceanalysis.io.video.Frames`, RGB), as the peer gets them: without a decoder
thread beside the analysis on the two cores ("frames decoded beforehand"; its end-to-end
figure is the same call's wall time).

And the landmark stage's own cost: ms per frame of :meth:`LandmarkTracker.track
<trackers.landmarks.LandmarkTracker.track>` in tracking mode (a detection on the first
frame, then each frame cropped from the last landmarks) on the same frames, decoded
beforehand, per runtime.

Cases: a rendered 640x360 happiness sequence of the project's face model (with head
motion and noise), and ``WolfgangLanger_Pexels.mp4`` (640x360: crying, a hand over the
mouth, a laugh with the head turned) and ``cap13_edit2.mp4`` (400x300, a talking face)
from ``../shared/data/real`` (or ``$FACEANALYSIS_REAL_DATA``) when present.

Peer, measured in the same run where it is installed: MediaPipe's face mesh (the
landmark tracker the issue names) on the same frames, decode excluded
(``peers/mediapipe_face_mesh.py``). MediaPipe pins its own OpenCV and protobuf, so it
runs in its own interpreter: ``MEDIAPIPE_PYTHON=/path/to/python`` (a virtual
environment with ``pip install mediapipe==0.10.14``, whose wheel still carries the face
mesh model), or this interpreter if it can import MediaPipe. The ratio is our analysis
figure over MediaPipe's, the median of turns in which every configuration and the peer
run once each (so that a slow spell of a shared machine weighs on all of them). MediaPipe
runs its graph on more than one core (about 1.25 CPU seconds per second here), and so
does the landmark analysis: the ratio per CPU second compares frames per CPU second,
ours being the CPU time of tracking (all threads) and estimation less that of
decoding the same frames alone.

Targets: the landmark analysis at least 100 frames/s and at least 0.5x MediaPipe's face
mesh alone; the snakes' analysis 300 frames/s (1.11x MediaPipe's 270 frames/s on the
machine that target was set on) and 150 frames/s end to end.
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

REAL = Path(os.environ.get("FACEANALYSIS_REAL_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))
PEER = Path(__file__).resolve().parent / "peers" / "mediapipe_face_mesh.py"

#: (label, analyze options, analysis target frames/s, ratio target, end-to-end target)
SNAKES = ("snakes + joint", {"tracker": "snakes"}, 300.0, 1.11, 150.0)
LANDMARKS = ("landmarks + mesh (cv2.dnn)",
             {"tracker": "landmarks", "tracker_options": {"runtime": "opencv"}},
             100.0, 0.5, None)
LANDMARKS_LITERT = ("landmarks + mesh (LiteRT)",
                    {"tracker": "landmarks", "tracker_options": {"runtime": "litert"}},
                    100.0, 0.5, None)
#: ``--eyes``: the iris model on every frame as well (no target: an option)
LANDMARKS_EYES = ("landmarks + mesh + eyes (LiteRT)",
                  {"tracker": "landmarks", "tracker_options": {"runtime": "litert"},
                   "eyes": True}, None, None, None)
#: The default on the same frames decoded beforehand and passed in memory
#: (:class:`faceanalysis.io.video.Frames`), as the peer gets them: no decoder thread
#: competes for the two cores (each frame's RGB to BGR conversion is timed, as the
#: peer's BGR to RGB is)
LANDMARKS_IN_MEMORY = ("landmarks + mesh (LiteRT), frames decoded beforehand",
                       {"tracker": "landmarks", "tracker_options": {"runtime": "litert"}},
                       100.0, 0.5, None)


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


def _measure(video: Path, **options) -> tuple[float, float, int, float, float]:
    """One analysis: (analysis frames/s, end-to-end frames/s, frames, tracked share,
    CPU seconds of tracking (decoding included) and estimation, all threads)."""
    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.estimation.identifiability import estimator_errors

    # the identifiability's simulation is remembered per question, and a video asks the
    # same one each time: forgotten, each turn pays what a user's analysis pays
    estimator_errors.cache_clear()
    t0 = time.perf_counter()
    result = analyze(video, **options)
    wall = time.perf_counter() - t0
    cpu = result.timings["track_cpu_s"] + result.timings["estimate_cpu_s"]
    frames = result.timings["frames"]
    work = result.timings["track_s"] + result.timings["estimate_s"]
    return frames / work, frames / wall, frames, float(result.tracks.success.mean()), cpu


def _decode(video: Path, end: int | None) -> tuple[list, float]:
    """The frames, and the CPU seconds that decoding them took."""
    c0 = time.process_time()
    cap = cv2.VideoCapture(str(video))
    frames = []
    while end is None or len(frames) < end:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    return frames, time.process_time() - c0


def _landmark_stage(frames: list, runtime: str) -> tuple[float, int, int]:
    """One pass of the landmark tracker alone: (ms per frame, frames found, detections)."""
    from trackers.landmarks import LandmarkTracker

    tracker = LandmarkTracker(channel_order="bgr", runtime=runtime)
    found = detected = 0
    t0 = time.perf_counter()
    for frame in frames:
        lm = tracker.track(frame)
        found += lm is not None
        detected += lm is not None and lm.detected
    return 1e3 * (time.perf_counter() - t0) / len(frames), found, detected


def run(quick: bool = False) -> list[Figure]:
    from faceanalysis.estimation.model_response import model_response
    from faceanalysis.io.video import Frames
    from synth.render.sequence import render_sequence
    from trackers.landmarks import ensure_models, litert_available

    cv2.setNumThreads(1)
    from faceanalysis.analysis.pipeline import analyze

    model_response()                      # build or load the cached table first
    ensure_models()
    configs = [SNAKES, LANDMARKS]
    runtimes = ["opencv"]
    if litert_available():
        configs += [LANDMARKS_LITERT, LANDMARKS_EYES, LANDMARKS_IN_MEMORY]
        runtimes.append("litert")
    else:
        print("ai-edge-litert is not importable: the LiteRT runtime is not measured",
              file=sys.stderr)
    repeat = 1 if quick else 3
    figures = []
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        frames = 40 if quick else 120
        files = render_sequence(Path(tmp) / "seq", expression="happiness", frames=frames,
                                size=(640, 360), seed=11, head_motion=0.3, noise=2.0,
                                flow=False)
        cases.append(("synthetic 640x360 happiness", Path(files["video"]), None))
        real = REAL / "WolfgangLanger_Pexels.mp4"
        if real.is_file():
            cases.append(("real WolfgangLanger 640x360", real, 160 if quick else None))
        else:
            print(f"# {real} is absent: the real clip is skipped", file=sys.stderr)
        # a talking face without hands or large turns (smaller frames: the targets are
        # set on 640x360, this is for comparison)
        talking = REAL / "cap13_edit2.mp4"
        if talking.is_file():
            cases.append(("real cap13 400x300", talking, 160 if quick else None))
        peer_python = _mediapipe_python()
        for name, video, end in cases:
            decoded, decode_cpu = _decode(video, end)
            in_memory = Frames([cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in decoded],
                               fps=cv2.VideoCapture(str(video)).get(cv2.CAP_PROP_FPS) or None)
            for c in configs:                # warm-up: compiled kernels, networks
                analyze(in_memory if c is LANDMARKS_IN_MEMORY else video, end=3, **c[1])
            for rt in runtimes:
                _landmark_stage(decoded[:3], rt)
            # every configuration and the peer in turns, so that a slow spell of this
            # shared machine weighs on all; ratios are the medians of per-turn ratios
            ours = {c[0]: [] for c in configs}
            stage = {rt: [] for rt in runtimes}
            peers = []
            for _ in range(repeat):
                for c in configs:
                    ours[c[0]].append(_measure(in_memory if c is LANDMARKS_IN_MEMORY else video,
                                               end=end, **c[1]))
                for rt in runtimes:
                    stage[rt].append(_landmark_stage(decoded, rt))
                if peer_python is not None:
                    peers.append(_mediapipe_fps(peer_python, video, end))
            peer_ok = [p for p in peers if p is not None]
            peer_label = (f"MediaPipe face mesh {peer_ok[0]['version']}" if peer_ok
                          else None)
            for label, _, target, ratio_target, e2e_target in configs:
                runs = ours[label]
                a = statistics.median(o[0] for o in runs)
                ratios = [o[0] / p["fps"] for o, p in zip(runs, peers) if p is not None]
                extra = {"tracker": label, "frames": runs[0][2],
                         "tracked": round(runs[0][3], 3),
                         "runs": [round(o[0], 1) for o in runs]}
                if peer_ok:
                    extra.update(peer_fps=statistics.median(p["fps"] for p in peer_ok),
                                 peer_runs=[round(p["fps"], 1) for p in peer_ok],
                                 peer_faces_found=peer_ok[0]["found"],
                                 peer_cpu_per_wall=statistics.median(p["cpu_per_wall"]
                                                                     for p in peer_ok))
                ratio = statistics.median(ratios) if ratios else None
                figures.append(Figure(
                    "analyze", name, f"{label}: analysis (track + estimate)", a, "frames/s",
                    True, target=target, peer=peer_label, ratio=ratio, extra=extra))
                if ratio is not None:
                    figures.append(Figure(
                        "analyze", name, f"{label}: analysis / MediaPipe face mesh", ratio,
                        "x", True, target=ratio_target,
                        extra={"tracker": label,
                               "turn_ratios": [round(r, 3) for r in ratios]}))
                    # both use more than one core: frames per CPU second of each, ours
                    # being the tracking loop's and the estimation's CPU time less what
                    # decoding alone takes
                    decoding = 0.0 if label == LANDMARKS_IN_MEMORY[0] else decode_cpu
                    cpu = [o[2] / max(o[4] - decoding, 1e-9) / (p["fps"] / p["cpu_per_wall"])
                           for o, p in zip(runs, peers) if p is not None]
                    figures.append(Figure(
                        "analyze", name,
                        f"{label}: analysis / MediaPipe face mesh, per CPU second",
                        statistics.median(cpu), "x", True,
                        extra={"tracker": label, "turn_ratios": [round(r, 3) for r in cpu]}))
                figures.append(Figure(
                    "analyze", name, f"{label}: end to end (" + (
                        "the whole call" if label == LANDMARKS_IN_MEMORY[0]
                        else "decode + analysis") + ")",
                    statistics.median(o[1] for o in runs), "frames/s", True,
                    target=e2e_target, extra={"tracker": label, "frames": runs[0][2]}))
            for rt in runtimes:
                ms = statistics.median(s[0] for s in stage[rt])
                label = "cv2.dnn" if rt == "opencv" else "LiteRT"
                own = ours[f"landmarks + mesh ({label})"]
                share = ms / (1e3 / statistics.median(o[0] for o in own))
                figures.append(Figure(
                    "analyze", name, f"landmark stage alone ({label}), tracking mode", ms,
                    "ms/frame", False,
                    extra={"runtime": rt, "frames": len(decoded),
                           "found": stage[rt][0][1], "detections": stage[rt][0][2],
                           "runs": [round(s[0], 2) for s in stage[rt]],
                           "share_of_analysis": round(share, 3)}))
    return figures
