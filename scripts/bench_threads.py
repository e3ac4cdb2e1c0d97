"""torch threads against load: ms per tucker_tnn iteration on 3000 x 41 frames (bench_long's
recording), 1 vs 2 threads alternated, with the load average beside each number.

    python scripts/bench_threads.py [--iters 40] [--repeat 2]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_long import recording  # noqa: E402

from torchfill.solvers import get_solver  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iters", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    truth, mask = recording(3000)
    X = torch.from_numpy(np.where(mask[..., None], np.nan, truth))
    for n in (1, 2) * args.repeat:
        torch.set_num_threads(n)
        solver = get_solver("tucker_tnn", max_iter=args.iters)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            start = time.perf_counter()
            solver.fit(X)
        ms = 1000 * (time.perf_counter() - start) / solver.n_iter_
        print(f"{n} thread(s): {ms:7.1f} ms/iteration   load average {os.getloadavg()[0]:.1f}",
              flush=True)


if __name__ == "__main__":
    main()
