"""``python -m benchmarks SUITE [options]``: see docs/benchmark.md and docs/experiments.md."""
from __future__ import annotations

import argparse
import sys

from . import data
from .suites import SUITES, load


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description="torchfill's benchmarks: real gap masks scored by marker error, verdicts and "
                    "joint angles, peers in the same table; every docs table regenerated.")
    ap.add_argument("--data", help="folder of the recordings (default $TORCHFILL_DATA or "
                                   "shared/data beside the checkout)")
    sub = ap.add_subparsers(dest="suite", metavar="SUITE", required=True)
    for name in SUITES:
        mod = load(name)
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    data.set_folder(args.data)
    return load(args.suite).main(args) or 0


if __name__ == "__main__":
    sys.exit(main())
