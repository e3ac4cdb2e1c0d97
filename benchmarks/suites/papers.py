"""The papers' tables through the Lightning runner: ``torchfill experiment CONFIG`` for each
config in experiments/ (docs/experiments.md lists them and the pages they feed), then the
tables copied into the pages (``python -m benchmarks docs``)::

    python -m benchmarks papers --list
    OMP_NUM_THREADS=1 python -m benchmarks papers tucker_table2 cp_tables --resume
"""
from __future__ import annotations

import subprocess
import sys

from .. import data

HELP = "the papers' tables through the Lightning runner (torchfill experiment CONFIG)"
CONFIGS = data.REPO / "experiments"


def add_arguments(p) -> None:
    p.add_argument("configs", nargs="*", help="config names (experiments/NAME.yaml); "
                                              "default: all but smoke")
    p.add_argument("--list", action="store_true", help="list the configs and stop")
    p.add_argument("--resume", action="store_true", help="skip the cases already in cases.csv")
    p.add_argument("--workers", type=int, default=1, help="processes side by side")


def main(args) -> int:
    names = args.configs or [p.stem for p in sorted(CONFIGS.glob("*.yaml")) if p.stem != "smoke"]
    missing = [n for n in names if not (CONFIGS / f"{n}.yaml").is_file()]
    if missing:
        raise SystemExit(f"papers: no experiments/{missing[0]}.yaml")
    if args.list:
        print("\n".join(names))
        return 0
    for name in names:
        cmd = [sys.executable, "-m", "torchfill", "experiment", str(CONFIGS / f"{name}.yaml"),
               "--workers", str(args.workers)] + (["--resume"] if args.resume else [])
        print(f"== {name}: {' '.join(cmd[1:])}", flush=True)
        code = subprocess.run(cmd, cwd=data.REPO).returncode
        if code:
            return code
    from .docs import main as docs

    return docs(type("Args", (), {"check": False})())
