"""Segment-based reconstruction against the mocap tools, on the real-gap-pattern suite.

Peers, run with the same named segments (``torchfill.segments.Segments.from_names``):

* ``gapfill`` 0.0.7 ``recover_marker_rbt`` (rigid-body transform from three cluster markers; for
  each segment of the marker, its three mates nearest on average, segments in table order);
* Kinetics Toolkit ``track_cluster`` (a cluster per segment, created from the frames where all of
  its markers are observed; the marker's reconstruction from the first segment that gives one).

Next to them: torchfill ``rigid`` with the named segments, ``rigid`` with segments found from the
data alone (labels hidden), and the default fill. Every method is scored (RMSE, 3-D, mm) on the
samples gapfill fills; the table gives each ratio to gapfill's RMSE. Then the agreement of the
data-found segments with the named tables on the complete recordings, and the time of ``rigid``
on 3 000 frames x 41 markers::

    OMP_NUM_THREADS=1 python scripts/eval_segments.py            # all cases
    OMP_NUM_THREADS=1 python scripts/eval_segments.py --limit 6 --no-default
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import torchfill
from torchfill.data import data_dir
from torchfill.segments import Segments, agreement

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_gap_suite  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
AGREEMENT = ("biomechzoo_hockey_wrist_shot_009.c3d", "osim_gait2392_subject01_walk1.trc",
             "osim_hamner_subject02_running.trc", "osim_rajagopal_motion_capture_run.trc",
             "osim_rajagopal_motion_capture_walk.trc", "hdm05_bd_05-01_01_120.c3d",
             "hdm05_mm_01-02_03_120.c3d", "HDM_bd_01-02_01_120.c3d", "hdm05_dg_06-03_03_120.c3d",
             "cmu_135_02.c3d", "cmu_02_01.c3d", "cmu_85_02.c3d", "cmu_85_12.c3d")


def _gapfill():
    np.int = int                     # gapfill 0.0.7 uses np.int, removed in NumPy 1.24
    import gapfill
    return gapfill


def gapfill_fill(G: np.ndarray, seg_idx: dict) -> np.ndarray:
    """gapfill's recover_marker_rbt per marker and segment; NaN where it fills nothing."""
    gf = _gapfill()
    T, J = G.shape[:2]
    seen = np.isfinite(G).all(axis=2)
    out = np.full_like(G, np.nan)
    for j in np.flatnonzero((~seen).any(axis=0) & seen.any(axis=0)):
        for seg, members in seg_idx.items():
            if j not in members or len(members) < 4:
                continue
            mates = [m for m in members if m != j]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                dist = [np.nanmean(np.linalg.norm(G[:, m] - G[:, j], axis=1)) for m in mates]
            mates = [m for _, m in sorted(zip(np.nan_to_num(dist, nan=np.inf), mates))][:3]
            tgt = G[:, j].copy()
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                ok, _ = gf.recover_marker_rbt(tgt, np.stack([G[:, m] for m in mates]))
            if not ok:
                continue
            new = ~seen[:, j] & np.isfinite(tgt).all(axis=1) & ~np.isfinite(out[:, j]).all(axis=1)
            out[new, j] = tgt[new]
    return out


def ktk_fill(G: np.ndarray, seg_idx: dict, rate: float) -> np.ndarray:
    """Kinetics Toolkit track_cluster per segment; NaN where it fills nothing."""
    import kineticstoolkit as ktk
    T, J = G.shape[:2]
    seen = np.isfinite(G).all(axis=2)
    out = np.full_like(G, np.nan)
    ts = ktk.TimeSeries(time=np.arange(T) / rate)
    for j in range(J):
        ts.data[f"m{j}"] = np.concatenate([G[:, j], np.ones((T, 1))], axis=1)
    for seg, members in seg_idx.items():
        if len(members) < 4:
            continue
        names = [f"m{m}" for m in members]
        full = seen[:, members].all(axis=1)
        if not full.any():
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                cluster = ktk.kinematics.create_cluster(_frames(ts, full), names)
                tracked = ktk.kinematics.track_cluster(ts, cluster)
            except Exception as err:                       # noqa: BLE001 - a peer's failure
                print(f"  ktk {seg}: {type(err).__name__}: {err}")
                continue
        for m in members:
            P = tracked.data[f"m{m}"][:, :3]
            new = ~seen[:, m] & np.isfinite(P).all(axis=1) & ~np.isfinite(out[:, m]).all(axis=1)
            out[new, m] = P[new]
    return out


def _frames(ts, keep):
    sub = ts.copy()
    sub.time = ts.time[keep]
    for k in sub.data:
        sub.data[k] = ts.data[k][keep]
    return sub


def rmse(F, truth, on) -> float:
    if not on.any():
        return float("nan")
    return float(np.sqrt(np.mean(np.sum((F[on] - truth[on]) ** 2, axis=1))))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=int, default=None, help="first N cases only")
    ap.add_argument("--no-default", action="store_true", help="skip the default fill (slow)")
    ap.add_argument("--no-ktk", action="store_true")
    args = ap.parse_args(argv)
    folder = data_dir(REPO)
    cases = real_gap_suite.cases(folder)[:args.limit]
    cols = ["gapfill", "ktk", "rigid", "rigid_data", "default"]
    print(f"{'case':58s} {'n':>6s} " + " ".join(f"{c:>10s}" for c in cols) + "   ratios to gapfill")
    ratios = {c: [] for c in cols}
    for case in cases:
        truth = case.truth.points
        seq = case.gapped()
        G = seq.points
        labels = list(seq.labels)
        seg_idx = Segments.from_names(labels).indices(labels)
        res = {}
        t = time.perf_counter()
        GF = gapfill_fill(G, seg_idx)
        on = np.isfinite(GF).all(axis=2) & case.mask
        res["gapfill"] = rmse(GF, truth, on)
        if not args.no_ktk:
            K = ktk_fill(G, seg_idx, seq.rate)
            kon = on & np.isfinite(K).all(axis=2)
            res["ktk"] = rmse(K, truth, kon) if kon.sum() == on.sum() else float("nan")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            R = torchfill.fill(seq, "rigid", segments="names", constraints=False).points
            RD = torchfill.fill(G, "rigid", segments="data", constraints=False)
            res["rigid"], res["rigid_data"] = rmse(R, truth, on), rmse(RD, truth, on)
            if not args.no_default:
                D = torchfill.fill(seq, extrapolate=None).points
                res["default"] = rmse(D, truth, on)
        for c in cols:
            if c in res and res["gapfill"] > 0 and np.isfinite(res[c]):
                ratios[c].append(res[c] / res["gapfill"])
        print(f"{case.name[:58]:58s} {int(on.sum()):6d} " +
              " ".join(f"{res.get(c, np.nan):10.2f}" for c in cols) + "   " +
              " ".join(f"{res.get(c, np.nan) / res['gapfill']:5.2f}" for c in cols[1:]),
              flush=True)
    print("\nratio to gapfill on its samples: mean / worst (cases)")
    for c in cols[1:]:
        r = np.asarray(ratios[c])
        if r.size:
            print(f"  {c:10s} {r.mean():6.3f} / {r.max():6.3f}  ({r.size})")
    print("\ndata-found segments vs named tables (membership agreement)")
    for name in AGREEMENT:
        if not (folder / name).exists():
            continue
        seq = real_gap_suite.complete(folder / name)
        named = Segments.from_names(seq.labels)
        found = Segments.from_data(seq.points, seq.labels)
        print(f"  {name:42s} {agreement(found, named, seq.labels):5.2f}  "
              f"({len(found)} found, {len(named)} named)")
    seq = real_gap_suite.complete(folder / "HDM_bd_01-02_01_120.c3d")
    X = seq.points[:3000].copy()
    rng = np.random.default_rng(0)
    for j in rng.choice(X.shape[1], 20):
        a = rng.integers(0, 2800)
        X[a:a + rng.integers(100, 200), j] = np.nan
    times = []
    for _ in range(5):
        t = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torchfill.fill(seq.with_points(X), "rigid", constraints=False)
        times.append(time.perf_counter() - t)
    print(f"\nrigid, 3000 frames x {X.shape[1]} markers, 20 gaps: median {np.median(times):.3f} s "
          f"(runs {', '.join(f'{x:.3f}' for x in times)})")


if __name__ == "__main__":
    main()
