"""Other tools' gap fillers behind one call: ``fill(seq) -> (T, J, 3)`` points, NaN where the
tool fills nothing, observed samples as given. Each is installed by the ``peers`` extra
(``pip install '.[peers]'``); :func:`available` says which import here."""
from __future__ import annotations

import importlib
import warnings

import numpy as np

import torchfill
from torchfill.segments import Segments


def _segments(seq: torchfill.MarkerSequence) -> dict:
    """The named segments as marker indices (the same table torchfill's ``rigid`` uses)."""
    return Segments.from_names(seq.labels).indices(list(seq.labels))


def gapfill(seq: torchfill.MarkerSequence) -> np.ndarray:
    """gapfill ``recover_marker_rbt`` per marker and named segment: the rigid-body transform of
    the marker's three segment-mates nearest on average, segments in table order."""
    np.int = int                     # gapfill 0.0.7 uses np.int, removed in NumPy 1.24
    import gapfill as gf

    G = seq.points
    seen = np.isfinite(G).all(axis=2)
    out = np.full_like(G, np.nan)
    for j in np.flatnonzero((~seen).any(axis=0) & seen.any(axis=0)):
        for members in _segments(seq).values():
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


def _ktk_series(seq: torchfill.MarkerSequence):
    import kineticstoolkit as ktk

    T = seq.n_frames
    ts = ktk.TimeSeries(time=np.arange(T) / seq.rate)
    for j in range(seq.n_markers):
        ts.data[f"m{j}"] = np.concatenate([seq.points[:, j], np.ones((T, 1))], axis=1)
    return ts


def ktk_cluster(seq: torchfill.MarkerSequence) -> np.ndarray:
    """Kinetics Toolkit ``track_cluster`` per named segment (a cluster made from the frames where
    all its markers are observed); a marker's fill from the first segment that gives one."""
    import kineticstoolkit as ktk

    ts = _ktk_series(seq)
    seen = np.isfinite(seq.points).all(axis=2)
    out = np.full_like(seq.points, np.nan)
    for members in _segments(seq).values():
        full = seen[:, members].all(axis=1)
        if len(members) < 4 or not full.any():
            continue
        names = [f"m{m}" for m in members]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                cluster = ktk.kinematics.create_cluster(_frames(ts, full), names)
                tracked = ktk.kinematics.track_cluster(ts, cluster)
            except Exception:                               # noqa: BLE001 - the peer fills nothing
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


def ktk_interp(seq: torchfill.MarkerSequence) -> np.ndarray:
    """Kinetics Toolkit ``fill_missing_samples(0)`` (its default, linear): every gap interpolated
    in time, and extrapolated before the first and after the last observation."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ts = _ktk_series(seq).fill_missing_samples(0)
    return np.stack([ts.data[f"m{j}"][:, :3] for j in range(seq.n_markers)], axis=1)


def iterative_imputer(seq: torchfill.MarkerSequence) -> np.ndarray:
    """scikit-learn ``IterativeImputer`` (BayesianRidge, its defaults, ``max_iter=10``) on the
    frames x 3J matrix: each coordinate regressed on the others, frame by frame."""
    from sklearn.experimental import enable_iterative_imputer  # noqa: F401
    from sklearn.impute import IterativeImputer

    T, J, D = seq.points.shape
    M = seq.points.reshape(T, J * D)
    keep = np.isfinite(M).any(axis=0)
    out = np.full_like(M, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out[:, keep] = IterativeImputer(max_iter=10, random_state=0).fit_transform(M[:, keep])
    return out.reshape(T, J, D)


def pose2sim(seq: torchfill.MarkerSequence, gap: int = 10, kind: str = "cubic") -> np.ndarray:
    """Pose2Sim's ``interpolate_zeros_nans`` per coordinate, as its filtering step calls it:
    cubic, gaps of at most ``gap`` frames (its ``interp_if_gap_smaller_than`` default)."""
    import pandas as pd
    from Pose2Sim.common import interpolate_zeros_nans

    T, J, D = seq.points.shape
    M = seq.points.reshape(T, J * D)
    cols = [interpolate_zeros_nans(pd.Series(M[:, c]), gap, kind).to_numpy() for c in range(J * D)]
    return np.stack(cols, axis=1).reshape(T, J, D)


def saits(seq: torchfill.MarkerSequence, steps: int = 48, stride: int = 8,
          epochs: int = 100) -> np.ndarray:
    """PyPOTS SAITS trained on the recording itself (windows of ``steps`` frames every
    ``stride``, coordinates standardised, its observed samples only), then imputing the same
    windows, averaged where they overlap; a small model on the CPU, seeded
    (docs/benchmark.md#peers)."""
    from pypots.imputation import SAITS
    from pypots.utils.random import set_random_seed

    T, J, D = seq.points.shape
    M = seq.points.reshape(T, J * D)
    mu, sd = np.nanmean(M, axis=0), np.nanstd(M, axis=0) + 1e-9
    Z = (M - mu) / sd
    steps = min(steps, T)
    starts = sorted(set(range(0, T - steps + 1, stride)) | {T - steps})
    W = np.stack([Z[a:a + steps] for a in starts])
    set_random_seed(0)              # its weights, masks and batch order are drawn: one seed
    model = SAITS(n_steps=steps, n_features=J * D, n_layers=2, d_model=64, n_heads=4, d_k=16,
                  d_v=16, d_ffn=128, epochs=epochs, device="cpu", verbose=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit({"X": W})
        out = model.impute({"X": W})
    acc, count = np.zeros_like(Z), np.zeros((T, 1))
    for a, w in zip(starts, out):
        acc[a:a + steps] += w
        count[a:a + steps] += 1
    return (acc / count * sd + mu).reshape(T, J, D)


def mogapfill(seq: torchfill.MarkerSequence) -> np.ndarray:
    """Burke & Lasenby's low-dimensional Kalman smoother (MoGapFill ``smooth.smooth``, its
    defaults ``tol=0.0025, sigR=1e-3``) on the frames x 3J matrix. Its code is not part of this
    repository: ``$MOGAPFILL_SMOOTH`` names a copy of its ``smooth.py`` (docs/benchmark.md#peers).
    It needs complete frames for its subspace; without any it fills nothing."""
    import contextlib
    import io
    import os
    from importlib.util import module_from_spec, spec_from_file_location

    spec = spec_from_file_location("mogapfill_smooth", os.environ["MOGAPFILL_SMOOTH"])
    module = module_from_spec(spec)
    spec.loader.exec_module(module)
    T, J, D = seq.points.shape
    M = seq.points.reshape(T, J * D)
    if not np.isfinite(M).all(axis=1).any():
        return np.full_like(seq.points, np.nan)
    np.random.seed(0)                                   # its initial state is drawn
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.asarray(module.smooth(M.copy()), dtype=np.float64).reshape(T, J, D)


#: name -> (what it is, the module that must import, fill)
PEERS = {
    "gapfill": ("gapfill 0.0.7 recover_marker_rbt, named segments", "gapfill", gapfill),
    "ktk_cluster": ("Kinetics Toolkit track_cluster, named segments", "kineticstoolkit",
                    ktk_cluster),
    "ktk_interp": ("Kinetics Toolkit fill_missing_samples (linear)", "kineticstoolkit", ktk_interp),
    "iterative_imputer": ("scikit-learn IterativeImputer", "sklearn", iterative_imputer),
    "pose2sim": ("Pose2Sim interpolate_zeros_nans (cubic, gaps <= 10 frames)", "Pose2Sim.common",
                 pose2sim),
    "mogapfill": ("Burke & Lasenby Kalman smoother (MoGapFill)", "$MOGAPFILL_SMOOTH", mogapfill),
    "saits": ("PyPOTS SAITS trained on the recording (CPU, 100 epochs, seed 0)",
              "pypots.imputation", saits),
}


def available(name: str) -> bool:
    """Whether the peer's package imports here."""
    try:
        if name == "gapfill":
            np.int = int
        if PEERS[name][1].startswith("$"):
            import os
            return os.path.isfile(os.environ.get(PEERS[name][1][1:], ""))
        importlib.import_module(PEERS[name][1])
        return True
    except Exception:                                       # noqa: BLE001 - any import failure
        return False


def fill(name: str, seq: torchfill.MarkerSequence) -> np.ndarray:
    """The peer's fill of ``seq`` (NaN where it fills nothing), observed samples as given."""
    F = np.asarray(PEERS[name][2](seq), dtype=np.float64)
    seen = np.isfinite(seq.points).all(axis=2)
    return np.where(seen[..., None], seq.points, F)
