"""Reference check: the MATLAB originals (PMA of Tits et al. 2018, Gløersen & Federolf's
PredictMissingMarkers) against torchfill's methods, on the same masks (scripts/mask_suite.py).

Needs no Octave: the originals' fills are read from ``ORIGINALS/<case>__<name>.npz`` (``filled``
(T, J, 3), ``seconds``, ``ok``) as written by the out-of-repo Octave run (ref/). torchfill's
methods are run here on each case's ``points``. Per case: RMSE over all entries and over the missing
entries (mm; unfilled samples are left out of both and counted separately), seconds. Means: over
the cases every method fills, and over all cases with each method's unfilled samples taken from
linear interpolation (what a user would fall back to).

    OMP_NUM_THREADS=1 .venv/bin/python scripts/pma_reference.py --masks ref/masks \\
        --originals ref/out --out experiments/results/pma_reference.md [--csv runs.csv]
"""
from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np
import torch

from torchfill import metrics
from torchfill.solvers import available, get_solver

ORIGINALS = {"pma": "PMA (Octave)", "gloersen": "Gløersen PCA (Octave)"}
OURS = ["linear", "pchip", "tucker_tnn", "pca_gloersen", "glr", "li", "lpr", "lgrnn", "pma"]


def score(filled: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> dict:
    """RMSE over all entries / missing entries on the samples that were filled, and the count of
    hidden samples left unfilled (NaN or not finite)."""
    unfilled = mask & ~np.isfinite(filled).all(axis=2)
    done = mask & ~unfilled
    F = np.where(unfilled[..., None], truth, filled)        # unfilled samples count as no error here
    return {"rmse": metrics.rmse(F, truth, done), "rmse_missing": metrics.rmse_missing(F, truth, done),
            "unfilled": int(unfilled.sum()), "hidden": int(mask.sum())}


def run_ours(method: str, points: np.ndarray) -> tuple[np.ndarray, float, str]:
    solver = get_solver(method)
    t0 = time.perf_counter()
    try:
        filled = solver.fit_transform(torch.from_numpy(points.copy())).numpy()
        err = ""
    except Exception as exc:                                 # a failure is a result here, not a crash
        filled, err = points.copy(), f"{type(exc).__name__}: {exc}"
    return filled, time.perf_counter() - t0, err


def load_original(folder: Path, case: str, name: str, points: np.ndarray):
    path = folder / f"{case}__{name}.npz"
    if not path.exists():
        return None
    z = np.load(path)
    filled = z["filled"] if bool(z["ok"]) else points.copy()
    msg = "" if bool(z["ok"]) else "failed: " + str(z["msg"])
    if not np.isfinite(z["seconds"]):
        msg = "timed out"
    return filled, float(z["seconds"]), msg


def evaluate(masks: Path, originals: Path, methods: list[str]) -> list[dict]:
    rows = []
    for case in json.loads((masks / "cases.json").read_text()):
        z = np.load(masks / f"{case['name']}.npz")
        points, truth, mask = z["points"], z["truth"], z["mask"]
        fills = {}
        for name, label in ORIGINALS.items():
            got = load_original(originals, case["name"], name, points)
            if got is not None:
                fills[label] = got
        for m in methods:
            fills[m] = run_ours(m, points)
        linear = fills["linear"][0] if "linear" in fills else run_ours("linear", points)[0]
        for label, (filled, secs, msg) in fills.items():
            sc = score(filled, truth, mask)
            changed = np.isfinite(points) & (filled != points)
            row = {"case": case["name"], "kind": case["kind"], "method": label, **sc, "seconds": secs,
                   "observed_changed": int(changed.any(axis=2).sum()),
                   "observed_max_change": float(np.nanmax(np.abs(filled - points), initial=0.0)),
                   "note": msg}
            F = np.where(np.isfinite(filled), filled, linear)   # unfilled -> linear interpolation
            row["rmse_fallback"] = metrics.rmse(F, truth, mask)
            rows.append(row)
            print(f"{case['name']:24s} {label:24s} rmse={sc['rmse']:7.3f} miss={sc['rmse_missing']:7.2f} "
                  f"unfilled={sc['unfilled']:5d}/{sc['hidden']} {secs:7.2f}s {msg}", flush=True)
    return rows


def markdown(rows: list[dict]) -> str:
    methods = list(dict.fromkeys(r["method"] for r in rows))
    cases = list(dict.fromkeys(r["case"] for r in rows))
    R = {(r["case"], r["method"]): r for r in rows}
    kinds = {r["case"]: r["kind"] for r in rows}
    cell = lambda r, k: "—" if r is None else ("unfilled" if r["unfilled"] == r["hidden"] else
                                               f"{r[k]:.2f}" + ("*" if r["unfilled"] else ""))
    out = []
    for key, title in (("rmse", "RMSE over all entries (mm)"), ("rmse_missing", "RMSE over missing entries (mm)")):
        out += [f"### {title}", "", "| case | kind | " + " | ".join(methods) + " | best |",
                "|---|---|" + "---|" * (len(methods) + 1)]
        for c in cases:
            rs = [R.get((c, m)) for m in methods]
            ok = [(r[key], r["method"]) for r in rs if r is not None and r["unfilled"] == 0]
            best = min(ok)[1] if ok else "—"
            out.append(f"| {c} | {kinds[c]} | " + " | ".join(cell(r, key) for r in rs)
                       + f" | {best} |")
        out.append("")
    full = [c for c in cases if all(R.get((c, m)) and R[(c, m)]["unfilled"] == 0 for m in methods)]
    out += ["### Means", "", f"Cases every method fills completely: {len(full)} of {len(cases)}.", "",
            "| method | mean RMSE all (filled-by-all cases) | mean RMSE missing (same) | mean RMSE all, unfilled → linear (all cases) | cases with unfilled samples | median s | max s |",
            "|---|---|---|---|---|---|---|"]
    for m in methods:
        rs = [R[(c, m)] for c in cases if (c, m) in R]
        a = np.mean([R[(c, m)]["rmse"] for c in full]) if full else np.nan
        b = np.mean([R[(c, m)]["rmse_missing"] for c in full]) if full else np.nan
        fb = np.mean([r.get("rmse_fallback", np.nan) for r in rs])
        nu = sum(r["unfilled"] > 0 for r in rs)
        s = [r["seconds"] for r in rs]
        out.append(f"| {m} | {a:.2f} | {b:.2f} | {fb:.2f} | {nu} | {np.median(s):.1f} | {np.max(s):.1f} |")
    best = [min(R[(c, m)]["rmse"] for m in methods if (c, m) in R and R[(c, m)]["unfilled"] == 0) for c in full]
    out += ["", f"Per-case best over these methods, mean over the {len(full)} fully filled cases: "
            f"{np.mean(best):.2f} mm." if best else "", "", "### Unfilled samples", ""]
    for c in cases:
        left = [f"{m} ({R[(c, m)]['unfilled']}/{R[(c, m)]['hidden']}{', ' + R[(c, m)]['note'] if R[(c, m)]['note'] else ''})"
                for m in methods if (c, m) in R and R[(c, m)]["unfilled"]]
        out.append(f"- {c}: " + (", ".join(left) if left else "all methods fill every hidden sample"))
    changed = [f"{r['case']}/{r['method']} ({int(r['observed_changed'])} samples, max {r['observed_max_change']:.1e} mm)"
               for r in rows if r["observed_changed"]]
    out += ["", "Observed samples changed (any bit): " + ("; ".join(changed) if changed else "none")]
    return "\n".join(out) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--masks", type=Path, default=Path("ref/masks"))
    ap.add_argument("--originals", type=Path, default=Path("ref/out"))
    ap.add_argument("--methods", nargs="*", default=None,
                    help=f"torchfill methods (default: those of {OURS} that are registered)")
    ap.add_argument("--csv", type=Path, default=None, help="every row, for later --tables")
    ap.add_argument("--tables", type=Path, nargs="+", default=None,
                    help="only print the markdown of earlier --csv files (rows merged)")
    ap.add_argument("--out", type=Path, default=None, help="markdown file")
    args = ap.parse_args(argv)
    if args.tables:
        rows = [{k: (v if k in ("case", "kind", "method", "note") else float(v)) for k, v in r.items()}
                for path in args.tables for r in csv.DictReader(open(path))]
    else:
        methods = [m for m in OURS if m in available()] if args.methods is None else args.methods
        rows = evaluate(args.masks, args.originals, methods)
        if args.csv:
            with open(args.csv, "w", newline="") as fh:
                w = csv.DictWriter(fh, fieldnames=list(rows[0]))
                w.writeheader()
                w.writerows(rows)
    text = markdown(rows)
    if args.out:
        args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
