"""Speed of the PCA fillers (Li et al. 2020 Table 4: 0.15-0.27 s per fill).

A 200-frame test segment (5 gaps of 50 frames, or a 40-frame blackout) filled from a 2 500-frame
training set. "cold" is the first fill with a training set (eigenspace computed); "warm" the best
of the following fills (eigenspace reused from the cache). Uses real recordings when present
(../shared/data or $TORCHFILL_DATA), else synthetic data.

Usage: .venv/bin/python scripts/bench_pca.py [--repeat 5] [--device cpu|cuda] [--threads N]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

import torchfill
from torchfill import gaps, metrics
from torchfill.data import data_dir
from torchfill.solvers import get_solver, pca

DATA = data_dir(Path(__file__).resolve().parents[1])


def data(n_train: int = 2500):
    test_file, train_file = DATA / "hdm05_mm_01-02_03_120.c3d", DATA / "HDM_bd_01-02_01_120.c3d"
    if test_file.is_file() and train_file.is_file():
        test, train = torchfill.read(test_file), torchfill.read(train_file)
        labels = train.short_labels()
        order = [test.short_labels().index(lab) for lab in labels]
        return test.points[1000:1200, order], train.points[:n_train], "real (HDM05 mm / bd)"
    rng = np.random.default_rng(0)
    walk = np.cumsum(rng.normal(size=(n_train + 200, 41, 3)), axis=0) + rng.normal(size=(1, 41, 3)) * 300
    return walk[n_train:], walk[:n_train], "synthetic random walk"


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    if torch.cuda.is_available():
        torch.cuda.synchronize()
    return time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--device", default="cpu")
    p.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: "
                   "torch's); on a loaded 2-core machine 1 thread avoids BLAS oversubscription")
    args = p.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    X, train, source = data()
    dev = torch.device(args.device)
    Xt, Tt = torch.as_tensor(X, device=dev), [torch.as_tensor(train, device=dev)]
    print(f"data: {source}; test {X.shape}, training {train.shape}, device {dev}, "
          f"torch threads {torch.get_num_threads()}")
    cases = {
        "pca_train (5 gaps x 50 frames)": ("pca_train", gaps.evenly_spaced(200, X.shape[1], n_gaps=5, gap_length=50, seed=0)),
        "pca_blackout (40-frame blackout)": ("pca_blackout", gaps.blackout(200, X.shape[1], gap_length=40, seed=0)),
    }
    for label, (method, mask) in cases.items():
        Xg = Xt.clone()
        Xg[torch.as_tensor(mask, device=dev)] = float("nan")
        pca._CACHE.clear()
        out = {}
        cold = timed(lambda: out.setdefault("x", torchfill.fill(Xg, method=method, training=Tt)))
        warm = min(timed(lambda: torchfill.fill(Xg, method=method, training=Tt)) for _ in range(args.repeat))
        solver = min(timed(lambda: get_solver(method, training=Tt).fit_transform(Xg))
                     for _ in range(args.repeat))                  # the solver alone, cache warm
        err = metrics.gap_error(out["x"].cpu().numpy(), X, mask)
        print(f"{label:36s} cold {cold:.3f} s   warm {warm:.3f} s (fill)   {solver:.3f} s (solver)"
              f"   gap error {err:.1f} mm")


if __name__ == "__main__":
    main()
