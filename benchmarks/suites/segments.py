"""Segment-based reconstruction against the mocap tools, on the real-gap benchmark's cases.

Peers, run with the same named segments (``torchfill.segments.Segments.from_names``): gapfill
``recover_marker_rbt`` and Kinetics Toolkit ``track_cluster`` (benchmarks/peers.py). Next to
them: torchfill ``rigid`` with the named segments, ``rigid`` with segments found from the data
alone (labels hidden), ``rigid`` with the segments a fill resolves when none are given (the
tables completed from the data: ``rigid_auto``), and the default fill. Every method is scored (RMSE, 3-D, mm) on the
samples gapfill fills; the table gives each ratio to gapfill's RMSE. Then the agreement of the
data-found segments with the named tables on the complete recordings (and their purity), and the
time of ``rigid`` on 3 000 frames x 41 markers::

    OMP_NUM_THREADS=1 python -m benchmarks segments --doc docs/segments.md
    OMP_NUM_THREADS=1 python -m benchmarks segments --limit 6 --no-default
    python -m benchmarks segments --agreement-only
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

import torchfill
from torchfill.segments import Segments, agreement, purity

from .. import data, peers
from ..cases import load_masks, select
from ..rows import Rows, num, read_csv, write_csv
from ..scores import rmse3d
from ..tables import write_block
from ..timing import measure
from . import case_arguments

HELP = "rigid and the default against gapfill and Kinetics Toolkit on gapfill's samples"
CSV = data.RESULTS / "segments" / "cases.csv"
AGREE = data.RESULTS / "segments" / "agreement.csv"
RUN = data.RESULTS / "segments" / "run.csv"
DOC = data.DOCS / "segments.md"
AGREEMENT = ("biomechzoo_hockey_wrist_shot_009.c3d", "osim_gait2392_subject01_walk1.trc",
             "osim_hamner_subject02_running.trc", "osim_rajagopal_motion_capture_run.trc",
             "osim_rajagopal_motion_capture_walk.trc", "hdm05_bd_05-01_01_120.c3d",
             "hdm05_mm_01-02_03_120.c3d", "HDM_bd_01-02_01_120.c3d", "hdm05_dg_06-03_03_120.c3d",
             "cmu_135_02.c3d", "cmu_02_01.c3d", "cmu_85_02.c3d", "cmu_85_12.c3d")
COLS = ("gapfill", "ktk", "rigid", "rigid_data", "rigid_auto", "default")


def add_arguments(p) -> None:
    case_arguments(p, str(CSV))
    p.add_argument("--limit", type=int, default=None, help="first N cases only")
    p.add_argument("--no-default", action="store_true", help="skip the default fill (slow)")
    p.add_argument("--no-ktk", action="store_true")
    p.add_argument("--agreement-only", action="store_true",
                   help="print only the agreement table (seconds: no fills)")
    p.add_argument("--doc", help="also write the tables into this page's segments block")


def score(case, methods, row: dict) -> dict:
    """RMSE (mm, 3-D) of each method on the samples gapfill fills in ``case``; ``row`` holds the
    columns already computed (a resumed run)."""
    truth, seq = case.truth.points, case.gapped()
    GF = peers.fill("gapfill", seq)
    on = np.isfinite(GF).all(axis=2) & case.mask
    row.update(case=case.name, n=int(on.sum()), gapfill=rmse3d(GF, truth, on))
    fills = {
        "ktk": lambda: peers.fill("ktk_cluster", seq),
        "rigid": lambda: torchfill.fill(seq, "rigid", segments="names", constraints=False).points,
        "rigid_data": lambda: torchfill.fill(seq.points, "rigid", segments="data",
                                             constraints=False),
        "rigid_auto": lambda: torchfill.fill(seq, "rigid", constraints=False).points,
        "default": lambda: torchfill.fill(seq, extrapolate=None).points,
    }
    for m in methods:
        if m == "gapfill" or row.get(m, "") not in ("", "nan", None):
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            F = fills[m]()
        hit = on & np.isfinite(F).all(axis=2)
        row[m] = rmse3d(F, truth, on) if hit.sum() == on.sum() else float("nan")
    return row


def ratio_table(rows: list[dict], methods) -> tuple[str, dict]:
    """Markdown table of each method's ratio to gapfill's RMSE per case, and the ratios."""
    others = [m for m in methods if m != "gapfill"]
    lines = ["| case | samples | gapfill mm | " + " | ".join(others) + " |",
             "|---|---:|---:|" + "---:|" * len(others)]
    ratios = {m: [] for m in others}
    for r in rows:
        g = num(r["gapfill"])
        cells = []
        for m in others:
            q = num(r.get(m)) / g if g > 0 else np.nan
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


def agreement_rows(folder) -> list[dict]:
    """Per recording: agreement (share of the named memberships the data-found segments
    reproduce), purity (share of the found memberships inside their matched named segment)."""
    out = []
    for name in AGREEMENT:
        if not (folder / name).exists():
            continue
        seq = data.complete(folder / name)
        named = Segments.from_names(seq.labels)
        found = Segments.from_data(seq.points, seq.labels)
        out.append({"recording": name, "agreement": agreement(found, named, seq.labels),
                    "purity": purity(found, named, seq.labels), "found": len(found),
                    "named": len(named)})
    return out


def agreement_table(rows: list[dict]) -> str:
    lines = ["| recording | agreement | purity | found | named |", "|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['recording']} | {100 * num(r['agreement']):.1f} % | "
                     f"{100 * num(r['purity']):.1f} % | {r['found']} | {r['named']} |")
    if rows:
        a = 100 * np.mean([num(r["agreement"]) for r in rows])
        p = 100 * np.mean([num(r["purity"]) for r in rows])
        lines.append(f"| **mean** | **{a:.2f} %** | **{p:.2f} %** | | |")
    return "\n".join(lines)


def timing(folder, repeats: int = 5) -> str:
    """``rigid`` on the first 3 000 frames of hdm05_bd_05-01 (41 markers) with 20 seeded gaps."""
    from torchfill.solvers.rigid import clear_cache

    seq = data.complete(folder / "hdm05_bd_05-01_01_120.c3d")
    X = seq.points[:3000].copy()
    rng = np.random.default_rng(0)
    for j in rng.choice(X.shape[1], 20):
        a = rng.integers(0, 2800)
        X[a:a + rng.integers(100, 200), j] = np.nan
    wall, cpu = [], []
    for _ in range(repeats):
        clear_cache()                       # each run computes (fill() keeps its last results)
        with measure() as t, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torchfill.fill(seq.with_points(X), "rigid", constraints=False)
        wall.append(t.wall)
        cpu.append(t.cpu)
    return (f"`rigid`, {X.shape[0]} frames x {X.shape[1]} markers, 20 gaps, one thread: median "
            f"{np.median(cpu):.3f} s CPU, {np.median(wall):.3f} s wall (of {repeats} runs)")


def main(args) -> int:
    folder = data.need()
    if args.agreement_only:
        print(agreement_table(agreement_rows(folder)))
        return 0
    cases = select(load_masks(folder), args.only, args.shard)[:args.limit]
    if args.list:
        for c in cases:
            print(c.name)
        return 0
    methods = [m for m in COLS if not (m == "ktk" and args.no_ktk)
               and not (m == "default" and args.no_default)]
    rows = Rows(args.csv or None, ("case",))
    print(f"{'case':58s} {'n':>6s} " + " ".join(f"{c:>10s}" for c in methods))
    for case in cases:
        old = {} if args.redo else dict(rows.get(case=case.name) or {})
        row = score(case, methods, old)
        rows.add(row)
        print(f"{case.name[:58]:58s} {row['n']:6d} " +
              " ".join(f"{num(row.get(c)):10.2f}" for c in methods), flush=True)
    got = [r for r in rows.rows if r["case"] in {c.name for c in cases}]
    table, stat = ratio_table(got, methods)
    print("\nratio to gapfill's RMSE on its samples: mean / worst (cases)")
    for m, (mean, worst, n) in stat.items():
        print(f"  {m:10s} {mean:6.3f} / {worst:6.3f}  ({n})")
    agree = agreement_rows(folder)
    print("\ndata-found segments vs named tables (share of memberships)\n" + agreement_table(agree))
    speed = timing(folder)
    print("\n" + speed)
    if args.csv:                        # beside the rows: what docs/segments.md is made of
        folder = Path(args.csv).parent
        write_csv(folder / AGREE.name, agree)
        write_csv(folder / RUN.name, [{"methods": ",".join(methods), "timing": speed}])
    if args.doc:
        write_block(args.doc, "segments", doc_text(got, methods, agree, speed))
    return 0


def doc_text(rows, methods, agree: str, speed: str) -> str:
    return "\n\n".join([
        f"{len(rows)} cases; RMSE ratio to gapfill's on the samples gapfill fills "
        "(— where gapfill fills none, or a method leaves some of them empty).",
        ratio_table(rows, methods)[0],
        "Data-found segments (labels hidden) against the named tables:", agreement_table(agree),
        speed])


def doc_blocks() -> dict:
    """docs/segments.md's tables from the stored rows."""
    run = read_csv(RUN)
    if not run:
        return {}
    rows = read_csv(CSV)
    return {(DOC, "segments"): doc_text(rows, run[0]["methods"].split(","), read_csv(AGREE),
                                        run[0]["timing"])}
