"""``faceanalysis analyze``: a face video in, muscle contractions out."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from faceanalysis.cli._common import (
    add_output_options,
    add_quiet_option,
    image_point,
    non_negative_float,
    non_negative_int,
    progress_wanted,
)
from faceanalysis.cli._input import add_input_options

HELP = "analyse a face video into muscle contractions (CSV, JSON, plot, overlay)"


def _neutral_frame(text: str) -> int | str:
    """argparse type of ``--neutral``: a frame number or ``auto``."""
    return "auto" if text == "auto" else non_negative_int(text)


def add_analysis_options(parser: argparse.ArgumentParser) -> None:
    """Options of the analysis itself (shared with ``batch``)."""
    from faceanalysis.estimation.names import ESTIMATOR_NAMES

    group = parser.add_argument_group("analysis")
    group.add_argument("--estimator", choices=ESTIMATOR_NAMES, default=None,
                       help="mesh: bounded least squares through the face model on the "
                            "contour points and the landmark tracker's face mesh (default "
                            "with the landmark tracker; implies --tracker landmarks); model: "
                            "mesh, then each frame fitted through the face model's own "
                            "equilibrium (about 0.1 s a frame); joint: "
                            "the same on the contours' points alone (default with --tracker "
                            "snakes, --layout or --refine); fused: mesh with the dense flow "
                            "in the same fit (reads the video twice); tw93: the paper's "
                            "per-muscle inversion of eq. 5; "
                            "flow: dense optical flow on the model's per-muscle flow templates")
    group.add_argument("--neutral", type=_neutral_frame, metavar="FRAME|auto",
                       help="frame showing the neutral face, for calibration "
                            "(default: the first tracked frame; with --tracker snakes, "
                            "the first that sees every point, waiting at most 1 s); auto: "
                            "the default unless it is coarsely coded, has the brows raised "
                            "or the mouth open or widened, else the nearest frame that is none "
                            "of these")
    group.add_argument("--tracker", choices=("landmarks", "snakes"),
                       help="landmarks (default): MediaPipe's face mesh finds the face on "
                            "every frame and holds the snakes; frames without a face are lost "
                            "(the model is downloaded on first use, see `faceanalysis "
                            "models`); snakes: the paper's Haar cascades and free snakes, no "
                            "model needed (the default with --layout)")
    group.add_argument("--layout", type=Path, metavar="JSON",
                       help="initial contours from a JSON file (FaceLayout.to_json) instead "
                            "of automatic placement")
    group.add_argument("--refine", action="store_true",
                       help="joint estimator: refine every frame through the face model itself "
                            "(more accurate where muscles interact, about ten times slower)")
    group.add_argument("--personalize", action="store_true",
                       help="model estimator: fit through the face model warped onto the "
                            "subject's neutral frame instead of the generic face")
    group.add_argument("--eyes", action="store_true",
                       help="trace the eyelids with MediaPipe's iris model (about 2.5 ms a "
                            "frame): eye_openness_l/_r columns and the blinks in "
                            "analysis.json; landmark tracker only")
    group.add_argument("--temporal", type=non_negative_float, metavar="WEIGHT",
                       help="joint, mesh, fused: weight of the prior that draws each frame's "
                            "contractions toward its neighbours' (default 0.01), so that "
                            "muscles the points barely tell apart do not trade places from "
                            "frame to frame; 0 fits every frame on its own (frames that are "
                            "not a sequence; the default for a folder of images given "
                            "without --fps, taken as photographs)")
    group.add_argument("--mirror-check", action="store_true",
                       help="analyse the video mirrored too and flag (0 in "
                            "<control>_identifiable) what does not come back on it: on a "
                            "video, controls whose series the mirrored partner's does not "
                            "follow (r < 0.5); on photographs, values the mirrored partner's "
                            "differ from; doubles the tracking time; not with --estimator "
                            "fused or flow, nor --layout")
    group.add_argument("--keep-suspect-points", action="store_true",
                       help="keep measurement points that the neutral frame puts far from "
                            "the calibrated face model (a contour on the wrong feature) in "
                            "the estimation; by default they are left out (and named in a "
                            "warning either way)")
    group.add_argument("--backend", choices=["numpy", "torch"], default="numpy",
                       help="snake relaxation: compiled NumPy (default) or batched torch "
                            "(needs the [torch] extra)")
    group.add_argument("--device", metavar="DEVICE",
                       help="torch device with --backend torch: cpu (default), cuda, cuda:N")


def check_analysis_options(args: argparse.Namespace) -> None:
    """Refuse option combinations the analysis cannot run, before any work (exit 2)."""
    from faceanalysis.cli._common import UsageError
    from faceanalysis.estimation.names import (
        MESH_ESTIMATORS,
        TEMPORAL_ESTIMATORS,
        VIDEO_ESTIMATORS,
    )

    if args.estimator in MESH_ESTIMATORS and args.tracker == "snakes":
        raise UsageError(f"--estimator {args.estimator} reads the landmark tracker's face "
                         "mesh; drop --tracker snakes")
    if args.refine and args.estimator not in (None, "joint"):
        raise UsageError(f"--refine goes with --estimator joint, not {args.estimator}")
    if getattr(args, "personalize", False) and args.estimator != "model":
        raise UsageError("--personalize goes with --estimator model, not "
                         f"{args.estimator or 'the default estimator'}")
    if getattr(args, "eyes", False) and (args.tracker == "snakes" or args.layout is not None):
        raise UsageError("--eyes goes with the landmark tracker; drop --tracker snakes and "
                         "--layout")
    if args.temporal is not None and args.estimator not in (None, *TEMPORAL_ESTIMATORS):
        raise UsageError(f"--temporal goes with --estimator {', '.join(TEMPORAL_ESTIMATORS)}, "
                         f"not {args.estimator}")
    if getattr(args, "mirror_check", False) and args.estimator in VIDEO_ESTIMATORS:
        raise UsageError(f"--mirror-check does not go with --estimator {args.estimator} (it "
                         "reads the video's frames again)")
    if getattr(args, "mirror_check", False) and args.layout is not None:
        raise UsageError("--mirror-check does not go with --layout (the layout places the "
                         "contours on the video as it is, not mirrored)")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Track the nine facial contours of Terzopoulos & Waters (1993) through a video, "
        "calibrate the face model on the neutral frame and estimate, per frame, the "
        "contraction of the facial muscles and the jaw rotation. Writes "
        "contractions.csv, analysis.json, contractions.png and, with --overlay, overlay.mp4.")
    parser.epilog = (
        "examples:\n"
        "  faceanalysis analyze clip.mp4 -o results/\n"
        "  faceanalysis analyze clip.mp4 -o results/ --overlay --start 100 --end 400\n"
        "  faceanalysis analyze clip.mp4 -o results/ --mirror-check\n"
        "  faceanalysis analyze interview.mp4 -o results/ --face 820,300\n"
        "  faceanalysis analyze frames/ --fps 25 -o results/ --estimator tw93 --overwrite")
    add_input_options(parser)
    add_output_options(parser)
    add_analysis_options(parser)
    parser.add_argument("--face", type=image_point, metavar="X,Y",
                        help="where the video shows several faces: a point (pixels) on or "
                             "near the one to analyse, on the first frame with a face "
                             "(default: the largest); landmark tracker only")
    parser.add_argument("--overlay", action="store_true",
                        help="also write overlay.mp4 with contours and fiducials drawn")
    add_quiet_option(parser)


def run(args: argparse.Namespace) -> int:
    from faceanalysis.analysis.pipeline import analyze_to_folder
    from faceanalysis.cli._common import UsageError
    from faceanalysis.io.outputs import CONTRACTIONS_CSV
    from faceanalysis.io.report import summary_line

    check_analysis_options(args)
    if args.face is not None and (args.tracker == "snakes" or args.layout is not None):
        raise UsageError("--face goes with the landmark tracker; drop --tracker snakes and "
                         "--layout")
    result = analyze_to_folder(
        args.video, args.output, overwrite=args.overwrite, overlay=args.overlay,
        quiet=not progress_wanted(args), estimator=args.estimator, fps=args.fps, start=args.start,
        end=args.end, neutral=args.neutral, tracker=args.tracker, layout=args.layout,
        refine=args.refine, personalize=args.personalize, eyes=args.eyes, face=args.face,
        temporal=args.temporal,
        mirror_check=args.mirror_check,
        backend=args.backend, device=args.device,
        suspect_points="keep" if args.keep_suspect_points else "exclude")
    print(f"{summary_line(result.metadata, len(result.table))} -> {args.output}",
          file=sys.stderr)
    print(args.output / CONTRACTIONS_CSV)
    return 0

