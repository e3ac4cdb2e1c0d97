"""Speed of the matrix family on CMU 135_02 (5202 frames x 41 markers, X is 5202 x 123) with
10 markers x 60-frame gaps (``gaps.continuous_runs``, seed 0): iterations, seconds, time per
iteration, the profile of one run, and the thin-SVD question (Gram + eigh vs torch.linalg.svd).

Usage::

    python scripts/bench_matrix.py                 # all three methods, default threads
    python scripts/bench_matrix.py --profile trnn_d2 --repeat 2

Prints numbers only; nothing is asserted (timings on a shared machine are noisy: run it twice
and keep the best).
"""
from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import sys
import time
from pathlib import Path

import numpy as np
import torch

import torchfill
from torchfill import gaps, metrics
from torchfill.data import data_dir
from torchfill.solvers import get_solver
from torchfill.solvers.matrix import BandedCholesky, d2_system_bands, gram_svd, svt

REPO = Path(__file__).resolve().parents[1]


def load(name: str) -> np.ndarray:
    path = data_dir(REPO) / name
    return np.asarray(torchfill.read(path).points, dtype=np.float64)


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def bench_svd(X: torch.Tensor, repeat: int) -> None:
    """Thin SVD of the 5202 x 123 unfolding: timing and accuracy of the Gram route."""
    t_full = best_of(lambda: torch.linalg.svd(X, full_matrices=False), repeat)
    t_gram = best_of(lambda: gram_svd(X), repeat)
    s_full = torch.linalg.svdvals(X)
    s_gram, _ = gram_svd(X)
    rel = ((s_gram - s_full).abs() / s_full[0]).max()
    tau = 0.01 * float(s_full[0])
    t_svt_full = best_of(lambda: svt(X, tau, "full"), repeat)
    t_svt_gram = best_of(lambda: svt(X, tau, "gram"), repeat)
    A, _ = svt(X, tau, "full")
    B, _ = svt(X, tau, "gram")
    print(f"thin SVD of {tuple(X.shape)}: torch.linalg.svd {t_full * 1e3:.1f} ms, "
          f"Gram+eigh {t_gram * 1e3:.1f} ms; max |sigma_gram - sigma_svd| / sigma_1 = {rel:.1e} "
          f"(sigma_min / sigma_1 = {float(s_full[-1] / s_full[0]):.1e})")
    print(f"SVT (tau = 0.01 sigma_1): full {t_svt_full * 1e3:.1f} ms, Gram {t_svt_gram * 1e3:.1f} ms; "
          f"||D_gram - D_svd||_F / ||D_svd||_F = {float(torch.linalg.norm(A - B) / torch.linalg.norm(A)):.1e}")
    K = d2_system_bands(X.shape[0])
    t_fac = best_of(lambda: BandedCholesky(K), repeat)
    chol = BandedCholesky(K)
    t_solve = best_of(lambda: chol.solve(X), repeat)
    print(f"banded (pentadiagonal) system T={X.shape[0]}: factor once {t_fac * 1e3:.1f} ms, "
          f"solve for {X.shape[1]} columns {t_solve * 1e3:.1f} ms")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recording", default="cmu_135_02.c3d")
    ap.add_argument("--methods", nargs="+", default=["svt", "trnn", "trnn_d2"])
    ap.add_argument("--repeat", type=int, default=2, help="runs per method; the best is kept")
    ap.add_argument("--profile", nargs="*", default=None, help="methods to profile (cProfile)")
    ap.add_argument("--svd", default="gram", choices=("gram", "full"))
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)

    truth = load(args.recording)
    T, J, _ = truth.shape
    mask = gaps.continuous_runs(T, J, n_markers=10, gap_length=60, seed=0)
    X = truth.copy()
    X[mask] = np.nan
    Xt = torch.from_numpy(X)
    print(f"{args.recording}: {T} x {J} markers, 10 markers x 60-frame gaps; "
          f"torch threads = {torch.get_num_threads()}, load average = {os.getloadavg()[0]:.1f}")
    for method in args.methods:
        best = None
        for _ in range(args.repeat):
            solver = get_solver(method, svd=args.svd)
            start = time.perf_counter()
            solver.initialize(Xt)
            t_init = time.perf_counter() - start
            while not solver.converged_ and solver.n_iter_ < solver.max_iter:
                solver.step_and_record()
            total = time.perf_counter() - start
            if best is None or total < best[0]:
                out = solver.transform(Xt).numpy()
                best = (total, t_init, solver.n_iter_, metrics.rmse_missing(out, truth, mask),
                        getattr(solver, "r_", None))
        total, t_init, n_iter, err, r = best
        print(f"{method:8s} {total:6.2f} s  ({n_iter} iterations, {1e3 * (total - t_init) / n_iter:.1f} "
              f"ms/iteration, set-up {1e3 * t_init:.0f} ms, r = {r})  rmse_missing = {err:.2f} mm")
    for method in args.profile or []:
        solver = get_solver(method, svd=args.svd)
        prof = cProfile.Profile()
        prof.enable()
        solver.fit(Xt)
        prof.disable()
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(10)
        print(f"--- profile of {method} ({solver.n_iter_} iterations), by own time ---")
        print("\n".join(buf.getvalue().splitlines()[4:22]))
    bench_svd(ops_unfold(Xt), args.repeat)
    return 0


def ops_unfold(X: torch.Tensor) -> torch.Tensor:
    """The temporal unfolding of the interpolated data, as the solvers see it."""
    solver = get_solver("svt")
    solver.initialize(X)
    return solver.Xhat_.clone()


if __name__ == "__main__":
    sys.exit(main())
