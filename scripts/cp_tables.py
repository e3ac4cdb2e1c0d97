"""Tables 4-6 of Mohaoui & Dmytryshyn 2024 on the recordings we have (see experiments/results/cp.md).

Shared-window protocol: ``n_markers`` random markers missing over one window of ``gap_length``
frames; RMSE/AvE/STD over all entries (mm) and the RMSE over missing entries. Usage::

    OMP_NUM_THREADS=1 .venv/bin/python scripts/cp_tables.py [--recordings cmu_02_01 ...]
        [--methods cp smooth_cp ...] [--markers 10 20 30] [--lengths 20 50 100] [--seeds 0 1 2]
        [--csv runs.csv]
    .venv/bin/python scripts/cp_tables.py --tables runs.csv ...   # markdown tables
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch

import torchfill
from torchfill import gaps, metrics
from torchfill.solvers import available, get_solver

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TORCHFILL_DATA", ROOT / ".." / "shared" / "data"))


def load(name: str) -> np.ndarray:
    """(T, J, 3) points of a C3D in ``DATA`` (the reader drops HDM05's `*` copies)."""
    return torchfill.read(DATA / (name if name.endswith(".c3d") else name + ".c3d")).points


def run(truth: np.ndarray, method: str, mask: np.ndarray, **params) -> tuple[dict, float, object]:
    X = truth.copy()
    X[mask] = np.nan
    solver = get_solver(method, **params)
    t0 = time.perf_counter()
    filled = solver.fit_transform(torch.from_numpy(X)).numpy()
    return metrics.score(filled, truth, mask), time.perf_counter() - t0, solver


#: The authors' own code on CMU 02_01, honest last iterate (issue 4): RMSE over all entries, mm.
AUTHORS_02_01 = {(10, 20): 0.75, (10, 50): 2.31, (10, 100): 3.68, (20, 20): 1.28, (20, 50): 2.78,
                 (20, 100): 5.36, (30, 20): 3.52, (30, 50): 5.29, (30, 100): 7.83}


def tables(csv_paths: list[str]) -> None:
    """Markdown tables (mean over seeds) from the CSV rows written by ``--csv``."""
    import csv
    from collections import defaultdict
    cols = ["rmse", "ave", "std", "rmse_missing", "time", "iters", "rank"]
    runs = defaultdict(list)
    for path in csv_paths:
        for row in csv.reader(open(path)):
            if row[0] == "recording":
                continue
            rec, nm, gl, method, seed = row[:5]
            runs[(rec, int(nm), int(gl), method)].append([float(v) for v in row[5:]])
    methods = [m for m in ("linear", "spline", "pchip", "tucker", "tucker_tnn", "cp", "smooth_cp",
                           "sparse_cp") if any(k[3] == m for k in runs)]
    settings = sorted({k[:3] for k in runs})
    for metric in ("rmse", "rmse_missing"):
        i = cols.index(metric)
        extra = " authors' code |" if metric == "rmse" else ""
        print(f"\n{metric} (mm, mean over seeds; n = seeds)\n")
        print("| recording | markers | gap |" + extra + "".join(f" {m} |" for m in methods))
        print("|---|---|---|" + ("---|" if extra else "") + "---|" * len(methods))
        for rec, nm, gl in settings:
            line = f"| {rec} | {nm} | {gl} |"
            if extra:
                a = AUTHORS_02_01.get((nm, gl)) if rec == "cmu_02_01" else None
                line += f" {a:.2f} |" if a is not None else " - |"
            vals = {m: np.mean([r[i] for r in runs[(rec, nm, gl, m)]]) for m in methods
                    if runs.get((rec, nm, gl, m))}
            best = min(vals.values()) if vals else None
            for m in methods:
                if m not in vals:
                    line += " - |"
                    continue
                n = len(runs[(rec, nm, gl, m)])
                txt = f"{vals[m]:.2f}" + ("" if n == 3 else f" (n={n})")
                line += f" **{txt}** |" if vals[m] == best else f" {txt} |"
            print(line)
    print("\nCP family: AvE / STD (mm), time (s), sweeps, rank (means over seeds)\n")
    cp = [m for m in ("cp", "smooth_cp", "sparse_cp") if m in methods]
    print("| recording | markers | gap |" + "".join(f" {m} AvE / STD | {m} s / sweeps / R |" for m in cp))
    print("|---|---|---|" + "---|---|" * len(cp))
    for rec, nm, gl in settings:
        line = f"| {rec} | {nm} | {gl} |"
        for m in cp:
            r = np.mean(runs[(rec, nm, gl, m)], axis=0) if runs.get((rec, nm, gl, m)) else None
            line += (f" {r[1]:.3f} / {r[2]:.2f} | {r[4]:.1f} / {r[5]:.0f} / {r[6]:.0f} |"
                     if r is not None else " - | - |")
        print(line)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tables", nargs="+", default=None, metavar="CSV",
                    help="print the markdown tables from these CSV files and exit")
    ap.add_argument("--recordings", nargs="+", default=["cmu_02_01", "cmu_85_02"])
    default = [m for m in ("linear", "spline", "pchip", "tucker", "tucker_tnn", "cp",
                           "smooth_cp", "sparse_cp") if m in available()]
    ap.add_argument("--methods", nargs="+", default=default)
    ap.add_argument("--markers", nargs="+", type=int, default=[10, 20, 30])
    ap.add_argument("--lengths", nargs="+", type=int, default=[20, 50, 100])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--csv", default=None, help="append one row per run to this CSV")
    args = ap.parse_args()
    if args.tables:
        tables(args.tables)
        return
    out = open(args.csv, "a") if args.csv else None
    for rec in args.recordings:
        truth = load(rec)
        T, J, _ = truth.shape
        for n_markers in args.markers:
            for length in args.lengths:
                for method in args.methods:
                    rows = []
                    for seed in args.seeds:
                        mask = gaps.shared_window(T, J, n_markers=n_markers, gap_length=length,
                                                  seed=seed)
                        s, dt, solver = run(truth, method, mask)
                        rank = getattr(solver, "rank_", float("nan"))
                        rank = float(rank) if isinstance(rank, (int, float)) else float("nan")
                        rows.append([s["rmse"], s["ave"], s["std"], s["rmse_missing"], dt,
                                     solver.n_iter_, rank])
                        if out:
                            out.write(f"{rec},{n_markers},{length},{method},{seed},"
                                      + ",".join(f"{v:.6g}" for v in rows[-1]) + "\n")
                            out.flush()
                    m = np.mean(rows, axis=0)
                    print(f"{rec:10s} {n_markers:3d} {length:4d} {method:10s} "
                          f"rmse {m[0]:6.3f} ave {m[1]:6.3f} std {m[2]:6.3f} "
                          f"rmse_miss {m[3]:7.3f}  {m[4]:6.2f} s  iters {m[5]:6.0f} "
                          f"rank {m[6]:5.1f}", flush=True)


if __name__ == "__main__":
    main()
