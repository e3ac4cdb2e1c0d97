"""Plausibility of fills on the REAL gaps of every gapped recording in ../shared/data.

For each file and method: teleports (one-frame steps touching a fill longer than 1.5 x the
recording's 99.9th-percentile observed step), jumps (the same against each marker's own
observed steps: a slow marker's jump that the feet's fast steps hide), samples outside the observed volume (+10 % per
axis), rigid-pair deviation (median / p95 over filled frames of pairs found rigid on the observed
data), p95 velocity jump at gap edges, samples left NaN, and seconds. ``default`` is the default
method with constraints (``fill()`` as a user calls it); the others are the methods' own fills
(``constraints=False``), as they were before the constraints existed; ``NAME+c`` is ``NAME`` with
the constraints (e.g. ``auto+c``). Last, the mean 3-D error on ktk_tennis_serve_nan.c3d against its
clean twin ktk_tennis_serve.c3d (``--files ''``: only that), and for ``auto`` its error estimate
there (share of filled samples within 2 sqrt(3) std, Spearman of per-gap std vs per-gap error).

Usage::

    OMP_NUM_THREADS=1 nice python scripts/eval_real_gaps.py [--methods default,pchip] [--files a,b]
"""
from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

import torchfill
from torchfill import metrics
from torchfill.solvers.rigid import rigid_pairs
from torchfill.data import data_dir

DATA = data_dir(Path(__file__).resolve().parents[1])   # $TORCHFILL_DATA or ../shared/data
#: The 17 recordings with real gaps (PROVENANCE.md): gaps in markers that are observed at times.
#: ktk_tennis_serve_nan.c3d (artificial gaps) is scored against its twin instead, and
#: osim_hamner_subject02_running.trc only lacks a never-observed marker.
FILES = [
    "c3dorg_s00_codamotion_gaitwands_20150204.c3d", "c3dorg_s01_eb015pr.c3d",
    "c3dorg_s02_pc_real.c3d", "c3dorg_s04_sub_labels.c3d", "c3dorg_s26_capture0002.c3d",
    "c3dorg_s26_walking_hybrid_1_1.c3d", "c3dorg_s26_walking_hybrid_1_2.c3d",
    "c3dorg_s26_walking_hybrid_1_3.c3d", "c3dorg_s26_walking_hybrid_1_4.c3d",
    "c3dorg_s26_walking_hybrid_1_5.c3d", "c3dorg_s26_walking_hybrid_2.c3d",
    "c3dorg_s28_type1.c3d", "ktk_basket_sprint.c3d", "ktk_c3d_sample_bts.c3d",
    "ktk_racing_full.c3d", "mogapfill_gait-raw.csv", "numediart_03_rolling.c3d",
]
METHODS = ["default", "tucker_tnn", "cp", "pchip", "linear"]


def run(seq, method: str, std: bool = False):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        start = time.perf_counter()
        if method == "default":
            out = torchfill.fill(seq, return_std=std)
        else:
            name, constrained = method.removesuffix("+c"), method.endswith("+c")
            out = torchfill.fill(seq, name, constraints=constrained, return_std=std)
        return out, time.perf_counter() - start


def plausibility(seq, out) -> dict:
    X = seq.points
    missing = seq.mask
    observed = ~missing
    pairs = rigid_pairs(np.where(observed[..., None], X, np.nan))        # near neighbours only
    rigid = pairs.matrix(pairs.rigid & ~pairs.duplicate, fill=False)
    dev = metrics.rigid_deviation(out.points, missing, rigid, pairs.matrix(pairs.distance))
    jumps = metrics.edge_jumps(out.points, missing)
    scale = 1000.0 if seq.units.strip().lower() == "m" else 1.0       # report mm
    return {
        "teleports": metrics.teleports(out.points, missing, metrics.step_limit(X, observed)),
        "jumps": metrics.marker_jumps(out.points, missing, observed),
        "outside": metrics.outside_volume(out.points, missing, metrics.volume(X, observed)),
        "rigid_med": scale * float(np.median(dev)) if dev.size else np.nan,
        "rigid_p95": scale * float(np.percentile(dev, 95)) if dev.size else np.nan,
        "edge_p95": scale * float(np.percentile(jumps, 95)) if jumps.size else np.nan,
        "nan_left": int((missing & ~np.isfinite(out.points).all(axis=2)).sum()),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--files", default=",".join(FILES))
    args = parser.parse_args()
    methods = args.methods.split(",")
    cols = ["teleports", "jumps", "outside", "rigid_med", "rigid_p95", "edge_p95", "nan_left", "seconds"]
    print(f"{'file':<44} {'method':<11}" + "".join(f"{c:>10}" for c in cols))
    for name in filter(None, args.files.split(",")):
        seq = torchfill.read(DATA / name)
        for method in methods:
            out, seconds = run(seq, method)
            row = {**plausibility(seq, out), "seconds": seconds}
            print(f"{name[:44]:<44} {method:<11}" + "".join(
                f"{row[c]:>10.3g}" if isinstance(row[c], float) else f"{row[c]:>10d}"
                for c in cols),
                flush=True)
    clean = torchfill.read(DATA / "ktk_tennis_serve.c3d")
    gappy = torchfill.read(DATA / "ktk_tennis_serve_nan.c3d")
    for method in methods:
        auto = method.startswith("auto")
        out, _ = run(gappy, method, std=auto)
        out, std = out if auto else (out, None)
        err = 1000 * metrics.gap_error(out.points, clean.points, gappy.mask)
        e3 = np.linalg.norm(out.points - clean.points, axis=2)
        mean3d = 1000 * float(e3[gappy.mask].mean())
        line = (f"ktk_tennis_serve_nan vs clean  {method:<11} mean 3-D error {mean3d:.2f} mm "
                f"(mean per gap {err:.2f} mm)")
        if auto:
            m = gappy.mask & np.isfinite(std)
            runs = metrics.gap_runs(gappy.mask)
            real = [np.sqrt(np.nanmean(e3[a:b, j] ** 2)) for j, a, b in runs]
            est = [np.nanmean(std[a:b, j]) for j, a, b in runs]
            line += (f"; within 2 sqrt(3) std {np.mean(e3[m] <= 2 * np.sqrt(3) * std[m]):.2f}, "
                     f"Spearman per gap {spearmanr(real, est).statistic:.2f} ({len(runs)} gaps)")
        print(line, flush=True)


if __name__ == "__main__":
    main()
