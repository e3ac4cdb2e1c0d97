"""The real-gap-pattern suite: the missing-marker masks of every real gapped recording in the data
folder, laid onto complete recordings so that the truth of every hidden sample is known.

Each case takes one source file's mask (:func:`torchfill.gaps.transplant`: resampled to the
target's rate so gaps keep their duration, dead markers dropped) and one complete recording, cut
to the mask's length so that trial-end gaps stay at the trial ends. Two assignments of source to
target markers per source: ``random`` (seeded) and ``layout`` (a source marker goes to the target
marker at the most similar place on the body: height, side, distance from the body's axis), since
real occlusions hit neighbouring markers together.

Every method fills the same case as a MarkerSequence (labels, rate, units: what a user's file
gives), with ``extrapolate=None`` so that every missing sample is filled and scored. Prints per
case the RMSE over the missing samples (mm) of each method, then the summary: each method's mean,
the default's worst ratio to the case's best single method, and the error estimate's checks
(Spearman of per-gap estimated vs real RMS error; share of filled coordinates within 2 std).
Rows go to ``--csv`` as they finish; ``--reuse CSV`` takes methods already scored there::

    OMP_NUM_THREADS=1 python scripts/real_gap_suite.py --csv experiments/results/real_gaps/cases.csv
    python scripts/real_gap_suite.py --list          # the cases only
"""
from __future__ import annotations

import argparse
import csv
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

import torchfill
from docblock import write_csv
from torchfill import gaps
from torchfill.data import data_dir
from torchfill.metrics import gap_runs, rmse_missing

REPO = Path(__file__).resolve().parents[1]
#: Complete recordings the masks are laid onto (markers never missing after dropping HDM05's
#: unlabeled ``*`` copies and the Hamner file's dead marker).
TARGETS = ("hdm05_bd_05-01_01_120.c3d", "cmu_135_02.c3d", "osim_rajagopal_motion_capture_run.trc",
           "hdm05_mm_01-02_03_120.c3d", "biomechzoo_hockey_wrist_shot_009.c3d",
           "cmu_85_12.c3d", "osim_hamner_subject02_running.trc", "ktk_tennis_serve.c3d",
           "HDM_bd_01-02_01_120.c3d", "osim_gait2392_subject01_walk1.trc",
           "osim_rajagopal_motion_capture_walk.trc", "cmu_85_02.c3d")
SINGLES = ("linear", "pchip", "spline", "pma", "lgrnn", "pca_gloersen", "li", "glr", "svt",
           "tucker_tnn", "rigid")
DEFAULT = "default"


@dataclass
class Case:
    name: str
    truth: torchfill.MarkerSequence      # complete, in mm
    mask: np.ndarray                     # (T, J) True = hidden
    source: str
    target: str
    assign: str

    def gapped(self) -> torchfill.MarkerSequence:
        P = self.truth.points.copy()
        P[self.mask] = np.nan
        return self.truth.with_points(P)


def in_mm(seq: torchfill.MarkerSequence) -> torchfill.MarkerSequence:
    scale = {"m": 1000.0, "cm": 10.0, "mm": 1.0}.get(seq.units.strip().lower(), 1.0)
    out = seq.with_points(seq.points * scale)
    out.units = "mm"
    return out


def complete(path: Path) -> torchfill.MarkerSequence:
    """The recording's markers that are never missing (unlabeled ``*`` copies dropped)."""
    seq = in_mm(torchfill.read(path))
    keep = [j for j, lab in enumerate(seq.labels)
            if not lab.startswith("*") and np.isfinite(seq.points[:, j]).all()]
    return seq.select(keep)


def sources(folder: Path) -> list[tuple[str, np.ndarray, float, np.ndarray]]:
    """(file, mask, rate, layout) of every recording with real gaps in a marker that is not dead."""
    out = []
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in (".c3d", ".trc"):
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            seq = torchfill.read(path)
        mask = ~np.isfinite(seq.points).all(axis=2)
        share = mask.mean(axis=0)
        if not ((share > 0) & (share <= 0.95)).any():
            continue
        out.append((path.name, mask, float(seq.rate), gaps.body_layout(seq.points, seq.labels)))
    return out


def cases(folder: Path | None = None, seeds: int = 1) -> list[Case]:
    """The suite, deterministically: every source x (random, layout) x ``seeds`` seeds, each on
    the next target recording long enough for the source's mask (else the longest)."""
    folder = folder or data_dir(REPO)
    targets = [(name, complete(folder / name)) for name in TARGETS if (folder / name).exists()]
    layouts = {name: gaps.body_layout(t.points, t.labels) for name, t in targets}
    out, k = [], 0
    for seed in range(seeds):
        for src, mask, rate, src_layout in sources(folder):
            for assign in ("random", "layout"):
                order = targets[k % len(targets):] + targets[:k % len(targets)]
                k += 1
                need = lambda t: int(round(mask.shape[0] * t.rate / rate))  # noqa: E731
                name, truth = next(((n, t) for n, t in order if t.n_frames >= need(t)),
                                   max(order, key=lambda nt: nt[1].n_frames / need(nt[1])))
                T = min(need(truth), truth.n_frames)
                rng = np.random.default_rng(1000 * seed + k)
                start = int(rng.integers(0, truth.n_frames - T + 1))
                part = truth.with_points(truth.points[start:start + T])
                lay = (src_layout, layouts[name]) if assign == "layout" else (None, None)
                M = gaps.transplant(mask, T, part.n_markers, seed=1000 * seed + k,
                                    rate_ratio=truth.rate / rate, source_layout=lay[0],
                                    target_layout=lay[1])
                if not M.any():
                    continue
                tag = f"{Path(src).stem}__{Path(name).stem}__{assign}{seed or ''}"
                out.append(Case(tag, part, M, src, name, assign))
    return out


def mask_suite(folder: Path, data: Path | None = None) -> list[Case]:
    """The cases written by scripts/mask_suite.py (simulated gaps: the papers' protocols, dense
    clustered occlusions, blackouts), as MarkerSequences with the recording's labels and rate."""
    import json
    data = data or data_dir(REPO)
    out = []
    for c in json.loads((folder / "cases.json").read_text()):
        with np.load(folder / f"{c['name']}.npz") as z:
            truth, mask = np.array(z["truth"]), np.array(z["mask"])
            rec, markers = str(z["recording"]), [int(i) for i in z["markers"]]
        seq = torchfill.read(next(data.glob(f"{rec}.*")))
        seq = in_mm(seq).select(markers)
        seq = seq.with_points(truth)
        out.append(Case(c["name"], seq, mask, "mask_suite", rec, c.get("kind", "")))
    return out


def per_gap(filled, std, truth, mask):
    """Per marker-gap: (real RMS 3-D error, mean estimated std per coordinate)."""
    err = np.linalg.norm(filled - truth, axis=2)
    return [(float(np.sqrt(np.mean(err[a:b, j] ** 2))), float(np.nanmean(std[a:b, j])))
            for j, a, b in gap_runs(mask)]


def std_checks(filled, std, truth, mask) -> tuple[float, float, list]:
    """Spearman of per-gap estimated vs real error, share of filled coordinates within 2 std."""
    g = per_gap(filled, std, truth, mask)
    ok = [x for x in g if np.isfinite(x[1])]
    rho = spearmanr([x[0] for x in ok], [x[1] for x in ok]).statistic if len(ok) > 2 else np.nan
    E = np.abs(filled - truth)[mask]                      # (n, 3) per coordinate
    s = std[mask][:, None]
    fin = np.isfinite(s[:, 0])
    within = float(np.mean(E[fin] <= 2 * s[fin])) if fin.any() else np.nan
    return float(rho), within, g


def run(case: Case, methods, reuse: dict, seed: int = 0) -> tuple[dict, list]:
    X = case.gapped()
    row = {"case": case.name, "source": case.source, "target": case.target, "assign": case.assign,
           "T": X.n_frames, "J": X.n_markers, "missing": int(case.mask.sum()),
           "trial_end": float(_trial_end_share(case.mask))}
    gaps_out = []
    for m in methods:
        if reuse.get(m, "") not in ("", "nan"):
            row[m], row[f"{m}_s"] = float(reuse[m]), float(reuse[f"{m}_s"])
            row[f"{m}_cpu"] = float(reuse.get(f"{m}_cpu") or "nan")
            for k in ("spearman", "within"):
                if m == DEFAULT and k in reuse:
                    row[k] = float(reuse[k])
            continue
        t, cpu = time.perf_counter(), time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                if m == DEFAULT:
                    out, std = torchfill.fill(X, extrapolate=None, return_std=True,
                                              params={"seed": seed})
                else:
                    out = torchfill.fill(X, method=m, extrapolate=None)
            except ValueError as err:
                print(f"  {case.name}: {m} failed: {err}", flush=True)
                row[m], row[f"{m}_s"] = np.nan, np.nan
                continue
        row[f"{m}_s"] = time.perf_counter() - t
        row[f"{m}_cpu"] = time.process_time() - cpu          # all threads; robust to load
        F = out.points
        row[m] = rmse_missing(np.nan_to_num(F), case.truth.points, case.mask) \
            if np.isfinite(F[case.mask]).all() else np.nan
        if m == DEFAULT:
            row["spearman"], row["within"], g = std_checks(F, std, case.truth.points, case.mask)
            gaps_out = [(case.name, *x) for x in g]
    return row, gaps_out


def _trial_end_share(mask: np.ndarray) -> float:
    """Share of the hidden samples in gaps touching the first or last frame."""
    T = mask.shape[0]
    ends = sum(b - a for j, a, b in gap_runs(mask) if a == 0 or b == T)
    return ends / max(int(mask.sum()), 1)


def select(suite: list, only: str | None, shard: str = "0/1") -> list:
    """The cases whose names hold one of the comma-separated ``only`` substrings, then every N-th
    from the I-th (``shard`` "I/N")."""
    if only:
        suite = [c for c in suite if any(s in c.name for s in only.split(","))]
    i, n = (int(x) for x in shard.split("/"))
    return suite[i::n]


def print_cases(suite: list) -> None:
    for c in suite:
        print(f"{c.name}: {c.truth.n_frames} x {c.truth.n_markers}, "
              f"{int(c.mask.sum())} hidden, {100 * _trial_end_share(c.mask):.0f} % at trial ends")


def summary(rows: list[dict], methods: list[str]) -> str:
    singles = [m for m in methods if m != DEFAULT]
    lines = ["| case | end % | " + " | ".join(methods) + " | default / best |",
             "|---|---:|" + "---:|" * (len(methods) + 1)]
    ratios = []
    for r in rows:
        best = min((float(r[m]) for m in singles if np.isfinite(float(r.get(m, np.nan)))),
                   default=np.nan)
        ratio = float(r.get(DEFAULT, np.nan)) / best if best > 0 else np.nan
        ratios.append(ratio)
        lines.append(f"| {r['case']} | {100 * float(r['trial_end']):.0f} | " +
                     " | ".join(f"{float(r.get(m, np.nan)):.2f}" for m in methods) +
                     f" | {ratio:.2f} |")
    means = {m: np.nanmean([float(r.get(m, np.nan)) for r in rows]) for m in methods}
    secs = {m: np.nanmedian([float(r.get(f"{m}_cpu", np.nan)) for r in rows]) for m in methods}
    lines.append("| **mean** | | " + " | ".join(f"**{means[m]:.2f}**" for m in methods) +
                 f" | worst {np.nanmax(ratios):.2f} |")
    lines.append("| median CPU s | | " + " | ".join(f"{secs[m]:.2f}" for m in methods) + " | |")
    lines.append("")
    if not singles:
        return "\n".join(lines)
    best_single = min(singles, key=lambda m: means[m])
    lines.append(f"{len(rows)} cases; best single method by mean: {best_single} "
                 f"{means[best_single]:.2f} mm; default {means.get(DEFAULT, np.nan):.2f} mm; "
                 f"default worst ratio to the case's best single {np.nanmax(ratios):.2f}")
    sp = [float(r["spearman"]) for r in rows if "spearman" in r]
    wi = [float(r["within"]) for r in rows if "within" in r]
    if sp:
        lines.append(f"std: per-case Spearman median {np.nanmedian(sp):.2f}; within 2 std "
                     f"mean {100 * np.nanmean(wi):.0f} % (range {100 * np.nanmin(wi):.0f}-"
                     f"{100 * np.nanmax(wi):.0f} %)")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", default=",".join((DEFAULT, *SINGLES)),
                    help="comma-separated; 'default' is torchfill.fill's default")
    ap.add_argument("--csv", type=Path, help="write rows here as they finish")
    ap.add_argument("--gaps-csv", type=Path, help="per-gap real vs estimated error of the default")
    ap.add_argument("--reuse", type=Path, nargs="*", default=(),
                    help="take methods already scored in these CSVs")
    ap.add_argument("--only", help="comma-separated substrings of case names to run")
    ap.add_argument("--seeds", type=int, default=1, help="seeds of the assignment and offset")
    ap.add_argument("--fill-seed", type=int, default=0,
                    help="the default's seed (which shifts its hold-out draws take: the mask "
                         "suite's mean moves by several percent from one seed to another)")
    ap.add_argument("--shard", default="0/1", metavar="I/N",
                    help="run every N-th case from the I-th (processes side by side; merge their "
                         "CSVs with --reuse)")
    ap.add_argument("--list", action="store_true", help="list the cases and stop")
    ap.add_argument("--doc", type=Path, help="also write the summary into this docs page, between "
                                             "its <!-- real_gap_suite:start/end --> markers "
                                             "(mask_suite:start/end with --mask-suite)")
    ap.add_argument("--mask-suite", type=Path,
                    help="run the simulated-gap cases written by scripts/mask_suite.py in this "
                         "folder instead of the real gap patterns")
    args = ap.parse_args()
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    suite = mask_suite(args.mask_suite) if args.mask_suite else cases(seeds=args.seeds)
    suite = select(suite, args.only, args.shard)
    if args.list:
        print_cases(suite)
        return
    reuse: dict[str, dict] = {}
    for path in args.reuse:
        with open(path) as f:
            for r in csv.DictReader(f):
                reuse.setdefault(r["case"], {}).update({k: v for k, v in r.items() if v != ""})
    rows, per_gaps = [], []
    for c in suite:
        keep = {k: v for k, v in reuse.get(c.name, {}).items()
                if any(k in (m, f"{m}_s", f"{m}_cpu") for m in methods)
                or (k in ("spearman", "within") and DEFAULT in methods)}
        row, g = run(c, methods, keep, args.fill_seed)
        rows.append(row)
        per_gaps += g
        print(f"{c.name}: " + ", ".join(f"{m} {float(row.get(m, np.nan)):.2f}" for m in methods),
              flush=True)
        if args.csv:
            write_csv(args.csv, rows)
    table = summary(rows, methods)
    print(table)
    if args.doc:
        from docblock import write_block
        write_block(args.doc, "mask_suite" if args.mask_suite else "real_gap_suite", table)
    if args.gaps_csv and per_gaps:
        write_csv(args.gaps_csv, [dict(zip(("case", "real_rmse", "est_std"), g)) for g in per_gaps])
        real = np.array([g[1] for g in per_gaps])
        est = np.array([g[2] for g in per_gaps])
        ok = np.isfinite(est)
        print(f"pooled per-gap Spearman {spearmanr(real[ok], est[ok]).statistic:.2f} "
              f"over {ok.sum()} gaps")


if __name__ == "__main__":
    main()
