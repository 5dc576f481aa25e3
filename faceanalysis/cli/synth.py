"""``faceanalysis synth``: render a synthetic face video with exact ground truth."""

from __future__ import annotations

import argparse
import logging
import re

from faceanalysis.cli._common import add_output_options, add_quiet_option, progress_wanted

HELP = "render a synthetic face video (expression, AU script or contractions) with ground truth"

log = logging.getLogger(__name__)


def _size(text: str):
    m = re.fullmatch(r"\s*(\d+)\s*(?:[xX]\s*(\d+))?\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"size {text!r} is not N or WxH (e.g. 256, 640x480)")
    w = int(m.group(1))
    h = int(m.group(2)) if m.group(2) else w
    if w < 16 or h < 16 or w > 8192 or h > 8192:
        raise argparse.ArgumentTypeError(f"size {text!r} must be between 16 and 8192 px")
    return w if not m.group(2) else (w, h)


def _au_script(text: str) -> str:
    """argparse type: an AU script of known action units with intensities in [0, 1]."""
    from synth.facs import ACTION_UNITS
    from synth.render.sequence import parse_au_string

    try:
        aus = parse_au_string(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    unknown = sorted(set(aus) - set(ACTION_UNITS))
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown action unit(s) {unknown}; known: "
                                         f"{sorted(ACTION_UNITS)}")
    return text


def _expression(text: str) -> str:
    """argparse type: one of the primary expressions."""
    from synth.facs import EXPRESSIONS

    if text not in EXPRESSIONS:
        raise argparse.ArgumentTypeError(f"unknown expression {text!r}; choose from "
                                         f"{', '.join(sorted(EXPRESSIONS))}")
    return text


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Drive the physics-based face model with known contractions, render the frames "
        "headlessly and write OUT/video.mp4 (or .avi when the mp4 codec is missing), "
        "OUT/truth.csv (contractions, jaw, head frame and the 11 fiducials per frame, in "
        "the columns of contractions.csv), OUT/flow.npz (exact dense forward flow with "
        "occlusion masks, face masks, depth) and OUT/meta.json (camera, identity, seed, "
        "versions). With --face PHOTO the face is a real person's: the model is fitted to "
        "a frontal, neutral photograph (the landmark model finds the face) and textured "
        "with it, so the rest frame is the photograph and the script moves their own skin; "
        "--size then frames the face like the procedural ones (default: the photograph's "
        "own size and framing).")
    parser.epilog = ("examples:\n"
                     "  faceanalysis synth --expression surprise --frames 60 --size 256 "
                     "--seed 3 -o out/surprise\n"
                     "  faceanalysis synth --au 12:0.8,6:0.5 --head-motion --noise -o out/smile\n"
                     "  faceanalysis synth --contractions contractions.csv -o out/resynth\n"
                     "  faceanalysis synth --face me.jpg --expression happiness -o out/me")
    src = parser.add_mutually_exclusive_group()
    src.add_argument("--expression", type=_expression, metavar="NAME",
                     help="primary expression (happiness, sadness, surprise, fear, anger, "
                          "disgust) with onset-apex-offset timing")
    src.add_argument("--au", type=_au_script, metavar="SCRIPT",
                     help="action units and intensities in [0, 1], e.g. '12:0.8,6:0.5'")
    src.add_argument("--contractions", metavar="CSV",
                     help="a contractions.csv (muscle columns, jaw_rotation); one frame per row")
    parser.add_argument("--frames", type=int, default=None,
                        help="number of frames (default 60; a CSV gives its own)")
    parser.add_argument("--fps", type=float, default=30.0, help="frame rate (default 30)")
    parser.add_argument("--face", metavar="PHOTO",
                        help="a frontal, neutral photograph of a real face to animate "
                             "instead of a procedural face")
    parser.add_argument("--size", type=_size, default=None, metavar="N|WxH",
                        help="image size in px (default 256; with --face the photograph's)")
    parser.add_argument("--seed", type=int, default=0,
                        help="identity (face shape, texture) and random motion/noise seed")
    parser.add_argument("--intensity", type=float, default=1.0,
                        help="multiplier of the expression/AU intensities (0..2, default 1)")
    parser.add_argument("--head-motion", type=float, nargs="?", const=1.0, default=0.0,
                        metavar="AMPLITUDE",
                        help="smooth head motion (translation, roll, yaw, pitch); amplitude "
                             "1 = ~0.6 cm and ~4 degrees")
    parser.add_argument("--in-plane-only", action="store_true",
                        help="head motion without yaw/pitch")
    parser.add_argument("--illumination", type=float, nargs="?", const=1.0, default=0.0,
                        metavar="AMPLITUDE", help="slowly changing light (1 = ~15 degrees, 10%%)")
    parser.add_argument("--noise", type=float, nargs="?", const=2.0, default=0.0,
                        metavar="STD", help="Gaussian sensor noise, grey levels (default 2 "
                                            "when given without a value)")
    parser.add_argument("--blur", type=float, default=0.0, metavar="SIGMA",
                        help="Gaussian blur in px")
    parser.add_argument("--camera", choices=("orthographic", "perspective"),
                        default="orthographic", help="projection (default orthographic)")
    parser.add_argument("--supersample", type=int, default=2,
                        help="anti-aliasing factor (default 2; 1 = off)")
    parser.add_argument("--grey", action="store_true", help="single-channel frames")
    parser.add_argument("--resolution", type=float, default=None,
                        help="face mesh resolution of the model (default: the model's own)")
    parser.add_argument("--flow-float16", action="store_true",
                        help="store the flow as float16 (half the size of flow.npz)")
    parser.add_argument("--no-flow", action="store_true",
                        help="skip the dense flow ground truth (masks and depth are kept)")
    add_output_options(parser)
    add_quiet_option(parser)


def run(args: argparse.Namespace) -> int:
    frames = args.frames if (args.frames is not None or args.contractions) else 60
    options = dict(
        overwrite=args.overwrite, flow_dtype="float16" if args.flow_float16 else "float32",
        expression=args.expression, au=args.au,
        contractions=args.contractions, frames=frames, fps=args.fps, size=args.size,
        seed=args.seed, head_motion=args.head_motion,
        out_of_plane=not args.in_plane_only, illumination=args.illumination,
        noise=args.noise, blur=args.blur, supersample=args.supersample, grey=args.grey,
        flow=not args.no_flow, intensity=args.intensity, progress=progress_wanted(args))
    if args.face is not None:
        from faceanalysis.resynthesis.photo import render_face

        if args.camera != "orthographic":
            raise ValueError("--face renders through the photograph's own orthographic "
                             "camera; --camera perspective is for procedural faces")
        if args.resolution is not None:
            raise ValueError("--resolution is for procedural faces; --face fits the "
                             "default model")
        out = render_face(args.face, args.output, **options)
    else:
        from synth.render.sequence import render_sequence

        out = render_sequence(args.output, camera=args.camera, resolution=args.resolution,
                              **options)
    if out.get("note"):
        log.warning("%s", out["note"])
    log.info("wrote %s, %s, %s, %s", out["video"], out["truth"], out["flow"], out["meta"])
    return 0
