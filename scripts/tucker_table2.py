"""Table 2 of Mohaoui & Dmytryshyn 2026 (layout) on the HDM05 recordings we have.

multi_gap protocol: 20 markers x gap length 100/150/200 x up to 2/5/10 gaps per marker, seeds
0,1,2; RMSE/AvE/STD over all entries and RMSE on the missing entries, for the interpolation
baselines and tucker / tucker_tnn with their defaults. The solvers never see the truth.

    OMP_NUM_THREADS=1 .venv/bin/python scripts/tucker_table2.py --out experiments/results/tucker_table2.csv
"""
from __future__ import annotations

import argparse
import csv
import itertools
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

import torchfill.solvers as S
from torchfill import gaps, metrics

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TORCHFILL_DATA") or REPO / ".." / "shared" / "data").resolve()
HDM = ["hdm05_mm_01-02_03_120.c3d", "hdm05_bd_05-01_01_120.c3d"]


def load(name: str) -> np.ndarray:
    """(T, J, 3) float64 marker positions (the reader drops HDM05's `*` copies)."""
    from torchfill import read

    return read(DATA / name).points


def run_one(method: str, points: np.ndarray, mask: np.ndarray, params: dict) -> tuple[np.ndarray, float, object]:
    X = torch.from_numpy(points.copy())
    X[torch.from_numpy(mask)] = float("nan")
    solver = S.get_solver(method, **params)
    t0 = time.perf_counter()
    out = solver.fit_transform(X).numpy()
    return out, time.perf_counter() - t0, solver


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recordings", nargs="+", default=HDM)
    ap.add_argument("--methods", nargs="+", default=["linear", "spline", "pchip", "tucker", "tucker_tnn"])
    ap.add_argument("--gap-length", nargs="+", type=int, default=[100, 150, 200])
    ap.add_argument("--max-gaps", nargs="+", type=int, default=[2, 5, 10])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--markers", type=int, default=20)
    ap.add_argument("--param", action="append", default=[],
                    help="method.key=value (python literal), e.g. tucker_tnn.lam=0.02")
    ap.add_argument("--out", default=None, help="CSV of every run")
    ap.add_argument("--markdown", nargs="+", default=None, metavar="CSV",
                    help="only print the markdown tables of earlier runs' CSVs")
    args = ap.parse_args(argv)
    if args.markdown:
        print(markdown(args.markdown))
        return
    params: dict[str, dict] = {m: {} for m in args.methods}
    for item in args.param:
        key, value = item.split("=", 1)
        m, k = key.split(".", 1)
        import ast
        params.setdefault(m, {})[k] = ast.literal_eval(value)
    rows = []
    writer = None
    fh = open(args.out, "w", newline="") if args.out else None
    for rec in args.recordings:
        P = load(rec)
        T, J, _ = P.shape
        for L, K, seed in itertools.product(args.gap_length, args.max_gaps, args.seeds):
            mask = gaps.multi_gap(T, J, n_markers=args.markers, gap_length=L, max_gaps=K, seed=seed)
            for m in args.methods:
                out, secs, solver = run_one(m, P, mask, params.get(m, {}))
                sc = metrics.score(out, P, mask)
                row = {"recording": rec, "gap_length": L, "max_gaps": K, "seed": seed, "method": m,
                       **{k: sc[k] for k in ("rmse", "ave", "std", "rmse_missing")},
                       "seconds": secs, "iters": getattr(solver, "n_iter_", 0),
                       "rank": str(getattr(solver, "chosen_rank_", getattr(solver, "rank_", "")))}
                rows.append(row)
                print(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()),
                      flush=True)
                if fh:
                    if writer is None:
                        writer = csv.DictWriter(fh, fieldnames=list(row))
                        writer.writeheader()
                    writer.writerow(row)
                    fh.flush()
    summarize(rows)


def summarize(rows) -> None:
    import collections
    by = collections.defaultdict(list)
    for r in rows:
        by[r["method"]].append(r["rmse"])
    print("mean RMSE (all entries) per method:",
          {m: round(float(np.mean(v)), 3) for m, v in by.items()})


def markdown(paths) -> str:
    """Seed-averaged tables (RMSE, AvE, STD over all entries; RMSE on missing entries), the mean
    over settings, and the blow-up check (worst seed / median seed per setting)."""
    import collections
    rows = []
    for path in paths:
        with open(path) as fh:
            rows += list(csv.DictReader(fh))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    cell = collections.defaultdict(list)
    for r in rows:
        cell[(r["recording"], int(r["gap_length"]), int(r["max_gaps"]), r["method"])].append(r)
    complete = lambda k: all(cell.get((*k, m)) for m in methods)  # noqa: E731
    settings = sorted({k[:3] for k in cell if complete(k[:3])})
    out = []
    for metric in ("rmse", "ave", "std", "rmse_missing"):
        out.append(f"\n**{metric}** (mm, mean over seeds)\n")
        out.append("| recording | gap | max gaps | " + " | ".join(methods) + " |")
        out.append("|---|---|---|" + "---|" * len(methods))
        means = collections.defaultdict(list)
        for rec, L, K in settings:
            vals = []
            for m in methods:
                v = [float(r[metric]) for r in cell[(rec, L, K, m)]]
                means[m].append(np.mean(v))
                vals.append(f"{np.mean(v):.2f}")
            out.append(f"| {rec.replace('_120.c3d', '')} | {L} | {K} | " + " | ".join(vals) + " |")
        out.append("| **mean** | | | " + " | ".join(f"**{np.mean(means[m]):.2f}**" for m in methods) + " |")
    out.append("\n**Blow-up check** (worst seed RMSE / median seed RMSE, largest over settings)\n")
    out.append("| method | worst/median | seeds per setting |")
    out.append("|---|---|---|")
    for m in methods:
        ratios, n = [], 0
        for rec, L, K in settings:
            v = [float(r["rmse"]) for r in cell[(rec, L, K, m)]]
            n = len(v)
            ratios.append(max(v) / max(np.median(v), 1e-12))
        out.append(f"| {m} | {max(ratios):.2f} | {n} |")
    secs = {m: np.mean([float(r["seconds"]) for r in rows if r["method"] == m]) for m in methods}
    out.append("\nMean seconds per fill (under load, 1 thread): " +
               ", ".join(f"{m} {v:.2f}" for m, v in secs.items()))
    return "\n".join(out)


if __name__ == "__main__":
    main(sys.argv[1:])
