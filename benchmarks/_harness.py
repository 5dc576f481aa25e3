"""Small benchmark harness: figures, timing by median, markdown + JSON-lines output.

A benchmark is a module ``benchmarks/bench_<name>.py`` with a docstring (its first
line is shown by ``--list``) and a function ``run(quick: bool) -> list[Figure]``.
Benchmarks measure; they assert nothing and CI does not run them.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field


@dataclass
class Figure:
    """One measured number. ``target``: the figure an issue sets; ``peer``: the other tool
    measured in the same run, with ``ratio`` = our value / peer value for
    higher-is-better figures and peer / ours otherwise (so > 1 always means we win)."""

    benchmark: str
    case: str
    metric: str
    value: float
    unit: str
    higher_is_better: bool
    target: float | None = None
    peer: str | None = None
    ratio: float | None = None
    extra: dict = field(default_factory=dict)

    def as_json(self) -> dict:
        d = asdict(self)
        extra = d.pop("extra")
        d = {k: v for k, v in d.items() if v is not None}
        d.update(extra)
        return d

    @property
    def meets_target(self) -> bool | None:
        if self.target is None:
            return None
        return self.value >= self.target if self.higher_is_better else self.value <= self.target


def median_time(fn: Callable[[], object], *, repeat: int = 7, number: int = 1,
                warmup: int = 1) -> float:
    """Median wall time in seconds of ``number`` calls of ``fn``, over ``repeat`` runs,
    divided by ``number``. The median resists the noise of a shared machine."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return statistics.median(times)


def ratio(ours: float, peer: float, *, higher_is_better: bool) -> float:
    """Ratio > 1 when we win, whatever the direction of the metric."""
    if higher_is_better:
        return ours / peer if peer else float("inf")
    return peer / ours if ours else float("inf")


def machine_description() -> str:
    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
            f"Python {platform.python_version()}")


def format_markdown(figures: list[Figure]) -> str:
    head = "| case | metric | value | unit | target | peer | ratio |"
    lines = [head, "|---|---|---:|---|---:|---|---:|"]
    for f in figures:
        target = "" if f.target is None else (
            f"{f.target:g} {'ok' if f.meets_target else 'MISSED'}")
        ratio_s = "" if f.ratio is None else f"{f.ratio:.1f}x"
        lines.append(f"| {f.case} | {f.metric} | {f.value:.4g} | {f.unit} | {target} | "
                     f"{f.peer or ''} | {ratio_s} |")
    return "\n".join(lines)


def emit(name: str, figures: list[Figure]) -> None:
    print(f"## benchmark `{name}` ({machine_description()})\n")
    print(format_markdown(figures))
    print()
    for f in figures:
        print(json.dumps(f.as_json()))


#: Copies of a clip as other cameras would give it (``altered_copies``).
ALTERATIONS = ("enlarged 3x", "halved", "turned 20 degrees", "mirrored", "grey",
               "in a 1920x1080 frame", "a quarter of the light", "sensor noise",
               "coarse JPEG")
#: A face far from the camera in a wide shot: the clip halved, in a 1920x1080 frame.
FAR = "halved, in a 1920x1080 frame"


def read_frames(path, limit: int | None = None) -> list:
    """The first ``limit`` frames of the video ``path`` (all of them: None), as OpenCV
    decodes them (BGR)."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    frames = []
    try:
        while limit is None or len(frames) < limit:
            ok, frame = cap.read()
            if not ok:
                break
            frames.append(frame)
    finally:
        cap.release()
    return frames


def altered_copies(path, folder, labels=ALTERATIONS):
    """Yield ``(label, copy)``: the video ``path`` enlarged 3 times (bicubic), halved (area
    mean), turned by 20 degrees about its centre (borders reflected), mirrored left to right,
    in grey, as it is or halved inside a 1920x1080 frame (right of and below its centre, its
    edges drawn out: a wide shot), with every level a quarter (a dim room), with Gaussian
    noise of 4 grey levels added to each channel of each frame (a dim room's sensor; the
    same noise on every run), or each frame coded as a JPEG of quality 30 (a low bit rate's
    blocks), each written
    in turn to ``folder/altered.avi`` (MJPEG: one copy on disk at a time, overwritten by the
    next)."""
    from pathlib import Path

    import cv2
    import numpy as np

    def turned(f):
        h, w = f.shape[:2]
        m = cv2.getRotationMatrix2D((w / 2, h / 2), 20, 1.0)
        return cv2.warpAffine(f, m, (w, h), borderMode=cv2.BORDER_REFLECT)

    def framed(f):
        # its edge rows and columns drawn out to the wider frame: no hard border for a
        # contour to take (a pasted frame's edge held a laughing chin)
        h, w = f.shape[:2]
        y0, x0 = min(540, 1080 - h), min(1100, 1920 - w)
        return cv2.copyMakeBorder(f, y0, 1080 - h - y0, x0, 1920 - w - x0,
                                  cv2.BORDER_REPLICATE)

    def noisy(f):
        return np.clip(f + rng.normal(0.0, 4.0, f.shape), 0, 255).astype(np.uint8)

    def coarse(f):
        return cv2.imdecode(cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, 30])[1],
                            cv2.IMREAD_COLOR)

    alter = {"in a 1920x1080 frame": framed, "sensor noise": noisy, "coarse JPEG": coarse,
             "a quarter of the light": lambda f: cv2.convertScaleAbs(f, alpha=0.25),
             FAR: lambda f: framed(cv2.resize(f, None, fx=0.5, fy=0.5,
                                              interpolation=cv2.INTER_AREA)),
             "enlarged 3x": lambda f: cv2.resize(f, None, fx=3, fy=3,
                                                  interpolation=cv2.INTER_CUBIC),
             "halved": lambda f: cv2.resize(f, None, fx=0.5, fy=0.5,
                                            interpolation=cv2.INTER_AREA),
             "turned 20 degrees": turned, "mirrored": lambda f: cv2.flip(f, 1),
             "grey": lambda f: cv2.cvtColor(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY),
                                            cv2.COLOR_GRAY2BGR)}
    dst = Path(folder) / "altered.avi"
    for label in labels:
        rng = np.random.default_rng(0)     # the same noise for every copy and run
        cap = cv2.VideoCapture(str(path))
        fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
        out = None
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            frame = alter[label](frame)
            if out is None:
                out = cv2.VideoWriter(str(dst), cv2.VideoWriter_fourcc(*"MJPG"), fps,
                                      (frame.shape[1], frame.shape[0]))
            out.write(frame)
        out.release()
        yield label, dst
