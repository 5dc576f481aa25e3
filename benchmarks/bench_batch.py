"""Batch throughput on a local Dask cluster: 8 videos with 1 and 2 worker processes.

Each case starts one local cluster (``faceanalysis.batch.start_local_cluster``), runs
the batch once to warm the workers up (imports, Numba compilation), then times complete
re-runs (``overwrite=True``: every video analysed again) and reports the median.
Every worker gets one thread for its numerical libraries in both cases, so that the
speed-up measures the distribution over processes; the cluster start-up time is reported
separately (it is paid once per command, not per video).

The per-video task is the real single-video analysis
(``faceanalysis.analysis.analyze_to_folder``) on rendered synthetic faces when both
exist; otherwise a CPU-bound stand-in (per-frame gradient-magnitude filtering, same
output files) on synthetic noise videos, and the case names say so.
"""

from __future__ import annotations

import functools
import importlib.util
import json
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from _harness import Figure, median_time

N_VIDEOS = 8
TARGET_SPEEDUP = 1.7


def standin_task(path, output, *, rounds: int = 12, **options):
    """Stand-in analysis: gradient-magnitude filtering of every frame at 256 px, written as
    contractions.csv / analysis.json / contractions.png."""
    cap = cv2.VideoCapture(str(path))
    rows = []
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            grey = cv2.resize(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), (256, 256))
            image = grey.astype(np.float32)
            for _ in range(rounds):
                image = cv2.GaussianBlur(image, (0, 0), 2.0)
                gx = cv2.Sobel(image, cv2.CV_32F, 1, 0)
                gy = cv2.Sobel(image, cv2.CV_32F, 0, 1)
                image = cv2.magnitude(gx, gy) + 0.5 * image
            rows.append({"frame": len(rows), "success": True, "confidence": 1.0,
                         "frontalis_inner_l": float(image.mean() / (1 + image.max()))})
    finally:
        cap.release()
    if not rows:
        raise ValueError(f"{path}: not a readable video")
    table = pd.DataFrame(rows)
    table.insert(1, "timestamp", table["frame"] / 30.0)
    table.to_csv(Path(output) / "contractions.csv", index=False)
    quality = {"frames_total": len(table), "frames_lost": 0, "frames_tracked": len(table)}
    (Path(output) / "analysis.json").write_text(json.dumps({"quality": quality}))
    cv2.imwrite(str(Path(output) / "contractions.png"), np.zeros((8, 8), np.uint8))


def _real_analysis_available() -> bool:
    return all(importlib.util.find_spec(m) is not None
               for m in ("faceanalysis.analysis", "synth.model"))


def _make_videos(folder: Path, frames: int, *, real: bool) -> list[Path]:
    paths = []
    for i in range(N_VIDEOS):
        if real:
            from synth.render.sequence import render_sequence

            out = render_sequence(folder / f"face{i}", expression="happiness", frames=frames,
                                  size=192, seed=i, flow=False)
            paths.append(Path(out["video"]))
        else:
            rng = np.random.default_rng(i)
            path = folder / f"clip{i}.avi"
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0,
                                     (128, 128))
            texture = rng.integers(0, 255, (128, 128 + frames, 3), dtype=np.uint8)
            for t in range(frames):
                writer.write(np.ascontiguousarray(texture[:, t:t + 128]))
            writer.release()
            paths.append(path)
    return paths


def run(quick: bool) -> list[Figure]:
    from distributed import Client

    from faceanalysis.batch import run_batch, start_local_cluster

    real = _real_analysis_available()
    frames = (12 if quick else 30) if real else (20 if quick else 40)
    repeat = 1 if quick else 3
    # the stand-in does ~0.6 s of filtering per video (0.2 s quick), about what a short
    # clip costs the real analysis, so that the per-run overhead is not all it measures
    task = None if real else functools.partial(standin_task, rounds=60 if quick else 100)
    label = "analysis" if real else "stand-in task (filtering, not the analysis)"
    figures: list[Figure] = []
    throughput = {}
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        tmp = Path(tmp)
        videos = _make_videos(tmp, frames, real=real)
        total_frames = N_VIDEOS * frames
        for workers in (1, 2):
            t0 = time.perf_counter()
            cluster = start_local_cluster(workers, threads=1)
            client = Client(cluster, set_as_default=False)
            startup = time.perf_counter() - t0
            out = tmp / f"out{workers}"
            try:
                def once(client=client, out=out):
                    summary = run_batch(videos, out, scheduler=client, task=task,
                                        overwrite=True)
                    failed = summary[summary["status"] != "ok"]
                    if len(failed):
                        raise RuntimeError(f"batch failed: {failed['error'].iloc[0]}")

                seconds = median_time(once, repeat=repeat, warmup=1)
            finally:
                client.close()
                cluster.close()
            case = f"{label}, {N_VIDEOS} videos x {frames} frames, {workers} worker(s)"
            throughput[workers] = N_VIDEOS / seconds
            figures.append(Figure("batch", case, "throughput", N_VIDEOS / seconds, "videos/s",
                                  True, extra={"frames_per_s": total_frames / seconds,
                                               "seconds": seconds}))
            figures.append(Figure("batch", case, "cluster start", startup, "s", False))
    figures.append(Figure("batch", f"{label}, {N_VIDEOS} videos, 2 vs 1 worker", "speed-up",
                          throughput[2] / throughput[1], "x", True, target=TARGET_SPEEDUP))
    return figures
