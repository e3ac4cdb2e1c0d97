"""2-D keypoint tracks: the default fill against linear interpolation on side views of real recordings.

Target: on 2-D side-view projections (torchfill.projection.side_view: orthographic,
camera horizontal and perpendicular to the main horizontal direction, image axes = that direction and
up) of CMU and HDM05 recordings from ../shared/data, with 60-frame gaps on 8 keypoints (multi_gap:
each of 8 random keypoints gets 1-5 gaps of 60 frames, the Tucker paper's protocol), the default
fill's RMSE over the missing coordinates is <= 0.5 x linear interpolation's.

Per recording and seed it prints the RMSE (same units as the recording: mm in the image plane) of
each method, the ratio to linear, the seconds, whether every observed sample came back bit for bit,
and the largest frame-to-frame step inside the gaps relative to the largest observed step of the
same keypoints (plausibility: > 1 would be a teleport). HDM05's unlabelled duplicate points (``*0``
``*1`` ``*2``, exact copies of real markers) are dropped: a gap on a marker whose copy is observed
would be trivially filled.

    OMP_NUM_THREADS=1 nice python scripts/eval_2d.py                # all, seeds 0 1 2
    OMP_NUM_THREADS=1 nice python scripts/eval_2d.py --files cmu_02_01.c3d --seeds 0
"""
from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path

import numpy as np

import torchfill
from torchfill import gaps, metrics
from torchfill.projection import side_view
from torchfill.data import data_dir

DATA = data_dir(Path(__file__).resolve().parents[1])   # $TORCHFILL_DATA or ../shared/data
FILES = ("cmu_02_01.c3d", "cmu_85_02.c3d", "cmu_85_12.c3d", "cmu_135_02.c3d",
         "HDM_bd_01-02_01_120.c3d", "hdm05_bd_05-01_01_120.c3d", "hdm05_mm_01-02_03_120.c3d",
         "hdm05_dg_06-03_03_120.c3d")


def load(name: str) -> torchfill.MarkerSequence:
    seq = torchfill.read(DATA / name)
    keep = [j for j, label in enumerate(seq.short_labels()) if not label.startswith("*")]
    seq = seq.select(keep)
    complete = ~seq.mask.any(axis=0)
    return side_view(seq.select(np.flatnonzero(complete)))


def max_step_ratio(filled: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    """Largest step between consecutive frames inside the gaps over the largest true step of the
    gapped keypoints (observed motion)."""
    cols = mask.any(axis=0)
    step = np.linalg.norm(np.diff(filled[:, cols], axis=0), axis=2)
    true = np.linalg.norm(np.diff(truth[:, cols], axis=0), axis=2)
    inside = mask[1:, cols] | mask[:-1, cols]
    return float(step[inside].max() / true.max())


def run(name: str, seeds: list[int], methods: list[str], n_markers: int, gap_length: int,
        max_gaps: int) -> list[dict]:
    seq = load(name)
    X = seq.points
    T, J = X.shape[:2]
    rows = []
    for seed in seeds:
        mask = gaps.multi_gap(T, J, n_markers=n_markers, gap_length=gap_length, max_gaps=max_gaps,
                              seed=seed)
        gappy = np.where(mask[..., None], np.nan, X)
        result = {}
        for method in methods:
            start = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                out = torchfill.fill(gappy, method)
            result[method] = dict(rmse=metrics.rmse_missing(out, X, mask),
                                  seconds=time.perf_counter() - start,
                                  kept=bool(np.array_equal(out[~mask], X[~mask])),
                                  step=max_step_ratio(out, X, mask))
        base = result["linear"]["rmse"]
        for method, r in result.items():
            rows.append(dict(file=name, T=T, J=J, seed=seed, method=method, ratio=r["rmse"] / base, **r))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", nargs="+", default=list(FILES))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--methods", nargs="+", default=None,
                        help="default: linear, pchip and the default method")
    parser.add_argument("--markers", type=int, default=8)
    parser.add_argument("--gap-length", type=int, default=60)
    parser.add_argument("--max-gaps", type=int, default=5)
    args = parser.parse_args()
    methods = list(dict.fromkeys(["linear"] + (args.methods or ["pchip", torchfill.default_method()])))
    default = torchfill.default_method()
    print(f"side views, multi_gap {args.markers} keypoints x 1-{args.max_gaps} gaps of "
          f"{args.gap_length} frames; rmse over missing coordinates (mm in the image plane); "
          f"default method {default}; load: {os.getloadavg()[0]:.2f}")
    print(f"{'file':<28}{'T':>6}{'J':>4}{'seed':>5}  {'method':<12}{'rmse':>9}{'x linear':>10}"
          f"{'s':>8}{'kept':>6}{'step':>7}")
    summary = {}
    for name in args.files:
        for r in run(name, args.seeds, methods, args.markers, args.gap_length, args.max_gaps):
            print(f"{r['file']:<28}{r['T']:>6}{r['J']:>4}{r['seed']:>5}  {r['method']:<12}"
                  f"{r['rmse']:>9.2f}{r['ratio']:>10.3f}{r['seconds']:>8.2f}{str(r['kept']):>6}"
                  f"{r['step']:>7.2f}", flush=True)
            summary.setdefault((r["file"], r["method"]), []).append(r["ratio"])
    print("\nmedian ratio to linear over seeds (worst in brackets):")
    for (name, method), ratios in summary.items():
        if method != "linear":
            print(f"  {name:<28} {method:<12} {np.median(ratios):.3f} ({max(ratios):.3f})")
    ours = [max(v) for (n, m), v in summary.items() if m == default]
    print(f"default fill <= 0.5 x linear on every recording and seed: {max(ours) <= 0.5} "
          f"(worst {max(ours):.3f})")


if __name__ == "__main__":
    main()
