"""The real-gap benchmark: the masks of real gapped recordings (shipped in benchmarks/masks/),
laid onto complete recordings of other subjects, filled by ours and the peers, scored by marker
RMSE (all hidden samples, trial-end, interior), the error estimate and the per-gap verdicts.

    python -m benchmarks real-gaps --quick                      # 6 cases, a table in minutes
    OMP_NUM_THREADS=1 python -m benchmarks real-gaps             # all cases, resumable rows
    python -m benchmarks real-gaps --split held-out --methods default,pma,peer:gapfill
"""
from __future__ import annotations

import numpy as np

from .. import cases as C
from .. import data, methods, runner, scores
from ..rows import Rows, num, write_csv
from ..tables import markdown, write_block
from . import case_arguments

HELP = "real gap masks on complete recordings: marker RMSE, verdicts, error estimate"
CSV = data.RESULTS / "real_gaps" / "rows.csv"
QUICK_METHODS = ("default", "linear", "pchip", "pma", "rigid")


def add_arguments(p) -> None:
    case_arguments(p, str(CSV))
    p.add_argument("--methods", default=None,
                   help="comma-separated: 'default' (fill()'s default), torchfill methods, "
                        "peer:NAME (python -m benchmarks peers --list); 'peers': every peer "
                        "that imports here (default: the default and "
                        f"{', '.join(methods.SINGLES)}; with --quick {', '.join(QUICK_METHODS)})")
    p.add_argument("--quick", action="store_true",
                   help=f"the {len(C.QUICK)} quick cases (rows kept in memory unless --csv "
                        "is given)")
    p.add_argument("--split", choices=("all", "tuning", "held-out"), default="all",
                   help="held-out masks are never used for a choice of the default")
    p.add_argument("--seed", type=int, default=0, help="the default's seed (its hold-out draws)")
    p.add_argument("--no-verdicts", action="store_true", help="skip the per-gap verdicts")
    p.add_argument("--gaps-csv", help="per-gap real vs estimated error of the default")
    p.add_argument("--doc", help="write the tables into this page's real_gaps block")
    p.add_argument("--rebuild-masks", action="store_true",
                   help="derive the shipped masks again from the gapped recordings and stop")


def method_names(spec: str) -> list[str]:
    from ..peers import PEERS

    out = []
    for m in (s.strip() for s in spec.split(",") if s.strip()):
        out += [f"peer:{p}" for p in PEERS if methods.available(f"peer:{p}")] if m == "peers" \
            else [m]
    return out


def main(args) -> int:
    folder = data.need(*{t for t in C.TARGETS})
    if args.rebuild_masks:
        C.save_masks(C.build_real_gaps(folder))
        return 0
    suite = C.select(C.load_masks(folder), args.only, args.shard, args.split, args.quick)
    if args.list:
        C.print_cases(suite)
        return 0
    names = method_names(args.methods or ",".join(
        QUICK_METHODS if args.quick else (methods.DEFAULT, *methods.SINGLES)))
    csv = args.csv if not (args.quick and args.csv == str(CSV)) else None
    rows = Rows(csv or None, ("case", "method"))
    gaps: list = []
    got = runner.run(suite, names, rows, args.redo, args.seed, not args.no_verdicts,
                     gaps if args.gaps_csv else None, log=True)
    text = tables(got, names)
    print(text)
    if args.gaps_csv and gaps:
        write_csv(args.gaps_csv, gaps)
    if args.doc:
        write_block(args.doc, "real_gaps", text)
    return 0


def by_case(rows: list[dict]) -> dict[str, dict[str, dict]]:
    out: dict[str, dict[str, dict]] = {}
    for r in rows:
        out.setdefault(r["case"], {})[r["method"]] = r
    return out


def default_ratios(rows: list[dict], names: list[str]) -> dict[str, float]:
    """Per case the default's RMSE over the best of ``names``' single methods of ours there."""
    singles = [m for m in names if m != methods.DEFAULT and not methods.is_peer(m)]
    out = {}
    for case, got in by_case(rows).items():
        best = np.nanmin([num(got[m]["rmse"]) if m in got else np.nan for m in singles]
                         or [np.nan])
        out[case] = num(got[methods.DEFAULT]["rmse"]) / best \
            if methods.DEFAULT in got and best > 0 else np.nan
    return out


def case_table(rows: list[dict], names: list[str]) -> str:
    """Per case the RMSE (mm, all hidden samples) of each method, the default's ratio to the
    case's best single method of ours; the means and median CPU seconds."""
    ratio = default_ratios(rows, names)
    ratios = list(ratio.values())
    body = []
    for case, got in by_case(rows).items():
        val = {m: num(got[m]["rmse"]) if m in got else np.nan for m in names}
        split = next(iter(got.values()))["split"]
        body.append([case + (" (held out)" if split == "held-out" else ""),
                     f"{100 * num(next(iter(got.values()))['trial_end']):.0f}",
                     *[val[m] for m in names], ratio[case]])
    cols = {m: [num(r["rmse"]) for r in rows if r["method"] == m] for m in names}
    cpu = {m: [num(r.get("cpu")) for r in rows if r["method"] == m] for m in names}
    body.append(["**mean**", "", *[f"**{np.nanmean(cols[m]):.2f}**" if cols[m] else "—"
                                   for m in names], f"worst {np.nanmax(ratios + [np.nan]):.2f}"])
    body.append(["median CPU s", "", *[np.nanmedian(cpu[m]) if cpu[m] else np.nan
                                        for m in names], ""])
    return markdown(["case", "end %", *names, "default / best"], body)


def method_table(rows: list[dict], names: list[str]) -> str:
    """Per method: RMSE over all cases, the tuning and held-out cases, trial-end and interior
    samples, the share it left missing and its RMSE on its own samples, the verdicts' accuracy,
    the error estimate's checks and the median cost."""
    body = []
    for m in names:
        mine = [r for r in rows if r["method"] == m]
        if not mine:
            continue
        mean = lambda k, rs=mine: np.nanmean([num(r.get(k)) for r in rs]) if rs else np.nan  # noqa: E731
        acc, big, small = scores.verdict_accuracy(mine)
        body.append([m, len(mine), mean("rmse"),
                     mean("rmse", [r for r in mine if r["split"] == "tuning"]),
                     mean("rmse", [r for r in mine if r["split"] == "held-out"]),
                     mean("rmse_end"), mean("rmse_interior"), f"{100 * mean('left'):.1f}",
                     mean("rmse_own"), _pct(acc), _pct(big), _pct(small),
                     np.nanmedian([num(r.get("spearman")) for r in mine]),
                     np.nanmedian([num(r.get("cpu")) for r in mine]),
                     np.nanmedian([num(r.get("peak_mb")) for r in mine])])
    return markdown(["method", "cases", "RMSE all", "tuning", "held out", "trial-end",
                     "interior", "left %", "RMSE own", "verdicts right", "big flagged",
                     "small ok", "Spearman", "CPU s", "peak MB"], body)


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %" if np.isfinite(x) else "—"


def tables(rows: list[dict], names: list[str]) -> str:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)       # means of empty columns
        n = len({r["case"] for r in rows})
        held = len({r["case"] for r in rows if r["split"] == "held-out"})
        return "\n\n".join([
            f"{n} cases ({held} held out). RMSE per coordinate over the hidden samples, mm; a peer's "
            "unfilled samples count with `linear`'s fill in the RMSE columns, its own samples "
            "alone in RMSE own.", method_table(rows, names), "Per case:", case_table(rows, names)])


#: A real-gaps method -> the IK suite's name for the same fill (everything filled).
IK_NAME = {"default": "default_all"}
BENCHMARK = data.DOCS / "benchmark.md"
QUICK_CSV = data.RESULTS / "real_gaps" / "quick.csv"


def benchmark_table(rows: list[dict], ik: list[dict]) -> str:
    """docs/benchmark.md's table: per method the marker RMSE (all, held out, trial-end,
    interior), what it left missing and its RMSE there, the verdicts, and the IK columns."""
    from ..peers import PEERS

    ik_by = {r["method"]: r for r in ik}
    names = list(dict.fromkeys(r["method"] for r in rows))
    body = []
    for m in names:
        mine = [r for r in rows if r["method"] == m]
        mean = lambda k, rs=mine: np.nanmean([num(r.get(k)) for r in rs]) if rs else np.nan  # noqa: E731
        acc = scores.verdict_accuracy(mine)[0]
        k = ik_by.get(IK_NAME.get(m, m), {})
        what = PEERS[m[5:]][0] if methods.is_peer(m) else ("torchfill default" if m == "default"
                                                           else f"torchfill `{m}`")
        body.append([what, len(mine), mean("rmse"),
                     mean("rmse", [r for r in mine if r["split"] == "held-out"]),
                     mean("rmse_end"), mean("rmse_interior"), f"{100 * mean('left'):.1f}",
                     mean("rmse_own"), _pct(acc), num(k.get("rmse_all")), num(k.get("rmse_gap")),
                     f"{k['worse_than_gaps']} of {k['masks']}" if k.get("worse_than_gaps")
                     not in (None, "") else "—",
                     np.nanmedian([num(r.get("cpu")) for r in mine])])
    if "gaps" in ik_by:                         # IK's baseline: the gaps left, nothing filled
        body.append(["gaps left (IK skips a missing marker)", *["—"] * 8,
                     num(ik_by["gaps"].get("rmse_all")), num(ik_by["gaps"].get("rmse_gap")),
                     "—", "—"])
    return markdown(["method", "cases", "RMSE mm", "held out", "trial-end", "interior", "left %",
                     "RMSE own", "verdicts right", "IK deg", "IK gap frames",
                     "IK worse than gaps", "CPU s"], body)


def peer_case_table(rows: list[dict]) -> str:
    """Per case the RMSE (mm, all hidden samples) of the default, the best single method of
    ours on that case, and each peer (in brackets the share it left to `linear`)."""
    peers = list(dict.fromkeys(r["method"] for r in rows if methods.is_peer(r["method"])))
    body = []
    for case, got in by_case(rows).items():
        ours = {m: num(r["rmse"]) for m, r in got.items()
                if m != methods.DEFAULT and not methods.is_peer(m)}
        best = min(ours, key=ours.get) if ours else None
        first = next(iter(got.values()))
        body.append([case + (" (held out)" if first["split"] == "held-out" else ""),
                     f"{100 * num(first['trial_end']):.0f}",
                     num(got[methods.DEFAULT]["rmse"]) if methods.DEFAULT in got else np.nan,
                     f"{ours[best]:.2f} `{best}`" if best else "—",
                     *[_with_left(got.get(m)) for m in peers]])
    return markdown(["case", "end %", "default", "best single of ours", *peers], body)


def _with_left(row: dict | None) -> str:
    if row is None:
        return "—"
    left = num(row.get("left"))
    return f"{num(row['rmse']):.2f}" + (f" ({100 * left:.0f} %)" if left >= 0.005 else "")


def cost_table(rows: list[dict]) -> str:
    """docs/speed.md's block: per method the CPU seconds of a case (median, the largest, the
    sum over the cases it ran), from the rows this harness wrote (older rows lack ``rmse_end``)."""
    rows = [r for r in rows if r.get("rmse_end", "") != ""]
    body = []
    for m in dict.fromkeys(r["method"] for r in rows):
        cpu = [num(r.get("cpu")) for r in rows if r["method"] == m]
        body.append([f"`{m}`", len(cpu), np.nanmedian(cpu), np.nanmax(cpu), np.nansum(cpu)])
    frames = sorted(int(num(r["T"])) for r in rows if r["method"] == rows[0]["method"])
    return (f"The real-gap benchmark's cases ({frames[0]}-{frames[-1]} frames; "
            "`OMP_NUM_THREADS=1 python -m benchmarks real-gaps`, the rows of "
            "experiments/results/real_gaps/rows.csv): CPU seconds of each fill, all threads of "
            "the process (robust to a loaded machine: these ran on a shared 2-core machine).\n\n"
            + markdown(["method", "cases", "median CPU s", "max CPU s", "sum CPU s"], body))


def _quiet(table, *args) -> str:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # means of columns a method's rows lack
        return table(*args)


def ik_summary() -> list[dict]:
    """The IK suite's summaries: ours, then the peers' own run."""
    from . import ik

    out = []
    for folder in (ik.RESULTS, ik.RESULTS / "peers"):
        got = ik.stored(folder)
        out += ik.summarise(*got[:2]) if got else []
    return out


def doc_blocks() -> dict:
    """docs/real-gaps.md's tables (ours), docs/benchmark.md's (ours and the peers: all cases
    once the peers ran on all of them, else the quick rows) and docs/speed.md's cost table."""
    from ..rows import read_csv

    out = {}
    rows = read_csv(CSV)
    ours = [r for r in rows if not methods.is_peer(r["method"])]
    if ours:
        names = list(dict.fromkeys(r["method"] for r in ours))
        out[(data.DOCS / "real-gaps.md", "real_gaps")] = tables(ours, names)
        out[(data.DOCS / "speed.md", "real_gaps_cost")] = cost_table(rows)
    full = any(methods.is_peer(r["method"]) for r in rows)
    source, used = ("all cases", rows) if full else ("the quick cases", read_csv(QUICK_CSV))
    if used:
        out[(BENCHMARK, "benchmark")] = "\n\n".join([
            f"From the stored rows of {source} ({len({r['case'] for r in used})} cases, "
            f"{len({r['case'] for r in used if r['split'] == 'held-out'})} held out). "
            "RMSE per coordinate over the hidden samples, mm, means over the cases; a peer's "
            "unfilled samples count with `linear`'s fill in the RMSE columns, its own samples "
            "alone in RMSE own. IK columns: the IK suite's masks (docs/ik.md), mean joint-angle "
            "RMSE in degrees.", _quiet(benchmark_table, used, ik_summary()),
            "Per case (RMSE mm; in brackets the share of the hidden samples a peer left):",
            peer_case_table(used)])
    return out
