"""``faceanalysis probe``: what the analysis will see in a video, before running it."""

from __future__ import annotations

import argparse
import json

from faceanalysis.cli._input import add_input_options, open_input

HELP = "describe a video or image folder: size, frame rate, frames, decodable frames"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Describe the input as the analysis reads it: kind, size, pixel type, frame rate "
        "and its origin, frames announced by the container. With --decode, every frame of "
        "the range is decoded, the undecodable ones are counted and the shots are found "
        "(a cut: the whole picture changes at once, an edit; analyse each shot on its own "
        "with --start/--end). With --face, the first frame with a face is looked for "
        "(within 250 frames) as the landmark tracker finds it, with its size between the "
        "eyes and the detector that found it. Memory stays flat.")
    parser.epilog = ("examples:\n  faceanalysis probe clip.mp4\n"
                     "  faceanalysis probe wide_shot.mp4 --face\n"
                     "  faceanalysis probe frames/ --fps 25 --decode --json")
    add_input_options(parser)
    parser.add_argument("--decode", action="store_true",
                        help="decode every frame of the range, count the lost ones and list "
                             "the shots")
    parser.add_argument("--face", action="store_true",
                        help="find the first frame with a face: where, how large (pixels "
                             "between the eyes), which detector, and every face on it "
                             "(analyze follows the largest; --face X,Y there picks another) "
                             "(needs the face models)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    from faceanalysis.io.cuts import frame_changes, shot_cuts
    from faceanalysis.io.report import input_metadata

    with open_input(args, any_size=True) as source:
        info = input_metadata(source)
        info["n_frames"] = source.n_frames
        if args.decode:
            decoded = lost = 0
            numbers, changes = [], []
            for frame, change in frame_changes(source):
                decoded += frame.ok
                lost += not frame.ok
                numbers.append(frame.index)
                changes.append(change)
            cuts = shot_cuts(changes, numbers)
            starts = numbers[:1] + cuts
            ends = [c - 1 for c in cuts] + numbers[-1:]
            info.update(frames_decoded=decoded, frames_lost_mid_stream=lost,
                        frames_undecodable=source.n_failed, missing_tail=source.missing_tail,
                        shot_cuts=cuts, shots=[[a, b] for a, b in zip(starts, ends)])
        else:
            for key in ("frames_undecodable", "missing_tail"):
                info.pop(key, None)
    if args.face:
        from faceanalysis.analysis.pipeline import SMALL_FACE_IOD
        from faceanalysis.tracking import find_face

        face = find_face(args.video, fps=args.fps, start=args.start, end=args.end) or {}
        info.update(first_face=face.get("frame"), interocular_px=face.get("interocular_px"),
                    face_box=face.get("box"), face_detector=face.get("detector"),
                    faces=face.get("faces"),
                    face_small=(None if not face
                                else face["interocular_px"] < SMALL_FACE_IOD))
    if args.json:
        print(json.dumps(info))
    else:
        width = max(map(len, info))
        for key, value in info.items():
            print(f"{key:<{width}}  {value if value is not None else '-'}")
    return 0
