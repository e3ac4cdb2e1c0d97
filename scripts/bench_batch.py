"""A batch of recordings through the CLI: wall time with --workers 1 vs 2 (and --ray local), and
whether the outputs are byte-identical.

The batch: ``--files`` clips of ``--frames`` frames cut from the HDM05/CMU recordings in the shared
data, each with the Tucker paper's simulated gaps (10 markers, 1-3 gaps of 60 frames), written as
.npz to a temporary folder. Each configuration is one ``python -m torchfill fill DIR --out-dir``.

    OMP_NUM_THREADS=1 nice python scripts/bench_batch.py --files 50 --frames 400
"""
from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from torchfill.data import data_dir  # noqa: E402  (this checkout's, after the path)

DATA = data_dir(ROOT)   # $TORCHFILL_DATA or ../shared/data
SOURCES = ("HDM_bd_01-02_01_120.c3d", "hdm05_bd_05-01_01_120.c3d", "hdm05_mm_01-02_03_120.c3d",
           "cmu_85_02.c3d", "cmu_135_02.c3d")


def make_batch(folder: Path, n_files: int, frames: int) -> None:
    import torchfill
    from torchfill import gaps

    clips = []
    for name in SOURCES:
        X = torchfill.read(DATA / name).points
        X = X[:, ~np.isnan(X).any(axis=(0, 2))]
        clips += [X[a:a + frames] for a in range(0, len(X) - frames + 1, frames)]
    for k in range(n_files):
        X = clips[k % len(clips)].copy()
        mask = gaps.multi_gap(*X.shape[:2], n_markers=10, gap_length=60, max_gaps=3, seed=k)
        X[mask] = np.nan
        np.savez(folder / f"clip{k:03d}.npz", points=X,
                 labels=np.array([f"M{j}" for j in range(X.shape[1])]), rate=120.0, units="mm")


def digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.iterdir()):
        h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()[:16]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", type=int, default=50)
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--method", default=None)
    parser.add_argument("--configs", nargs="+", default=["--workers=1", "--workers=2", "--ray=local"])
    args = parser.parse_args()
    uptime = lambda: subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    print(uptime())
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "in"
        src.mkdir()
        make_batch(src, args.files, args.frames)
        env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
        for config in args.configs:
            out = Path(tmp) / config.strip("-").replace("=", "_")
            cmd = [sys.executable, "-m", "torchfill", "fill", str(src), "--out-dir", str(out), "-q",
                   config] + (["-m", args.method] if args.method else [])
            start = time.perf_counter()
            res = subprocess.run(cmd, env=env, capture_output=True, text=True)
            wall = time.perf_counter() - start
            print(f"{config:<12} {args.files} files x {args.frames} frames: {wall:7.1f} s  rc={res.returncode}"
                  f"  outputs {digest(out) if out.exists() else '-'}  [{uptime()}]", flush=True)
            if res.returncode:
                print(res.stderr[-500:])


if __name__ == "__main__":
    main()
