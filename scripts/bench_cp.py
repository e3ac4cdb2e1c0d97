"""Speed of the CP family (Mohaoui & Dmytryshyn 2024) on real recordings; prints numbers only.

1. A full fill of CMU 02_01 (343 x 41) with each of ``cp``, ``smooth_cp``, ``sparse_cp``
   (10 markers missing over one 50-frame window, seed 0): wall time, sweeps, time per sweep,
   chosen rank. The issue's target: every fill under 5 s on a 2-core machine.
2. Time per sweep at a fixed rank against the number of frames on HDM05 bd_05-01 (first
   1000 .. 5920 frames, 10 markers x 100 frames missing): the growth with T.

Usage: ``.venv/bin/python scripts/bench_cp.py [--repeat 2] [--rank 30] [--threads 1]``
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # this checkout's torchfill
import torchfill  # noqa: E402
from torchfill import gaps, metrics  # noqa: E402
from torchfill.data import data_dir  # noqa: E402
from torchfill.solvers import get_solver  # noqa: E402

DATA = data_dir(Path(__file__).resolve().parents[1])


def load(name: str) -> np.ndarray:
    """(T, J, 3) points of a C3D in ``DATA`` (the reader drops HDM05's `*` copies)."""
    return torchfill.read(DATA / (name if name.endswith(".c3d") else name + ".c3d")).points


def full_fills(repeat: int) -> None:
    truth = load("cmu_02_01")
    T, J, _ = truth.shape
    mask = gaps.shared_window(T, J, n_markers=10, gap_length=50, seed=0)
    X = truth.copy()
    X[mask] = np.nan
    Xt = torch.from_numpy(X)
    print(f"CMU 02_01 ({T} x {J} x 3), 10 markers x 50 frames missing; best of {repeat}")
    for name in ("cp", "smooth_cp", "sparse_cp"):
        best = None
        for _ in range(repeat):
            solver = get_solver(name)
            t0 = time.perf_counter()
            out = solver.fit_transform(Xt)
            dt = time.perf_counter() - t0
            best = dt if best is None else min(best, dt)
        err = metrics.rmse(out.numpy(), truth, mask)
        print(f"  {name:10s} {best:6.2f} s  {solver.n_iter_:4d} sweeps  "
              f"{1000 * best / solver.n_iter_:6.2f} ms/sweep  rank {solver.rank_:3d}  "
              f"rmse {err:.3f} mm")


def per_sweep(repeat: int, rank: int, sweeps: int = 20) -> None:
    name = "hdm05_bd_05-01_01_120"
    if not (DATA / f"{name}.c3d").is_file():
        print(f"{name}.c3d not found in {DATA}; skipping the growth with frames")
        return
    full = load(name)
    print(f"{name}: time per sweep at rank {rank} (holdout off), best of {repeat} x {sweeps} sweeps")
    for T in (1000, 2000, 4000, full.shape[0]):
        truth = full[:T]
        mask = gaps.shared_window(T, truth.shape[1], n_markers=10, gap_length=100, seed=0)
        X = truth.copy()
        X[mask] = np.nan
        for name_ in ("cp", "smooth_cp", "sparse_cp"):
            solver = get_solver(name_, rank=rank, max_rank=rank, holdout=None)
            solver.initialize(torch.from_numpy(X))
            best = None
            for _ in range(repeat):
                t0 = time.perf_counter()
                for _ in range(sweeps):
                    solver.step()
                dt = (time.perf_counter() - t0) / sweeps
                best = dt if best is None else min(best, dt)
            print(f"  T={T:5d} {name_:10s} {1000 * best:7.2f} ms/sweep")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--rank", type=int, default=30)
    ap.add_argument("--threads", type=int, default=None,
                    help="torch threads (default: torch's own; 1 is much faster on a loaded machine)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    full_fills(args.repeat)
    per_sweep(args.repeat, args.rank)


if __name__ == "__main__":
    main()
