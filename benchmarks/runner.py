"""One loop for the case-based suites: every (case, method) not yet in the rows is filled,
scored and written as it finishes, under a progress bar."""
from __future__ import annotations

import numpy as np
from tqdm import tqdm

import torchfill

from . import methods, scores
from .cases import Case
from .rows import Rows


def case_fields(case: Case) -> dict:
    return {"case": case.name, "split": case.split, "source": case.source, "target": case.target,
            "assign": case.assign, "T": case.truth.n_frames, "J": case.truth.n_markers,
            "missing": int(case.mask.sum()), "trial_end": case.trial_end}


def score(case: Case, name: str, got: methods.Filled, rest=None, verdicts: bool = True,
          gaps_out: list | None = None) -> dict:
    """The row of one method on one case (``rest``: what fills the samples it leaves)."""
    truth = case.truth.points
    row = {**case_fields(case), "method": name,
           **scores.marker_scores(got.points, truth, case.mask, rest),
           "wall": got.timing.wall, "cpu": got.timing.cpu, "peak_mb": got.timing.peak_mb}
    if got.error:
        row["error"] = got.error.splitlines()[0]
        return row
    if got.std is not None:
        row["spearman"], row["within"], g = scores.std_checks(got.points, got.std, truth, case.mask)
        if gaps_out is not None:
            gaps_out += [{"case": case.name, "real_rmse": a, "est_std": b} for a, b in g]
    if verdicts and not methods.is_peer(name):
        X = case.gapped()
        rows = scores.verdicts(X.points, np.where(np.isfinite(got.points), got.points, np.nan),
                               truth, X.rate, X.labels, std=got.std, units=X.units,
                               spatial=methods.spatial(name))
        row.update(scores.verdict_counts(rows))
    return row


def run(cases: list[Case], names: list[str], rows: Rows, redo: bool = False, seed: int = 0,
        verdicts: bool = True, gaps_out: list | None = None, log=None) -> list[dict]:
    """Fill and score every (case, method) pair not in ``rows`` yet; the rows of ``cases``."""
    todo = [(c, m) for c in cases for m in names if redo or not rows.done(case=c.name, method=m)]
    bar = tqdm(total=len(todo), unit="fill", disable=not todo, dynamic_ncols=True)
    for case in cases:
        mine = [m for c, m in todo if c is case]
        rest = None
        for m in mine:
            bar.set_description(f"{case.name[:40]} {m}")
            got = methods.run(m, case.gapped(), seed=seed)
            if methods.is_peer(m) and rest is None:
                rest = torchfill.fill(case.gapped(), method="linear", extrapolate=None).points
            rows.add(score(case, m, got, rest if methods.is_peer(m) else None, verdicts, gaps_out))
            bar.update()
        if mine and log:
            got = {r["method"]: r for r in rows.rows if r["case"] == case.name}
            tqdm.write(f"{case.name}: " + ", ".join(
                f"{m} {float(got[m]['rmse']):.2f}" for m in names if m in got))
    bar.close()
    keep = {c.name for c in cases}
    return [r for r in rows.rows if r["case"] in keep and r["method"] in names]
