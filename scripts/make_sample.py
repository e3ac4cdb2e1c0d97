"""Regenerate the embedded sample recording ``torchfill/data/sample_walk.c3d``.

    .venv/bin/python scripts/make_sample.py            # write it (deterministic for a given writer)
    .venv/bin/python scripts/make_sample.py --compare  # also compare it with a real walk

The file is ``synthetic_walk(seed=0)`` written by torchfill itself, then read back and checked.
``--compare`` simulates 10 markers x 60-frame gaps (``continuous_runs``, seeds 0-9) on the sample
and on the CMU walk ``cmu_02_01.c3d`` (from ``$TORCHFILL_DATA`` or ``../shared/data``) and prints
the interpolation errors and the singular value energy of both, to show the sample is realistic.
"""
from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

import torchfill
from torchfill import gaps, metrics
from torchfill.data import data_dir, sample_path
from torchfill.data.synth import synthetic_walk

DATA_DIR = data_dir(Path(__file__).resolve().parents[1])


def make() -> None:
    seq = synthetic_walk(seconds=8.0, rate=120.0, seed=0)
    path = sample_path()
    torchfill.write(seq, path)
    back = torchfill.read(path)
    assert back.short_labels() == seq.labels, "labels changed on the round trip"
    assert back.rate == seq.rate and back.units == seq.units
    err = float(np.max(np.abs(back.points - seq.points)))
    assert err < 0.01, f"points changed by {err} mm on the round trip"
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB): {back}; "
          f"max round-trip change {err:.1e} mm (float32)")


def interpolation_errors(points: np.ndarray, seeds=range(10)) -> dict[str, float]:
    """Mean RMSE over the gaps (mm) of linear/spline/pchip, 10 markers x 60-frame gaps."""
    T, J, _ = points.shape
    errors = {m: [] for m in ("linear", "spline", "pchip")}
    for seed in seeds:
        mask = gaps.continuous_runs(T, J, n_markers=10, gap_length=60, seed=seed)
        gappy = np.where(mask[..., None], np.nan, points)
        for method, values in errors.items():
            values.append(metrics.rmse_missing(torchfill.fill(gappy, method=method), points, mask))
    return {m: float(np.mean(v)) for m, v in errors.items()}


def energy(points: np.ndarray, ranks=(1, 3, 5)) -> list[float]:
    """Share of the energy in the leading singular values of the centred T x 3J unfolding."""
    M = points.reshape(points.shape[0], -1)
    s = np.linalg.svd(M - M.mean(axis=0), compute_uv=False)
    share = np.cumsum(s ** 2) / np.sum(s ** 2)
    return [round(float(share[r - 1]), 5) for r in ranks]


def compare() -> None:
    real = DATA_DIR / "cmu_02_01.c3d"
    rows = [("sample_walk (960 frames)", torchfill.read(sample_path()).points)]
    if real.is_file():
        cmu = torchfill.read(real)
        complete = np.isfinite(cmu.points).all(axis=(0, 2))
        rows.append((f"cmu_02_01 ({cmu.n_frames} frames)", cmu.points[:, complete]))
        rows.append(("sample_walk, first 343 frames", rows[0][1][:343]))
    else:
        print(f"({real} not found: comparing the sample only)")
    print("RMSE over 10 markers x 60-frame gaps (mm, mean of seeds 0-9); energy in 1/3/5 SVs")
    for name, points in rows:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            err = interpolation_errors(points)
        print(f"{name:32s} " + "  ".join(f"{m} {v:6.1f}" for m, v in err.items())
              + f"   energy {energy(points)}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compare", action="store_true", help="also compare it with a real walk")
    args = parser.parse_args()
    make()
    if args.compare:
        compare()
