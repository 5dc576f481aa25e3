"""Run a named benchmark: ``python benchmarks/run.py NAME [--quick]``; ``--list`` names them.

Prints a markdown table, then one JSON object per figure:
``{"benchmark", "case", "metric", "value", "unit", "higher_is_better"}`` plus
``"target"`` where an issue sets one and ``"peer"``/``"ratio"`` where a peer tool
was measured in the same run.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _harness import emit  # noqa: E402


def available() -> dict[str, str]:
    out = {}
    for path in sorted(HERE.glob("bench_*.py")):
        name = path.stem.removeprefix("bench_")
        doc = ""
        for line in path.read_text().splitlines():
            line = line.strip().strip('"').strip()
            if line:
                doc = line
                break
        out[name] = doc
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="benchmarks/run.py", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("name", nargs="?", help="benchmark to run")
    parser.add_argument("--list", action="store_true", help="name the benchmarks")
    parser.add_argument("--quick", action="store_true", help="smaller cases, fewer repeats")
    args = parser.parse_args(argv)
    names = available()
    if args.list or not args.name:
        for name, doc in names.items():
            print(f"{name:<12} {doc}")
        return 0 if args.list else 2
    if args.name not in names:
        print(f"run.py: error: no benchmark {args.name!r}; choose from {', '.join(names)}",
              file=sys.stderr)
        return 2
    module = importlib.import_module(f"bench_{args.name}")
    figures = module.run(quick=args.quick)
    emit(args.name, figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
