"""Li et al. 2020 protocols on the recordings we have: PCA gap filling with a training set.

Test data: 200-frame segments cut from a test recording (evenly spread over it). Gaps:

* ``table1``: 5 evenly spaced gaps of 20/50/80/100 frames, each on a random marker (paper Table 1);
* ``table2``: 1-8 evenly spaced gaps of 100 frames (paper Table 2);
* ``blackout``: 5-40 % of the segment's frames missing entirely, one run (paper Fig. 8).

Metric: mean 3-D error per gap in mm (Eq. 17, ``torchfill.metrics.gap_error``), averaged over
segments and seeds. Training scenarios: ``cross`` = other recordings with the same 41-marker Vicon
set (matched by label); ``self`` = the rest of the test recording (the segment cut out), the paper's
"long motion sequence" case.

``--dev`` runs the development set used to choose the defaults (other test recordings than the
reported ones); the reported numbers come from the default set.

Usage::

    OMP_NUM_THREADS=1 nice .venv/bin/python scripts/pca_tables.py [--dev] [--lowrank]
        [--segments 3] [--seeds 2] [--only table1,table2,blackout] [--csv out.csv]
"""
from __future__ import annotations

import argparse
import csv
import datetime
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

import torchfill
from torchfill import gaps, metrics

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TORCHFILL_DATA") or REPO / ".." / "shared" / "data").resolve()
SEG = 200

REPORT = dict(tests=["hdm05_mm_01-02_03_120.c3d", "cmu_85_12.c3d"],
              training=["hdm05_bd_05-01_01_120.c3d", "HDM_bd_01-02_01_120.c3d", "cmu_135_02.c3d"])
DEV = dict(tests=["cmu_85_02.c3d", "HDM_bd_01-02_01_120.c3d"],
           training=["cmu_02_01.c3d", "hdm05_mm_01-02_03_120.c3d", "cmu_135_02.c3d"])

GRIDS = {
    "table1": [dict(protocol="evenly_spaced", n_gaps=5, gap_length=L) for L in (20, 50, 80, 100)],
    "table2": [dict(protocol="evenly_spaced", n_gaps=k, gap_length=100) for k in range(1, 9)],
    "blackout": [dict(protocol="blackout", gap_length=round(SEG * f)) for f in (0.05, 0.1, 0.2, 0.3, 0.4)],
}


def methods(kind: str, dev: bool, lowrank: bool) -> dict[str, tuple[str, dict, str | None]]:
    """label -> (solver, hyperparameters, training scenario or None)."""
    out = {"linear": ("linear", {}, None), "spline": ("spline", {}, None)}
    if lowrank:
        out.update({m: (m, {}, None) for m in ("svt", "tucker_tnn") if m in torchfill.methods()})
    if kind == "blackout":
        out.update({
            "pca_blackout cross": ("pca_blackout", {}, "cross"),
            "pca_blackout self": ("pca_blackout", {}, "self"),
            "pca_blackout cross W=I": ("pca_blackout", {"edge_scale": None}, "cross"),
            "pca_blackout cross paper (no prior, 0.99)": (
                "pca_blackout", {"prior": False, "variance": 0.99}, "cross"),
        })
        if dev:
            for v in (0.99, 0.999, 0.9999, 0.99999):
                for e in (None, 1.0, 3.0):
                    out[f"cross v={v} edge={e}"] = ("pca_blackout", {"variance": v, "edge_scale": e}, "cross")
                out[f"self v={v} edge=1.0"] = ("pca_blackout", {"variance": v}, "self")
            out["cross paper v=0.9999"] = ("pca_blackout", {"prior": False, "variance": 0.9999}, "cross")
    else:
        out.update({
            "pca_train cross": ("pca_train", {}, "cross"),
            "pca_train self": ("pca_train", {}, "self"),
            "pca_train cross no-centre": ("pca_train", {"centre": False}, "cross"),
            "pca_train cross no own frames": ("pca_train", {"self_share": 0.0}, "cross"),
            "pca_train cross paper rank (0.99)": ("pca_train", {"variance": 0.99}, "cross"),
            "pca_train cross horizontal": ("pca_train", {"layout": "horizontal"}, "cross"),
        })
        if dev:
            for v in (0.99, 0.999, 0.9999, 0.99999):
                for c in (True, False):
                    for sc in ("cross", "self"):
                        out[f"{sc} v={v} centre={c}"] = ("pca_train", {"variance": v, "centre": c}, sc)
            for share in (0.0, 0.1, 0.25, 0.5):
                out[f"cross share={share}"] = ("pca_train", {"self_share": share}, "cross")
            out["cross horizontal no-prior"] = ("pca_train", {"layout": "horizontal", "prior": False}, "cross")
            out["self horizontal"] = ("pca_train", {"layout": "horizontal"}, "self")
    return out


def load(name: str, labels: list[str] | None = None) -> tuple[np.ndarray, list[str]]:
    seq = torchfill.read(DATA / name)
    short = seq.short_labels()
    if labels is None:
        return seq.points, short
    missing = [lab for lab in labels if lab not in short]
    if missing:
        raise ValueError(f"{name} lacks markers {missing}")
    return seq.points[:, [short.index(lab) for lab in labels]], labels


def segment_starts(T: int, n: int) -> list[int]:
    if T <= SEG:
        return [0][: max(n, 1)] if T == SEG else []
    return sorted(set(np.linspace(0, T - SEG, n + 2)[1:-1].round().astype(int).tolist()))


def run(args) -> list[dict]:
    sets = DEV if args.dev else REPORT
    rows = []
    for test_name in sets["tests"]:
        points, labels = load(test_name)
        cross = [load(n, labels)[0] for n in sets["training"]]
        starts = segment_starts(points.shape[0], args.segments)
        for kind in args.only:
            table = methods(kind, args.dev, args.lowrank)
            if args.match:
                table = {k: v for k, v in table.items() if any(m in k for m in args.match)}
            for point in GRIDS[kind]:
                protocol = point["protocol"]
                kw = {k: v for k, v in point.items() if k != "protocol"}
                for si, s0 in enumerate(starts):
                    X = points[s0:s0 + SEG]
                    own = [points[:s0], points[s0 + SEG:]]
                    own = [p for p in own if p.shape[0]]
                    for seed in range(args.seeds):
                        mask = gaps.generate(protocol, SEG, X.shape[1], seed=1000 * si + seed, **kw)
                        Xg = X.copy()
                        Xg[mask] = np.nan
                        for label, (solver, params, scenario) in table.items():
                            params = dict(params)
                            if scenario == "cross":
                                params["training"] = cross
                            elif scenario == "self":
                                params["training"] = own
                            t0 = time.perf_counter()
                            try:
                                out = torchfill.fill(Xg, method=solver, **params)
                                err = metrics.gap_error(out, X, mask)
                                status = "ok"
                            except Exception as exc:  # reported in the table, not fatal
                                err, status = float("nan"), f"{type(exc).__name__}: {exc}"[:200]
                            rows.append(dict(table=kind, recording=test_name, segment=s0, seed=seed,
                                             **kw, method=label, gap_error=err,
                                             seconds=time.perf_counter() - t0, status=status))
                print(f"{test_name} {kind} {kw} done", file=sys.stderr, flush=True)
    return rows


def markdown(rows: list[dict], kind: str) -> str:
    key = {"table1": "gap_length", "table2": "n_gaps", "blackout": "gap_length"}[kind]
    rows = [r for r in rows if r["table"] == kind]
    if not rows:
        return ""
    methods_ = list(dict.fromkeys(r["method"] for r in rows))
    groups = defaultdict(list)
    for r in rows:
        groups[(r["recording"], r[key], r["method"])].append(r["gap_error"])
    recs = list(dict.fromkeys(r["recording"] for r in rows))
    values = list(dict.fromkeys(r[key] for r in rows))
    head = key if kind != "blackout" else "blackout frames (of 200)"
    lines = [f"| recording | {head} | " + " | ".join(methods_) + " |",
             "|---|---|" + "---|" * len(methods_)]
    for rec in recs:
        for v in values:
            cells = []
            for m in methods_:
                errs = np.array(groups[(rec, v, m)], dtype=float)
                cells.append("fail" if np.isnan(errs).all() else f"{np.nanmean(errs):.1f}")
            lines.append(f"| {rec} | {v} | " + " | ".join(cells) + " |")
    fails = [r for r in rows if r["status"] != "ok"]
    if fails:
        lines.append("")
        lines.append(f"{len(fails)} failed fills, e.g. {fails[0]['method']}: {fails[0]['status']}")
    secs = defaultdict(list)
    for r in rows:
        secs[r["method"]].append(r["seconds"])
    lines.append("")
    lines.append("Mean seconds per fill (under load): " + ", ".join(
        f"{m} {np.mean(secs[m]):.2f}" for m in methods_))
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dev", action="store_true", help="the development set (defaults chosen on it)")
    p.add_argument("--lowrank", action="store_true", help="also svt and tucker_tnn (slower)")
    p.add_argument("--segments", type=int, default=3)
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--only", default="table1,table2,blackout")
    p.add_argument("--csv", default=None, help="write every fill's row here")
    p.add_argument("--match", default="", help="comma-separated substrings: only methods whose "
                                                "label contains one")
    args = p.parse_args(argv)
    args.only = [k.strip() for k in args.only.split(",") if k.strip()]
    args.match = [k for k in args.match.split(",") if k]
    rows = run(args)
    if args.csv:
        with open(args.csv, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=sorted({k for r in rows for k in r}))
            writer.writeheader()
            writer.writerows(rows)
    print(f"<!-- {' '.join(['scripts/pca_tables.py', *(argv or sys.argv[1:])])}; "
          f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC -->")
    for kind in args.only:
        print(f"\n### {kind}: mean 3-D error per gap (mm)\n")
        print(markdown(rows, kind))


if __name__ == "__main__":
    main()
