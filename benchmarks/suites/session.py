"""The session suite: does a subject's other trial make the fill of a trial better, and what
does it cost?

Recordings of one subject in the data folder (HDM05 actor bd, CMU subject 85, the Rajagopal
model's run and walk) form sessions. Each case lays the missing-marker mask of a real gapped
file (:func:`benchmarks.cases.lay`) onto one trial's complete markers, cut to the mask's length
at the trial start (so trial-end gaps stay at trial ends), and fills it with the default, once
alone and once with the session's other trial(s) as ``training`` (read as they are, each one's
own gaps included). Prints per case the RMSE over the hidden samples (mm) and their ratio, then
the mean ratio on the trial-end-dominated cases and the worst ratio over all cases.
``--timing`` instead times a batch (``torchfill fill DIR/*.c3d``) with and without ``--session``::

    OMP_NUM_THREADS=1 python -m benchmarks session            (rows: experiments/results/session/rows.csv)
    OMP_NUM_THREADS=1 python -m benchmarks session --timing --trials 10 --frames 400
"""
from __future__ import annotations

import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import torchfill
from torchfill import gaps
from torchfill.metrics import rmse_missing

from .. import data
from ..cases import Case, lay, print_cases, select, sources
from ..rows import Rows, num, read_csv
from ..timing import measure
from . import case_arguments

RESULTS = data.RESULTS / "session"
ROWS = RESULTS / "rows.csv"
HELP = "a subject's other trials as training: RMSE alone vs with the session, and its time"
#: Sessions: the trial the gaps are laid onto first, then the subject's other trial(s).
SESSIONS = {
    "hdm05_bd": ("HDM_bd_01-02_01_120.c3d", "hdm05_bd_05-01_01_120.c3d"),
    "cmu_85": ("cmu_85_02.c3d", "cmu_85_12.c3d"),
    "rajagopal": ("osim_rajagopal_motion_capture_walk.trc", "osim_rajagopal_motion_capture_run.trc"),
}
#: A case is trial-end-dominated when at least this share of its hidden samples is in gaps that
#: touch the first or last frame.
END_SHARE = 0.5


@dataclass
class SessionCase(Case):
    training: list = field(default_factory=list)


def cases(folder: Path, both_ways: bool = False) -> list[SessionCase]:
    """Every real gap pattern on the first trial of each session (every trial with
    ``both_ways``), the other trials as training."""
    masks = sources(folder)
    out = []
    for group, files in SESSIONS.items():
        if not all((folder / f).exists() for f in files):
            continue
        for target in files if both_ways else files[:1]:
            truth = data.complete(folder / target)
            training = [data.in_mm(data.read(folder / f)) for f in files if f != target]
            shared = [t for t in training if set(t.short_labels()) & set(truth.short_labels())]
            if not shared:
                print(f"{group}: {target} shares no marker label with "
                      f"{', '.join(f for f in files if f != target)} (another marker set): "
                      f"no session to learn from, left out")
                continue
            layout = gaps.body_layout(truth.points, truth.labels)
            for k, src in enumerate(masks):
                part, M = lay(src, truth, k, layout)
                if M.any():
                    name = f"{Path(src[0]).stem}__{Path(target).stem}"
                    out.append(SessionCase(name, part, M, src[0], target, training=training))
    return out


def run(case: SessionCase) -> dict:
    X = case.gapped()
    row = {"case": case.name, "T": X.n_frames, "J": X.n_markers, "missing": int(case.mask.sum()),
           "trial_end": float(case.trial_end)}
    for tag, training in (("alone", None), ("session", case.training)):
        with measure() as t, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = torchfill.fill(X, extrapolate=None, training=training)
        row[f"{tag}_s"], row[f"{tag}_cpu"] = t.wall, t.cpu
        row[tag] = rmse_missing(np.nan_to_num(out.points), case.truth.points, case.mask)
    row["ratio"] = row["session"] / row["alone"]
    return row


def summary(rows: list[dict]) -> str:
    rows = [{k: (v if k == "case" else float(v)) for k, v in r.items()} for r in rows]
    lines = ["| case | end % | alone | session | session / alone |", "|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['case']} | {100 * r['trial_end']:.0f} | {r['alone']:.2f} | "
                     f"{r['session']:.2f} | {r['ratio']:.2f} |")
    end, every = stats(rows, END_SHARE), stats(rows)
    lines += ["", f"{every['cases']} cases; trial-end-dominated ({end['cases']}): mean ratio "
              f"{end['ratio']:.2f} (mean RMSE {end['alone']:.2f} -> {end['session']:.2f} mm); "
              f"all: mean ratio {every['ratio']:.2f} (mean RMSE {every['alone']:.2f} -> "
              f"{every['session']:.2f} mm), worst {every['worst']:.2f}; "
              f"time session / alone {every['session_s'] / every['alone_s']:.2f}"]
    return "\n".join(lines)


def stats(rows: list[dict], end_share: float = 0.0) -> dict:
    """Over the rows with at least ``end_share`` of their hidden samples at trial ends: the
    number of cases, the means of each column and of the ratio, the worst ratio and how many
    cases the session makes worse by more than 5 %."""
    rows = [{k: num(v) for k, v in r.items() if k != "case"} for r in rows]
    rows = [r for r in rows if r["trial_end"] >= end_share]
    out = {k: float(np.mean([r[k] for r in rows])) if rows else np.nan
           for k in ("alone", "session", "ratio", "alone_s", "session_s")}
    return {**out, "cases": len(rows), "worst": max((r["ratio"] for r in rows), default=np.nan),
            "worse": sum(r["ratio"] > 1.05 for r in rows)}


def stored() -> list[dict]:
    """The rows kept in experiments/results/session/rows.csv (``python -m benchmarks session``)."""
    return read_csv(ROWS)


def add_arguments(p) -> None:
    case_arguments(p, str(ROWS))
    p.add_argument("--both-ways", action="store_true",
                   help="lay the gaps onto every trial of a session, not only the first")
    p.add_argument("--timing", action="store_true",
                   help="instead: a batch's time with and without --session")
    p.add_argument("--trials", type=int, default=10, help="with --timing: trials in the batch")
    p.add_argument("--frames", type=int, default=800,
                   help="with --timing: frames per trial at most")


def main(args) -> int:
    if args.timing:
        return timing(args.trials, args.frames)
    suite = select(cases(data.need(), args.both_ways), args.only, args.shard)
    if args.list:
        print_cases(suite)
        return 0
    rows = Rows(args.csv or None, ("case",))
    for c in suite:
        if not args.redo and rows.done(case=c.name):
            continue
        rows.add(run(c))
        r = rows.rows[-1]
        print(f"{c.name}: alone {r['alone']:.2f}, session {r['session']:.2f} mm "
              f"({r['ratio']:.2f}x; {r['alone_s']:.1f} / {r['session_s']:.1f} s)", flush=True)
    print(summary([r for r in rows.rows if r["case"] in {c.name for c in suite}]))
    return 0


#: The batch --timing fills: pieces of HDM05 actor bd's two trials.
BATCH = ("HDM_bd_01-02_01_120.c3d", "hdm05_bd_05-01_01_120.c3d")


def trials(folder: Path, n: int, frames: int) -> list[tuple[torchfill.MarkerSequence, np.ndarray]]:
    """``n`` (truth, mask) pairs: pieces of the session's recordings with real gap patterns."""
    whole = [data.complete(folder / name) for name in BATCH]
    labels = sorted(set.intersection(*(set(s.labels) for s in whole)))
    whole = [s.select([s.labels.index(lab) for lab in labels]) for s in whole]
    pieces = [s.with_points(s.points[a:a + frames]) for s in whole
              for a in range(0, s.n_frames - frames + 1, frames)][:n]
    masks = [m for m in sources(folder) if m[1].shape[0] * 120.0 / m[2] >= frames // 2]
    return [lay(masks[k % len(masks)], truth, k) for k, truth in enumerate(pieces)]


def timing(n: int, frames: int) -> int:
    """``torchfill fill DIR/*.c3d`` (this process, one worker) without and with ``--session``:
    wall and CPU seconds, their ratio and the mean RMSE over the hidden samples."""
    from torchfill.cli import main as cli

    pairs = trials(data.need(*BATCH), n, frames)
    result = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        paths = []
        for i, (truth, M) in enumerate(pairs):
            seq = truth.with_points(np.where(M[..., None], np.nan, truth.points))
            seq.source = None
            paths.append(tmp / f"trial{i:02d}.c3d")
            torchfill.write(seq, paths[-1])
        print(f"{len(paths)} trials, {sum(t.n_frames for t, _ in pairs)} frames, "
              f"{sum(int(M.sum()) for _, M in pairs)} hidden samples", flush=True)
        for tag, extra in (("alone", []), ("session", ["--session"])):
            with measure() as t:
                code = cli(["fill", *map(str, paths), "--out-dir", str(tmp / tag),
                            "--extrapolate", "none", "-qq", *extra])
            if code != 0:
                raise SystemExit(f"torchfill fill exited with {code}")
            errs = [rmse_missing(np.nan_to_num(torchfill.read(tmp / tag / p.name).points),
                                 truth.points, M) for p, (truth, M) in zip(paths, pairs)]
            result[tag] = (t.wall, t.cpu, float(np.mean(errs)))
            print(f"{tag}: {t.wall:.1f} s wall, {t.cpu:.1f} s CPU, mean RMSE {np.mean(errs):.2f} "
                  f"mm ({', '.join(f'{e:.1f}' for e in errs)})", flush=True)
    (w0, c0, e0), (w1, c1, e1) = result["alone"], result["session"]
    print(f"session / alone: wall {w1 / w0:.2f}x, CPU {c1 / c0:.2f}x, RMSE {e1 / e0:.2f}x")
    return 0
