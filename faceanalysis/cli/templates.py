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
from faceanalysis.io.outputs import ANALYSIS_JSON, CONTRACTIONS_CSV

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
    import json

    import pandas as pd

    from faceanalysis.flow.templates import make_templates, personalize_from_table, write_templates
    from faceanalysis.io.outputs import prepare_output_dir

    if args.subject is not None:
        csv = args.subject / CONTRACTIONS_CSV if args.subject.is_dir() else args.subject
        if not csv.is_file():
            raise FileNotFoundError(f"{csv}: no contractions.csv for --subject")
    out = prepare_output_dir(args.output, overwrite=args.overwrite)
    from synth.model import FaceModel

    options = {"size": args.size, "n_steps": args.steps, "source": args.source}
    generic = make_templates(FaceModel.default(), **options)
    written = write_templates(generic, out, name="generic", previews=not args.no_previews)
    if args.subject is not None:
        from faceanalysis.evaluation.validation import _personal_model

        personal = _personal_model(csv.parent, FaceModel.default())
        if personal is not None:
            # the face model warped to the subject in 3-D
            # (faceanalysis.resynthesis.personalize.personalize)
            pers = make_templates(personal, **options)
            pers.meta.update(personalised=True, personalisation="model")
        else:
            table = pd.read_csv(csv)
            meta_path = csv.parent / ANALYSIS_JSON
            neutral = None
            if meta_path.is_file():
                neutral = json.loads(meta_path.read_text()).get("parameters", {}).get(
                    "neutral_frame")
            if neutral is None:
                ok = table["success"].to_numpy() == 1 if "success" in table else None
                if ok is None or not ok.any():
                    raise ValueError(f"{csv}: no tracked frame to personalise on")
                neutral = int(table["frame"].to_numpy()[ok.argmax()])
            pers = personalize_from_table(generic, table, int(neutral))
            if not pers.meta.get("personalised"):
                raise ValueError(f"{csv}: the neutral frame's fiducials are missing")
            pers.meta["personalisation"] = "warp"
        written.update({f"personalised_{k}": v for k, v in write_templates(
            pers, out, name="personalised", previews=not args.no_previews).items()})
    if args.identity is not None:
        from synth.face_shape import FaceShape

        model = FaceModel.build(FaceShape.random(args.identity))
        tpl = make_templates(model, texture_seed=args.identity, **options)
        tpl.meta["identity"] = int(args.identity)
        name = f"identity_{args.identity}"
        written.update({f"{name}_{k}": v for k, v in write_templates(
            tpl, out, name=name, previews=not args.no_previews).items()})
    if not args.quiet:
        print(f"{len(generic.controls)} control and {len(generic.expressions)} expression "
              f"templates on a {generic.grid.rows}x{generic.grid.cols} grid -> {out}",
              file=sys.stderr)
    for p in written.values():
        print(p)
    return 0
