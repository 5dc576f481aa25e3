"""``faceanalysis templates``: optical-flow templates made by the face model."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from faceanalysis.cli._common import (
    add_output_options,
    add_quiet_option,
    non_negative_int,
    positive_int,
)

HELP = "make the face model's optical-flow templates (per muscle, per expression)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Render the face model and turn its own surface motion into optical-flow templates "
        "on the canonical face grid (Zhang et al., section 6): one per muscle (and the jaw), "
        "the image-plane motion per unit contraction from rest, and one per primary "
        "expression, the spatio-temporal motion from neutral to apex and its motion-energy "
        "map (Essa & Pentland). Writes generic.npz and preview PNGs (colour wheel: hue = "
        "direction, saturation = magnitude; arrows exaggerated). With --subject, also the "
        "templates of the model personalised to an analysed subject (personalised.npz: the "
        "model warped to the subject's neutral frame, or else the generic templates warped "
        "onto the subject's fiducials); with "
        "--identity, templates of a synthetic identity's own model (identity_SEED.npz).")
    parser.epilog = (
        "examples:\n"
        "  faceanalysis templates -o templates/\n"
        "  faceanalysis templates -o templates/ --subject results/ --overwrite\n"
        "  faceanalysis templates -o templates/ --identity 7 --source nodes")
    add_output_options(parser)
    parser.add_argument("--subject", type=Path, metavar="ANALYSIS",
                        help="analysis folder (contractions.csv) of a subject: also write "
                             "templates personalised to its neutral fiducials")
    parser.add_argument("--identity", type=non_negative_int, metavar="SEED",
                        help="also make templates with the model of synthetic identity SEED")
    parser.add_argument("--source", choices=("exact", "nodes"), default="exact",
                        help="exact: the renderer's exact flow (default); nodes: projected "
                             "node motion interpolated between vertices")
    parser.add_argument("--size", type=positive_int, default=256, metavar="PX",
                        help="render size of the model (default 256)")
    parser.add_argument("--steps", type=positive_int, default=6, metavar="N",
                        help="instants from neutral to apex in an expression template "
                             "(default 6)")
    parser.add_argument("--no-previews", action="store_true", help="write only the .npz files")
    add_quiet_option(parser)


def run(args: argparse.Namespace) -> int:
    from faceanalysis.resynthesis.templates import write_template_set

    written = write_template_set(args.output, subject=args.subject, identity=args.identity,
                                 size=args.size, n_steps=args.steps, source=args.source,
                                 previews=not args.no_previews, overwrite=args.overwrite)
    if not args.quiet:
        print(f"{len(written)} files -> {args.output}", file=sys.stderr)
    for p in written.values():
        print(p)
    return 0
