"""The mask suite that `auto` and the PMA reference check are judged on.

Writes, deterministically from seeds, ~19 cases to a folder (default ref/masks): per case
``<name>.npz`` (``points`` (T, J, 3) with NaN where hidden, ``mask`` (T, J) bool, ``truth``
(T, J, 3), ``recording``, ``frames`` [start, stop), ``markers`` (indices kept), ``kind``) and
``<name>.mat`` for Octave (``data``/``truth`` as T x 3J in the ``x1 y1 z1 x2 ...`` column layout
MATLAB code expects, ``mask`` T x J, ``freq``), plus ``cases.json``. Every hidden sample is
observed in the recording (the recordings used are complete). Kinds:

- ``hdm_multigap``: Tucker paper protocol (gaps.multi_gap: 20 markers, 100-200 frames, 2-10 gaps);
- ``cmu_window``: CP paper protocol (gaps.shared_window: 10/20/30 of 41 markers, 50/100 frames);
- ``still_window``: a shared window on the most nearly still stretch of a CMU recording;
- ``dense``: clustered occlusions (neighbouring markers together) until every marker has a gap;
- ``blackout``: whole-frame blackouts (gaps.blackout), every marker missing together.

    OMP_NUM_THREADS=1 .venv/bin/python scripts/mask_suite.py [--out ref/masks]
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

import torchfill
from torchfill import gaps

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TORCHFILL_DATA") or REPO / ".." / "shared" / "data").resolve()

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


def build(out: Path) -> list[dict]:
    from scipy.io import savemat

    out.mkdir(parents=True, exist_ok=True)
    index = []
    for name, kind, rec, frames, kw in CASES:
        seq = torchfill.read(DATA / f"{rec}.c3d")
        a, b = frames or (0, seq.points.shape[0])
        truth = np.ascontiguousarray(seq.points[a:b])
        markers = np.arange(truth.shape[1])
        if np.isnan(truth).any():
            raise SystemExit(f"{rec}[{a}:{b}] has real gaps; the suite needs complete windows")
        mask = make_mask(kind, truth, kw)
        points = truth.copy()
        points[mask] = np.nan
        T, J, _ = truth.shape
        np.savez_compressed(out / f"{name}.npz", points=points, mask=mask, truth=truth, recording=rec,
                            frames=np.array([a, b]), markers=markers, kind=kind)
        # x1 y1 z1 x2 ...: C-order reshape of (T, J, 3) keeps each marker's xyz together
        savemat(out / f"{name}.mat", {"data": points.reshape(T, 3 * J), "truth": truth.reshape(T, 3 * J),
                                      "mask": mask.astype(np.uint8), "freq": float(seq.rate)})
        index.append({"name": name, "kind": kind, "recording": rec, "frames": [a, b], "T": T, "J": J,
                      "params": kw, "hidden": int(mask.sum()),
                      "markers_with_gap": int(mask.any(0).sum())})
        print(f"{name:24s} {kind:13s} {rec}[{a}:{b}] T={T} J={J} hidden={mask.sum()} "
              f"markers_with_gap={mask.any(0).sum()}")
    (out / "cases.json").write_text(json.dumps(index, indent=1))
    return index


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="ref/masks", type=Path)
    build(ap.parse_args(argv).out)


if __name__ == "__main__":
    main()
