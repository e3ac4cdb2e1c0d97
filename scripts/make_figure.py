"""The README's figure: a real gap of a real recording, the default fill and its +-2 sigma band.

    python scripts/make_figure.py [RECORDING] [-o docs/img/fill.png]

RECORDING defaults to c3dorg_s26_walking_hybrid_1_1.c3d in the shared data folder
(TORCHFILL_DATA or ../shared/data). The gap shown is the longest one observed on both sides
(interpolated, not extrapolated) of at most 2 s; sigma is fill(..., return_std=True)'s estimate of
each filled coordinate's error std, from held-out observed samples only.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import torchfill
from torchfill.data import data_dir
from torchfill.metrics import gap_runs

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recording", nargs="?",
                    default=str(data_dir(ROOT) / "c3dorg_s26_walking_hybrid_1_1.c3d"))
    ap.add_argument("-o", "--output", default=str(ROOT / "docs" / "img" / "fill.png"))
    args = ap.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seq = torchfill.read(args.recording)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # the recording's trial-end gaps are not shown
        out, std = torchfill.fill(seq, return_std=True)
    T = seq.n_frames
    gaps = [(j, a, b) for j, a, b in gap_runs(seq.mask) if a > 0 and b < T
            and b - a <= 2 * seq.rate and np.isfinite(out.points[a:b, j]).all()]
    j, a, b = max(gaps, key=lambda g: g[2] - g[1])
    pad = int(seq.rate)
    lo, hi = max(a - pad, 0), min(b + pad, T)
    t = np.arange(lo, hi) / seq.rate
    inside = (np.arange(lo, hi) >= a - 1) & (np.arange(lo, hi) <= b)   # the gap and its edges
    fig, axes = plt.subplots(1, 3, figsize=(9, 2.4), sharex=True)
    for d, ax in enumerate(axes):
        seen = seq.points[lo:hi, j, d]
        fill = np.where(inside, out.points[lo:hi, j, d], np.nan)
        s = np.nan_to_num(np.where(inside, std[lo:hi, j], np.nan))
        ax.axvspan(a / seq.rate, (b - 1) / seq.rate, color="0.92", lw=0)
        ax.plot(t, seen, color="k", lw=1.2, label="observed")
        ax.plot(t, fill, color="tab:red", lw=1.2, label="filled")
        ax.fill_between(t, fill - 2 * s, fill + 2 * s, color="tab:red", alpha=0.25, lw=0,
                        label="±2σ (estimated)")
        ax.set_title(f"{'xyz'[d]} ({seq.units})", fontsize=9)
        ax.tick_params(labelsize=8)
        ax.set_xlabel("time (s)", fontsize=8)
    axes[0].legend(fontsize=7, frameon=False, loc="best")
    name = Path(args.recording).name
    fig.suptitle(f"{name}: marker {seq.labels[j]}, a real {b - a}-frame gap, default fill ({torchfill.default_method()})",
                 fontsize=9)
    fig.tight_layout()
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output, dpi=90)
    print(f"{name}: marker {seq.labels[j]}, frames {a}-{b - 1} -> {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
