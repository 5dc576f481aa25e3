"""Analyse many videos on a Dask cluster: resumable, fault-isolated, with a summary table.

The work runs on :mod:`dask.distributed`, an existing distributed engine: by default a
local cluster of worker *processes* (one thread each) is started for the run; given the
address of a running scheduler (``tcp://host:8786``) the same code runs on that cluster.
Every video is one task; the result of each video is one folder under the output root
holding the same files as ``faceanalysis analyze`` plus a finished marker.

How a run stays safe to interrupt and repeat:

- A task writes into a hidden temporary sibling folder ``OUT/.<name>.partial-<id>``; the
  marker ``_finished.json`` is written last (atomically) and only then is the folder
  renamed to ``OUT/<name>``. A worker that dies mid-video therefore leaves nothing that
  looks finished; the scheduler reruns the task on another worker (up to dask's
  ``distributed.scheduler.allowed-failures`` worker deaths, default 3, after which the
  video is recorded as failed).
- The marker holds the input's size and modification time and the options used;
  :func:`is_complete` checks them and the presence and sizes of the output files, so a
  rerun skips exactly the videos whose results are still valid.
- An exception raised by the analysis of one video (a corrupt file, no face...) is caught
  inside its task and becomes a ``failed`` row of ``OUT/summary.csv``; it is not retried
  and never stops the other videos.

Inputs must be readable at the same paths from every worker (a shared filesystem when
the cluster spans several machines), and the output root must be writable from them.
"""

from __future__ import annotations

import contextlib
import glob
import json
import logging
import math
import os
import shutil
import sys
import time
import uuid
from collections.abc import Callable, Iterable, Mapping
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis._version import __version__
from faceanalysis.errors import FaceAnalysisError
from faceanalysis.io.corpus import (
    MARKER,
    MARKER_FORMAT,
    canonical_options,
    completion_problem,
    discover_inputs,
    input_signature,
    missing_outputs,
    output_names,
    short_hash,
)
from faceanalysis.io.logs import quiet_logger
from faceanalysis.io.outputs import (
    ANALYSIS_JSON,
    CONTRACTIONS_CSV,
    SUMMARY_CSV,
    atomic_path,
    write_text_atomic,
)
from faceanalysis.io.report import LOST_REASONS
from faceanalysis.io.table import measured_values
from faceanalysis.io.video import is_photographs
from faceanalysis.tracking import available_cores

__all__ = ["SCHEDULER_TIMEOUT_S", "SUMMARY", "analysis_options", "run_batch",
           "start_local_cluster"]

logger = logging.getLogger(__name__)

#: The summary table written into the output root.
SUMMARY = SUMMARY_CSV
#: Seconds to wait for the scheduler given by address (dask's default is 30).
SCHEDULER_TIMEOUT_S = 10
_PARTIAL = ".partial-"
_OLD = ".old-"
# Columns of contractions.csv that are not contractions (see faceanalysis.io.table).
_NOT_CONTRACTION = {"frame", "timestamp", "success", "confidence"}
_NOT_CONTRACTION_PREFIXES = ("head_", "fid_")
_SUMMARY_COLUMNS = ["video", "output", "status", "resumed", "frames", "frames_lost",
                    "duration_s", "processing_s", "error"]


# --------------------------------------------------------------------------- one video

def analysis_options(options: Mapping | None) -> dict:
    """The options of :func:`~faceanalysis.analysis.pipeline.analyze_to_folder` that matter.

    Options left at their defaults (or None) are dropped, so that a result is recognised
    as finished whether its run spelled a default out or not; paths are made absolute,
    since workers may not share this process's working folder.

    Examples
    --------
    >>> analysis_options({"estimator": "mesh", "overlay": True, "neutral": None})
    {'overlay': True}
    >>> analysis_options({"estimator": "joint", "tracker": "snakes"})
    {'tracker': 'snakes'}
    """
    import inspect

    from faceanalysis.analysis.pipeline import analyze, analyze_to_folder, default_estimator

    defaults = {name: p.default for f in (analyze, analyze_to_folder)
                for name, p in inspect.signature(f).parameters.items()
                if p.default is not inspect.Parameter.empty}
    out = {}
    for name, value in (options or {}).items():
        if value is None or (name in defaults and value == defaults[name]):
            continue
        if name == "estimator" and value == default_estimator(
                options.get("tracker"), layout=options.get("layout"),
                refine=bool(options.get("refine"))):
            continue    # the one the analysis runs when none is named
        out[name] = str(Path(value).resolve()) if isinstance(value, Path) else value
    return out


def _default_task(path: Path, output: Path, **options):
    """The single-video analysis, imported in the worker when first needed."""
    from faceanalysis.analysis.pipeline import analyze_to_folder

    return analyze_to_folder(path, output, quiet=True, **options)


def _is_contraction_column(name: str) -> bool:
    """A column the summary averages: contractions, the jaw, AU intensities, eye openness
    and the share of frames each is measured (``_identifiable``)."""
    return not (name in _NOT_CONTRACTION or name.startswith(_NOT_CONTRACTION_PREFIXES))


def _finite_or_nan(value) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return math.nan
    return value if math.isfinite(value) else math.nan


def _summarise(folder: Path) -> dict:
    """Frames, losses, duration and mean contractions of one finished output folder, each
    over the tracked frames where it is measured
    (:func:`~faceanalysis.io.table.measured_values`)."""
    table = pd.read_csv(folder / CONTRACTIONS_CSV)
    metadata = json.loads((folder / ANALYSIS_JSON).read_text())
    quality = metadata.get("quality", {}) if isinstance(metadata, dict) else {}
    if "success" in table:
        success = table["success"].astype(str).str.lower().isin(["true", "1", "1.0"]).to_numpy()
    else:
        success = np.ones(len(table), dtype=bool)
    frames = int(quality.get("frames_total", len(table)))
    frames_lost = int(quality.get("frames_lost", int((~success).sum())))
    duration = math.nan
    info = metadata.get("input", {}) if isinstance(metadata, dict) else {}
    photographs = is_photographs(info)      # they last no time: no duration
    if isinstance(info, dict) and not photographs:
        for key in ("duration_s", "duration"):
            if key in info:
                duration = _finite_or_nan(info[key])
                break
        if math.isnan(duration) and info.get("fps"):
            duration = frames / _finite_or_nan(info["fps"])
    if math.isnan(duration) and "timestamp" in table and len(table) >= 2 and not photographs:
        t = table["timestamp"].to_numpy(dtype=float)
        duration = float((t[-1] - t[0]) * len(t) / (len(t) - 1))
    record = {"frames": frames, "frames_lost": frames_lost, "duration_s": duration}
    reasons = quality.get("lost_reasons")
    if isinstance(reasons, dict):
        # why they were lost (analyses that say so): a column per reason
        for code in LOST_REASONS:
            record[f"frames_lost_{code}"] = int(reasons.get(code, 0))
    # what says how far to trust the means: the tracker's mean confidence, the frames the
    # face model does not explain, and those whose head is turned beyond its limit
    fit = metadata.get("model_fit") if isinstance(metadata, dict) else None
    fit = fit if isinstance(fit, dict) else {}
    turn = fit.get("head_turn") if isinstance(fit.get("head_turn"), dict) else {}
    record["mean_confidence"] = _finite_or_nan(quality.get("mean_confidence"))
    record["frames_over_fit_limit"] = _finite_or_nan(fit.get("frames_over_limit"))
    record["frames_turned"] = _finite_or_nan(turn.get("frames_over_limit"))
    # every value of the video is measured from its neutral frame
    params = metadata.get("parameters") if isinstance(metadata, dict) else None
    record["neutral_frame"] = _finite_or_nan((params or {}).get("neutral_frame"))
    calibration = metadata.get("calibration") if isinstance(metadata, dict) else None
    # a coarsely coded neutral frame (an encoder's first pictures) biases every value
    record["neutral_blockiness"] = _finite_or_nan((calibration or {}).get("neutral_blockiness"))
    # where the neutral frame is coarsely coded, has raised brows or the mouth open or
    # widened: the frame offered instead, to analyse the video from (NaN: none warned)
    record["offered_neutral"] = _finite_or_nan((calibration or {}).get("offered_neutral"))
    cuts = quality.get("shot_cuts")
    # an edited video: the face after a cut may be someone else (analyses that say so)
    record["shot_cuts"] = len(cuts) if isinstance(cuts, list) else math.nan
    # a small face reads noisily (landmark tracker)
    record["interocular_px"] = _finite_or_nan(quality.get("interocular_px"))
    eyes = metadata.get("eyes") if isinstance(metadata, dict) else None
    if isinstance(eyes, dict):
        # with --eyes: how often the eyes shut
        record["blinks"] = _finite_or_nan(eyes.get("blinks"))
        record["blinks_per_minute"] = _finite_or_nan(eyes.get("blinks_per_minute"))
        record["eye_closures"] = len(eyes.get("closures") or ())
    columns = [c for c in table.columns
               if _is_contraction_column(c) and pd.api.types.is_numeric_dtype(table[c])]
    # a value the analysis flags as not measured (it leans on the prior that muscles rest)
    # is not averaged in as if it were
    measured = measured_values(table.assign(success=success.astype(int)), columns)
    for column in columns:
        values = measured[column].to_numpy(dtype=float)
        finite = values[np.isfinite(values)]
        record[f"mean_{column}"] = float(finite.mean()) if finite.size else math.nan
    return record


def _error_text(exc: BaseException) -> str:
    message = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {message[0]}" if message else type(exc).__name__


def _limit_threads_once() -> None:
    """Give OpenCV the thread budget the runner chose for this worker process."""
    budget = os.environ.get("FACEANALYSIS_WORKER_THREADS")
    if budget and not getattr(_limit_threads_once, "done", False):
        import cv2

        cv2.setNumThreads(int(budget))
        _limit_threads_once.done = True


def _process_video(input_path: str, out_root: str, name: str, options: dict,
                   task: Callable | None, overwrite: bool) -> dict:
    """Run on a worker: analyse one video into ``out_root/name``; return its summary row.

    Exceptions from ``task`` (bad input) become a failed row. Exceptions from the
    runner's own bookkeeping (the output filesystem) propagate, so that dask retries.
    """
    _limit_threads_once()
    started = time.perf_counter()
    path = Path(input_path)
    root = Path(out_root)
    final = root / name
    tmp = root / f".{name}{_PARTIAL}{uuid.uuid4().hex[:12]}"
    row = {"video": str(path), "output": name, "status": "failed", "resumed": False}
    if not overwrite:
        # a task is run again when the worker holding its result dies before the result
        # reached the client: the folder it finished is then reused, not redone.
        earlier = _finished_record(final, path, options)
        if earlier is not None:
            return {**earlier, **row, "status": "ok", "error": ""}
    tmp.mkdir(parents=True)
    try:
        try:
            signature = input_signature(path)
            (task or _default_task)(path, tmp, **options)
            missing = missing_outputs({f.name for f in tmp.iterdir() if f.is_file()},
                                       options)
            if missing:
                raise RuntimeError(f"the analysis wrote no {', '.join(missing)}")
            row.update(_summarise(tmp))
        except Exception as exc:  # one bad video must never stop the batch
            logger.debug("analysis of %s failed", path, exc_info=True)
            row["error"] = _error_text(exc)
            row["processing_s"] = time.perf_counter() - started
            return row
        row["status"] = "ok"
        row["error"] = ""
        row["processing_s"] = time.perf_counter() - started
        outputs = {f.name: f.stat().st_size for f in sorted(tmp.iterdir()) if f.is_file()}
        marker = {
            "format": MARKER_FORMAT,
            "input": {"path": str(path), **signature},
            "options": canonical_options(options),
            "outputs": outputs,
            "record": {k: _json_value(v) for k, v in row.items() if k != "resumed"},
            "faceanalysis": __version__,
            "finished_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        }
        write_text_atomic(tmp / MARKER, json.dumps(marker, indent=1, default=_json_default))
        if final.exists():
            if not overwrite:
                raise FileExistsError(f"{final} appeared while {path} was being analysed")
            old = root / f".{name}{_OLD}{uuid.uuid4().hex[:12]}"
            os.replace(final, old)
            os.replace(tmp, final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, final)
        return row
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def _finished_record(folder: Path, video: Path, options: Mapping) -> dict | None:
    """The summary row kept in ``folder``'s marker if it is a finished result of this very
    input (same path, size, modification time and options), else None."""
    if completion_problem(folder, video, options=options) is not None:
        return None
    try:
        marker = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    if marker["input"].get("path") != str(video):
        return None
    return dict(marker["record"])


def _json_value(value):
    """NaN and infinities as null, so that the marker is strict JSON."""
    if isinstance(value, (float, np.floating)) and not math.isfinite(value):
        return None
    return value


def _json_default(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


# --------------------------------------------------------------------------- the run

def _remove_partials(root: Path, names: Iterable[str]) -> None:
    """Remove temporary folders left by workers that died (ours, by their exact prefix)."""
    for name in names:
        for kind in (_PARTIAL, _OLD):
            for leftover in root.glob(f".{glob.escape(name)}{kind}*"):
                shutil.rmtree(leftover, ignore_errors=True)


def _write_summary(root: Path, rows: list[dict]) -> Path:
    frame = _summary_frame(rows)
    target = root / SUMMARY
    with atomic_path(target) as tmp:
        frame.to_csv(tmp, index=False)
    return target


def _summary_frame(rows: list[dict]) -> pd.DataFrame:
    columns = list(_SUMMARY_COLUMNS)
    for row in rows:
        for key in row:
            if key not in columns:
                columns.append(key)
    frame = pd.DataFrame(rows, columns=columns)
    frame["resumed"] = frame["resumed"].fillna(False).astype(bool)
    for column in ("frames", "frames_lost", "frames_over_fit_limit", "frames_turned",
                   *(f"frames_lost_{code}" for code in LOST_REASONS)):
        if column in frame:
            frame[column] = pd.to_numeric(frame[column]).astype("Int64")
    frame["error"] = frame["error"].fillna("")
    return frame


def _failed_row(path: Path, name: str, error: str) -> dict:
    return {"video": str(path), "output": name, "status": "failed", "resumed": False,
            "error": error}


def start_local_cluster(workers: int | None = None, *, threads: int | None = None,
                        silence_logs: int | bool = logging.ERROR):
    """Start the local Dask cluster that :func:`run_batch` uses by default.

    Worker processes that run one video at a time; each process's numerical libraries
    (OpenMP, BLAS, Numba, OpenCV) get ``threads`` threads, by default ``cores // workers``
    so that workers do not oversubscribe the cores; a worker holds only the video it is
    analysing (dask's ``worker-saturation`` 1.0), so that when it dies no queued video is
    blamed with it; no dashboard, and the scheduler's HTTP server on a free local port.
    Reuse one cluster for several runs with
    ``run_batch(..., scheduler=distributed.Client(cluster))``.

    Parameters
    ----------
    workers : int, optional
        Number of worker processes; default: one per available core.
    threads : int, optional, keyword-only
        Threads of the numerical libraries in each worker process; default
        ``max(1, cores // workers)``.
    silence_logs : int or bool, keyword-only
        Level below which the workers' log messages are dropped (False: keep them).

    Returns
    -------
    distributed.LocalCluster
        A running cluster; close it with ``cluster.close()`` (or use it in a ``with``).
    """
    import dask
    from distributed import LocalCluster

    if workers is not None and (isinstance(workers, bool)
                                or not isinstance(workers, (int, np.integer)) or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if threads is not None and (isinstance(threads, bool)
                                or not isinstance(threads, (int, np.integer)) or threads < 1):
        raise ValueError(f"threads must be a positive integer, got {threads!r}")
    n = int(workers or available_cores())
    budget = str(int(threads) if threads else max(1, available_cores() // n))
    env = {"OMP_NUM_THREADS": budget, "OPENBLAS_NUM_THREADS": budget, "MKL_NUM_THREADS": budget,
           "NUMBA_NUM_THREADS": budget, "FACEANALYSIS_WORKER_THREADS": budget}
    # Dask sets MALLOC_TRIM_THRESHOLD_ in new worker processes (to give memory back to the
    # OS), which also freezes glibc's mmap threshold at 128 KiB: every frame-sized array
    # is then mmap'ed and page-faulted afresh, which made image filtering ~3x slower in
    # workers than in a plain process. A 32 MiB mmap threshold keeps frames on the heap.
    pre_spawn = {**dask.config.get("distributed.nanny.pre-spawn-environ"), **env,
                 "MALLOC_MMAP_THRESHOLD_": str(32 * 2**20)}
    with dask.config.set({"distributed.scheduler.worker-saturation": 1.0,
                          "distributed.nanny.pre-spawn-environ": pre_spawn}):
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                            dashboard_address=None, silence_logs=silence_logs, env=env,
                            scheduler_kwargs={"dashboard": False,
                                              "dashboard_address": "127.0.0.1:0"})


def _start_client(workers: int | None, scheduler, silence_logs):
    """(client, cluster or None, owns_client) for a local cluster or an existing one."""
    from distributed import Client

    if scheduler is not None:
        if isinstance(scheduler, Client):
            return scheduler, None, False
        return _connect(scheduler), None, True
    cluster = start_local_cluster(workers, silence_logs=silence_logs)
    try:
        client = Client(cluster, set_as_default=False)
    except BaseException:
        cluster.close()
        raise
    return client, cluster, True


def _connect(address: str):
    """A client of the scheduler at ``address``; FaceAnalysisError (one line) if there is
    none within :data:`SCHEDULER_TIMEOUT_S` or the address is malformed."""
    from distributed import Client
    from distributed.comm import resolve_address

    try:
        # a malformed or unknown address is refused here, before a client exists: a
        # half-made client hangs for 20 s when it is collected
        resolve_address(address)
        return Client(address, set_as_default=False, timeout=SCHEDULER_TIMEOUT_S)
    except (OSError, ValueError) as exc:         # TimeoutError is an OSError
        reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    raise FaceAnalysisError(f"cannot connect to the Dask scheduler at {address}: {reason}")


def _close(client) -> None:
    if client is not None:
        with contextlib.suppress(Exception):
            client.close()


def run_batch(inputs: str | os.PathLike | Iterable[str | os.PathLike],
              out: str | os.PathLike, *,
              workers: int | None = None,
              scheduler=None,
              options: Mapping | None = None,
              task: Callable | None = None,
              overwrite: bool = False,
              progress: bool = False,
              silence_logs: int | bool = logging.ERROR) -> pd.DataFrame:
    """Analyse many videos on a Dask cluster, one output folder per video.

    Parameters
    ----------
    inputs : path-like or iterable of path-like
        Video files, folders and glob patterns, expanded by :func:`discover_inputs`.
        Inputs that lie inside ``out`` (e.g. overlays of an earlier run) are left out.
    out : path-like
        Output root: ``out/<name>/`` per video (see :func:`output_names`) and
        ``out/summary.csv``.
    workers : int, optional, keyword-only
        Worker processes of the local cluster (one thread each); default: one per
        available core. Cannot be combined with ``scheduler``.
    scheduler : str or distributed.Client, optional, keyword-only
        Address of a running Dask scheduler (``"tcp://host:8786"``) or a connected
        client; the run then uses that cluster's workers instead of starting one. An
        address that does not answer within :data:`SCHEDULER_TIMEOUT_S` seconds fails
        the run (:class:`~faceanalysis.errors.FaceAnalysisError` naming it).
    options : mapping, optional, keyword-only
        Analysis options passed to ``task`` for every video (e.g. ``overlay=True``); those
        left at the analysis defaults or None are dropped (:func:`analysis_options`), the
        others are recorded in each finished marker and a result made with other options
        is not reused.
    task : callable, optional, keyword-only
        ``task(path, output_folder, **options)`` analyses one video into an existing,
        empty folder, writing at least ``contractions.csv``, ``analysis.json`` and
        ``contractions.png``; exceptions it raises mark the video as failed. Default:
        :func:`faceanalysis.analysis.pipeline.analyze_to_folder` (imported on the workers). It
        must be importable or picklable by the workers.
    overwrite : bool, keyword-only
        Re-analyse every video, replacing finished results. Without it finished
        results are skipped, and a folder ``out/<name>`` that exists but is not a
        finished result for the current input and options is reported as failed.
    progress : bool, keyword-only
        Show a progress bar on stderr: videos done / failed / remaining and the
        overall frames per second.
    silence_logs : int or bool, keyword-only
        Level below which the local cluster's own log messages are dropped (False:
        keep them all).

    Returns
    -------
    pandas.DataFrame
        One row per video, in input order, as written to ``out/summary.csv``:
        ``video, output, status`` ("ok" or "failed"), ``resumed`` (finished by an
        earlier run and skipped), ``frames, frames_lost, duration_s, processing_s,
        error`` and ``mean_<column>`` for every contraction, ``AUxx_r`` and eye-openness
        column (over the frames tracked successfully where it is measured) and
        ``mean_<column>_identifiable`` (the share of them where it is).

    Raises
    ------
    FileNotFoundError
        If an input names nothing (see :func:`discover_inputs`).
    ValueError
        If ``workers`` is not a positive integer, both ``workers`` and ``scheduler``
        are given, or no input is left to analyse.
    FileExistsError
        If ``out`` exists and is not a folder.
    FaceAnalysisError
        If the ``scheduler`` address is malformed or does not answer; nothing is written.

    Notes
    -----
    Reruns are cheap: videos whose folders pass :func:`is_complete` are not sent to the
    cluster at all (no cluster is started when nothing is left to do); failed videos
    are tried again. A video whose worker dies is rerun by the scheduler on another
    worker, up to dask's ``distributed.scheduler.allowed-failures`` (default 3) deaths,
    then recorded as failed (``KilledWorker``); an error of the runner's own file
    handling is retried once. Temporary folders left by workers that died are removed
    at the start and end of a run; do not run two batches into the same ``out`` at the
    same time.

    Examples
    --------
    >>> summary = run_batch(["clips/", "more/*.mp4"], "results", workers=4,
    ...                     options={"estimator": "tw93"})  # doctest: +SKIP
    >>> summary.loc[summary.status == "failed", ["video", "error"]]  # doctest: +SKIP
    """
    if workers is not None:
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) \
                or workers < 1:
            raise ValueError(f"workers must be a positive integer, got {workers!r}")
        if scheduler is not None:
            raise ValueError("workers and scheduler are exclusive: the size of an existing "
                             "cluster is set where it is started")
    if task is not None and not callable(task):
        raise ValueError(f"task must be callable, got {type(task).__name__}")
    options = analysis_options(options)
    canonical_options(options)  # fails early on values that cannot be recorded
    root = Path(out)
    if root.exists() and not root.is_dir():
        raise FileExistsError(f"{root} exists and is not a folder")
    inside = (root.resolve(), Path(os.path.abspath(root)))
    videos = []
    for video in discover_inputs(inputs):
        if any(video.is_relative_to(r) or video.resolve().is_relative_to(r) for r in inside):
            logger.warning("leaving out %s: it lies inside the output folder %s", video, root)
        else:
            videos.append(video)
    if not videos:
        raise ValueError(f"no input left to analyse: every input lies inside {root}")
    names = output_names(videos)

    rows: list[dict | None] = [None] * len(videos)
    todo: list[int] = []
    taken = {n.lower() for n in names}
    for i, (video, name) in enumerate(zip(videos, names)):
        if not overwrite and not (root / name).exists():
            earlier = _finished_elsewhere(root, video, name, options, taken)
            if earlier is not None:
                names[i] = name = earlier
        folder = root / name
        if not overwrite and folder.exists():
            problem = completion_problem(folder, video, options=options)
            if problem is None:
                marker = json.loads((folder / MARKER).read_text())
                rows[i] = {**marker["record"], "video": str(video), "output": name,
                           "resumed": True}
            else:
                rows[i] = _failed_row(video, name, f"{folder} exists but is not a finished "
                                      f"result: {problem}; remove it, or pass --overwrite "
                                      f"(overwrite=True) to redo every video")
            continue
        todo.append(i)
    skipped = sum(1 for r in rows if r is not None and r["resumed"])
    blocked = len(videos) - skipped - len(todo)
    logger.info("%d video(s): %d finished before (skipped), %d to analyse%s", len(videos),
                skipped, len(todo), f", {blocked} blocked by an unfinished folder (see "
                f"{SUMMARY})" if blocked else "")

    # an unreachable scheduler fails the run before anything is written
    connected = _connect(scheduler) if todo and isinstance(scheduler, str) else None
    try:
        root.mkdir(parents=True, exist_ok=True)
    except BaseException:
        _close(connected)
        raise
    _remove_partials(root, names)
    try:
        if todo:
            _run_on_cluster(videos, names, todo, rows, root, options, task, overwrite,
                            workers, connected or scheduler, progress, silence_logs)
    finally:
        _close(connected)
        final_rows = [r if r is not None else {**_failed_row(videos[i], names[i],
                                                              "interrupted before it finished"),
                                               "status": "pending"}
                      for i, r in enumerate(rows)]
        _write_summary(root, final_rows)
        _remove_partials(root, names)
    frame = _summary_frame(final_rows)
    frame.attrs["skipped"] = skipped
    frame.attrs["summary_path"] = str(root / SUMMARY)
    return frame


def _finished_elsewhere(root: Path, video: Path, name: str, options: Mapping,
                        taken: set[str]) -> str | None:
    """The other name ``video`` may have had in an earlier run, if finished there.

    A stem gets a hash only while it clashes with another input's, so a run over a
    subset or a superset of the inputs may name a video's folder differently; its
    finished result is still found (when its marker names this very input).
    """
    stem = video.stem
    other = f"{stem.lstrip('._') or 'video'}-{short_hash(video)}" if name == stem else stem
    if other.lower() in taken or not (root / other / MARKER).is_file():
        return None
    return other if _finished_record(root / other, video, options) is not None else None


def _run_on_cluster(videos, names, todo, rows, root, options, task, overwrite, workers,
                    scheduler, progress, silence_logs) -> None:
    import distributed  # noqa: F401  (configures its loggers on import: do it before quieting)

    with contextlib.ExitStack() as stack:
        if silence_logs is not False:
            # the cluster's chatter in this process: scheduler, nannies, client
            stack.enter_context(quiet_logger("distributed", silence_logs))
        _run_futures(videos, names, todo, rows, root, options, task, overwrite, workers,
                     scheduler, progress, silence_logs)


def _run_futures(videos, names, todo, rows, root, options, task, overwrite, workers,
                 scheduler, progress, silence_logs) -> None:
    from distributed import as_completed
    from tqdm.auto import tqdm

    client, cluster, owns = _start_client(workers, scheduler, silence_logs)
    bar = tqdm(total=len(todo), unit="video", file=sys.stderr, disable=not progress,
               dynamic_ncols=True, desc="batch")
    try:
        futures = {}
        for i in todo:
            future = client.submit(_process_video, str(videos[i]), str(root.resolve()),
                                   names[i], options, task, overwrite, pure=False, retries=1,
                                   key=f"faceanalysis-{names[i]}-{uuid.uuid4().hex[:8]}")
            futures[future] = i
        started = time.perf_counter()
        frames = ok = failed = 0
        for future in as_completed(futures, loop=client.loop):
            i = futures[future]
            try:
                row = future.result()
            except Exception as exc:  # KilledWorker, lost connection, bookkeeping error
                reason = _error_text(exc)
                if type(exc).__name__ == "KilledWorker":
                    reason = ("KilledWorker: every worker that analysed it died (dask's "
                              "distributed.scheduler.allowed-failures was exceeded)")
                row = _failed_row(videos[i], names[i], reason)
            rows[i] = row
            if row["status"] == "ok":
                ok += 1
                frames += int(row.get("frames") or 0)
            else:
                failed += 1
                logger.debug("%s failed: %s", videos[i], row["error"])
            elapsed = max(time.perf_counter() - started, 1e-9)
            bar.set_postfix_str(f"ok={ok} failed={failed} left={len(todo) - ok - failed} "
                                f"{frames / elapsed:.1f} frames/s", refresh=False)
            bar.update(1)
    finally:
        bar.close()
        if owns:
            with contextlib.suppress(Exception):
                client.close()
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close()

