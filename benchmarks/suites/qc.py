"""The QC verdicts (torchfill.qc) checked on gaps whose truth is known, and the plausibility of
fills on the real gaps of the gapped recordings (no truth there).

Cases, deterministic from seeds:

- ``ktk_tennis_serve_nan`` against its clean twin ``ktk_tennis_serve``;
- real gap masks laid onto complete recordings (``TRANSPLANTS``): the missing-marker masks of real
  gapped files over a stretch of a complete recording of the source's length, source markers
  assigned to truth markers at random (seeded); a sample is hidden only where the truth is
  observed.

Each case is filled once with the default method (``return_std=True``, default extrapolation
limit) and cached (``--cache``); every filled gap is then judged with ``qc.gap_table`` -- which
sees the input, the fill and its std, never the truth -- and the verdict compared with the gap's
true RMS error (3-D, over its filled frames). The targets:

- of the gaps whose true RMS error is above both 10 mm and 3 x the case's median gap error,
  >= 90 % are ``check`` or ``reject``;
- of the gaps below 5 mm, <= 15 % are not ``ok``.

The split: the thresholds of ``torchfill.qc`` were chosen on this suite's own cases (group
``own``: the tennis file and the transplants); the real-gap benchmark's cases (group ``suite``)
are held out, and its cases whose mask comes from a source file the own cases do not use are
listed apart (``held out, new sources``)::

    OMP_NUM_THREADS=1 python -m benchmarks qc [--cache DIR] [--only NAME ...]
        [--group own|suite|all] [--refill] [--rows] [--doc docs/real-gaps.md]
    OMP_NUM_THREADS=1 python -m benchmarks qc --plausibility [--methods default,pchip]
"""
from __future__ import annotations

import os
import tempfile
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

import torchfill
from torchfill import metrics
from torchfill.solvers.rigid import rigid_pairs

from .. import data, scores
from ..cases import MASKS, load_masks, split_of
from ..methods import spatial
from ..rows import read_csv, write_csv
from ..tables import write_block

HELP = "the per-gap verdicts against the truth, and plausibility on real gaps (--plausibility)"
GAPS = data.RESULTS / "qc" / "gaps.csv"
DOC = data.DOCS / "real-gaps.md"
COMMAND = "python -m benchmarks qc --doc docs/real-gaps.md"

#: name, gap source (its mask), truth recording, seed (benchmarks/masks/qc_transplants.csv)
TRANSPLANTS = [(r["name"], r["source"], r["truth"], int(r["seed"]))
               for r in read_csv(MASKS / "qc_transplants.csv")]

#: Frames kept at most per case (long sources are cut to a window that keeps a trial end).
MAX_FRAMES = 1500

def transplant_case(source: str, truth: str, seed: int):
    """(gappy, truth) MarkerSequences: ``source``'s mask over a stretch of ``truth``."""
    rng = np.random.default_rng(seed)
    src = torchfill.read(data.folder() / source).mask
    src = src[:, ~src.all(axis=0)]                       # markers never seen carry no pattern
    full = torchfill.read(data.folder() / truth)
    keep = ~full.mask.any(axis=0)                        # complete truth markers only
    full = full.select(np.flatnonzero(keep))
    T = min(len(src), full.n_frames, MAX_FRAMES)
    s0 = 0 if len(src) <= T else int(rng.choice([0, len(src) - T]))   # keep one trial end
    t0 = int(rng.integers(0, full.n_frames - T + 1))
    mask_src = src[s0:s0 + T]
    J = full.n_markers
    cols = rng.permutation(mask_src.shape[1])[:J]        # source markers, at most J of them
    targets = rng.permutation(J)[:len(cols)]
    mask = np.zeros((T, J), dtype=bool)
    mask[:, targets] = mask_src[:, cols]
    truth_seq = full.with_points(full.points[t0:t0 + T])
    gappy = truth_seq.with_points(np.where(mask[..., None], np.nan, truth_seq.points))
    return gappy, truth_seq


def suite_cases(only=None):
    """The real-gap benchmark's cases (held out from the thresholds)."""
    for case in load_masks(data.folder()):
        if only and case.name not in only:
            continue
        yield case.name, lambda c=case: (c.gapped(), c.truth)


def cases(only=None, group="all"):
    """(name, make) of every case: ``group`` "own" (tennis + TRANSPLANTS: the thresholds were
    chosen on these), "suite" (the real-gap-pattern suite: held out), or "all"."""
    if group in ("suite", "all"):
        yield from suite_cases(only)
    if group == "suite":
        return
    if not only or "tennis" in only:
        gappy = torchfill.read(data.folder() / "ktk_tennis_serve_nan.c3d")
        truth = torchfill.read(data.folder() / "ktk_tennis_serve.c3d")
        yield "tennis", lambda: (gappy, truth)
    for name, source, truth, seed in TRANSPLANTS:
        if only and name not in only:
            continue
        yield name, lambda s=source, t=truth, k=seed: transplant_case(s, t, k)


def filled_case(name, make, cache: Path, refill: bool) -> dict:
    path = cache / f"{name}.npz"
    if path.exists() and not refill:
        z = np.load(path, allow_pickle=False)
        return {k: z[k] for k in z.files}
    gappy, truth = make()
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out, std = torchfill.fill(gappy, return_std=True)
    seconds = time.perf_counter() - start
    data = dict(points=gappy.points, filled=out.points, std=std, truth=truth.points,
                rate=np.float64(gappy.rate), units=np.str_(gappy.units),
                labels=np.array(gappy.labels), seconds=np.float64(seconds),
                method=np.str_(out.meta["fill_info"]["method"]))
    with tempfile.NamedTemporaryFile(dir=cache, suffix=".npz", delete=False) as tmp:
        np.savez_compressed(tmp, **data)
    os.replace(tmp.name, path)
    return data


def judged(name: str, d: dict) -> list[dict]:
    """The qc rows of a case plus each gap's true RMS error in mm (NaN where nothing was filled)
    and, on a short interior gap, the true RMS error of the ``pchip`` method's fill there."""
    rows = scores.verdicts(d["points"], d["filled"], d["truth"], float(d["rate"]), list(d["labels"]),
                           std=d["std"], units=str(d["units"]), spatial=spatial(str(d["method"])))
    pchip = None
    for r in rows:
        r["case"] = name
        r["gap_kind"] = ("short interior" if r["kind"] == "interior" and r["frames"] <= SHORT
                         else "trial end" if r["kind"] in ("start", "end") else "other")
        r["pchip_mm"] = np.nan
        if r["gap_kind"] == "short interior":
            pchip = pchip if pchip is not None else run(d["points"], "pchip")[0]
            e = np.linalg.norm(pchip[r["start"]:r["stop"], r["j"]]
                               - d["truth"][r["start"]:r["stop"], r["j"]], axis=1)
            r["pchip_mm"] = float(np.sqrt(np.mean(e ** 2))) * scores.MM.get(str(d["units"]), 1.0)
    return rows


#: Interior gaps up to this many frames are reported as short (the qc's short-gap rules).
SHORT = 10
KINDS = ("short interior", "trial end")


def by_kind(rows: list[dict]) -> list[str]:
    """Markdown rows: the real-gap suite's cases (all, then its tuning and held-out splits,
    docs/benchmark.md), each gap kind apart: large-error gaps flagged, gaps < 5 mm not ok, true
    error within 2 x est_rmse, and (short interior gaps) the fill's true RMS error within 1.5 x
    the ``pchip`` method's or 2 mm of it."""
    out = []
    for split in ("all", "tuning", "held-out"):
        for kind in KINDS:
            sel = [r for r in rows if "__" in r["case"] and r.get("gap_kind") == kind
                   and split in ("all", split_of(r["case"].split("__")[0]))
                   and np.isfinite(r["true_mm"])]
            n_big, hit, n_small, false = shares(sel)
            est = [r for r in sel if np.isfinite(float(r["est_mm"]))]
            within = 100.0 * np.mean([r["true_mm"] <= 2 * float(r["est_mm"]) for r in est]) \
                if est else float("nan")
            near = [r["true_mm"] <= max(1.5 * float(r["pchip_mm"]), float(r["pchip_mm"]) + 2.0)
                    for r in sel if np.isfinite(float(r.get("pchip_mm", np.nan)))]
            pchip = f"{100.0 * np.mean(near):.1f} %" if near else ""
            out.append(f"| {split} | {kind} | {len(sel)} | {n_big} | {hit:.1f} % | {n_small} | "
                       f"{false:.1f} % | {within:.1f} % | {pchip} |")
    return out


BINS = [("< 5 mm", lambda r: r["true_mm"] < 5), ("5-10 mm", lambda r: 5 <= r["true_mm"] < 10),
        (">= 10 mm, not big", lambda r: r["true_mm"] >= 10 and not r["big"]),
        ("big (> 10 mm and > 3 x median)", lambda r: r["big"])]


def counts(rows: list[dict]) -> list[tuple[str, int, Counter]]:
    """(bin, gaps, verdict counts) of the scored gaps in each true-error bin."""
    scored = [r for r in rows if np.isfinite(r["true_mm"])]
    return [(label, len(sel), Counter(r["verdict"] for r in sel))
            for label, test in BINS for sel in [[r for r in scored if test(r)]]]


def shares(rows: list[dict]) -> tuple[int, float, int, float]:
    """(big gaps, share flagged, gaps < 5 mm, share flagged) in %."""
    scored = [r for r in rows if np.isfinite(r["true_mm"])]
    big = [r for r in scored if r["big"]]
    small = [r for r in scored if r["small"]]
    pct = lambda sel: 100.0 * sum(r["verdict"] != "ok" for r in sel) / len(sel) \
        if sel else float("nan")                                    # noqa: E731
    return len(big), pct(big), len(small), pct(small)


def confusion(rows: list[dict]) -> str:
    lines = [f"{'true RMS error':<32}{'gaps':>6}{'ok':>6}{'check':>7}{'reject':>8}{'not ok':>9}"]
    for label, n, c in counts(rows):
        bad = c["check"] + c["reject"]
        lines.append(f"{label:<32}{n:>6}{c['ok']:>6}{c['check']:>7}{c['reject']:>8}"
                     f"{(100.0 * bad / n if n else float('nan')):>8.1f}%")
    _, hit, _, false = shares(rows)
    unscored = sum(not np.isfinite(r["true_mm"]) for r in rows)
    lines.append(f"big gaps flagged: {hit:.1f} % (target >= 90 %); "
                 f"gaps < 5 mm flagged: {false:.1f} % (target <= 15 %); "
                 f"{unscored} gap(s) left wholly unfilled (not scored)")
    return "\n".join(lines)


def group_of(name: str) -> str:
    """``own`` (the thresholds were chosen on it), ``suite`` (held out, a source the own cases
    use too) or ``new`` (held out, a source file no own case uses)."""
    if "__" not in name:
        return "own"
    used = {Path(src).stem for _, src, _, _ in TRANSPLANTS} | {"ktk_tennis_serve_nan"}
    return "suite" if name.split("__")[0] in used else "new"


GROUPS = [("all cases", lambda g, n: True),
          ("calibration (own: tennis + transplants)", lambda g, n: g == "own"),
          ("held out (real-gap-pattern suite)", lambda g, n: g in ("suite", "new")),
          ("held out, new sources", lambda g, n: g == "new"),
          ("ktk_tennis_serve_nan vs its clean twin", lambda g, n: n == "tennis"),
          ("suite + ktk_tennis_serve_nan", lambda g, n: g in ("suite", "new") or n == "tennis")]


def markdown(rows: list[dict], command: str) -> str:
    """The doc block: the targets per group of cases, then the confusion table of all."""
    out = [f"`{command}`", "",
           "| cases | gaps scored | big gaps | flagged (target >= 90 %) | gaps < 5 mm | "
           "flagged (target <= 15 %) |", "|---|---|---|---|---|---|"]
    for label, test in GROUPS:
        sel = [r for r in rows if test(group_of(r["case"]), r["case"])]
        if not sel:
            continue
        cases = len({r["case"] for r in sel})
        n_big, hit, n_small, false = shares(sel)
        scored = sum(np.isfinite(r["true_mm"]) for r in sel)
        out.append(f"| {label}: {cases} case(s) | {scored} | {n_big} | {hit:.1f} % | {n_small} | "
                   f"{false:.1f} % |")
    out += ["", "The real-gap suite by gap kind (short interior: <= 10 frames):", "",
            "| cases | gap kind | gaps scored | big gaps | flagged (target >= 90 %) | "
            "gaps < 5 mm | not ok (target <= 15 %) | within 2 std (target >= 90 %) | "
            "within 1.5 x PCHIP or 2 mm (target >= 98 %) |",
            "|---|---|---|---|---|---|---|---|---|", *by_kind(rows)]
    out += ["", "All cases, verdict by true RMS error of the gap:", "",
            "| true RMS error | gaps | ok | check | reject | not ok |", "|---|---|---|---|---|---|"]
    for label, n, c in counts(rows):
        bad = 100.0 * (c["check"] + c["reject"]) / n if n else float("nan")
        out.append(f"| {label} | {n} | {c['ok']} | {c['check']} | {c['reject']} | {bad:.1f} % |")
    return "\n".join(out)


def add_arguments(p) -> None:
    p.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "torchfill_qc_cal"),
                   help="fills are cached here (delete it, or --refill, after the default "
                        "method changes)")
    p.add_argument("--only", nargs="*")
    p.add_argument("--refill", action="store_true")
    p.add_argument("--cached-only", action="store_true",
                   help="judge only the cases already filled in the cache")
    p.add_argument("--rows", action="store_true", help="print every big or flagged gap")
    p.add_argument("--group", choices=("own", "suite", "all"), default="all",
                   help="own: tennis + the transplants (the thresholds were chosen on these); "
                        "suite: the real-gap benchmark (held out)")
    p.add_argument("--csv", default=str(GAPS), help="per-gap rows ('' : none)")
    p.add_argument("--doc", help="also write the tables into this docs page, between "
                                 "<!-- qc:start/end --> markers ('' : none)")
    p.add_argument("--plausibility", action="store_true",
                   help="instead: plausibility of fills on the real gaps (no truth)")
    p.add_argument("--methods", default=",".join(PLAUSIBLE_METHODS),
                   help="with --plausibility: methods ('NAME+c': with the post-step)")
    p.add_argument("--files", default=",".join(PLAUSIBLE_FILES),
                   help="with --plausibility: the recordings")


def main(args) -> int:
    if args.plausibility:
        return plausibility_main(args)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    rows = []
    for name, make in cases(args.only, args.group):
        if args.cached_only and not (cache / f"{name}.npz").exists():
            continue
        d = filled_case(name, make, cache, args.refill)
        got = judged(name, d)
        rows += got
        print(f"{name:<14} {str(d['method']):<11} {d['points'].shape[0]:>5} frames "
              f"{d['points'].shape[1]:>3} markers {len(got):>4} gaps, fill "
              f"{float(d['seconds']):6.1f} s, median gap error "
              f"{got[0]['median_mm'] if got else np.nan:6.2f} mm", flush=True)
    print()
    for label, test in GROUPS:
        sel = [r for r in rows if test(group_of(r["case"]), r["case"])]
        if sel:
            print(f"{label}, {len({r['case'] for r in sel})} case(s):\n{confusion(sel)}\n")
    print("cases | gap kind | gaps | big | flagged | < 5 mm | not ok | within 2 std | near PCHIP")
    print("\n".join(by_kind(rows)) + "\n")
    for name in dict.fromkeys(r["case"] for r in rows):
        print(f"  {name}: " + confusion([r for r in rows if r["case"] == name]).splitlines()[-1])
    if args.csv:
        write_csv(args.csv, [{k: r[k] for k in STORED} for r in rows])
    if args.doc:
        write_block(args.doc, "qc", markdown(rows, COMMAND))
    if args.rows:
        print("\ncase           marker       frames   true_mm est_mm verdict  reasons")
        for r in rows:
            if r["big"] or (r["small"] and r["verdict"] != "ok"):
                print(f"{r['case']:<14} {r['marker'][:12]:<12} {r['start']:>4}-{r['stop'] - 1:<5}"
                      f"{r['true_mm']:>7.1f} {r['est_mm']:>6.1f} {r['verdict']:<7}  "
                      f"{'; '.join(r['reasons'])}")
    return 0


#: The per-gap columns stored (enough to regenerate the tables).
STORED = ("case", "marker", "start", "stop", "verdict", "true_mm", "est_mm", "median_mm", "big",
          "small", "gap_kind", "pchip_mm")


def doc_blocks() -> dict:
    """docs/real-gaps.md's verdict tables from the stored per-gap rows."""
    rows = read_csv(GAPS)
    for r in rows:
        r["true_mm"], r["est_mm"] = float(r["true_mm"]), float(r["est_mm"])
        r["pchip_mm"] = float(r.get("pchip_mm") or "nan")
        r["big"], r["small"] = r["big"] == "True", r["small"] == "True"
    return {(DOC, "qc"): markdown(rows, COMMAND)} if rows else {}


# ---------------------------------------------------------------------------------------------
# Plausibility on the real gaps (no truth)
# ---------------------------------------------------------------------------------------------
#: The 17 recordings with real gaps (PROVENANCE.md): gaps in markers that are observed at times.
#: ktk_tennis_serve_nan.c3d (artificial gaps) is scored against its twin instead, and
#: osim_hamner_subject02_running.trc only lacks a never-observed marker.
PLAUSIBLE_FILES = [
    "c3dorg_s00_codamotion_gaitwands_20150204.c3d", "c3dorg_s01_eb015pr.c3d",
    "c3dorg_s02_pc_real.c3d", "c3dorg_s04_sub_labels.c3d", "c3dorg_s26_capture0002.c3d",
    "c3dorg_s26_walking_hybrid_1_1.c3d", "c3dorg_s26_walking_hybrid_1_2.c3d",
    "c3dorg_s26_walking_hybrid_1_3.c3d", "c3dorg_s26_walking_hybrid_1_4.c3d",
    "c3dorg_s26_walking_hybrid_1_5.c3d", "c3dorg_s26_walking_hybrid_2.c3d",
    "c3dorg_s28_type1.c3d", "ktk_basket_sprint.c3d", "ktk_c3d_sample_bts.c3d",
    "ktk_racing_full.c3d", "mogapfill_gait-raw.csv", "numediart_03_rolling.c3d",
]
PLAUSIBLE_METHODS = ["default", "tucker_tnn", "cp", "pchip", "linear"]


def run(seq, method: str, std: bool = False):
    """A fill as a user calls it (``default``), or a method's own (``NAME+c``: with the post-step)."""
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


def plausibility_main(args) -> int:
    """Per file and method: teleports, jumps, samples outside the observed volume, rigid-pair
    deviation, edge velocity jumps, samples left NaN, seconds; then the tennis file's error."""
    methods = args.methods.split(",")
    cols = ["teleports", "jumps", "outside", "rigid_med", "rigid_p95", "edge_p95", "nan_left", "seconds"]
    print(f"{'file':<44} {'method':<11}" + "".join(f"{c:>10}" for c in cols))
    for name in filter(None, args.files.split(",")):
        seq = torchfill.read(data.folder() / name)
        for method in methods:
            out, seconds = run(seq, method)
            row = {**plausibility(seq, out), "seconds": seconds}
            print(f"{name[:44]:<44} {method:<11}" + "".join(
                f"{row[c]:>10.3g}" if isinstance(row[c], float) else f"{row[c]:>10d}"
                for c in cols),
                flush=True)
    clean = torchfill.read(data.folder() / "ktk_tennis_serve.c3d")
    gappy = torchfill.read(data.folder() / "ktk_tennis_serve_nan.c3d")
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
    return 0
