"""Does the default's hold-out rank the candidates as their real errors do? Three ways to hide
observed samples, compared on the real-gap-pattern suite and the mask suite.

For each case, each method of ``METHODS`` fills the real gaps (its real error, the truth of the
hidden samples: the yardstick only), then the hold-out ``V`` of the default's first draw
(:meth:`torchfill.solvers.auto.Auto._holdout`: the recording's gap pattern shifted in time and
its trial-end gaps mirrored) is scored three ways, each on the observed samples of ``V`` alone:

- ``A`` (what ``auto`` does): the real gaps and ``V`` hidden together, so the fit sees about
  twice the recording's missing samples;
- ``B``: the real gaps filled with the method's own fill of them, ``V`` hidden (the recording's
  density of missing samples, but a method meets its own guesses as data);
- ``C``: the real gaps filled with the median of the methods' fills (all but ``pchip``), ``V``
  hidden.

Per case and style: the real error of the method with the lowest held-out error over the best
real error ("pick"), and the RMS of the real errors weighted as the inverse-MSE average of the
methods within 1.5x of the best held-out MSE weights them ("soft", ``auto``'s weights for one
kind; an upper bound on that average's error). Errors are 3-D RMS in mm, every
fill through ``fill()``'s post-step with ``extrapolate=None``::

    OMP_NUM_THREADS=1 python scripts/holdout_styles.py --mask-suite ref/masks --shard 0/2 --csv A.csv
    python scripts/holdout_styles.py --summary A.csv B.csv
"""
from __future__ import annotations

import argparse
import csv
import sys
import warnings
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_gap_suite as suite  # noqa: E402  (this folder's)
import torchfill  # noqa: E402
from docblock import write_csv  # noqa: E402
from torchfill.solvers.auto import Auto  # noqa: E402

METHODS = ("pchip", "li", "lgrnn", "pma", "pca_gloersen", "tucker_tnn")
STYLES = ("A", "B", "C")


def _fill(X: np.ndarray, method: str) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return torchfill.fill(X, method=method, extrapolate=None)
        except ValueError:
            return np.full(X.shape, np.nan)


def score(case, seed: int = 0) -> dict:
    """One row: per method and style, the RMS error (mm) on the real gaps ("real") or on ``V``."""
    P, m = case.truth.points, case.mask
    rmse = lambda F, sel: float(np.sqrt(np.mean(np.sum((F - P) ** 2, axis=2)[sel])))  # noqa: E731
    auto = Auto(seed=seed)
    auto.generator_ = torch.Generator().manual_seed(seed)
    V = auto._holdout(torch.from_numpy(~m)).numpy()
    real = {k: _fill(np.where(m[..., None], np.nan, P), k) for k in METHODS}
    common = np.where(m[..., None], np.nanmedian(
        np.stack([real[k] for k in METHODS if k != "pchip"]), axis=0), P)
    common[V] = np.nan
    row = {"case": case.name, "seed": seed, "missing": int(m.sum()), "held_out": int(V.sum())}
    for k in METHODS:
        own = np.where(m[..., None], real[k], P)
        own[V] = np.nan
        row[f"{k}_real"] = rmse(real[k], m)
        if V.any():
            row[f"{k}_A"] = rmse(_fill(np.where((m | V)[..., None], np.nan, P), k), V)
            row[f"{k}_B"] = rmse(_fill(own, k), V)
            row[f"{k}_C"] = rmse(_fill(common, k), V)
    return row


def regrets(row: dict, style: str) -> tuple[float, float]:
    """(pick, soft) regret of one row under one style (NaN where nothing was held out)."""
    truth = np.array([float(row[f"{k}_real"]) for k in METHODS])
    held = np.array([float(row.get(f"{k}_{style}", np.nan)) for k in METHODS])
    ok = np.isfinite(truth) & np.isfinite(held)
    if not ok.any():
        return np.nan, np.nan
    best = np.nanmin(truth)
    pick = truth[np.flatnonzero(ok)[np.argmin(held[ok])]] / best
    mse = np.where(ok, held ** 2, np.inf)
    w = np.where(mse <= 1.5 * mse.min(), 1.0 / mse, 0.0)
    soft = np.sqrt(np.sum(w / w.sum() * np.nan_to_num(truth) ** 2)) / best
    return float(pick), float(soft)


def summarize(rows: list[dict]) -> str:
    lines = ["| hold-out | pick: mean regret | cases > 1.25x | soft: mean regret | cases > 1.25x |",
             "|---|---:|---:|---:|---:|"]
    for style in STYLES:
        r = np.array([regrets(row, style) for row in rows])
        r = r[np.isfinite(r).all(axis=1)]
        lines.append(f"| {style} | {r[:, 0].mean():.2f} | {(r[:, 0] > 1.25).sum()} of {len(r)} | "
                     f"{r[:, 1].mean():.2f} | {(r[:, 1] > 1.25).sum()} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mask-suite", type=Path, help="also the cases of scripts/mask_suite.py here")
    ap.add_argument("--seed", type=int, default=0, help="the hold-out draw's seed")
    ap.add_argument("--shard", default="0/1", metavar="I/N")
    ap.add_argument("--csv", type=Path, help="write rows here as they finish")
    ap.add_argument("--summary", type=Path, nargs="*", help="summarize these CSVs and stop")
    args = ap.parse_args()
    if args.summary:
        rows = []
        for path in args.summary:
            with open(path, newline="") as handle:
                rows += list(csv.DictReader(handle))
        print(f"{len(rows)} cases\n" + summarize(rows))
        return
    cases = (suite.mask_suite(args.mask_suite) if args.mask_suite else []) + suite.cases()
    rows = []
    for case in suite.select(cases, None, args.shard):
        rows.append(score(case, args.seed))
        r = rows[-1]
        print(f"{case.name}: " + ", ".join(
            f"{k} {r[f'{k}_real']:.1f}/" + "/".join(f"{r.get(f'{k}_{s}', np.nan):.1f}"
                                                   for s in STYLES) for k in METHODS),
              flush=True)
        if args.csv:
            write_csv(args.csv, rows)
    print(summarize(rows))


if __name__ == "__main__":
    main()
