"""``faceanalysis validate``: flow agreement between a video and its analysis's resynthesis."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from faceanalysis.cli._common import add_quiet_option, positive_float

HELP = "compare the optical flow of a video with that of its analysis's resynthesis"


def configure(parser: argparse.ArgumentParser) -> None:
    from faceanalysis.flow.options import FLOW_METHODS

    parser.description = (
        "Compute the face flow of VIDEO (from its neutral frame, in the head frame, on the "
        "canonical face grid), render the flow of the face model driven by the analysed "
        "contractions (personalised to the subject's neutral fiducials), and report their "
        "agreement per frame and per face region: cosine similarity and end-point error on "
        "the face mask. Writes validation.csv and validation.png into the analysis folder "
        "and adds the summary to its analysis.json (key 'validation').")
    parser.epilog = (
        "examples:\n"
        "  faceanalysis analyze clip.mp4 -o results/\n"
        "  faceanalysis validate clip.mp4 --analysis results/\n"
        "  faceanalysis validate clip.mp4 --analysis results/ --method tvl1 --json")
    parser.add_argument("video", type=Path, metavar="VIDEO", help="the analysed video")
    parser.add_argument("--analysis", type=Path, required=True, metavar="OUT",
                        help="the analysis output folder (contractions.csv, analysis.json)")
    parser.add_argument("--method", choices=FLOW_METHODS, default="dis",
                        help="optical flow of the input (default dis)")
    parser.add_argument("--generic", action="store_true",
                        help="compare with the generic face's resynthesis (no personalisation)")
    parser.add_argument("--fps", type=positive_float, metavar="FPS",
                        help="frame rate, as given to analyze")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_quiet_option(parser)


def run(args: argparse.Namespace) -> int:
    from faceanalysis.evaluation.validation import validate
    from faceanalysis.io.video import missing_input

    if not args.video.exists():
        raise missing_input(args.video)
    if not args.analysis.is_dir():
        raise FileNotFoundError(f"{args.analysis}: no such analysis folder")
    res = validate(args.video, args.analysis, method=args.method,
                   personalised=not args.generic, fps=args.fps)
    s = res.summary
    if args.json:
        print(json.dumps(s))
        return 0
    mc, me = s["mean_cosine"], s["mean_epe"]
    print(f"flow agreement ({s['active_frames']} active of {s['frames']} frames): "
          f"mean cosine {'-' if mc is None else f'{mc:.3f}'}, "
          f"mean end-point error {'-' if me is None else f'{me:.4f}'} head units")
    for name, r in s["regions"].items():
        c = r["mean_cosine"]
        print(f"  {name:<9} cosine {'-' if c is None else f'{c:6.3f}'}")
    if not args.quiet:
        print(f"-> {res.paths.get('table')}, {res.paths.get('plot')}", file=sys.stderr)
    return 0
