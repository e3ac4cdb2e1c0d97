"""Our tensor-algebra ops (torchfill.ops.tensor) against TensorLy's torch backend, per call and per
solver iteration; prints numbers only.

1. Per call, at a recording's sizes (T x J x 3 = 1000 x 41 x 3, Tucker rank (40, 24, 3), CP rank
   40): median of ``--repeat`` timings of a loop of calls, each op ours vs TensorLy (functional API
   under ``tl.backend_context("pytorch")``).
2. Per iteration of ``tucker`` and ``cp`` on hdm05_mm_01-02_03_120 (first 1000 frames, multi_gap
   20 markers x 100 frames, seed 0; fixed iteration count, no hold-out): median over runs that
   alternate ours / TensorLy (the TensorLy ops patched in for every ``ops.<name>`` call).

    OMP_NUM_THREADS=1 python scripts/bench_tensorly.py [--repeat 7]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings

from pathlib import Path

import numpy as np
import torch

import torchfill
from torchfill.data import data_dir
from torchfill import gaps, ops
from torchfill.ops import tensor as ours
from torchfill.solvers import get_solver

NAMES = ("unfold", "fold", "mode_dot", "multi_mode_dot", "tucker_to_tensor", "cp_to_tensor",
         "khatri_rao")


def torch_ops() -> dict:
    """Our own torch contractions for every op (the library before TensorLy took some over)."""
    def multi_mode_dot(X, factors, skip=None, transpose=False):
        for n, A in enumerate(factors):
            if n != skip:
                X = ours.mode_dot(X, A.T if transpose else A, n)
        return X

    def cp_to_tensor(weights, factors):
        i = "abcdefghijklm"[:len(factors)]
        return torch.einsum(",".join(["z"] + [c + "z" for c in i]) + "->" + i, weights, *factors)

    return {"unfold": ours.unfold, "fold": ours.fold, "mode_dot": ours.mode_dot,
            "multi_mode_dot": multi_mode_dot, "tucker_to_tensor": ours.tucker_to_tensor,
            "cp_to_tensor": cp_to_tensor, "khatri_rao": ours.khatri_rao}


def tensorly_ops() -> dict:
    """The same ops through TensorLy (``tl.backend_context("pytorch")`` around each call)."""
    import tensorly as tl
    from tensorly import tenalg

    def ctx(fn):
        def call(*args, **kwargs):
            with tl.backend_context("pytorch"):
                return fn(*args, **kwargs)
        return call

    return {
        "unfold": ctx(lambda X, mode: tl.unfold(X, mode)),
        "fold": ctx(lambda M, mode, shape: tl.fold(M, mode, tuple(shape))),
        "mode_dot": ctx(lambda X, A, mode: tenalg.mode_dot(X, A, mode)),
        "multi_mode_dot": ctx(lambda X, factors, skip=None, transpose=False:
                              tenalg.multi_mode_dot(X, list(factors), skip=skip, transpose=transpose)),
        "tucker_to_tensor": ctx(lambda G, factors: tl.tucker_to_tensor((G, list(factors)))),
        "cp_to_tensor": ctx(lambda w, factors: tl.cp_to_tensor((w, list(factors)))),
        "khatri_rao": ctx(lambda B, C: tenalg.khatri_rao([B, C])),
    }


def per_call(repeat: int) -> None:
    g = torch.Generator().manual_seed(0)
    T, J, K = 1000, 41, 3
    X = torch.randn(T, J, K, generator=g, dtype=torch.float64)
    G = torch.randn(40, 24, 3, generator=g, dtype=torch.float64)
    A = [torch.randn(n, r, generator=g, dtype=torch.float64) for n, r in zip((T, J, K), G.shape)]
    w = torch.randn(40, generator=g, dtype=torch.float64)
    C = [torch.randn(n, 40, generator=g, dtype=torch.float64) for n in (T, J, K)]
    M1 = ours.unfold(X, 1)
    cases = {
        "unfold": lambda f: f(X, 1),
        "fold": lambda f: f(M1, 1, X.shape),
        "mode_dot": lambda f: f(X, A[1].T, 1),
        "multi_mode_dot": lambda f: f(X, A, transpose=True),
        "tucker_to_tensor": lambda f: f(G, A),
        "cp_to_tensor": lambda f: f(w, C),
        "khatri_rao": lambda f: f(C[1], C[2]),
    }
    tl_ops, torch_own = tensorly_ops(), torch_ops()
    print(f"per call (us), median of {repeat}; X {T}x{J}x{K}, Tucker rank {tuple(G.shape)}, CP rank 40")
    for name in NAMES:
        a, b = torch_own[name], tl_ops[name]
        torch.testing.assert_close(cases[name](a), cases[name](b))       # same result
        n = 200
        times = {"ours": [], "tensorly": []}
        for _ in range(repeat):
            for label, f in (("ours", a), ("tensorly", b)):
                t0 = time.perf_counter()
                for _ in range(n):
                    cases[name](f)
                times[label].append((time.perf_counter() - t0) / n * 1e6)
        mo, mt = statistics.median(times["ours"]), statistics.median(times["tensorly"])
        print(f"  {name:18s} torch {mo:9.1f}  tensorly {mt:9.1f}  ratio {mt / mo:5.2f}")


def per_iteration(repeat: int) -> None:
    data = data_dir(Path(__file__).resolve().parents[1])
    truth = torchfill.read(os.path.join(data, "hdm05_mm_01-02_03_120.c3d")).points[:1000]
    mask = gaps.multi_gap(*truth.shape[:2], n_markers=20, gap_length=100, max_gaps=5, seed=0)
    X = torch.from_numpy(np.where(mask[..., None], np.nan, truth))
    variants = {"torch": torch_ops(), "tensorly": tensorly_ops(),
                "library": {name: getattr(ops, name) for name in NAMES}}
    saved = variants["library"]
    runs = {"tucker": dict(max_iter=60, tol=0.0, holdout=None, eps=1e-2),
            "tucker_tnn": dict(max_iter=60, tol=0.0, holdout=None, eps=1e-2),
            "cp": dict(max_iter=60, tol=0.0, holdout=None, rank=30, max_rank=30),
            "grad_tucker": dict(max_iter=60, tol=0.0),
            "grad_cp": dict(max_iter=60, tol=0.0)}
    print(f"per iteration (ms), median of {repeat} fits of 60 iterations, alternating; torch = "
          f"all our own ops (before), tensorly = all TensorLy, library = the mix in torchfill.ops")
    for method, params in runs.items():
        times = {label: [] for label in variants}
        for _ in range(repeat):
            for label in variants:
                for name in NAMES:
                    setattr(ops, name, variants[label][name])
                try:
                    solver = get_solver(method, **params)
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        solver.initialize(X)
                        t0 = time.perf_counter()
                        for _ in range(params["max_iter"]):
                            solver.step_and_record()
                    times[label].append((time.perf_counter() - t0) / params["max_iter"] * 1e3)
                finally:
                    for name in NAMES:
                        setattr(ops, name, saved[name])
        med = {label: statistics.median(v) for label, v in times.items()}
        print(f"  {method:12s} " + "  ".join(f"{k} {v:8.2f}" for k, v in med.items())
              + f"  library/torch {med['library'] / med['torch']:5.2f}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--skip-calls", action="store_true")
    args = ap.parse_args()
    print(f"torch threads {torch.get_num_threads()}, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}")
    if not args.skip_calls:
        per_call(args.repeat)
    per_iteration(args.repeat)


if __name__ == "__main__":
    main()
