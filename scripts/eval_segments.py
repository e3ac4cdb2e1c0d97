"""Segment-based reconstruction against the mocap tools, on the real-gap-pattern suite.

Peers, run with the same named segments (``torchfill.segments.Segments.from_names``):

* ``gapfill`` 0.0.7 ``recover_marker_rbt`` (rigid-body transform from three cluster markers; for
  each segment of the marker, its three mates nearest on average, segments in table order);
* Kinetics Toolkit ``track_cluster`` (a cluster per segment, created from the frames where all of
  its markers are observed; the marker's reconstruction from the first segment that gives one).

Next to them: torchfill ``rigid`` with the named segments, ``rigid`` with segments found from the
data alone (labels hidden), and the default fill. Every method is scored (RMSE, 3-D, mm) on the
samples gapfill fills; the table gives each ratio to gapfill's RMSE. Then the agreement of the
data-found segments with the named tables on the complete recordings (and their purity: found
segments may overlap, so extra ones could only raise the agreement), and the time of ``rigid``
on 3 000 frames x 41 markers::

    OMP_NUM_THREADS=1 python scripts/eval_segments.py --csv experiments/results/segments/cases.csv \
        --doc docs/segments.md                                     # all cases, table into the page
    OMP_NUM_THREADS=1 python scripts/eval_segments.py --limit 6 --no-default
    OMP_NUM_THREADS=1 python scripts/eval_segments.py --reuse experiments/results/segments/cases.csv
                                                      # the peers' columns from an earlier run
    OMP_NUM_THREADS=1 python scripts/eval_segments.py --agreement-only   # the segments alone
"""
from __future__ import annotations

import argparse
import csv
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import torchfill
from torchfill.data import data_dir
from torchfill.segments import Segments, agreement, purity
from torchfill.solvers.rigid import clear_cache

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_gap_suite  # noqa: E402
from docblock import write_block, write_csv  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
AGREEMENT = ("biomechzoo_hockey_wrist_shot_009.c3d", "osim_gait2392_subject01_walk1.trc",
             "osim_hamner_subject02_running.trc", "osim_rajagopal_motion_capture_run.trc",
             "osim_rajagopal_motion_capture_walk.trc", "hdm05_bd_05-01_01_120.c3d",
             "hdm05_mm_01-02_03_120.c3d", "HDM_bd_01-02_01_120.c3d", "hdm05_dg_06-03_03_120.c3d",
             "cmu_135_02.c3d", "cmu_02_01.c3d", "cmu_85_02.c3d", "cmu_85_12.c3d")


def _gapfill():
    np.int = int                     # gapfill 0.0.7 uses np.int, removed in NumPy 1.24
    import gapfill
    return gapfill


def gapfill_fill(G: np.ndarray, seg_idx: dict) -> np.ndarray:
    """gapfill's recover_marker_rbt per marker and segment; NaN where it fills nothing."""
    gf = _gapfill()
    T, J = G.shape[:2]
    seen = np.isfinite(G).all(axis=2)
    out = np.full_like(G, np.nan)
    for j in np.flatnonzero((~seen).any(axis=0) & seen.any(axis=0)):
        for seg, members in seg_idx.items():
            if j not in members or len(members) < 4:
                continue
            mates = [m for m in members if m != j]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                dist = [np.nanmean(np.linalg.norm(G[:, m] - G[:, j], axis=1)) for m in mates]
            mates = [m for _, m in sorted(zip(np.nan_to_num(dist, nan=np.inf), mates))][:3]
            tgt = G[:, j].copy()
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                ok, _ = gf.recover_marker_rbt(tgt, np.stack([G[:, m] for m in mates]))
            if not ok:
                continue
            new = ~seen[:, j] & np.isfinite(tgt).all(axis=1) & ~np.isfinite(out[:, j]).all(axis=1)
            out[new, j] = tgt[new]
    return out


def ktk_fill(G: np.ndarray, seg_idx: dict, rate: float) -> np.ndarray:
    """Kinetics Toolkit track_cluster per segment; NaN where it fills nothing."""
    import kineticstoolkit as ktk
    T, J = G.shape[:2]
    seen = np.isfinite(G).all(axis=2)
    out = np.full_like(G, np.nan)
    ts = ktk.TimeSeries(time=np.arange(T) / rate)
    for j in range(J):
        ts.data[f"m{j}"] = np.concatenate([G[:, j], np.ones((T, 1))], axis=1)
    for seg, members in seg_idx.items():
        if len(members) < 4:
            continue
        names = [f"m{m}" for m in members]
        full = seen[:, members].all(axis=1)
        if not full.any():
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                cluster = ktk.kinematics.create_cluster(_frames(ts, full), names)
                tracked = ktk.kinematics.track_cluster(ts, cluster)
            except Exception as err:                       # noqa: BLE001 - a peer's failure
                print(f"  ktk {seg}: {type(err).__name__}: {err}")
                continue
        for m in members:
            P = tracked.data[f"m{m}"][:, :3]
            new = ~seen[:, m] & np.isfinite(P).all(axis=1) & ~np.isfinite(out[:, m]).all(axis=1)
            out[new, m] = P[new]
    return out


def _frames(ts, keep):
    sub = ts.copy()
    sub.time = ts.time[keep]
    for k in sub.data:
        sub.data[k] = ts.data[k][keep]
    return sub


def rmse(F, truth, on) -> float:
    if not on.any():
        return float("nan")
    return float(np.sqrt(np.mean(np.sum((F[on] - truth[on]) ** 2, axis=1))))


COLS = ("gapfill", "ktk", "rigid", "rigid_data", "default")
PEERS = ("gapfill", "ktk")


def score(case, methods, reuse: dict) -> dict:
    """RMSE (mm) of each method on the samples gapfill fills in ``case``; columns in ``reuse``
    (a row of an earlier CSV) are taken from there (the peers do not change with torchfill)."""
    truth, seq = case.truth.points, case.gapped()
    G, labels = seq.points, list(seq.labels)
    seg_idx = Segments.from_names(labels).indices(labels)
    GF = gapfill_fill(G, seg_idx)
    on = np.isfinite(GF).all(axis=2) & case.mask
    row = {"case": case.name, "n": int(on.sum()), "gapfill": rmse(GF, truth, on)}
    fills = {
        "ktk": lambda: ktk_fill(G, seg_idx, seq.rate),
        "rigid": lambda: torchfill.fill(seq, "rigid", segments="names", constraints=False).points,
        "rigid_data": lambda: torchfill.fill(G, "rigid", segments="data", constraints=False),
        "default": lambda: torchfill.fill(seq, extrapolate=None).points,
    }
    for m in methods:
        if m == "gapfill":
            continue
        if reuse.get(m, "") not in ("", "nan") and m in PEERS:
            row[m] = float(reuse[m])
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            F = fills[m]()
        hit = on & np.isfinite(F).all(axis=2)
        row[m] = rmse(F, truth, on) if hit.sum() == on.sum() else float("nan")
    return row


def ratio_table(rows: list[dict], methods) -> tuple[str, dict]:
    """Markdown table of each method's RMSE and ratio to gapfill per case, and the ratios."""
    others = [m for m in methods if m != "gapfill"]
    lines = ["| case | samples | gapfill mm | " + " | ".join(others) + " |",
             "|---|---:|---:|" + "---:|" * len(others)]
    ratios = {m: [] for m in others}
    for r in rows:
        g = float(r["gapfill"])
        cells = []
        for m in others:
            x = float(r.get(m, np.nan))
            q = x / g if g > 0 else np.nan
            if np.isfinite(q):
                ratios[m].append(q)
            cells.append(f"{q:.2f}" if np.isfinite(q) else "—")
        lines.append(f"| {r['case']} | {r['n']} | {g:.2f} | " + " | ".join(cells) + " |")
    stat = {m: (np.mean(v), np.max(v), len(v)) for m, v in ratios.items() if v}
    lines.append("| **mean ratio** | | | " + " | ".join(
        f"**{stat[m][0]:.2f}**" if m in stat else "—" for m in others) + " |")
    lines.append("| worst ratio | | | " + " | ".join(
        f"{stat[m][1]:.2f}" if m in stat else "—" for m in others) + " |")
    return "\n".join(lines), stat


def agreement_table(folder: Path) -> str:
    """Agreement (share of the named memberships the data-found segments reproduce) and purity
    (share of the found memberships inside their matched named segment) per recording."""
    lines = ["| recording | agreement | purity | found | named |", "|---|---:|---:|---:|---:|"]
    shares = []
    for name in AGREEMENT:
        if not (folder / name).exists():
            continue
        seq = real_gap_suite.complete(folder / name)
        named = Segments.from_names(seq.labels)
        found = Segments.from_data(seq.points, seq.labels)
        shares.append((agreement(found, named, seq.labels), purity(found, named, seq.labels)))
        lines.append(f"| {name} | {100 * shares[-1][0]:.1f} % | {100 * shares[-1][1]:.1f} % | "
                     f"{len(found)} | {len(named)} |")
    if shares:
        a, p = 100 * np.mean(shares, axis=0)
        lines.append(f"| **mean** | **{a:.2f} %** | **{p:.2f} %** | | |")
    return "\n".join(lines)


def timing(folder: Path, repeats: int = 5) -> str:
    """``rigid`` on the first 3 000 frames of hdm05_bd_05-01 (41 markers) with 20 seeded gaps."""
    seq = real_gap_suite.complete(folder / "hdm05_bd_05-01_01_120.c3d")
    X = seq.points[:3000].copy()
    rng = np.random.default_rng(0)
    for j in rng.choice(X.shape[1], 20):
        a = rng.integers(0, 2800)
        X[a:a + rng.integers(100, 200), j] = np.nan
    wall, cpu = [], []
    for _ in range(repeats):
        clear_cache()                       # each run computes (fill() keeps its last results)
        t, c = time.perf_counter(), time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torchfill.fill(seq.with_points(X), "rigid", constraints=False)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return (f"`rigid`, {X.shape[0]} frames x {X.shape[1]} markers, 20 gaps, one thread: median "
            f"{np.median(cpu):.3f} s CPU, {np.median(wall):.3f} s wall (of {repeats} runs)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=int, default=None, help="first N cases only")
    ap.add_argument("--only", help="comma-separated substrings of case names to run")
    ap.add_argument("--no-default", action="store_true", help="skip the default fill (slow)")
    ap.add_argument("--no-ktk", action="store_true")
    ap.add_argument("--csv", type=Path, help="write the per-case RMSEs here as they finish")
    ap.add_argument("--reuse", type=Path, help="take the peers' RMSEs (gapfill's samples are "
                                               "recomputed) from this CSV of an earlier run")
    ap.add_argument("--agreement-only", action="store_true",
                    help="print only the agreement table (seconds: no fills)")
    ap.add_argument("--doc", type=Path, help="also write the tables into this docs page, between "
                                             "its <!-- segments:start/end --> markers")
    args = ap.parse_args(argv)
    folder = data_dir(REPO)
    if args.agreement_only:
        print(agreement_table(folder))
        return
    cases = real_gap_suite.cases(folder)
    if args.only:
        cases = [c for c in cases if any(x in c.name for x in args.only.split(","))]
    cases = cases[:args.limit]
    methods = [m for m in COLS if not (m == "ktk" and args.no_ktk)
               and not (m == "default" and args.no_default)]
    reuse = {}
    if args.reuse:
        with open(args.reuse) as f:
            reuse = {r["case"]: r for r in csv.DictReader(f)}
    print(f"{'case':58s} {'n':>6s} " + " ".join(f"{c:>10s}" for c in methods))
    rows = []
    for case in cases:
        row = score(case, methods, reuse.get(case.name, {}))
        rows.append(row)
        print(f"{case.name[:58]:58s} {row['n']:6d} " +
              " ".join(f"{row.get(c, np.nan):10.2f}" for c in methods), flush=True)
        if args.csv:
            write_csv(args.csv, rows)
    table, stat = ratio_table(rows, methods)
    print("\nratio to gapfill's RMSE on its samples: mean / worst (cases)")
    for m, (mean, worst, n) in stat.items():
        print(f"  {m:10s} {mean:6.3f} / {worst:6.3f}  ({n})")
    agree = agreement_table(folder)
    print("\ndata-found segments vs named tables (share of memberships)\n" + agree)
    speed = timing(folder)
    print("\n" + speed)
    if args.doc:
        write_block(args.doc, "segments", "\n\n".join([
            f"{len(rows)} cases; RMSE ratio to gapfill's on the samples gapfill fills "
            "(— where gapfill fills none, or a method leaves some of them empty).", table,
            "Data-found segments (labels hidden) against the named tables:", agree, speed]))


if __name__ == "__main__":
    main()
