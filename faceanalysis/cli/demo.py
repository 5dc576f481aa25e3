"""``faceanalysis demo``: the whole loop on a synthetic face, no data needed."""

from __future__ import annotations

import argparse
from pathlib import Path

from faceanalysis.cli._common import (
    add_quiet_option,
    non_negative_int,
    positive_int,
    progress_wanted,
)

HELP = "render a synthetic expression, analyse it and compare with the truth"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Render an expression on a synthetic face with the physics-based model, analyse the "
        "video as a user's video would be analysed, and compare the estimated contractions "
        "with the ones that made it. Prints where the results are.")
    parser.epilog = ("examples:\n  faceanalysis demo -o demo_out\n"
                     "  faceanalysis demo -o demo_out --expression happiness --overwrite")
    parser.add_argument("-o", "--output", type=Path, default=Path("demo_out"), metavar="OUT",
                        help="output folder (default: demo_out)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the results already in OUT")
    parser.add_argument("--expression", default="surprise",
                        help="happiness, sadness, surprise, fear, anger or disgust "
                             "(default: surprise)")
    parser.add_argument("--frames", type=positive_int, default=48, help="frames (default 48)")
    parser.add_argument("--seed", type=non_negative_int, default=7,
                        help="identity seed (default 7)")
    add_quiet_option(parser)


def run(args: argparse.Namespace) -> int:
    from faceanalysis.evaluation.demo import run_demo

    files = run_demo(args.output, expression=args.expression, frames=args.frames,
                     seed=args.seed, overwrite=args.overwrite, progress=progress_wanted(args))
    report = files.pop("_report")
    print(f"demo: {args.expression} on synthetic identity {args.seed}, "
          f"{report['frames_compared']}/{report['frames']} frames tracked")
    snakes = report.get("snakes")
    for label, r in (("landmark tracker + mesh fit (the default)", report),
                     ("snakes of 004 + joint fit (--tracker snakes)", snakes)):
        if r is not None:
            print(f"  {label}: mean fiducial error {r['fiducial_error_px']:.2f} px, jaw error "
                  f"{r['jaw_rmse_deg']:.2f} deg, median muscle RMSE "
                  f"{r['identifiable_median_rmse']:.3f}")
    if snakes is not None:
        print("  (rendered faces are drawn for the snakes; on real faces they slide off "
              "features the landmark tracker holds)")
    for name, path in files.items():
        print(f"  {name:<13} {path}")
    return 0
