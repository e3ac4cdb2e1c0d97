"""Budget of ``auto``: its fill time against each default candidate alone on a ~3 000-frame recording.

HDM_bd_01-02_01_120 (2 900 frames x 41 markers), multi_gap 20 markers x 100 frames x up to 5 gaps,
seed 0. Median of ``--repeat`` runs each, all in the same process, ``uptime`` printed beside::

    OMP_NUM_THREADS=1 nice python scripts/bench_auto.py --repeat 3
"""
from __future__ import annotations

import argparse
import os
import subprocess
import time
import warnings
from pathlib import Path

import numpy as np

import torchfill
from torchfill import gaps
from torchfill.metrics import rmse
from torchfill.solvers import get_solver
from torchfill.data import data_dir

DATA = data_dir(Path(__file__).resolve().parents[1])   # $TORCHFILL_DATA or ../shared/data


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--frames", type=int, default=3000)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    P = torchfill.read(DATA / "HDM_bd_01-02_01_120.c3d").points[:args.frames]
    P = P[:, np.isfinite(P).all(axis=2).all(axis=0)]
    mask = gaps.multi_gap(*P.shape[:2], n_markers=20, gap_length=100, max_gaps=5, seed=0)
    X = np.where(mask[..., None], np.nan, P)
    candidates = get_solver("auto").candidate_names()
    times = {}
    for method in [*candidates, "auto"]:
        runs = []
        for _ in range(args.repeat):
            start = time.perf_counter()
            out = torchfill.fill(X, method=method)
            runs.append(time.perf_counter() - start)
        times[method] = float(np.median(runs))
        print(f"{method:<12} {times[method]:7.2f} s  rmse {rmse(out, P, mask):6.2f} mm", flush=True)
    slowest = max(times[m] for m in candidates)
    print(f"T={P.shape[0]} J={P.shape[1]}: auto / slowest candidate = {times['auto'] / slowest:.2f}, "
          f"auto / sum of candidates = {times['auto'] / sum(times[m] for m in candidates):.2f}")
    print("threads", os.environ.get("OMP_NUM_THREADS"), "|",
          subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())


if __name__ == "__main__":
    main()
