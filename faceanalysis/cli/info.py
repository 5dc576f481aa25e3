"""``faceanalysis info``: versions of the toolkit and of the libraries it runs on."""

from __future__ import annotations

import argparse
import importlib
import json
import platform

HELP = "print the versions of the toolkit and its dependencies"

_LIBRARIES = ["numpy", "scipy", "cv2", "skimage", "pandas", "matplotlib", "numba", "dask",
              "distributed", "torch", "kornia"]


def versions() -> dict[str, str | None]:
    """Version of the toolkit, Python and every library it can use (None if absent)."""
    from faceanalysis import __version__

    out: dict[str, str | None] = {"faceanalysis": __version__, "python": platform.python_version()}
    for name in _LIBRARIES:
        try:
            module = importlib.import_module(name)
        except ImportError:
            out[name] = None
        else:
            out[name] = getattr(module, "__version__", "unknown")
    return out


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = "Print the versions of the toolkit and of the libraries it uses."
    parser.epilog = "example:\n  faceanalysis info --json"
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    info = versions()
    if args.json:
        print(json.dumps(info))
    else:
        width = max(map(len, info))
        for name, version in info.items():
            print(f"{name:<{width}}  {version if version is not None else '-'}")
    return 0
