"""``faceanalysis models``: where the learned face models are, and installing them offline."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "show or install the face landmark models (MediaPipe's, from its PyPI wheel)"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "The landmark tracker runs MediaPipe's face detection, face mesh, palm detection "
        "and hand landmark models "
        "(Apache-2.0). They are taken from the pinned mediapipe wheel on PyPI, checked by "
        "sha256 and cached per user on first use. Without arguments: say where they are, "
        "downloading them if missing. With --wheel: install them from a local copy of the "
        "wheel (machines without network).")
    parser.epilog = (
        "examples:\n"
        "  faceanalysis models\n"
        "  pip download mediapipe==0.10.21 --no-deps --only-binary=:all: -d wheels/\n"
        "  faceanalysis models --wheel wheels/mediapipe-0.10.21-*.whl")
    parser.add_argument("--wheel", type=Path, metavar="WHEEL",
                        help="install the models from this local mediapipe wheel")
    parser.add_argument("--no-download", action="store_true",
                        help="only check the cache; fail instead of downloading")


def run(args: argparse.Namespace) -> int:
    from faceanalysis.errors import FaceAnalysisError
    from trackers.landmarks.models import (
        LICENSE_NAME,
        MEDIAPIPE_VERSION,
        ensure_models,
        model_dir,
    )

    try:
        paths = ensure_models(wheel=args.wheel, download=not args.no_download)
    except RuntimeError as exc:
        raise FaceAnalysisError(str(exc)) from None
    print(f"mediapipe {MEDIAPIPE_VERSION} face models in {model_dir()}")
    for name, path in paths.items():
        print(f"  {name}: {path}")
    print(f"  licence: {model_dir() / LICENSE_NAME}")
    return 0
