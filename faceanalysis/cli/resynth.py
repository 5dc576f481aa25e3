"""``faceanalysis resynth``: drive the face model with a contraction time series and render it."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from faceanalysis.cli._common import add_quiet_option, positive_float, progress_wanted

HELP = "render the face model driven by a contraction time series (resynthesis)"


def _size(text: str):
    try:
        if "x" in text.lower():
            w, h = (int(v) for v in text.lower().split("x"))
            return (w, h)
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must be WIDTH or WIDTHxHEIGHT, got {text!r}") \
            from None


def configure(parser: argparse.ArgumentParser) -> None:
    from faceanalysis.resynthesis.options import MESH_FORMATS, SHADINGS, VIEWS

    parser.description = (
        "Drive the physics-based face model with a contraction time series (the muscle "
        "columns and jaw_rotation of contractions.csv; missing muscles stay relaxed), reach "
        "equilibrium every frame and render it at the source frame rate (004, Fig. 7c). "
        "Frames the analysis lost (success 0) hold the last good contractions. In the front "
        "view the model follows the tracked head frame of the input. With --subject the "
        "model is first warped onto the subject's neutral frame (landmark-driven warp of the "
        "whole model, Kähler ch. 8) and textured with it; its landmark and photometric "
        "agreement with the neutral frame is added to the analysis.json of the subject (or of "
        "CONTRACTIONS when the subject is the video it analysed; key 'resynthesis') and "
        "written beside the video (OUT.json). The report also compares, frame by frame, the "
        "resynthesised fiducials with the analysis's tracked ones (output pixels; the "
        "command prints their mean, median and maximum) and, when the analysed video is at "
        "hand, the agreement of the resynthesis's face flow with the video's, as "
        "'faceanalysis validate' measures it (mean cosine over the frames that move).")
    parser.epilog = (
        "examples:\n"
        "  faceanalysis analyze clip.mp4 -o results/\n"
        "  faceanalysis resynth results/contractions.csv -o resynth.mp4\n"
        "  faceanalysis resynth results/ -o resynth.mp4 --subject results/ --side-by-side\n"
        "  faceanalysis resynth results/ -o wire.mp4 --shading wireframe --view three-quarter\n"
        "  faceanalysis resynth results/ -o resynth.mp4 --export-meshes meshes/")
    parser.add_argument("contractions", type=Path, metavar="CONTRACTIONS",
                        help="contractions.csv, or an analysis folder holding one")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="VIDEO",
                        help="output video (.mp4; .avi if no mp4 encoder)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    parser.add_argument("--size", type=_size, metavar="W[xH]",
                        help="frame width (height follows the input's aspect), or WxH "
                             "(default: the input's size in the front view, else 256)")
    parser.add_argument("--view", choices=list(VIEWS), default="front",
                        help="camera view (default front)")
    parser.add_argument("--shading", choices=SHADINGS, default="textured",
                        help="textured skin, plain skin, or wireframe with the muscles drawn "
                             "(default textured)")
    parser.add_argument("--fps", type=positive_float, metavar="FPS",
                        help="output frame rate (default: the source's)")
    parser.add_argument("--subject", type=Path, metavar="VIDEO_OR_ANALYSIS_DIR",
                        help="personalise the model to this subject's neutral frame")
    parser.add_argument("--side-by-side", action="store_true",
                        help="input and resynthesis side by side, contraction plot below")
    parser.add_argument("--input", type=Path, metavar="VIDEO",
                        help="the input video for --side-by-side (default: the subject's, or "
                             "the one analysis.json names)")
    parser.add_argument("--export-meshes", type=Path, metavar="DIR_OR_NPZ",
                        help="write one mesh per frame into DIR, or all vertex trajectories "
                             "into one .npz file")
    parser.add_argument("--mesh-format", choices=MESH_FORMATS, default="obj",
                        help="per-frame mesh format (default obj)")
    parser.add_argument("--no-flow-check", action="store_true",
                        help="do not compare the resynthesis's face flow with the input "
                             "video's (the check measures the video's flow once more)")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    add_quiet_option(parser)


def run(args: argparse.Namespace) -> int:
    from faceanalysis.resynthesis.pipeline import resynthesize

    res = resynthesize(args.contractions, subject=args.subject, size=args.size, view=args.view,
                       shading=args.shading, fps=args.fps, side_by_side=args.side_by_side,
                       output=args.output, export_meshes=args.export_meshes,
                       mesh_format=args.mesh_format, input_video=args.input,
                       overwrite=args.overwrite, progress=progress_wanted(args),
                       check_flow=not args.no_flow_check)
    if args.json:
        print(json.dumps(json.loads(res.report_path.read_text())))
        return 0
    timing = res.report.get("timing", {})
    line = f"{len(res)} frames at {res.fps:g} fps -> {res.path}"
    if timing.get("frames_per_second"):
        line += f" ({timing['frames_per_second']:.0f} frames/s)"
    print(line)
    # figures that can fail; the personalisation's own (zero by construction on the
    # neutral frame) stay in the report
    f = res.report.get("fiducial_agreement")
    if f and "skipped" in f:
        print(f"fiducials vs tracked: not compared ({f['skipped']})")
    elif f:
        print(f"fiducials vs tracked: {f['mean_px']:.2f} px mean, {f['median_px']:.2f} median, "
              f"{f['max_px']:.2f} max (frame {f['worst_frame']}) over {f['frames']} frames"
              + ("" if args.subject is not None else
                 " (the generic face's features, not the subject's: --subject personalises it)"))
    a = res.report.get("flow_agreement")
    if a and "skipped" in a:
        print(f"flow vs input: not measured ({a['skipped']})")
    elif a and a.get("active_frames"):
        line = (f"flow vs input: {a['mean_cosine']:.2f} mean cosine over {a['active_frames']} "
                f"active frames of {a['frames']}")
        if a.get("mean_epe_px") is not None:
            line += f", {a['mean_epe_px']:.2f} px mean end-point error"
        print(line)
    elif a:
        print(f"flow vs input: no active frame among {a['frames']} (nothing moves)")
    c = res.report.get("frame_comparison")
    if c:
        print(f"input vs resynthesis: {c['mean_mae_grey']:.2f} grey levels mean absolute "
              f"difference on the face over {c['frames']} frames")
    if not args.quiet:
        print(f"report -> {res.report_path}", file=sys.stderr)
    return 0
