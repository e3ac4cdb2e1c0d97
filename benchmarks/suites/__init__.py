"""The suites, in the order ``python -m benchmarks --help`` lists them. Each module has ``HELP``
(one line), ``add_arguments(parser)`` and ``main(args)``; ``doc_blocks()`` where its stored rows
feed a docs page (``python -m benchmarks docs``)."""
from __future__ import annotations

import argparse
import importlib

#: subcommand -> module under benchmarks.suites
SUITES = {"real-gaps": "real_gaps", "masks": "masks", "ik": "ik", "segments": "segments",
          "qc": "qc", "session": "session", "speed": "speed", "peers": "peers",
          "papers": "papers", "docs": "docs", "fuzz": "fuzz"}


def load(name: str):
    return importlib.import_module(f"benchmarks.suites.{SUITES[name]}")


def case_arguments(p: argparse.ArgumentParser, csv_default=None) -> None:
    """The options every case-based suite shares."""
    p.add_argument("--only", help="comma-separated substrings of case names to run")
    p.add_argument("--shard", default="0/1", metavar="I/N",
                   help="every N-th case from the I-th (processes side by side on one --csv "
                        "each; merge by running again on the merged rows)")
    p.add_argument("--list", action="store_true", help="list the cases and stop")
    p.add_argument("--csv", type=str, default=csv_default,
                   help=f"result rows (resumable: rows already there are skipped; '' : none; "
                        f"default {csv_default})")
    p.add_argument("--redo", action="store_true", help="recompute rows already in --csv")
