"""Backends: NumPy/Numba vs torch (CPU; CUDA when present) for 1, 8 and 64 videos at once.

The same work is timed on both backends, single-threaded on the CPU
(``cv2.setNumThreads(1)``, ``torch.set_num_threads(1)``; the Numba kernels are
serial), median of several runs. B videos of the drawn 640x480 face of the tracking
benchmark, each at its own phase of the motion, each with its own layout (node
counts differ a little between videos).

Cases (``B`` = videos at once):

* ``relax B=..``: the nine contours of every video take 30 semi-implicit steps (no
  equilibrium test: identical work) in the per-contour potential boxes the tracker
  builds for its second frame. NumPy: one ``ContourSystem.step`` per video; torch:
  one :class:`trackers.torch_backend.TorchContourSystem` step for all B, including
  packing the boxes into one padded tensor and its force field. Figure:
  contour-steps per second (9 x 30 x B / time).
* ``potentials B=..``: the three whole-frame potentials the layout uses (edge
  sigma 2, valley at the brow and the line widths) of B grey frames. NumPy:
  ``potential_from_gray`` per frame; torch: ``potential_batch`` on the
  [B, 1, 480, 640] stack, in float32 as OpenCV. Figure: frames per second.
* ``tracking B=..``: everything ``Tracker.track`` does, frames 2-6 of each video
  (the first frame settles the layout and is excluded). NumPy: B trackers one after
  the other; torch: :class:`trackers.torch_backend.TorchTracker` (one batched
  relaxation per relaxation round, per-contour boxes and bookkeeping still NumPy).
  Figure: frames per second over all videos.

``ratio`` = torch / NumPy throughput (> 1: torch wins). CUDA cases (float32) run
only where ``torch.cuda.is_available()``; the CPU relaxations use float64, the
precision the equivalence tests check.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _harness import Figure, median_time, ratio  # noqa: E402
from bench_tracking import H, W, draw_face  # noqa: E402

from trackers import Tracker, layout_from_eyes  # noqa: E402
from trackers.potentials import potential_from_gray, to_gray  # noqa: E402

BATCHES = (1, 8, 64)
STEPS = 30


def _videos(B, n_frames, seed=0):
    rng = np.random.default_rng(seed)
    skin = (1.0 + 0.12 * cv2.GaussianBlur(rng.normal(size=(H, W)).astype(np.float32),
                                          (0, 0), 3.0)).astype(np.float32)
    videos, layouts = [], []
    for b in range(B):
        phase = b / max(B, 1)
        frames = []
        for i in range(n_frames):
            img, _, eyes = draw_face((phase + 0.01 * i) % 1.0, rng, skin)
            frames.append(img)
            if i == 0:
                layouts.append(layout_from_eyes(*eyes, (W, H)))
        videos.append(frames)
    return videos, layouts


def _relax_case(B, videos, layouts, torch, device, dtype, repeat):
    from trackers.torch_backend import TorchContourSystem

    trackers = [Tracker(lay) for lay in layouts]
    fields = []
    for t, v in zip(trackers, videos):
        t.track(v[0])  # strengths, ends: the state of a running tracker
        Ps, origins, _, _ = t._fields(v[1])
        fields.append((Ps, origins))
    X0 = [t.system.X.copy() for t in trackers]
    rest0 = [t.system.rest.copy() for t in trackers]

    def reset():
        for t, x, r in zip(trackers, X0, rest0):
            t.system.X[:] = x
            t.system.rest[:] = r

    def numpy_run():
        reset()
        for t, (Ps, org) in zip(trackers, fields):
            t.system.step(potentials=Ps, origin=org, n=STEPS)

    reset()
    ts = TorchContourSystem([t.system for t in trackers], device=device, dtype=dtype)
    org = np.stack([o for _, o in fields])

    def torch_run():
        reset()
        ts.load()
        ts.step(potentials=[Ps for Ps, _ in fields], origin=org, n=STEPS)
        if device != "cpu":
            torch.cuda.synchronize()
        ts.store()

    t_np = median_time(numpy_run, repeat=repeat)
    t_t = median_time(torch_run, repeat=repeat)
    # the same steps give the same contours (a check, not a figure)
    numpy_run()
    want = [t.system.X.copy() for t in trackers]
    torch_run()
    diff = max(float(np.abs(t.system.X - w).max()) for t, w in zip(trackers, want))
    work = 9 * STEPS * B
    return t_np, t_t, work, diff


def _potential_case(B, videos, torch, device, repeat):
    from trackers.torch_backend import potential_batch

    specs = [("edge", 2.0), ("valley", 2.0), ("valley", 1.2)]
    grays = [to_gray(v[1]) for v in videos]

    def numpy_run():
        for g in grays:
            for kind, sigma in specs:
                potential_from_gray(g, kind, sigma)

    # float32 like OpenCV's blur on the NumPy side (float64 convolutions on the CPU
    # have no vectorised kernels in torch)
    stack = torch.from_numpy(np.stack(grays)[:, None]).to(device, torch.float32)

    def torch_run():
        for kind, sigma in specs:
            potential_batch(stack, kind, sigma)
        if device != "cpu":
            torch.cuda.synchronize()

    return median_time(numpy_run, repeat=repeat), median_time(torch_run, repeat=repeat)


def _tracking_case(B, videos, layouts, device, dtype, repeat):
    from trackers.torch_backend import TorchTracker

    n = len(videos[0])
    t_np, t_t = [], []
    for _ in range(repeat):
        trackers = [Tracker(lay) for lay in layouts]
        for t, v in zip(trackers, videos):
            t.track(v[0])
        t0 = time.perf_counter()
        ref = [[t.track(f) for f in v[1:]] for t, v in zip(trackers, videos)]
        t_np.append(time.perf_counter() - t0)
        tt = TorchTracker(layouts, device=device, dtype=dtype)
        tt.track([v[0] for v in videos])
        t0 = time.perf_counter()
        got = [tt.track([v[i] for v in videos]) for i in range(1, n)]
        t_t.append(time.perf_counter() - t0)
    diff = max(float(np.abs(got[i][b].contours[k] - ref[b][i].contours[k]).max())
               for b in range(B) for i in range(n - 1) for k in ref[b][i].contours)
    return statistics.median(t_np), statistics.median(t_t), B * (n - 1), diff


def run(quick: bool = False) -> list[Figure]:
    try:
        import torch
    except ImportError:
        return [Figure("backend", "torch", "available", 0.0, "", higher_is_better=True,
                       extra={"error": "the [torch] extra is not installed"})]
    threads_cv, threads_t = cv2.getNumThreads(), torch.get_num_threads()
    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    try:
        return _run(quick, torch)
    finally:
        cv2.setNumThreads(threads_cv)
        torch.set_num_threads(threads_t)


def _run(quick, torch):
    devices = [("cpu", torch.float64)]
    if torch.cuda.is_available():
        devices.append(("cuda", torch.float32))
    repeat = 3 if quick else 5
    n_frames = 4 if quick else 6
    figures = []
    for B in BATCHES:
        videos, layouts = _videos(B, n_frames)
        for device, dtype in devices:
            tag = f"B={B} {device}"
            t_np, t_t, work, diff = _relax_case(B, videos, layouts, torch, device, dtype,
                                                repeat)
            ours, peer = work / t_t, work / t_np
            figures.append(Figure("backend", f"relax {tag}", "contour-steps per second", ours,
                                  "steps/s", higher_is_better=True, peer="numpy",
                                  ratio=ratio(ours, peer, higher_is_better=True),
                                  extra={"numpy_steps_per_s": peer, "steps": STEPS,
                                         "max_node_difference_px": diff,
                                         "dtype": str(dtype)}))
            t_np, t_t = _potential_case(B, videos, torch, device, repeat)
            ours, peer = B / t_t, B / t_np
            figures.append(Figure("backend", f"potentials {tag}", "frames per second", ours,
                                  "frame/s", higher_is_better=True, peer="numpy",
                                  ratio=ratio(ours, peer, higher_is_better=True),
                                  extra={"numpy_frames_per_s": peer, "size": f"{W}x{H}",
                                         "potentials_per_frame": 3}))
            if not quick or B < 64:
                t_np, t_t, frames, diff = _tracking_case(B, videos, layouts, device, dtype,
                                                         max(repeat // 2, 1))
                ours, peer = frames / t_t, frames / t_np
                figures.append(Figure("backend", f"tracking {tag}", "frames per second", ours,
                                      "frame/s", higher_is_better=True, peer="numpy",
                                      ratio=ratio(ours, peer, higher_is_better=True),
                                      extra={"numpy_frames_per_s": peer, "frames": frames,
                                             "max_node_difference_px": diff}))
    return figures


if __name__ == "__main__":
    from _harness import emit

    emit("backend", run(quick="--quick" in sys.argv))
