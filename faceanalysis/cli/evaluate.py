"""``faceanalysis evaluate``: score an analysis against synthetic ground truth."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from faceanalysis.cli._common import add_quiet_option, positive_int, progress_wanted

HELP = "compare an analysis with ground truth, or run the standard synthetic suite"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Closed-loop evaluation. With --truth and --estimate: compare one analysis with the "
        "ground truth of the synthetic sequence it analysed (per-muscle RMSE and Pearson r, "
        "jaw error in degrees, fiducial error in pixels), printed as a table and JSON. With "
        "--suite standard -o OUT: render the standard suite (six expressions and mixed action "
        "units over several identities, with head motion, noise and illumination change), "
        "analyse it with every estimator and write report.json, report.md and report.png. With "
        "--suite ceiling: score the fiducial estimators on perfect measurements of the "
        "suite's faces (no rendering, no tracking): the best any tracker of these points "
        "can reach.")
    parser.epilog = (
        "examples:\n"
        "  faceanalysis synth --expression surprise -o seq/ && "
        "faceanalysis analyze seq/video.mp4 -o res/\n"
        "  faceanalysis evaluate --truth seq/ --estimate res/\n"
        "  faceanalysis evaluate --suite standard -o suite/ --identities 10\n"
        "  faceanalysis evaluate --suite standard --faces photos/ --tracker landmarks "
        "-o suite/\n"
        "  faceanalysis evaluate --suite ceiling --identities 10")
    parser.add_argument("--truth", type=Path, metavar="DIR",
                        help="folder of a synthetic sequence (truth.csv)")
    parser.add_argument("--estimate", type=Path, metavar="DIR",
                        help="analysis folder (contractions.csv)")
    parser.add_argument("--allow-partial", action="store_true",
                        help="score the frames truth and estimate share even when they hold "
                             "different frames (an analysis of a subrange) or their folders "
                             "name different inputs (refused by default)")
    parser.add_argument("--suite", choices=["standard", "ceiling"],
                        help="run a whole suite: 'standard' renders and analyses it; "
                             "'ceiling' estimates from its exact measurement points")
    parser.add_argument("--own-response", action="store_true",
                        help="with --suite ceiling: invert each face's own response table "
                             "(about 10 s per identity) instead of the generic face's")
    parser.add_argument("--mesh", action="store_true",
                        help="with --suite ceiling: also the mesh estimator, on the exact "
                             "skin points under the face-mesh landmarks (needs the landmark "
                             "model)")
    parser.add_argument("--model", action="store_true",
                        help="with --suite ceiling: also the model estimator (the mesh fit, "
                             "then through the generic face model's own equilibrium; each "
                             "face's own with --own-response; about 0.1 s a frame)")
    parser.add_argument("--personalize", action="store_true",
                        help="with --suite ceiling --model: through the generic face warped "
                             "onto each sequence's neutral frame (not with --own-response)")
    parser.add_argument("-o", "--output", type=Path, metavar="OUT",
                        help="output folder of the suite")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the results already in OUT")
    parser.add_argument("--identities", type=positive_int, default=10,
                        help="identities in the suite (default 10)")
    parser.add_argument("--frames", type=positive_int, default=30,
                        help="frames per sequence (default 30)")
    parser.add_argument("--faces", type=Path, metavar="DIR",
                        help="with --suite standard: also render the suite on the people in "
                             "a folder of frontal, neutral photographs (one per person) and "
                             "report that photo suite beside the procedural one")
    parser.add_argument("--tracker", choices=("snakes", "landmarks"), default=None,
                        help="with --suite standard: the tracker of the analyses (default "
                             "snakes: the method of 004, on the faces drawn for it; landmarks: "
                             "as `analyze` runs by default)")
    parser.add_argument("--json", action="store_true", help="print only JSON")
    add_quiet_option(parser)


def run(args: argparse.Namespace) -> int:
    from faceanalysis.evaluation import scores, suite
    from faceanalysis.io.outputs import REPORT_MD

    if args.suite and (args.truth or args.estimate):
        raise ValueError("--suite runs its own sequences; do not combine it with "
                         "--truth/--estimate")
    if args.suite and args.allow_partial:
        raise ValueError("--allow-partial goes with --truth/--estimate")
    if (args.faces or args.tracker) and args.suite != "standard":
        raise ValueError("--faces and --tracker go with --suite standard")
    if args.suite == "ceiling":
        from faceanalysis.evaluation.ceiling import measurement_ceiling

        if args.output is not None:
            raise ValueError("--suite ceiling writes nothing; it prints its table "
                             "(use --json for JSON)")
        if args.personalize and (not args.model or args.own_response):
            raise ValueError("--personalize goes with --model and without --own-response")
        config = suite.SuiteConfig(identities=args.identities, frames=args.frames)
        reports = measurement_ceiling(
            config, own_response=args.own_response, personalize=args.personalize,
            progress=progress_wanted(args),
            estimators=("joint", *(("mesh",) if args.mesh else ()),
                        *(("model",) if args.model else ()), "tw93"))
        if not args.json:
            print(scores.format_table(reports))
        print(json.dumps(reports))
        return 0
    ceiling_only = [f for f, on in (("--own-response", args.own_response),
                                    ("--mesh", args.mesh), ("--model", args.model),
                                    ("--personalize", args.personalize)) if on]
    if ceiling_only:
        raise ValueError(f"{ceiling_only[0]} goes with --suite ceiling")
    if args.suite:
        if args.output is None:
            raise ValueError("--suite needs -o OUT")
        faces = suite.photographs(args.faces) if args.faces else ()
        config = suite.SuiteConfig(identities=args.identities, frames=args.frames,
                                   faces=faces, tracker=args.tracker or "snakes")
        from faceanalysis.estimation.names import MESH_ESTIMATORS

        # those read the landmark tracker's face mesh
        estimators = (("joint", *MESH_ESTIMATORS, "tw93", "flow") if args.tracker == "landmarks"
                      else ("joint", "tw93", "flow"))
        report = suite.run_suite(args.output, config=config, overwrite=args.overwrite,
                                 estimators=estimators, progress=progress_wanted(args))
        if args.json:
            print(json.dumps(report["estimators"]))
        else:
            print((args.output / REPORT_MD).read_text())
            print(f"report: {args.output / 'report.json'}", file=sys.stderr)
        return 0
    if args.truth is None or args.estimate is None:
        raise ValueError("give --truth DIR and --estimate DIR, or --suite standard -o OUT")
    report = scores.evaluate(args.truth, args.estimate, allow_partial=args.allow_partial)
    if not args.json:
        print(scores.format_table({"estimate": report}))
    print(json.dumps(report))
    return 0
