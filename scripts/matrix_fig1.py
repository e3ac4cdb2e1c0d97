"""Imamura & Okuda (2018), Fig. 1 protocol on the CMU recordings we have.

(a) random missing entries (each frame x marker sample missing with probability ``rate``),
rates 0.2 ... 0.6; (b) continuous runs of 20 ... 60 frames on 10 random markers. Error: RMSE over
the missing entries (Eq. 23, ``torchfill.metrics.rmse_missing``), in the file's units (mm), mean
and standard deviation over seeds. Methods: svt, trnn, trnn_d2 with their defaults, beside linear
and spline interpolation. No solver sees the missing truth; it is used only for the score.

Usage::

    OMP_NUM_THREADS=1 python scripts/matrix_fig1.py --seeds 0 1 2 \\
        --csv experiments/results/matrix_fig1.csv --md experiments/results/matrix_fig1_table.md

The same protocol as a runner config is ``experiments/matrix_fig1.yaml``.
"""
from __future__ import annotations

import argparse
import csv
import os
import sys
import time
from pathlib import Path

import numpy as np

import torchfill
from torchfill import gaps, metrics

REPO = Path(__file__).resolve().parents[1]
RECORDINGS = ["cmu_02_01.c3d", "cmu_85_02.c3d", "cmu_135_02.c3d"]
METHODS = ["linear", "spline", "svt", "trnn", "trnn_d2"]
PROTOCOLS = {
    "random_entries": ("rate", [0.2, 0.3, 0.4, 0.5, 0.6], {}),
    "continuous_runs": ("gap_length", [20, 30, 40, 50, 60], {"n_markers": 10}),
}


def data_dir() -> Path:
    return Path(os.environ.get("TORCHFILL_DATA") or REPO / ".." / "shared" / "data").resolve()


def load(path: Path) -> np.ndarray:
    """Points (T, J, 3) of a recording."""
    return torchfill.read(path).points


def run_one(truth: np.ndarray, mask: np.ndarray, method: str) -> tuple[float, float, int]:
    X = truth.copy()
    X[mask] = np.nan
    start = time.perf_counter()
    out = torchfill.fill(X, method=method)
    seconds = time.perf_counter() - start
    if not np.array_equal(out[~mask], truth[~mask]):
        raise AssertionError(f"{method} changed observed samples")
    return metrics.rmse_missing(out, truth, mask), seconds, 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recordings", nargs="+", default=RECORDINGS)
    ap.add_argument("--methods", nargs="+", default=METHODS)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--protocols", nargs="+", default=list(PROTOCOLS))
    ap.add_argument("--rates", nargs="+", type=float, default=None,
                    help="subset of the random-entry rates (default 0.2 .. 0.6)")
    ap.add_argument("--lengths", nargs="+", type=int, default=None,
                    help="subset of the run lengths (default 20 .. 60)")
    ap.add_argument("--csv", type=Path, default=None, help="write every run here")
    ap.add_argument("--md", type=Path, default=None, help="write the markdown tables here")
    ap.add_argument("--from-logs", nargs="+", type=Path, default=None,
                    help="rebuild the tables from the lines earlier runs printed (no solving)")
    args = ap.parse_args(argv)

    rows = parse_logs(args.from_logs) if args.from_logs else []
    for rec in [] if args.from_logs else args.recordings:
        truth = load(data_dir() / rec)
        T, J, _ = truth.shape
        for protocol in args.protocols:
            key, values, extra = PROTOCOLS[protocol]
            chosen = args.rates if protocol == "random_entries" else args.lengths
            values = chosen if chosen is not None else values
            for value in values:
                for seed in args.seeds:
                    mask = gaps.generate(protocol, T, J, seed=seed, **{key: value}, **extra)
                    for method in args.methods:
                        err, sec, _ = run_one(truth, mask, method)
                        rows.append({"recording": rec, "protocol": protocol, "param": value,
                                     "seed": seed, "method": method, "rmse_missing": err,
                                     "seconds": sec})
                        print(f"{rec} {protocol} {key}={value} seed={seed} {method}: "
                              f"{err:.3f} ({sec:.1f} s)", flush=True)
    if args.csv:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        with args.csv.open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    if not rows:
        print("no results")
        return 1
    text = tables(rows, args.methods)
    print(text)
    if args.md:
        args.md.parent.mkdir(parents=True, exist_ok=True)
        args.md.write_text(text)
    return 0


def parse_logs(paths: list[Path]) -> list[dict]:
    """Rows from lines ``REC PROTOCOL KEY=VALUE seed=S METHOD: ERR (SEC s)`` (later lines win)."""
    found = {}
    for path in paths:
        for line in path.read_text().splitlines():
            parts = line.split()
            if len(parts) != 8 or not parts[4].endswith(":") or "=" not in parts[2]:
                continue
            value = float(parts[2].split("=")[1])
            value = int(value) if value.is_integer() else value
            row = {"recording": parts[0], "protocol": parts[1], "param": value,
                   "seed": int(parts[3].split("=")[1]), "method": parts[4].rstrip(":"),
                   "rmse_missing": float(parts[5]),
                   "seconds": float(parts[6].lstrip("("))}
            found[(row["recording"], row["protocol"], value, row["seed"], row["method"])] = row
    return list(found.values())


def tables(rows: list[dict], methods: list[str]) -> str:
    """One markdown table per protocol: rows (recording, parameter), columns method, mean +- sd."""
    out = []
    for protocol, (key, _, _) in PROTOCOLS.items():
        sub = [r for r in rows if r["protocol"] == protocol]
        if not sub:
            continue
        out.append(f"\n**{protocol}** (RMSE over missing entries, mm; mean ± sd over seeds; "
                   "best per row in bold)\n")
        out.append("| recording | " + key + " | " + " | ".join(methods) + " |")
        out.append("|---|---|" + "---|" * len(methods))
        cells = sorted({(r["recording"], r["param"]) for r in sub},
                       key=lambda c: (RECORDINGS.index(c[0]) if c[0] in RECORDINGS else 99, c[1]))
        for rec, value in cells:
            stats = {}
            for m in methods:
                e = [r["rmse_missing"] for r in sub
                     if r["recording"] == rec and r["param"] == value and r["method"] == m]
                stats[m] = (np.mean(e), np.std(e), len(e)) if e else None
            best = min((s[0] for s in stats.values() if s), default=None)
            line = []
            for m in methods:
                s = stats[m]
                text = "–" if s is None else f"{s[0]:.2f} ± {s[1]:.2f}"
                line.append(f"**{text}**" if s and s[0] == best else text)
            out.append(f"| {rec.removesuffix('.c3d')} | {value} | " + " | ".join(line) + " |")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    sys.exit(main())
