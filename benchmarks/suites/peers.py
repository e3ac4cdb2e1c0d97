"""The peers on the real-gap benchmark's cases: ``--list`` says which import here (each is
installed by the ``peers`` extra); otherwise every available peer (or ``--methods``) and the
default fill the cases, into the real-gap rows, so the tables show them side by side::

    python -m benchmarks peers --list
    OMP_NUM_THREADS=1 python -m benchmarks peers --quick
"""
from __future__ import annotations

from .. import methods
from ..peers import PEERS
from . import real_gaps

HELP = "the other tools (gapfill, Kinetics Toolkit, scikit-learn, Pose2Sim, PyPOTS) on the cases"


def add_arguments(p) -> None:
    real_gaps.add_arguments(p)
    p.set_defaults(methods="default,peers")


def main(args) -> int:
    if args.list:
        for name, (what, module, _) in PEERS.items():
            ok = "installed" if methods.available(f"peer:{name}") else f"missing ({module})"
            print(f"peer:{name:18s} {what}: {ok}")
        return 0
    return real_gaps.main(args)
