"""The simulated-gap mask suite (~19 cases, deterministic from seeds): the papers' protocols,
dense clustered occlusions, blackouts; run through the same methods and tables as the real-gap
benchmark, or exported for the MATLAB originals (``--export DIR``: ``<name>.npz`` and
``<name>.mat`` with ``data``/``truth`` as T x 3J in the ``x1 y1 z1 x2 ...`` layout, ``mask``,
``freq``, plus ``cases.json``). Kinds:

- ``hdm_multigap``: Tucker paper protocol (gaps.multi_gap: 20 markers, 100-200 frames, 2-10 gaps);
- ``cmu_window``: CP paper protocol (gaps.shared_window: 10/20/30 of 41 markers, 50/100 frames);
- ``still_window``: a shared window on the most nearly still stretch of a CMU recording;
- ``dense``: clustered occlusions (neighbouring markers together) until every marker has a gap;
- ``blackout``: whole-frame blackouts (gaps.blackout), every marker missing together.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from torchfill import gaps

from .. import data, methods, runner
from ..cases import Case, print_cases, select
from ..rows import Rows
from ..tables import write_block
from . import case_arguments
from .real_gaps import tables

HELP = "the simulated-gap mask suite (papers' protocols, dense occlusions, blackouts)"
CSV = data.RESULTS / "real_gaps" / "mask_rows.csv"

#: name, kind, recording, (start, stop) frames, generator keyword arguments (seed included)
CASES = [
    ("hdm_mm_L100_K5", "hdm_multigap", "hdm05_mm_01-02_03_120", (0, 1000), dict(gap_length=100, max_gaps=5, seed=0)),
    ("hdm_mm_L200_K2", "hdm_multigap", "hdm05_mm_01-02_03_120", (1500, 2700), dict(gap_length=200, max_gaps=2, seed=1)),
    ("hdm_bd_L150_K10", "hdm_multigap", "hdm05_bd_05-01_01_120", (0, 1200), dict(gap_length=150, max_gaps=10, seed=2)),
    ("hdm_bd_L100_K10", "hdm_multigap", "hdm05_bd_05-01_01_120", (3000, 4000), dict(gap_length=100, max_gaps=10, seed=3)),
    ("hdm_bd0102_L200_K5", "hdm_multigap", "HDM_bd_01-02_01_120", (0, 1000), dict(gap_length=200, max_gaps=5, seed=4)),
    ("cmu0201_m10_L50", "cmu_window", "cmu_02_01", None, dict(n_markers=10, gap_length=50, seed=0)),
    ("cmu0201_m20_L50", "cmu_window", "cmu_02_01", None, dict(n_markers=20, gap_length=50, seed=1)),
    ("cmu0201_m30_L100", "cmu_window", "cmu_02_01", None, dict(n_markers=30, gap_length=100, seed=2)),
    ("cmu8502_m10_L50", "cmu_window", "cmu_85_02", None, dict(n_markers=10, gap_length=50, seed=0)),
    ("cmu8502_m20_L100", "cmu_window", "cmu_85_02", None, dict(n_markers=20, gap_length=100, seed=1)),
    ("cmu8502_m30_L50", "cmu_window", "cmu_85_02", None, dict(n_markers=30, gap_length=50, seed=2)),
    ("cmu13502_m20_L100", "cmu_window", "cmu_135_02", (0, 1000), dict(n_markers=20, gap_length=100, seed=3)),
    ("still8502_m30_L50", "still_window", "cmu_85_02", None, dict(n_markers=30, gap_length=50, seed=0)),
    ("still8512_m20_L80", "still_window", "cmu_85_12", (0, 1500), dict(n_markers=20, gap_length=80, seed=1)),
    ("dense_hdm_mm", "dense", "hdm05_mm_01-02_03_120", (2000, 2800), dict(seed=0)),
    ("dense_cmu8512", "dense", "cmu_85_12", (1500, 2300), dict(seed=1)),
    ("dense_cmu0201", "dense", "cmu_02_01", None, dict(seed=2)),
    ("blackout_cmu0201_L20", "blackout", "cmu_02_01", None, dict(gap_length=20, seed=0)),
    ("blackout_hdm_dg_L15", "blackout", "hdm05_dg_06-03_03_120", None, dict(gap_length=15, seed=1)),
]


def make_mask(kind: str, P: np.ndarray, kw: dict) -> np.ndarray:
    T, J, _ = P.shape
    if kind == "hdm_multigap":
        return gaps.multi_gap(T, J, n_markers=20, **kw)
    if kind == "cmu_window":
        return gaps.shared_window(T, J, **kw)
    if kind == "still_window":
        return gaps.still_window(P, **kw)
    if kind == "dense":
        return gaps.clustered(P, **kw)
    if kind == "blackout":
        return gaps.blackout(T, J, **kw)
    raise ValueError(f"unknown case kind {kind!r}")


def cases(folder: Path) -> list[Case]:
    out = []
    for name, kind, rec, frames, kw in CASES:
        seq = data.in_mm(data.read(folder / f"{rec}.c3d"))
        a, b = frames or (0, seq.n_frames)
        truth = seq.with_points(np.ascontiguousarray(seq.points[a:b]))
        if np.isnan(truth.points).any():
            raise SystemExit(f"{rec}[{a}:{b}] has real gaps; the suite needs complete windows")
        truth.meta["frames"] = (a, b)
        out.append(Case(name, truth, make_mask(kind, truth.points, kw), "mask_suite", rec, kind))
    return out


def export(suite: list[Case], out: Path) -> None:
    """The cases as .npz and .mat files (the MATLAB originals' layout) and cases.json."""
    from scipy.io import savemat

    out.mkdir(parents=True, exist_ok=True)
    index = []
    for c in suite:
        truth, mask = c.truth.points, c.mask
        points = c.gapped().points
        T, J, _ = truth.shape
        np.savez_compressed(out / f"{c.name}.npz", points=points, mask=mask, truth=truth,
                            recording=c.target, frames=np.array(c.truth.meta["frames"]),
                            markers=np.arange(J), kind=c.assign)
        # x1 y1 z1 x2 ...: C-order reshape of (T, J, 3) keeps each marker's xyz together
        savemat(out / f"{c.name}.mat", {"data": points.reshape(T, 3 * J),
                                        "truth": truth.reshape(T, 3 * J),
                                        "mask": mask.astype(np.uint8), "freq": float(c.truth.rate)})
        index.append({"name": c.name, "kind": c.assign, "recording": c.target, "T": T, "J": J,
                      "frames": list(c.truth.meta["frames"]), "hidden": int(mask.sum()),
                      "markers_with_gap": int(mask.any(0).sum())})
    (out / "cases.json").write_text(json.dumps(index, indent=1))


def add_arguments(p) -> None:
    case_arguments(p, str(CSV))
    p.add_argument("--methods", default=",".join((methods.DEFAULT, *methods.SINGLES)),
                   help="comma-separated, as real-gaps --methods")
    p.add_argument("--seed", type=int, default=0, help="the default's seed")
    p.add_argument("--export", type=Path, help="write the cases to this folder and stop")
    p.add_argument("--doc", help="write the tables into this page's mask_suite block")


def main(args) -> int:
    from .real_gaps import method_names

    suite = select(cases(data.need()), args.only, args.shard)
    if args.list:
        print_cases(suite)
        return 0
    if args.export:
        export(suite, args.export)
        return 0
    names = method_names(args.methods)
    got = runner.run(suite, names, Rows(args.csv or None, ("case", "method")), args.redo,
                     args.seed, verdicts=False, log=True)
    text = tables(got, names)
    print(text)
    if args.doc:
        write_block(args.doc, "mask_suite", text)
    return 0


def doc_blocks() -> dict:
    """docs/real-gaps.md's mask-suite table from the stored rows."""
    from ..rows import read_csv

    rows = read_csv(CSV)
    names = list(dict.fromkeys(r["method"] for r in rows))
    return {(data.DOCS / "real-gaps.md", "masks"): tables(rows, names)} if rows else {}
