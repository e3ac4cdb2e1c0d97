"""Overhead of driving a solver with a Lightning Trainer vs a plain ``solver.fit()``.

For each method: one case (a short HDM05 recording, multi_gap 5 markers x 40 frames x 2 gaps, seed
0), timed as (a) ``solver.fit`` alone, (b) ``torchfill.lightning.fit`` without loggers, (c) with the
runner's callbacks and CSV logger. Prints the best of ``--repeat`` runs and the overhead per step.

    OMP_NUM_THREADS=1 .venv/bin/python scripts/bench_lightning.py [--repeat 3] [--methods linear svt]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from torchfill.data import data_dir
from torchfill.lightning import CaseDataModule, Evaluation, HistoryLogger, fit, load_recording
from torchfill.lightning.data import make_mask
from torchfill.solvers import available, get_solver

DATA = data_dir(Path(__file__).resolve().parents[1])


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--recording", default="hdm05_dg_06-03_03_120.c3d")
    parser.add_argument("--methods", nargs="*",
                        default=["linear", "svt", "tucker", "tucker_tnn", "cp", "grad_tucker"])
    args = parser.parse_args()
    rec = load_recording(DATA / args.recording)
    mask = make_mask("multi_gap", rec.shape, {"n_markers": 5, "gap_length": 40, "max_gaps": 2}, 0)
    X = torch.as_tensor(np.where(mask[..., None], np.nan, rec.truth))
    print(f"{rec.note()}; torch threads {torch.get_num_threads()}; best of {args.repeat}")
    print(f"{'method':<12} {'iters':>5} {'plain s':>8} {'trainer s':>9} {'+log s':>8} "
          f"{'ms/step':>8} {'ratio':>6}")
    from pytorch_lightning.loggers import CSVLogger

    for method in [m for m in args.methods if m in available()]:
        plain, bare, logged, n = [], [], [], 0
        for _ in range(args.repeat):
            solver = get_solver(method)
            t = time.perf_counter()
            solver.fit(X, torch.as_tensor(mask))
            plain.append(time.perf_counter() - t)
            n = solver.n_iter_
            solver = get_solver(method)
            t = time.perf_counter()
            fit(solver, CaseDataModule(rec.truth, mask, n_steps=solver.max_iter))
            bare.append(time.perf_counter() - t)
            solver = get_solver(method)
            with tempfile.TemporaryDirectory() as tmp:
                t = time.perf_counter()
                fit(solver, CaseDataModule(rec.truth, mask, n_steps=solver.max_iter),
                    callbacks=[HistoryLogger(), Evaluation()],
                    logger=CSVLogger(tmp, name="bench", version=""))
                logged.append(time.perf_counter() - t)
        p, b, g = min(plain), min(bare), min(logged)
        print(f"{method:<12} {n:>5} {p:>8.3f} {b:>9.3f} {g:>8.3f} {1000 * (g - p) / n:>8.2f} "
              f"{g / p:>6.2f}", flush=True)


if __name__ == "__main__":
    main()
