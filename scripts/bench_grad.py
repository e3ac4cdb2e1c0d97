"""Gradient fits vs the closed form on the HDM05 cases of experiments/grad_vs_closed.yaml.

hdm05_mm_01-02_03_120 (first 1000 frames), multi_gap 20 markers x gaps of 100/200 frames x up to
5 per marker, seeds 0-2: time and RMSE (all entries, as the Tucker paper) of tucker, grad_tucker,
cp and grad_cp through the solvers directly (no constraints), one line per fit.

    OMP_NUM_THREADS=1 python scripts/bench_grad.py [--methods grad_tucker grad_cp] [--profile]
"""
from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import time
import warnings

from pathlib import Path

import numpy as np
import torch

import torchfill
from torchfill.data import data_dir
from torchfill import gaps, metrics
from torchfill.solvers import get_solver


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--recording", default="hdm05_mm_01-02_03_120.c3d")
    ap.add_argument("--methods", nargs="+", default=["tucker", "grad_tucker", "cp", "grad_cp"])
    ap.add_argument("--gap-lengths", nargs="+", type=int, default=[100, 200])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("-p", "--param", action="append", default=[], help="method=name=value")
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args()
    data = data_dir(Path(__file__).resolve().parents[1])
    truth = torchfill.read(os.path.join(data, args.recording)).points[:1000]
    extra: dict[str, dict] = {}
    for item in args.param:
        m, k, v = item.split("=", 2)
        extra.setdefault(m, {})[k] = eval(v)                       # noqa: S307 - a bench script
    for gap in args.gap_lengths:
        for seed in args.seeds:
            mask = gaps.multi_gap(*truth.shape[:2], n_markers=20, gap_length=gap, max_gaps=5,
                                  seed=seed)
            X = torch.from_numpy(np.where(mask[..., None], np.nan, truth))
            for method in args.methods:
                solver = get_solver(method, seed=seed, **extra.get(method, {}))
                prof = cProfile.Profile() if args.profile else None
                start = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    if prof:
                        prof.enable()
                    out = solver.fit_transform(X).numpy()
                    if prof:
                        prof.disable()
                seconds = time.perf_counter() - start
                rmse = metrics.rmse(out, truth, mask)
                print(f"{gap},{seed},{method},{rmse:.4f},{seconds:.2f},{solver.n_iter_},"
                      f"{seconds / max(solver.n_iter_, 1) * 1e3:.2f} ms/iter", flush=True)
                if prof:
                    pstats.Stats(prof).sort_stats("tottime").print_stats(25)


if __name__ == "__main__":
    main()
