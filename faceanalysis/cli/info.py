"""``faceanalysis info``: versions of the toolkit and of the libraries it runs on."""

from __future__ import annotations

import argparse
import json

HELP = "print the versions of the toolkit and its dependencies"

def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = "Print the versions of the toolkit and of the libraries it uses."
    parser.epilog = "example:\n  faceanalysis info --json"
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    from faceanalysis.io.report import software_versions

    info = software_versions()
    if args.json:
        print(json.dumps(info))
    else:
        width = max(map(len, info))
        for name, version in info.items():
            print(f"{name:<{width}}  {version if version is not None else '-'}")
    return 0
