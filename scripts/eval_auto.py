"""Evaluate ``auto`` against every single method on a suite of gap masks on real recordings.

Cases (built with torchfill.gaps and the small generators below, seeded):
HDM05 multi-gap (Tucker paper protocol), CMU shared windows of 10/20/30 of 41 markers (CP paper
protocol), dense clustered occlusions where every marker has a gap, a shared window on the most
still stretch, a whole-frame blackout, and gaps at the trial ends. Masks from the MATLAB reference
suite (``--masks ref/masks``, written by scripts/mask_suite.py) are used
instead when given, with the MATLAB PMA / Gloersen fills of that run (``--ref``, default
ref/out, ``<case>__pma.npz``) scored beside (columns refreshed on every run, ``--resume``
included, so a later run picks up reference fills that finished since).

Prints per case the RMSE over all entries (Tucker/CP papers' convention, mm) of every method and of
``auto``, then the summary the issue asks for, and the error estimate's checks: Spearman rank
correlation of the per-gap mean estimated std with the real per-gap RMS error, and the share of
filled samples whose 3-D error is within 2*sqrt(3)*std. Rows go to ``--csv`` as they finish
(``--resume`` skips finished cases)::

    OMP_NUM_THREADS=1 nice python scripts/eval_auto.py --csv experiments/results/auto_eval.csv
"""
from __future__ import annotations

import argparse
import csv
import json
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

import torchfill
from torchfill import gaps
from torchfill.metrics import gap_runs, rmse
from torchfill.data import data_dir

DATA = data_dir(Path(__file__).resolve().parents[1])   # $TORCHFILL_DATA or ../shared/data
SINGLES = ("linear", "pchip", "spline", "pca_train", "svt", "cp", "tucker_tnn", "rigid",
           "pca_gloersen", "li", "lgrnn", "pma")


def complete(name: str, frames: int | None) -> np.ndarray:
    """The recording's markers that are never missing, first ``frames`` frames."""
    P = torchfill.read(DATA / name).points
    P = P[:frames] if frames else P
    return P[:, np.isfinite(P).all(axis=2).all(axis=0)]


def suite() -> list[tuple[str, str, int | None, callable]]:
    """(case, recording, frames, mask maker) of the built-in suite: modest, for a shared machine."""
    return [
        ("hdm_bd_multigap", "HDM_bd_01-02_01_120.c3d", 1500,
         lambda P: gaps.multi_gap(*P.shape[:2], n_markers=20, gap_length=100, max_gaps=5, seed=0)),
        ("hdm_mm_multigap", "hdm05_mm_01-02_03_120.c3d", 1500,
         lambda P: gaps.multi_gap(*P.shape[:2], n_markers=20, gap_length=100, max_gaps=5, seed=1)),
        *[(f"cmu85_02_shared{n}", "cmu_85_02.c3d", None,
           (lambda n: lambda P: gaps.shared_window(*P.shape[:2], n_markers=n, gap_length=50,
                                                   seed=0))(n)) for n in (10, 20, 30)],
        ("cmu02_01_shared20", "cmu_02_01.c3d", None,
         lambda P: gaps.shared_window(*P.shape[:2], n_markers=20, gap_length=50, seed=2)),
        ("cmu85_02_still30", "cmu_85_02.c3d", None,
         lambda P: gaps.still_window(P, n_markers=30, gap_length=50)),
        ("hdm_bd_dense", "HDM_bd_01-02_01_120.c3d", 1200, lambda P: gaps.grouped_windows(P, seed=0)),
        ("cmu135_02_dense", "cmu_135_02.c3d", 1200, lambda P: gaps.grouped_windows(P, seed=1)),
        ("cmu85_12_blackout", "cmu_85_12.c3d", 1200,
         lambda P: gaps.blackout(*P.shape[:2], gap_length=20, seed=0)),
        ("hdm_dg_ends", "hdm05_dg_06-03_03_120.c3d", None,
         lambda P: gaps.trial_ends(*P.shape[:2], n_markers=10, gap_length=30)),
        ("cmu85_12_ends", "cmu_85_12.c3d", 1200,
         lambda P: gaps.trial_ends(*P.shape[:2], n_markers=12, gap_length=60, seed=1)),
    ]


def per_gap(filled: np.ndarray, std: np.ndarray, truth: np.ndarray, mask: np.ndarray):
    """Per marker-gap: (marker, start, stop, real RMS 3-D error, mean estimated std)."""
    err = np.linalg.norm(filled - truth, axis=2)
    return [(j, a, b, float(np.sqrt(np.mean(err[a:b, j] ** 2))), float(np.mean(std[a:b, j])))
            for j, a, b in gap_runs(mask)]


def mask_suite(folder: Path) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(case, truth, mask) of every case written by scripts/mask_suite.py, in cases.json order."""
    order = [c["name"] for c in json.loads((folder / "cases.json").read_text())]
    out = []
    for name in order:
        with np.load(folder / f"{name}.npz") as z:
            out.append((name, np.array(z["truth"]), np.array(z["mask"])))
    return out


def reference_rmse(folder: Path | None, case: str, truth: np.ndarray, mask: np.ndarray) -> dict:
    """RMSE of the MATLAB reference fills ``<case>__pma.npz`` / ``__gloersen.npz`` (from the
    i12-ref run) where present; NaN where that code left samples unfilled or failed."""
    row = {}
    for tag in ("pma", "gloersen"):
        path = folder / f"{case}__{tag}.npz" if folder else None
        if path is None or not path.exists():
            continue
        with np.load(path, allow_pickle=True) as z:
            filled, ok = np.array(z["filled"]), bool(z["ok"])
        done = ok and filled.shape == truth.shape and np.isfinite(filled[mask]).all()
        row[f"matlab_{tag}"] = rmse(filled, truth, mask) if done else float("nan")
    return row


def std_checks(filled: np.ndarray, std: np.ndarray, truth: np.ndarray, mask: np.ndarray):
    """(Spearman of per-gap mean std vs per-gap RMS error, share within 2 sqrt(3) std)."""
    err = np.linalg.norm(filled - truth, axis=2)
    gaps_ = per_gap(filled, std, truth, mask)
    rho = (spearmanr([g[3] for g in gaps_], [g[4] for g in gaps_]).statistic
           if len(gaps_) > 2 else float("nan"))
    return float(rho), float(np.mean(err[mask] <= 2 * np.sqrt(3) * std[mask]))


def run_case(case, P, mask, methods, auto_params, reuse: dict | None = None) -> dict:
    X = np.where(mask[..., None], np.nan, P)
    row = {"case": case, "T": P.shape[0], "J": P.shape[1], "missing": int(mask.sum())}
    for m in methods:
        if reuse and reuse.get(m, "") not in ("", "nan"):   # scored by an earlier run
            row[m], row[f"{m}_s"] = float(reuse[m]), float(reuse[f"{m}_s"])
            continue
        t = time.perf_counter()
        try:
            out = torchfill.fill(X, method=m)
            row[m] = rmse(out, P, mask)
        except ValueError as err:                       # a method that cannot fill this case
            row[m] = float("nan")
            print(f"  {case}: {m} failed: {err}", flush=True)
        row[f"{m}_s"] = time.perf_counter() - t
    if auto_params is None:                             # singles only (--no-auto)
        row.update(auto=float("nan"), auto_s=float("nan"), spearman=float("nan"),
                   within=float("nan"))
        return row, []
    if reuse and reuse.get("auto", "") not in ("", "nan"):
        row.update({k: float(reuse[k]) for k in ("auto", "auto_s", "spearman", "within")})
        return row, []
    t = time.perf_counter()
    out, std = torchfill.fill(X, method="auto", return_std=True, **auto_params)
    row["auto_s"] = time.perf_counter() - t
    row["auto"] = rmse(out, P, mask)
    row["spearman"], row["within"] = std_checks(out, std, P, mask)
    return row, [(case, *g) for g in per_gap(out, std, P, mask)]


def summary(rows: list[dict], methods: list[str]) -> str:
    present = [m for m in methods if any(np.isfinite(float(r.get(m, "nan"))) for r in rows)]
    lines = ["| case | " + " | ".join(present) + " | auto | auto/best | spearman | within | auto s | slowest s |",
             "|---|" + "---:|" * (len(present) + 6)]
    ratios = []
    for r in rows:
        vals = [float(r[m]) for m in present]
        best = np.nanmin(vals)
        ratios.append(float(r["auto"]) / best)
        slow = max(float(r[f"{m}_s"]) for m in present)
        lines.append(f"| {r['case']} | " + " | ".join(f"{v:.2f}" for v in vals)
                     + f" | **{float(r['auto']):.2f}** | {ratios[-1]:.2f} | {float(r['spearman']):.2f}"
                     f" | {float(r['within']):.2f} | {float(r['auto_s']):.1f} | {slow:.1f} |")
    means = {m: np.mean([float(r[m]) for r in rows]) for m in present}
    lines.append("| **mean** | " + " | ".join(f"{means[m]:.2f}" for m in present)
                 + f" | **{np.mean([float(r['auto']) for r in rows]):.2f}** | {max(ratios):.2f} (max) | "
                 f"{np.nanmean([float(r['spearman']) for r in rows]):.2f} | "
                 f"{np.mean([float(r['within']) for r in rows]):.2f} | | |")
    best_single = min(means, key=lambda m: means[m] if np.isfinite(means[m]) else np.inf)
    per_case = np.mean([np.nanmin([float(r[m]) for m in present]) for r in rows])
    lines.append(f"\nbest single method by mean: {best_single} {means[best_single]:.2f}; "
                 f"per-case best single method averages {per_case:.2f}; "
                 f"auto mean {np.mean([float(r['auto']) for r in rows]):.2f}; "
                 f"worst auto / per-case best {max(ratios):.2f}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--csv", default="experiments/results/auto_eval.csv")
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--cases", nargs="*", help="only these case names, in this order")
    parser.add_argument("--combine", default="average", choices=("average", "select"))
    parser.add_argument("--masks", type=Path, help="use the cases of scripts/mask_suite.py in DIR")
    parser.add_argument("--ref", type=Path, default=Path("ref/out"),
                        help="MATLAB reference fills <case>__pma.npz etc. (columns when present)")
    parser.add_argument("--methods", nargs="*", default=list(SINGLES), help="single methods")
    parser.add_argument("--no-auto", action="store_true", help="score the single methods only")
    parser.add_argument("--reuse", type=Path, nargs="+", help="take the scores of a case (single "
                        "methods, auto) from these earlier CSVs (same masks) instead of refilling")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    methods = [m for m in args.methods if m in torchfill.methods()]
    reuse = {}
    for earlier in args.reuse or ():
        with open(earlier) as f:
            for r in csv.DictReader(f):
                have = reuse.setdefault(r["case"], {})
                have.update({k: v for k, v in r.items() if v not in ("", "nan")})
    path = Path(args.csv)
    done = []
    if args.resume and path.exists():
        with open(path) as f:
            done = list(csv.DictReader(f))
    rows = list(done)
    if not args.resume:
        path.with_name(path.stem + "_gaps.csv").unlink(missing_ok=True)
    names = {r["case"] for r in done}
    if args.masks:
        cases = [(case, P, mask) for case, P, mask in mask_suite(args.masks)]
    else:
        cases = [(case, (P := complete(name, frames)), make(P))
                 for case, name, frames, make in suite()]
    if args.cases:                                      # in the order given
        cases = sorted((c for c in cases if c[0] in args.cases), key=lambda c: args.cases.index(c[0]))
    for case, P, mask in cases:
        if case in names:
            continue
        row, gap_rows = run_case(case, P, mask, methods,
                                 None if args.no_auto else {"combine": args.combine},
                                 reuse.get(case))
        rows.append(row)
        with open(path.with_name(path.stem + "_gaps.csv"), "a", newline="") as f:
            csv.writer(f).writerows(gap_rows)
        print(f"{case}: " + "  ".join(f"{m}={row[m]:.2f}" for m in methods + ["auto"])
              + f"  spearman={row['spearman']:.2f} within={row['within']:.2f} "
              f"auto {row['auto_s']:.1f}s", flush=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        keys = list(dict.fromkeys(k for r in rows for k in r))
        with open(path, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=keys)
            writer.writeheader()
            writer.writerows(rows)
    if args.masks and args.ref.is_dir():
        truth = {case: (P, mask) for case, P, mask in cases}
        for r in rows:
            r.update(reference_rmse(args.ref, r["case"], *truth[r["case"]]))
        keys = list(dict.fromkeys(k for r in rows for k in r))
        with open(path, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=keys)
            writer.writeheader()
            writer.writerows(rows)
    print(summary(rows, methods))
    for tag in ("matlab_pma", "matlab_gloersen"):
        both = [r for r in rows if np.isfinite(float(r.get(tag, "nan")))]
        if both:
            print(f"{tag}: filled {len(both)} of {len(rows)} cases; on those, mean {tag} "
                  f"{np.mean([float(r[tag]) for r in both]):.2f} vs auto "
                  f"{np.mean([float(r['auto']) for r in both]):.2f}; auto better on "
                  f"{sum(float(r['auto']) < float(r[tag]) for r in both)}")
    gaps_path = path.with_name(path.stem + "_gaps.csv")
    table = np.genfromtxt(gaps_path, delimiter=",", usecols=(4, 5), ndmin=2) \
        if gaps_path.exists() and gaps_path.stat().st_size else np.empty((0, 2))
    if len(table) > 2:
        print(f"pooled over {len(table)} marker-gaps of all cases: Spearman(real per-gap RMS error, "
              f"mean std) = {spearmanr(table[:, 0], table[:, 1]).statistic:.2f}")


if __name__ == "__main__":
    main()
