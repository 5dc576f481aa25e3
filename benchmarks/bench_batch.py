"""Batch throughput on a local Dask cluster: 8 face videos with 1 and 2 worker processes.

Each case has its own local cluster (``faceanalysis.batch.start_local_cluster``), runs
the batch once to warm the workers up (imports, Numba compilation), then times complete
re-runs (``overwrite=True``: every video analysed again), the two cases alternating, and
reports the median.
Every worker gets one thread for its numerical libraries in both cases, so that the
speed-up measures the distribution over processes; the cluster start-up time is reported
separately (it is paid once per command, not per video).

The per-video task is the real single-video analysis
(``faceanalysis.analysis.pipeline.analyze_to_folder``: tracking, calibration, estimation, CSV,
JSON and plot) on rendered synthetic faces. While ``synth.FaceModel`` (the physics
model) is not available, the clips are rendered with, and the analysis inverts the
fiducial response of, the kinematic test face (``tests/faceanalysis/_kinematic_face.py``),
and the case names say so; the per-video work is then the same analysis code with a
different response table.
"""

from __future__ import annotations

import contextlib
import functools
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from _harness import Figure

N_VIDEOS = 8
TARGET_SPEEDUP = 1.7
REPO = Path(__file__).resolve().parent.parent


def _face_model():
    """(model, label, task): the physics model when it exists, else the kinematic face."""
    from faceanalysis.analysis.pipeline import analyze_to_folder

    try:
        from synth import FaceModel
    except ImportError:
        sys.path.insert(0, str(REPO))
        from faceanalysis.estimation.model_response import tabulate_response
        from tests.faceanalysis._kinematic_face import KinematicFace

        model = KinematicFace()
        response = tabulate_response(model, (*model.muscle_names, "jaw_rotation"))
        task = functools.partial(analyze_to_folder, response=response)
        return model, "analysis (kinematic test face; no physics model yet)", task
    return FaceModel.default(), "analysis", None


def _make_videos(folder: Path, frames: int, model) -> list[Path]:
    from synth.render.sequence import synthesize, write_sequence

    paths = []
    muscles = [m for m in ("zygomaticus_major", "frontalis_inner", "depressor_anguli")
               if f"{m}_l" in model.muscle_names]
    for i in range(N_VIDEOS):
        muscle = muscles[i % len(muscles)]
        ramp = np.sin(np.linspace(0, np.pi, frames)) * (0.4 + 0.05 * i)
        timeline = pd.DataFrame({f"{muscle}_l": ramp, f"{muscle}_r": ramp})
        seq = synthesize(model=model, contractions=timeline, seed=i, size=192, fps=30,
                         flow=False, supersample=1)
        out = write_sequence(seq, folder / f"clip{i}")
        target = folder / f"clip{i}{Path(out['video']).suffix}"
        Path(out["video"]).rename(target)
        paths.append(target)
    return paths


def _spin(n: int) -> int:
    total = 0
    for i in range(n):
        total += i * i % 7
    return total


def _machine_capacity(n: int = 2_000_000, repeat: int = 3) -> float:
    """How many CPU-bound processes this machine runs at once right now: the time of two
    pure-Python loops one after the other over the time of the two in two processes
    (2.0 on two idle cores; less when other programs share them); median of ``repeat``
    interleaved measurements."""
    import statistics
    from concurrent.futures import ProcessPoolExecutor

    ratios = []
    with ProcessPoolExecutor(2) as pool:
        list(pool.map(_spin, [1000, 1000]))             # start both processes first
        for _ in range(repeat):
            t0 = time.perf_counter()
            _spin(n)
            _spin(n)
            serial = time.perf_counter() - t0
            t0 = time.perf_counter()
            list(pool.map(_spin, [n, n]))
            ratios.append(serial / (time.perf_counter() - t0))
    return statistics.median(ratios)


def run(quick: bool) -> list[Figure]:
    import statistics

    from distributed import Client

    from faceanalysis.batch import run_batch, start_local_cluster

    capacity_before = _machine_capacity()
    model, label, task = _face_model()
    frames = 15 if quick else 40
    repeat = 1 if quick else 3
    figures: list[Figure] = []
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp, \
            contextlib.ExitStack() as stack:
        tmp = Path(tmp)
        videos = _make_videos(tmp, frames, model)
        total_frames = N_VIDEOS * frames
        clients, startup = {}, {}
        for workers in (1, 2):
            t0 = time.perf_counter()
            cluster = stack.enter_context(start_local_cluster(workers, threads=1))
            clients[workers] = stack.enter_context(Client(cluster, set_as_default=False))
            startup[workers] = time.perf_counter() - t0

        def once(workers):
            t0 = time.perf_counter()
            summary = run_batch(videos, tmp / f"out{workers}", scheduler=clients[workers],
                                task=task, overwrite=True)
            seconds = time.perf_counter() - t0
            failed = summary[summary["status"] != "ok"]
            if len(failed):
                raise RuntimeError(f"batch failed: {failed['error'].iloc[0]}")
            return seconds

        for workers in (1, 2):  # warm-up: imports, compilation, response table
            once(workers)
        # 1 and 2 workers alternate, so that a change of load on the machine (other
        # programs) touches both cases alike
        times = {1: [], 2: []}
        for _ in range(repeat):
            for workers in (1, 2):
                times[workers].append(once(workers))
        seconds = {w: statistics.median(t) for w, t in times.items()}
        for workers in (1, 2):
            case = f"{label}, {N_VIDEOS} videos x {frames} frames, {workers} worker(s)"
            figures.append(Figure("batch", case, "throughput", N_VIDEOS / seconds[workers],
                                  "videos/s", True,
                                  extra={"frames_per_s": total_frames / seconds[workers],
                                         "seconds": seconds[workers],
                                         "runs_s": [round(t, 3) for t in times[workers]]}))
            figures.append(Figure("batch", case, "cluster start", startup[workers], "s",
                                  False))
    figures.append(Figure("batch", f"{label}, {N_VIDEOS} videos, 2 vs 1 worker", "speed-up",
                          seconds[1] / seconds[2], "x", True, target=TARGET_SPEEDUP))
    for when, capacity in (("before", capacity_before), ("after", _machine_capacity())):
        figures.append(Figure("batch", f"machine, {when} the runs: 2 CPU-bound processes vs 1 "
                              "(context for the speed-up; 2.0 on two idle cores)",
                              "parallel capacity", capacity, "x", True))
    return figures
