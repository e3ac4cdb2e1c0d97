"""The session suite: does a subject's other trial make the fill of a trial better?

Recordings of one subject in the data folder (HDM05 actor bd, CMU subject 85, the Rajagopal
model's run and walk) form sessions. Each case lays the missing-marker mask of a real gapped
file (the real-gap-pattern suite's sources, :func:`torchfill.gaps.transplant` with the ``layout``
assignment) onto one trial's complete markers, cut to the mask's length at the trial start (so
trial-end gaps stay at trial ends), and fills it with the default, once alone and once with the
session's other trial(s) as ``training`` (read as they are, each one's own gaps included: their
observed samples only). Prints per case the RMSE over the hidden samples (mm) and their ratio,
then the mean ratio on the trial-end-dominated cases (half or more of the hidden samples in gaps
touching a trial end) and the worst ratio over all cases::

    OMP_NUM_THREADS=1 python scripts/session_suite.py --csv experiments/results/session/cases.csv
    python scripts/session_suite.py --list
"""
from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import torchfill
from docblock import write_csv
from real_gap_suite import REPO, _trial_end_share, complete, in_mm, print_cases, select, sources
from torchfill import gaps
from torchfill.data import data_dir
from torchfill.metrics import rmse_missing

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
class SessionCase:
    name: str
    truth: torchfill.MarkerSequence
    mask: np.ndarray
    training: list

    def gapped(self) -> torchfill.MarkerSequence:
        P = self.truth.points.copy()
        P[self.mask] = np.nan
        return self.truth.with_points(P)


def cases(folder: Path, both_ways: bool = False) -> list[SessionCase]:
    """Every real gap pattern on the first trial of each session (every trial with
    ``both_ways``), the other trials as training."""
    masks = sources(folder)
    out = []
    for group, files in SESSIONS.items():
        if not all((folder / f).exists() for f in files):
            continue
        for target in files if both_ways else files[:1]:
            truth = complete(folder / target)
            training = [in_mm(torchfill.read(folder / f)) for f in files if f != target]
            shared = [t for t in training if set(t.short_labels()) & set(truth.short_labels())]
            if not shared:
                print(f"{group}: {target} shares no marker label with "
                      f"{', '.join(f for f in files if f != target)} (another marker set): "
                      f"no session to learn from, left out")
                continue
            layout = gaps.body_layout(truth.points, truth.labels)
            for k, (src, mask, rate, src_layout) in enumerate(masks):
                T = min(int(round(mask.shape[0] * truth.rate / rate)), truth.n_frames)
                part = truth.with_points(truth.points[:T])
                M = gaps.transplant(mask, T, part.n_markers, seed=k, rate_ratio=truth.rate / rate,
                                    source_layout=src_layout, target_layout=layout)
                if M.any():
                    name = f"{Path(src).stem}__{Path(target).stem}"
                    out.append(SessionCase(name, part, M, training))
    return out


def run(case: SessionCase) -> dict:
    X = case.gapped()
    row = {"case": case.name, "T": X.n_frames, "J": X.n_markers, "missing": int(case.mask.sum()),
           "trial_end": float(_trial_end_share(case.mask))}
    for tag, training in (("alone", None), ("session", case.training)):
        t = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = torchfill.fill(X, extrapolate=None, training=training)
        row[f"{tag}_s"] = time.perf_counter() - t
        row[tag] = rmse_missing(np.nan_to_num(out.points), case.truth.points, case.mask)
    row["ratio"] = row["session"] / row["alone"]
    return row


def summary(rows: list[dict]) -> str:
    lines = ["| case | end % | alone | session | session / alone |", "|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['case']} | {100 * r['trial_end']:.0f} | {r['alone']:.2f} | "
                     f"{r['session']:.2f} | {r['ratio']:.2f} |")
    end = [r for r in rows if r["trial_end"] >= END_SHARE]
    ratio = lambda rs: np.mean([r["ratio"] for r in rs]) if rs else np.nan  # noqa: E731
    mean = lambda rs, k: np.mean([r[k] for r in rs]) if rs else np.nan  # noqa: E731
    lines += ["", f"{len(rows)} cases; trial-end-dominated ({len(end)}): mean ratio "
              f"{ratio(end):.2f} (mean RMSE {mean(end, 'alone'):.2f} -> {mean(end, 'session'):.2f} "
              f"mm); all: mean ratio {ratio(rows):.2f} (mean RMSE {mean(rows, 'alone'):.2f} -> "
              f"{mean(rows, 'session'):.2f} mm), worst {max(r['ratio'] for r in rows):.2f}; "
              f"time session / alone {mean(rows, 'session_s') / mean(rows, 'alone_s'):.2f}"]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--csv", type=Path, help="write rows here as they finish")
    ap.add_argument("--only", help="comma-separated substrings of case names to run")
    ap.add_argument("--both-ways", action="store_true",
                    help="lay the gaps onto every trial of a session, not only the first")
    ap.add_argument("--shard", default="0/1", metavar="I/N", help="every N-th case from the I-th")
    ap.add_argument("--list", action="store_true", help="list the cases and stop")
    args = ap.parse_args()
    suite = cases(data_dir(REPO), args.both_ways)
    suite = select(suite, args.only, args.shard)
    if args.list:
        print_cases(suite)
        return
    rows = []
    for c in suite:
        rows.append(run(c))
        r = rows[-1]
        print(f"{c.name}: alone {r['alone']:.2f}, session {r['session']:.2f} mm "
              f"({r['ratio']:.2f}x; {r['alone_s']:.1f} / {r['session_s']:.1f} s)", flush=True)
        if args.csv:
            write_csv(args.csv, rows)
    print(summary(rows))


if __name__ == "__main__":
    main()
