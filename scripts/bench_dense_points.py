"""Cost of a fill with the default options on a dense point set (surface capture: 6 890 points,
the SMPL mesh's size), the case where all-pairs work grows with the square of the points.

A synthetic body: points on an ellipsoid that walks, turns and breathes, 1 mm noise, 5 % of the
points with one 20-40-frame gap. Runs ``torchfill fill`` in a child process and prints its wall
time and peak resident memory::

    OMP_NUM_THREADS=1 python scripts/bench_dense_points.py --points 6890 --frames 200 -m linear
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def body(T: int, J: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(J, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    shape = u * np.array([180.0, 120.0, 850.0])                      # mm, a standing body
    t = np.arange(T) / 100.0
    ang = 0.6 * np.sin(2 * np.pi * 0.5 * t)
    c, s = np.cos(ang), np.sin(ang)
    R = np.zeros((T, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1
    breathe = 1 + 0.02 * np.sin(2 * np.pi * 0.3 * t)[:, None, None]
    X = np.einsum("tcd,jd->tjc", R, shape) * breathe
    X += np.stack([1200 * t, 100 * np.sin(t), 900 + 0 * t], 1)[:, None]
    X += rng.normal(0, 1.0, X.shape)
    for j in rng.choice(J, max(1, J // 20), replace=False):
        a = rng.integers(0, T - 40)
        X[a:a + rng.integers(20, 41), j] = np.nan
    return X


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=6890)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("-m", "--method", default="linear")
    ap.add_argument("extra", nargs="*", help="more options for torchfill fill")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "dense.npy"
        np.save(src, body(args.frames, args.points))
        cmd = [sys.executable, "-m", "torchfill", "fill", str(src), "-o", str(Path(tmp) / "o.npy"),
               "-m", args.method, "-q", *args.extra]
        t = time.perf_counter()
        rc = subprocess.run(cmd, env=os.environ).returncode
        wall = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"{args.frames} frames x {args.points} points, -m {args.method} {' '.join(args.extra)}: "
          f"exit {rc}, {wall:.1f} s, peak RSS {peak:.0f} MB")


if __name__ == "__main__":
    main()
