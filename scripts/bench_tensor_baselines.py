"""Speed of the CP paper's baselines ``halrtc``, ``spc``, ``pstnn`` on real recordings.

1. CMU 02_01 (343 x 41): 10 markers x 50 frames missing (shared window, seed 0).
2. CMU 85_12, first 3000 frames x 41 markers: 10 markers x 100 frames missing (seed 0).

Prints, per method, the median wall time of ``--repeat`` full fills (default 3), iterations and
RMSE over all entries (mm), and ``uptime`` (the machine is shared: quote the load). Targets of the
issue: <= 5 s for (1) and <= 10 s for (2).

Usage (from the repository root): ``PYTHONPATH=. OMP_NUM_THREADS=1 nice .venv/bin/python
scripts/bench_tensor_baselines.py [--repeat 3]``
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from torchfill import gaps, metrics
from torchfill.lightning.data import load_recording
from torchfill.solvers import get_solver
from torchfill.data import data_dir

DATA = data_dir(Path(__file__).resolve().parents[1])   # $TORCHFILL_DATA or ../shared/data
METHODS = ("halrtc", "spc", "pstnn")


def bench(name: str, frames: int | None, n_markers: int, gap_length: int, repeat: int) -> None:
    path = DATA / f"{name}.c3d"
    if not path.is_file():
        print(f"{path} not found; skipped")
        return
    truth = load_recording(path).truth[:frames]
    T, J, _ = truth.shape
    mask = gaps.shared_window(T, J, n_markers=n_markers, gap_length=gap_length, seed=0)
    X = truth.copy()
    X[mask] = np.nan
    print(f"{name} ({T} x {J}), {n_markers} markers x {gap_length} frames missing; "
          f"median of {repeat}")
    for method in METHODS:
        times = []
        for _ in range(repeat):
            solver = get_solver(method)
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                out = solver.fit_transform(torch.from_numpy(X))
            times.append(time.perf_counter() - t0)
        err = metrics.rmse(out.numpy(), truth, mask)
        print(f"  {method:7s} {statistics.median(times):6.2f} s  (min {min(times):.2f})  "
              f"{solver.n_iter_:4d} it  rmse {err:.3f} mm", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; "
          + subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    bench("cmu_02_01", None, 10, 50, args.repeat)
    bench("cmu_85_12", 3000, 10, 100, args.repeat)
    print(subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())


if __name__ == "__main__":
    main()
