"""Time (and error) of a batch with ``--session`` against the same batch without it.

The batch: ``--trials`` trials of HDM05 actor bd (HDM_bd_01-02 and hdm05_bd_05-01 cut into
pieces of about ``--frames`` frames), each with the gap pattern of a real gapped file of the data
folder laid onto it (:func:`torchfill.gaps.transplant`, ``layout`` assignment), written as C3D
into a temporary folder. ``torchfill fill DIR/*.c3d --out-dir OUT`` runs in this process (one
worker, the default method) once without and once with ``--session``; prints the wall and CPU
seconds of each, their ratio and the mean RMSE over the hidden samples::

    OMP_NUM_THREADS=1 python scripts/bench_session.py --trials 10
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import torchfill
from real_gap_suite import REPO, complete, sources
from torchfill import gaps
from torchfill.cli import main as cli
from torchfill.data import data_dir
from torchfill.metrics import rmse_missing

SESSION = ("HDM_bd_01-02_01_120.c3d", "hdm05_bd_05-01_01_120.c3d")


def trials(folder: Path, n: int, frames: int) -> list[tuple[torchfill.MarkerSequence, np.ndarray]]:
    """``n`` (truth, mask) pairs: pieces of the session's recordings with real gap patterns."""
    whole = [complete(folder / name) for name in SESSION]
    labels = sorted(set.intersection(*(set(s.labels) for s in whole)))
    whole = [s.select([s.labels.index(lab) for lab in labels]) for s in whole]
    pieces = [s.with_points(s.points[a:a + frames]) for s in whole
              for a in range(0, s.n_frames - frames + 1, frames)][:n]
    masks = [m for m in sources(folder) if m[1].shape[0] * 120.0 / m[2] >= frames // 2]
    out = []
    for k, truth in enumerate(pieces):
        src, mask, rate, layout = masks[k % len(masks)]
        T = min(int(round(mask.shape[0] * truth.rate / rate)), truth.n_frames)
        truth = truth.with_points(truth.points[:T])
        M = gaps.transplant(mask, T, truth.n_markers, seed=k, rate_ratio=truth.rate / rate,
                            source_layout=layout,
                            target_layout=gaps.body_layout(truth.points, truth.labels))
        out.append((truth, M))
    return out


def run(paths: list[Path], out: Path, extra: list[str]) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    code = cli(["fill", *map(str, paths), "--out-dir", str(out), "--extrapolate", "none", "-qq",
                *extra])
    if code != 0:
        raise SystemExit(f"torchfill fill exited with {code}")
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--frames", type=int, default=800, help="frames per trial at most")
    args = ap.parse_args()
    cases = trials(data_dir(REPO), args.trials, args.frames)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        paths = []
        for i, (truth, M) in enumerate(cases):
            seq = truth.with_points(np.where(M[..., None], np.nan, truth.points))
            seq.source = None
            paths.append(tmp / f"trial{i:02d}.c3d")
            torchfill.write(seq, paths[-1])
        print(f"{len(paths)} trials, {sum(t.n_frames for t, _ in cases)} frames, "
              f"{sum(int(M.sum()) for _, M in cases)} hidden samples", flush=True)
        result = {}
        for tag, extra in (("alone", []), ("session", ["--session"])):
            wall, cpu = run(paths, tmp / tag, extra)
            errs = [rmse_missing(np.nan_to_num(torchfill.read(tmp / tag / p.name).points),
                                 truth.points, M) for p, (truth, M) in zip(paths, cases)]
            result[tag] = (wall, cpu, float(np.mean(errs)))
            print(f"{tag}: {wall:.1f} s wall, {cpu:.1f} s CPU, mean RMSE {np.mean(errs):.2f} mm "
                  f"({', '.join(f'{e:.1f}' for e in errs)})", flush=True)
    (w0, c0, e0), (w1, c1, e1) = result["alone"], result["session"]
    print(f"session / alone: wall {w1 / w0:.2f}x, CPU {c1 / c0:.2f}x, RMSE {e1 / e0:.2f}x")


if __name__ == "__main__":
    main()
