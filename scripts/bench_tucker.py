"""Speed of tucker / tucker_tnn: full fill time, time per iteration against one thin SVD of the
T x 3J unfolding, and how total time grows with the number of frames (1000 -> 8500).

    .venv/bin/python scripts/bench_tucker.py            # run twice, report the best
    .venv/bin/python scripts/bench_tucker.py --sizes    # without the scaling part

Recordings are tiled in time (hdm05_bd_05-01_01_120 followed by hdm05_mm_01-02_03_120) to reach
8500 frames; gaps: multi_gap, 20 markers x 100 frames x up to 5 gaps, seed 0.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

import torchfill
import torchfill.solvers as S
from torchfill import gaps, metrics
from torchfill.solvers import tucker as tk
from torchfill.data import data_dir

DATA = data_dir(Path(__file__).resolve().parents[1])   # $TORCHFILL_DATA or ../shared/data


def load(name: str) -> np.ndarray:
    """A recording's points (T, J, 3), float64, the markers observed in every frame."""
    P = torchfill.read(DATA / name).points
    return P[:, np.isfinite(P).all(axis=(0, 2))]


def best_of(fn, n=5):
    best = np.inf
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def fill(method, P, mask, **params):
    X = torch.from_numpy(P.copy())
    X[torch.from_numpy(mask)] = float("nan")
    s = S.get_solver(method, **params)
    t0 = time.perf_counter()
    out = s.fit_transform(X).numpy()
    return time.perf_counter() - t0, s, metrics.rmse(out, P, mask)


def main():
    import argparse
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", nargs="*", type=int, default=[1000, 2000, 4000, 8500],
                    help="frame counts for the scaling part (none to skip it)")
    args = ap.parse_args()
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}")
    bd = load("hdm05_bd_05-01_01_120.c3d")
    mm = load("hdm05_mm_01-02_03_120.c3d")
    ref = load("HDM_bd_01-02_01_120.c3d")               # 2900 frames x 41 unique markers
    T, J, _ = ref.shape
    mask = gaps.multi_gap(T, J, n_markers=20, gap_length=100, max_gaps=5, seed=0)
    print(f"\n== full fill, HDM_bd_01-02_01_120 ({T} frames x {J} markers), default settings ==")
    for m in ("tucker", "tucker_tnn"):
        secs, s, r = fill(m, ref, mask)
        print(f"{m:11s} total {secs:6.2f} s  iterations {s.n_iter_:4d}  per iteration "
              f"{1e3 * secs / s.n_iter_:6.1f} ms  rank {getattr(s, 'chosen_rank_', s.rank_)}  RMSE {r:.3f} mm")

    X1 = torch.from_numpy(ref.reshape(T, -1).copy())
    t_svd = best_of(lambda: torch.linalg.svd(X1, full_matrices=False))
    t_gram = best_of(lambda: torch.linalg.eigh(X1.T @ X1))
    t_svt = best_of(lambda: tk.svt(X1, 1.0, "gram"))
    print(f"thin SVD of the {T} x {3 * J} unfolding (torch.linalg.svd): {1e3 * t_svd:.1f} ms; "
          f"Gram + eigh: {1e3 * t_gram:.1f} ms; full SVT via Gram: {1e3 * t_svt:.1f} ms")

    print("\n== scaling with the number of frames (tiled bd + mm), tucker_tnn / tucker ==")
    tiled = np.concatenate([bd, mm], axis=0)
    for T in args.sizes:
        P = tiled[:T]
        mk = gaps.multi_gap(T, P.shape[1], n_markers=20, gap_length=100, max_gaps=5, seed=0)
        line = [f"T={T:5d}"]
        for m in ("tucker_tnn", "tucker"):
            secs, s, r = fill(m, P, mk)
            line.append(f"{m} {secs:6.2f} s ({s.n_iter_} it, {1e3 * secs / s.n_iter_:.1f} ms/it, RMSE {r:.2f})")
        print("  ".join(line), flush=True)


if __name__ == "__main__":
    main()
