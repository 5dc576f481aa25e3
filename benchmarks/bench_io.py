"""Input/output layer: video decoding through open_video vs bare cv2.VideoCapture, streaming
memory, contractions.csv writing and reading, AU derivation and the contractions plot.

Cases: a 640x480 MPEG-4 video made here (noise over a moving gradient, so the decoder
has real work; quick: 150 frames, full: 900) read through
:func:`faceanalysis.io.video.open_video` and through a bare ``cv2.VideoCapture.read`` loop
(the peer: the figure shows what the layer's checks and timestamps cost), and the time to
its tenth-last frame when reading starts there (a seek, against decoding every frame before
it); the peak
Python-heap growth while streaming it (tracemalloc, in frames of 640x480x3 bytes); a
contractions table of 54,000 rows (30 min at 30 fps; quick: 9,000) written with
:func:`faceanalysis.io.table.write_contractions`, read back with validation, converted to
AU intensities, and plotted to PNG.
"""

from __future__ import annotations

import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure, median_time, ratio  # noqa: E402

from faceanalysis.io.table import (  # noqa: E402
    JAW,
    MUSCLES,
    au_intensities,
    contraction_columns,
    empty_table,
    read_contractions,
    write_contractions,
)
from faceanalysis.io.video import open_video  # noqa: E402
from faceanalysis.viz.plots import plot_contractions  # noqa: E402

W, H = 640, 480


def _make_video(path: Path, n: int) -> Path:
    rng = np.random.default_rng(0)
    ramp = np.linspace(0, 180, W, dtype=np.float32)[None, :].repeat(H, 0)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30, (W, H))
    for i in range(n):
        grey = np.roll(ramp, 4 * i, axis=1) + rng.normal(0, 12, (H, W)).astype(np.float32)
        writer.write(cv2.cvtColor(np.clip(grey, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR))
    writer.release()
    return path


def _read_ours(path: Path) -> int:
    return sum(frame.ok for frame in open_video(path))


def _read_cv2(path: Path) -> int:
    capture = cv2.VideoCapture(str(path))
    n = 0
    while True:
        ok, _ = capture.read()
        if not ok:
            break
        n += 1
    capture.release()
    return n


def _first_frame_from(path: Path, start: int, *, seek: bool) -> int:
    import faceanalysis.io.video as video_module

    kept = video_module.SEEK_FROM
    video_module.SEEK_FROM = 1 if seek else 2**62
    try:
        with open_video(path, start=start, end=start + 1) as video:
            return next(iter(video)).index
    finally:
        video_module.SEEK_FROM = kept


def _table(n: int):
    rng = np.random.default_rng(1)
    t = empty_table(n, timestamps=np.arange(n) / 30)
    t["success"] = (rng.random(n) > 0.01).astype(int)
    t["confidence"] = rng.uniform(0.5, 1, n)
    geometric = [c for c in contraction_columns() if c.startswith(("head_", "fid_"))]
    t[geometric] = rng.uniform(0, 640, (n, len(geometric)))
    s = np.arange(n)[:, None]
    t[list(MUSCLES)] = np.clip(0.3 + 0.3 * np.sin(s / 90 + np.arange(len(MUSCLES))), 0, 1)
    t[JAW] = 0.1 * np.clip(np.sin(s[:, 0] / 120), 0, None)
    return t


def run(quick: bool = False) -> list[Figure]:
    n_frames = 150 if quick else 900
    n_rows = 9_000 if quick else 54_000
    repeat = 3 if quick else 5
    figures: list[Figure] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        video = _make_video(tmp / "bench.mp4", n_frames)
        ours = median_time(lambda: _read_ours(video), repeat=repeat)
        peer = median_time(lambda: _read_cv2(video), repeat=repeat)
        figures.append(Figure("io", f"decode {W}x{H} mp4v, {n_frames} frames", "frames per second",
                              n_frames / ours, "frames/s", higher_is_better=True,
                              peer="cv2.VideoCapture.read loop",
                              ratio=ratio(n_frames / ours, n_frames / peer,
                                          higher_is_better=True),
                              extra={"peer_value": n_frames / peer}))

        # reading from far into the video: a seek against decoding every frame before
        late = n_frames - 10
        seek = median_time(lambda: _first_frame_from(video, late, seek=True), repeat=repeat)
        decode = median_time(lambda: _first_frame_from(video, late, seek=False), repeat=repeat)
        figures.append(Figure("io", f"first frame from frame {late} of {W}x{H} mp4v",
                              "time (open, reach the frame, decode it)", seek, "s",
                              higher_is_better=False, peer="decoding every frame before it",
                              ratio=ratio(seek, decode, higher_is_better=False),
                              extra={"peer_value": decode}))

        tracemalloc.start()
        _read_ours(video)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        figures.append(Figure("io", f"stream {n_frames} frames", "peak heap growth",
                              peak / (W * H * 3), "frames", higher_is_better=False,
                              extra={"peak_bytes": peak}))

        table = _table(n_rows)
        csv = tmp / "contractions.csv"
        t_write = median_time(lambda: write_contractions(table, csv), repeat=repeat)
        t_read = median_time(lambda: read_contractions(csv), repeat=repeat)
        figures.append(Figure("io", f"contractions.csv {n_rows} rows", "write (validated)",
                              t_write, "s", higher_is_better=False,
                              extra={"bytes": csv.stat().st_size}))
        figures.append(Figure("io", f"contractions.csv {n_rows} rows", "read (validated)",
                              t_read, "s", higher_is_better=False))
        start = time.perf_counter()
        au_intensities(table)
        figures.append(Figure("io", f"AU intensities {n_rows} rows", "time per 1000 frames",
                              (time.perf_counter() - start) / n_rows * 1000, "s",
                              higher_is_better=False))
        t_plot = median_time(lambda: plot_contractions(table, tmp / "c.png").clear(),
                             repeat=max(1, repeat - 2))
        figures.append(Figure("io", f"contractions.png {n_rows} rows", "plot and save", t_plot,
                              "s", higher_is_better=False))
    return figures
