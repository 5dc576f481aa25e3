"""``faceanalysis batch``: analyse many videos on a local or remote Dask cluster."""

from __future__ import annotations

import argparse
import logging
import sys

from faceanalysis.cli._common import positive_int, progress_wanted
from faceanalysis.cli._input import add_input_options
from faceanalysis.cli.analyze import add_analysis_options, check_analysis_options

HELP = "analyse many videos (files, folders, glob patterns) on a Dask cluster"

_SHOWN_FAILURES = 20


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Analyse every video named by INPUTS into OUT/<name>/ (the files of 'analyze') and "
        "write OUT/summary.csv, one row per video. The work runs on dask.distributed: a "
        "local cluster of worker processes by default, or the cluster of --scheduler.\n\n"
        "Re-running the same command skips the videos whose results are finished and still "
        "match their input (size and modification time) and options. A video that cannot be "
        "analysed (corrupt, no face...) is recorded as failed and the others go on. Exit "
        "status: 0 when at least one video has results (failures are listed on stderr and in "
        "summary.csv), 1 when every video failed or the inputs are wrong.")
    parser.epilog = (
        "examples:\n"
        "  faceanalysis batch clips/ -o results\n"
        "  faceanalysis batch clips/ -o results --estimator tw93 --overlay\n"
        "  faceanalysis batch 'corpus/**/*.mp4' extra.avi -o results --workers 4\n"
        "  faceanalysis batch 'corpus/**/*.mp4' -o results --scheduler tcp://head:8786")
    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="video file, folder (its videos; a folder of images and no "
                             "video is one input, its images the frames) or quoted glob "
                             "pattern ('**' spans subfolders; folders of images it matches "
                             "are inputs too)")
    parser.add_argument("-o", "--output", required=True, metavar="OUT",
                        help="output root: one folder per video plus summary.csv")
    parser.add_argument("--overwrite", action="store_true",
                        help="re-analyse every video, replacing finished results")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=positive_int, metavar="N",
                       help="worker processes of the local cluster (default: all cores)")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="run on an existing Dask cluster; inputs and OUT must be "
                            "reachable at the same paths from its workers")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar, warnings and errors only")
    # the options of 'analyze', defined once there, applied to every video
    add_input_options(parser, positional=False)
    add_analysis_options(parser)
    parser.add_argument("--overlay", action="store_true",
                        help="also write overlay.mp4 for every video")


_ANALYSIS_OPTIONS = ("fps", "start", "end", "estimator", "neutral", "tracker", "layout",
                     "overlay", "refine", "personalize", "eyes", "temporal", "mirror_check",
                     "backend", "device")


def _options(args: argparse.Namespace) -> dict:
    options = {name: getattr(args, name) for name in _ANALYSIS_OPTIONS}
    if getattr(args, "keep_suspect_points", False):
        options["suspect_points"] = "keep"
    return options


def run(args: argparse.Namespace) -> int:
    from faceanalysis import batch

    check_analysis_options(args)
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be at least 1, got {args.workers}")
    verbose = getattr(args, "verbose", 0) > 0
    summary = batch.run_batch(args.inputs, args.output, workers=args.workers,
                              scheduler=args.scheduler, options=_options(args),
                              overwrite=args.overwrite, progress=progress_wanted(args),
                              silence_logs=False if verbose else logging.ERROR)
    failed = summary[summary["status"] != "ok"]
    for video, error in list(zip(failed["video"], failed["error"]))[:_SHOWN_FAILURES]:
        print(f"failed: {video}: {error}", file=sys.stderr)
    if len(failed) > _SHOWN_FAILURES:
        print(f"... and {len(failed) - _SHOWN_FAILURES} more failures", file=sys.stderr)
    ok = len(summary) - len(failed)
    skipped = int(summary["resumed"].sum())
    print(f"faceanalysis batch: {len(summary)} video(s): {ok} ok, {len(failed)} failed; "
          f"skipped {skipped} finished before", file=sys.stderr)
    print(summary.attrs["summary_path"])
    if ok == 0:
        print(f"faceanalysis: error: every video failed; see {summary.attrs['summary_path']}",
              file=sys.stderr)
        return 1
    return 0
