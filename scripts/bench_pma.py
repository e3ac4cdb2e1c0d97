"""Speed of the Tits et al. (2018) models and Gløersen PCA (each <= 2 s, pma <= 5 s on a
3 000-frame x 41-marker recording).

HDM05 mm_01-02_03 frames 0-3000 (41 markers), Tucker-paper gaps (20 markers, 100 frames, up to 5
gaps each, seed 0); a smooth synthetic recording of the same size when the data are absent.
Median of ``--repeat`` fills per method under ``nice``, one torch thread, wall and process CPU
time (CPU time is what load on the shared machine inflates least); linear interpolation in
the same run as the reference; ``uptime`` printed beside the numbers (the machine is shared).

    OMP_NUM_THREADS=1 .venv/bin/python scripts/bench_pma.py [--repeat 3] [--methods ...]
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np
import torch

import torchfill
from torchfill import gaps, metrics
from torchfill.data import data_dir

DATA = data_dir(Path(__file__).resolve().parents[1])   # $TORCHFILL_DATA or ../shared/data
METHODS = ["linear", "pca_gloersen", "glr", "li", "lpr", "lgrnn", "pma"]


def recording(T: int = 3000) -> tuple[np.ndarray, str]:
    path = DATA / "hdm05_mm_01-02_03_120.c3d"
    if path.is_file():
        return torchfill.read(path).points[:T], f"{path.name}[0:{T}]"
    t = np.arange(T) / 120.0
    rng = np.random.default_rng(0)
    basis = np.stack([np.sin(2 * np.pi * f * t + p) for f, p in rng.uniform(0.2, 2.0, (8, 2))], 1)
    return np.einsum("tk,kjc->tjc", basis, rng.normal(0, 80, (8, 41, 3))) + rng.normal(0, 400, (1, 41, 3)), "synthetic"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--methods", nargs="*", default=METHODS)
    args = ap.parse_args()
    os.nice(10)
    torch.set_num_threads(1)
    X, source = recording()
    T, J, _ = X.shape
    mask = gaps.multi_gap(T, J, n_markers=20, gap_length=100, max_gaps=5, seed=0)
    gappy = np.where(mask[..., None], np.nan, X)
    print(f"data: {source} {X.shape}, {int(mask.sum())} missing samples, torch threads 1")
    print("uptime:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    for method in args.methods:
        times, cpu = [], []
        for _ in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            out = torchfill.fill(gappy, method=method)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        print(f"{method:14s} median {statistics.median(times):6.2f} s wall, {statistics.median(cpu):6.2f} s CPU"
              f"  (wall runs {', '.join(f'{s:.2f}' for s in times)})"
              f"  RMSE missing {metrics.rmse_missing(out, X, mask):6.2f} mm", flush=True)
    print("uptime:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())


if __name__ == "__main__":
    main()
