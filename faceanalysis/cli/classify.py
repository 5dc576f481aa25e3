"""``faceanalysis classify``: name the expression of a video by flow-template matching."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from faceanalysis.cli._common import add_quiet_option, non_negative_int, positive_float
from faceanalysis.cli._input import add_input_options

HELP = "name the expression (six primaries or neutral) of a video by flow templates"


def configure(parser: argparse.ArgumentParser) -> None:
    from faceanalysis.flow.options import FLOW_METHODS, REST_LOOKBACK

    parser.description = (
        "Track the face, compute its flow from the neutral frame on the canonical face grid "
        "and match it against the face model's expression templates (spatio-temporal motion "
        "from neutral to apex and its motion energy). Prints the expression of the sequence "
        "and, for a longer video, of each segment found by motion energy, with a score per "
        "class (happiness, sadness, surprise, fear, anger, disgust, neutral); segments whose "
        "motion matches no expression, and frames without a face, are listed as such.")
    parser.epilog = (
        "examples:\n"
        "  faceanalysis classify clip.mp4\n"
        "  faceanalysis classify clip.mp4 --start 250 --end 470\n"
        "  faceanalysis classify clip.mp4 --analysis results/ --json")
    add_input_options(parser)
    parser.add_argument("--analysis", type=Path, metavar="OUT",
                        help="reuse the head frames and fiducials of an analysis folder "
                             "instead of tracking again")
    parser.add_argument("--neutral", type=non_negative_int, metavar="FRAME",
                        help="neutral reference frame, which may precede --start (default: "
                             "the detected rest frame, the least contracted face of the "
                             "range and the --rest-lookback frames before it; the command "
                             "says which frame it used and whether it looks at rest)")
    parser.add_argument("--rest-lookback", type=non_negative_int, metavar="FRAMES",
                        help="frames before --start searched for the rest frame "
                             f"(default {REST_LOOKBACK})")
    parser.add_argument("--method", choices=FLOW_METHODS, default="dis",
                        help="optical flow (default dis)")
    parser.add_argument("--threshold", type=positive_float, metavar="E",
                        help="motion energy (RMS head units) of an expression "
                             "(default: the calibrated value)")
    parser.add_argument("--templates", type=Path, metavar="NPZ",
                        help="templates file written by 'faceanalysis templates' "
                             "(default: the generic face's)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument("-o", "--output", type=Path, metavar="CSV",
                        help="also write the segments table to this CSV file")
    add_quiet_option(parser)


def run(args: argparse.Namespace) -> int:
    from faceanalysis.flow.recognition import CLASSES, classify_video
    from faceanalysis.flow.templates import FlowTemplates
    from faceanalysis.io.outputs import ANALYSIS_JSON, CONTRACTIONS_CSV
    from faceanalysis.io.report import check_analysed_input, hidden_frames_of, read_analysis
    from faceanalysis.io.table import read_csv_table
    from faceanalysis.io.video import missing_input

    if not args.video.exists():
        raise missing_input(args.video)
    table = hidden = None
    if args.analysis is not None:
        csv = args.analysis / CONTRACTIONS_CSV
        if not csv.is_file():
            raise FileNotFoundError(f"{csv}: no contractions.csv in the analysis folder")
        table = read_csv_table(csv)
        meta = args.analysis / ANALYSIS_JSON
        if meta.is_file():
            recorded = read_analysis(meta)
            check_analysed_input(args.video, recorded.get("input"), analysis=args.analysis)
            hidden = hidden_frames_of(recorded)
    templates = FlowTemplates.load(args.templates) if args.templates is not None else None
    lookback = {} if args.rest_lookback is None else {"rest_lookback": args.rest_lookback}
    rec = classify_video(args.video, templates=templates, table=table, neutral=args.neutral,
                         method=args.method, fps=args.fps, start=args.start, end=args.end,
                         threshold=args.threshold, hidden=hidden, **lookback)
    if args.output is not None:
        from faceanalysis.io.outputs import write_text_atomic

        write_text_atomic(args.output, rec.table().to_csv(index=False, float_format="%.4f",
                                                          lineterminator="\n"))
    if args.json:
        print(json.dumps(rec.as_dict()))
        return 0
    print(rec.label)
    print(f"  neutral reference: frame {rec.reference} ({reference_reason(rec)})")
    print("  " + "  ".join(f"{c} {rec.scores.get(c, 0.0):.3f}" for c in CLASSES))
    for line in segment_lines(rec):
        print("  " + line)
    return 0


def segment_lines(rec) -> list[str]:
    """One line per segment of a :class:`~faceanalysis.flow.recognition.Recognition`, the
    unmatched ones and the runs of frames not classified included, in frame order."""
    def span(a, b, apex=None):
        if a == b:
            return f"frame {a}"
        return f"frames {a}-{b}" + ("" if apex is None else f" (apex {apex})")

    lines = []
    for s in rec.segments:
        lines.append((s.start, f"{span(s.start, s.end, s.apex)}: {s.label} "
                               f"({s.scores[s.label]:.3f})"))
    for s in rec.unmatched:
        near = max((c for c in s.scores if c != "neutral"), key=s.scores.get)
        lines.append((s.start, f"{span(s.start, s.end, s.apex)}: motion that matches no "
                               f"expression (nearest {near}, {s.scores[near]:.3f})"))
    for a, b in rec.lost_ranges():
        lines.append((a, f"{span(a, b)}: not classified (no face tracked, or the face "
                         f"hidden)"))
    return [text for _, text in sorted(lines, key=lambda x: x[0])]


def reference_reason(rec) -> str:
    """Why the reference frame of a :class:`~faceanalysis.flow.recognition.Recognition` was
    used, and how far it can be trusted, in words."""
    how = {"given": "given by --neutral",
           "detected": "detected rest frame: the least contracted face searched",
           "first": "first frame searched; no frame is clearly less contracted",
           "first_photograph": "the first photograph with a face, as analyze takes it"}
    text = how.get(rec.reference_source, str(rec.reference_source))
    doubt = {"still": "",
             "moving": "; the face does not hold still there (a lull in an expression, or "
                       "a face still relaxing), so it may not be at rest: the labels are "
                       "doubtful, pass --neutral FRAME or a larger --rest-lookback",
             "unresolved": "; tracking noise on this clip hides the difference between rest "
                           "and expression, so it may not be at rest: the labels are "
                           "doubtful, pass --neutral FRAME"}
    return text + doubt.get(rec.reference_rest, "")
