"""Cases: a recording's complete markers (the truth), a gap mask laid on them, where both came
from. The real-gap cases are built from the masks shipped in ``benchmarks/masks/`` (see
docs/benchmark.md); :func:`build_real_gaps` derives those masks from the gapped recordings."""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import torchfill
from torchfill import gaps
from torchfill.metrics import gap_runs

from . import data

MASKS = Path(__file__).resolve().parent / "masks"
#: Complete recordings the real masks are laid onto (markers never missing after dropping
#: HDM05's unlabeled ``*`` copies and the Hamner file's dead marker).
TARGETS = ("hdm05_bd_05-01_01_120.c3d", "cmu_135_02.c3d", "osim_rajagopal_motion_capture_run.trc",
           "hdm05_mm_01-02_03_120.c3d", "biomechzoo_hockey_wrist_shot_009.c3d",
           "cmu_85_12.c3d", "osim_hamner_subject02_running.trc", "ktk_tennis_serve.c3d",
           "HDM_bd_01-02_01_120.c3d", "osim_gait2392_subject01_walk1.trc",
           "osim_rajagopal_motion_capture_walk.trc", "cmu_85_02.c3d")
#: Gap sources whose cases are held out: never used for any choice of the default
#: (docs/benchmark.md#held-out-masks).
HELD_OUT = ("c3dorg_s01_eb015pr", "c3dorg_s02_pc_real", "c3dorg_s04_sub_labels",
            "c3dorg_s26_walking_hybrid_1_2", "ktk_racing_full")
#: The ``--quick`` cases: three tuning and three held-out masks on short recordings.
QUICK = ("c3dorg_s26_walking_hybrid_2__HDM_bd_01-02_01_120__random",
         "ktk_tennis_serve_nan__ktk_tennis_serve__random",
         "c3dorg_s26_walking_hybrid_1_5__osim_hamner_subject02_running__random",
         "c3dorg_s01_eb015pr__hdm05_mm_01-02_03_120__random",
         "c3dorg_s04_sub_labels__osim_hamner_subject02_running__random",
         "ktk_racing_full__cmu_85_12__layout")


@dataclass
class Case:
    name: str
    truth: torchfill.MarkerSequence      # complete, in mm
    mask: np.ndarray                     # (T, J) True = hidden
    source: str = ""
    target: str = ""
    assign: str = ""
    split: str = ""                      # "tuning" or "held-out" (real-gap cases)

    def gapped(self) -> torchfill.MarkerSequence:
        P = self.truth.points.copy()
        P[self.mask] = np.nan
        return self.truth.with_points(P)

    @property
    def trial_end(self) -> float:
        return trial_end_share(self.mask)


def trial_end_share(mask: np.ndarray) -> float:
    """Share of the hidden samples in gaps touching the first or last frame."""
    T = mask.shape[0]
    ends = sum(b - a for j, a, b in gap_runs(mask) if a == 0 or b == T)
    return ends / max(int(mask.sum()), 1)


def split_of(source: str) -> str:
    return "held-out" if Path(source).stem in HELD_OUT else "tuning"


def sources(folder: Path) -> list[tuple[str, np.ndarray, float, np.ndarray]]:
    """(file, mask, rate, layout) of every recording with real gaps in a marker that is not dead."""
    out = []
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in (".c3d", ".trc"):
            continue
        seq = data.read(path)
        mask = ~np.isfinite(seq.points).all(axis=2)
        share = mask.mean(axis=0)
        if not ((share > 0) & (share <= 0.95)).any():
            continue
        out.append((path.name, mask, float(seq.rate), gaps.body_layout(seq.points, seq.labels)))
    return out


def lay(source: tuple, truth: torchfill.MarkerSequence, seed: int, target_layout=None):
    """(the first frames of ``truth``, the mask) with a ``sources()`` entry's mask laid on at its
    length in seconds, each source marker on the truth marker at the most similar body place
    (``target_layout``: default the laid frames' :func:`torchfill.gaps.body_layout`)."""
    _, mask, rate, layout = source
    T = min(int(round(mask.shape[0] * truth.rate / rate)), truth.n_frames)
    part = truth.with_points(truth.points[:T])
    if target_layout is None:
        target_layout = gaps.body_layout(part.points, part.labels)
    M = gaps.transplant(mask, T, part.n_markers, seed=seed, rate_ratio=truth.rate / rate,
                        source_layout=layout, target_layout=target_layout)
    return part, M


def build_real_gaps(folder: Path, seeds: int = 1) -> list[Case]:
    """The real-gap cases from the gapped recordings: every source x (random, layout) x ``seeds``,
    each on the next target recording long enough for the source's mask (else the longest), cut
    at a seeded offset; ``random`` assigns source to target markers at random, ``layout`` to the
    target marker at the most similar place on the body."""
    targets = [(name, data.complete(folder / name)) for name in TARGETS if (folder / name).exists()]
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
                part.meta["start"] = start
                lay = (src_layout, layouts[name]) if assign == "layout" else (None, None)
                M = gaps.transplant(mask, T, part.n_markers, seed=1000 * seed + k,
                                    rate_ratio=truth.rate / rate, source_layout=lay[0],
                                    target_layout=lay[1])
                if not M.any():
                    continue
                tag = f"{Path(src).stem}__{Path(name).stem}__{assign}{seed or ''}"
                out.append(Case(tag, part, M, src, name, assign, split_of(src)))
    return out


CASE_KEYS = ("case", "source", "target", "assign", "split", "start", "frames")


def save_masks(cases: list[Case], folder: Path = MASKS) -> None:
    """The cases' masks: ``real_gaps_cases.csv`` (one row a case: where it lies) and
    ``real_gaps_runs.csv`` (one row a gap: case, marker label, frames [start, stop))."""
    with open(folder / "real_gaps_cases.csv", "w", newline="") as handle:
        w = csv.writer(handle, lineterminator="\n")
        w.writerow(CASE_KEYS)
        for c in cases:
            w.writerow([c.name, c.source, c.target, c.assign, c.split,
                        c.truth.meta.get("start", 0), c.truth.n_frames])
    with open(folder / "real_gaps_runs.csv", "w", newline="") as handle:
        w = csv.writer(handle, lineterminator="\n")
        w.writerow(["case", "marker", "start", "stop"])
        for c in cases:
            w.writerows([c.name, c.truth.labels[j], a, b] for j, a, b in gap_runs(c.mask))


def load_masks(folder: Path, masks: Path = MASKS) -> list[Case]:
    """The shipped real-gap cases, laid onto the recordings in ``folder``."""
    with open(masks / "real_gaps_cases.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    recs: dict[str, torchfill.MarkerSequence] = {}
    out: dict[str, Case] = {}
    for r in rows:
        if r["target"] not in recs:
            recs[r["target"]] = data.complete(folder / r["target"])
        a, T = int(r["start"]), int(r["frames"])
        part = recs[r["target"]].with_points(recs[r["target"]].points[a:a + T])
        out[r["case"]] = Case(r["case"], part, np.zeros((T, part.n_markers), bool),
                              r["source"], r["target"], r["assign"], r["split"])
    with open(masks / "real_gaps_runs.csv", newline="") as handle:
        for r in csv.DictReader(handle):
            case = out[r["case"]]
            case.mask[int(r["start"]):int(r["stop"]), case.truth.labels.index(r["marker"])] = True
    return list(out.values())


def select(suite: list, only: str | None = None, shard: str = "0/1", split: str = "all",
           quick: bool = False) -> list:
    """The cases whose names hold one of the comma-separated ``only`` substrings, of ``split``
    (all, tuning, held-out), the ``--quick`` ones, then every N-th from the I-th (``shard``)."""
    if only:
        suite = [c for c in suite if any(s in c.name for s in only.split(","))]
    if split != "all":
        suite = [c for c in suite if c.split == split]
    if quick:
        suite = [c for c in suite if c.name in QUICK]
    i, n = (int(x) for x in shard.split("/"))
    return suite[i::n]


def print_cases(suite: list) -> None:
    for c in suite:
        print(f"{c.name}: {c.truth.n_frames} x {c.truth.n_markers}, {int(c.mask.sum())} hidden, "
              f"{100 * trial_end_share(c.mask):.0f} % at trial ends"
              + (f" [{c.split}]" if c.split else ""))
