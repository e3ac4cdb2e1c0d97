"""The verdict per gap of a fill -- ``ok``, ``check`` or ``reject`` -- with its reasons (pure
functions of the input, the fill and its error estimate; the text, JSON and HTML forms are in
:mod:`torchfill.qc.report`).

Every gap of every marker of the input (a run of missing frames of a marker seen elsewhere) is
judged on the fill's output and, when given, the fill's own error estimate ``std`` (T, J) (the
per-coordinate std of ``fill(..., return_std=True)``). The tests, each a pure function of
(input, fill, std) -- the truth is never seen:

- **estimated error**: ``est_rmse`` = sqrt(D x mean(std^2)) over the gap's filled frames, the
  expected RMS of its D-dimensional error; ``check`` above ``EST_CHECK_MM`` when it is also above
  ``EST_RELATIVE`` x the recording's median gap estimate, ``reject`` above ``EST_REJECT_MM``;
- **step at the cap**: a one-frame step inside or at the edges of the gap at or above
  ``STEP_AT_CAP`` x the recording's step cap -- for a gap touching a trial end, the lower cap
  of a fill held at one edge only (the constraints shorten longer steps to just below the cap,
  so a fill that needed shortening ends *at* it; above the interior cap means it was not
  constrained);
- **rigid partner**: the largest deviation of the distance to a rigid partner from that pair's
  median, over the pair's own observed spread (the 95th percentile of its observed deviations,
  at least the rigidity tolerance); ``check`` above ``RIGID_CHECK`` spreads, ``reject`` above
  ``RIGID_REJECT``;
- **volume**: filled samples at or beyond the observed volume widened by the constraints' margin
  (the constraints clamp onto that bound);
- **extrapolated in time**: filled frames of a gap touching a trial end without spatial support
  (no rigid donors from segment-mates, and not a spatial method's fill in a frame with
  ``SPATIAL_MIN`` markers seen), ``check`` when more than ``EXTRAPOLATED_SECONDS``;
- **short gap, fill off the interpolation**: an interior gap up to ``SHORT_SECONDS`` whose fill
  departs from the PCHIP interpolation across it by more than ``DISAGREE_MM`` (RMS); one that
  stays within ``AGREE_MM`` of it is not flagged on its estimated error alone;
- **blackout**: frames in which no marker was observed (interpolated in time);
- frames left unfilled are reported; a gap left wholly unfilled is ``reject``.

Thresholds in mm are converted to the file's units (m, cm, mm); for image keypoints (px) by the
body's size: the recording's median pairwise keypoint distance against ``BODY_SCALE_MM``. They
are constants calibrated on gaps with known truth (``python -m benchmarks qc``), never on the
gaps judged; how: experiments/results/qc.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import metrics
from ..constraints import (END_STEP_FACTOR, SPATIAL_MIN, STEP_FACTOR, STEP_PERCENTILE,
                           VOLUME_MARGIN, rigid_donors)
from ..sequence import UNITS_PER_MM as _PER_MM
from ..solvers.rigid import index_segments, rigid_pairs

# How these constants were chosen and what they give: experiments/results/qc.md.
#: Estimated RMS error (mm) above which a gap is ``check``, when it is also above ``EST_RELATIVE``
#: x the recording's median gap estimate (a recording whose every gap is hard is judged on its
#: own scale).
EST_CHECK_MM = 8.0
EST_RELATIVE = 1.0
#: Estimated RMS error (mm) above which a gap is ``reject`` (the default fill leaves samples
#: estimated above a limit unfilled only when asked: ``fill(reject=...)``).
EST_REJECT_MM = 30.0
#: A step at or above this share of the cap counts as "at the cap".
STEP_AT_CAP = 0.99
#: Relative rounding a step may exceed the cap by and still count as at it (a fill written to a
#: C3D file is float32: 1e-4 mm on coordinates of 2 m).
STEP_ROUNDING = 1e-4
#: Rigid-partner deviation, in the pair's own observed spreads: ``check`` / ``reject`` above.
RIGID_CHECK = 5.0
RIGID_REJECT = 15.0
#: Interior gaps up to this many seconds are compared with the interpolation across them (PCHIP
#: through the observed samples next to them); a fill that departs from it by more than
#: ``DISAGREE_MM`` is ``check`` (experiments/results/qc.md).
SHORT_SECONDS = 0.1
DISAGREE_MM = 8.0
#: A short interior gap whose fill stays within this RMS distance (mm) of the interpolation across
#: it is not flagged on its estimated error alone: two independent fills agree
#: (experiments/results/qc.md).
AGREE_MM = 2.0
#: A fill within this RMS distance (mm) of the interpolation across a short interior gap is that
#: interpolation (the default's finishing step puts it there; a C3D stores it in float32): there
#: are not two fills to agree, and the gap is judged on its estimate alone.
SAME_MM = 0.01
#: Seconds of time-only extrapolation at a trial end above which a gap is ``check`` (within the
#: default 0.25 s limit such gaps are listed with the reason but judged on their estimate;
#: experiments/results/qc.md).
EXTRAPOLATED_SECONDS = 0.25
#: Median pairwise marker distance of an adult full-body marker set (mm; HDM05, CMU and OpenSim
#: recordings: 630-690): converts mm thresholds to pixels for image keypoints.
BODY_SCALE_MM = 650.0

VERDICTS = ("ok", "check", "reject")


@dataclass(frozen=True)
class Thresholds:
    """A recording's thresholds, in its own units (``units``); ``per_mm`` converts from mm."""

    units: str
    per_mm: float
    est_check: float        # absolute part of the estimated-error test
    disagree: float         # short interior gaps: largest RMS departure from the interpolation
    agree: float            # short interior gaps: the estimate is overruled within this departure
    same: float             # ... but not within this one: the fill is the interpolation
    est_relative: float     # EST_RELATIVE x the median gap estimate (NaN without std)
    est_reject: float
    step_cap: float         # the recording's step cap (constraints)
    step_at: float          # STEP_AT_CAP x step_cap
    end_step_cap: float     # the cap of a gap touching a trial end
    rigid_check: float      # in spreads
    rigid_reject: float
    volume: tuple           # (lo, hi) per axis
    extrapolated_s: float
    rate: float = math.nan  # frames per second (the extrapolation test counts frames)
    dims: int = 3

    def extrapolated_frames(self) -> int:
        """``extrapolated_s`` in frames, rounded as ``fill()`` rounds its ``extrapolate``."""
        return int(round(self.extrapolated_s * self.rate)) if np.isfinite(self.rate) else 0

    def lines(self) -> list[str]:
        """The thresholds as text, in the file's units."""
        u = self.units
        median = (f"{self.est_relative:.4g} {u}" if np.isfinite(self.est_relative)
                  else "unknown")
        out = [f"estimated RMS error > {self.est_check:.4g} {u} and > {EST_RELATIVE:g} x the "
               f"median gap estimate ({median}): check; > {self.est_reject:.4g} {u}: reject",
               f"one-frame step >= {self.step_at:.4g} {u} ({STEP_AT_CAP:g} x the step cap "
               f"{self.step_cap:.4g} {u}; in a gap touching a trial end >= "
               f"{STEP_AT_CAP * self.end_step_cap:.4g} {u}, {STEP_AT_CAP:g} x its cap "
               f"{self.end_step_cap:.4g} {u}): check; above the step cap: reject",
               f"interior gaps up to {SHORT_SECONDS:g} s: fill departs from the interpolation "
               f"across the gap by > {self.disagree:.4g} {u} RMS: check; within "
               f"{self.agree:.4g} {u} of it but not on it (> {self.same:.4g} {u}): not flagged "
               "on the estimated error alone"]
        if self.dims == 3:
            out.append(f"rigid-partner distance off by > {self.rigid_check:g} x the pair's "
                       f"observed spread: check; > {self.rigid_reject:g} x: reject")
        support = ("no rigid donors, nor a spatial method with >= "
                   f"{SPATIAL_MIN} markers seen in the frame" if self.dims == 3 else
                   f"no spatial method with >= {SPATIAL_MIN} keypoints seen in the frame")
        return out + [f"filled samples at or beyond the observed volume "
                      f"(+{VOLUME_MARGIN:.0%} margin): check",
                      f"trial-end frames filled without spatial support ({support}) for > "
                      f"{self.extrapolated_s:g} s ({self.extrapolated_frames()} frames): check; "
                      "wholly unfilled gap: reject"]


def per_mm(units: str, dims: int = 3, scale: float | None = None) -> float:
    """File units per mm: m 0.001, cm 0.1, mm 1; px (``dims`` 2) the body's ``scale`` (median
    pairwise keypoint distance) over ``BODY_SCALE_MM``."""
    u = (units or "mm").strip().lower()
    if u in _PER_MM:
        return _PER_MM[u]
    if dims == 2 or u in ("px", "pixel", "pixels"):
        return (scale / BODY_SCALE_MM) if scale and np.isfinite(scale) else 1.0
    return 1.0


def thresholds(units: str, per: float, step_cap: float, bounds, median_est: float,
               rate: float | None = None, dims: int = 3) -> Thresholds:
    """The constants of this module in a recording's units."""
    return Thresholds(units=units, per_mm=per, est_check=EST_CHECK_MM * per,
                      disagree=DISAGREE_MM * per, agree=AGREE_MM * per, same=SAME_MM * per,
                      est_relative=EST_RELATIVE * median_est, est_reject=EST_REJECT_MM * per,
                      step_cap=step_cap, step_at=STEP_AT_CAP * step_cap,
                      end_step_cap=step_cap * END_STEP_FACTOR / STEP_FACTOR,
                      rigid_check=RIGID_CHECK, rigid_reject=RIGID_REJECT, volume=bounds,
                      extrapolated_s=EXTRAPOLATED_SECONDS,
                      rate=float(rate) if rate else math.nan, dims=dims)


def est_rmse(std, j: int, a: int, b: int, dims: int) -> float:
    """sqrt(D x mean std^2) over the gap's frames where ``std`` is finite (NaN: none)."""
    if std is None:
        return math.nan
    s = np.asarray(std, dtype=np.float64)[a:b, j]
    s = s[np.isfinite(s)]
    return float(np.sqrt(dims * np.mean(s ** 2))) if s.size else math.nan


def untested(missing, std) -> np.ndarray:
    """``(T, J)`` filled samples that the default leaves NaN: those of a marker never observed in
    two consecutive frames, where the fill has an error estimate (finite ``std``; ``missing``:
    the samples that were missing).

    The rule weighs a fill against what OpenSim IK loses without it: IK skips a NaN marker and
    solves the frame from the others, so a fill is worth writing only where it is better than
    that. A marker never seen in two consecutive frames has no observed motion: the fill places
    it from a handful of isolated frames, ``auto``'s hold-out cannot hide a gap-shaped run of it
    (it keeps half of a marker's samples, two at least), and its error model, which reads the
    marker's observed speed, extrapolates to a tiny estimate. On the OpenSim IK benchmark's
    heaviest mask (docs/ik.md: Hamner run <- ktk_basket_sprint, 57 % missing) nine such markers,
    seen in 2-15 isolated frames of 240, got estimates of 0.3-0.6 mm where their fills erred by
    24-627 mm (median per marker); the worst hip/knee error fell from 53 to 14 deg and the mean
    joint-angle RMSE from 22.8 to 14.7 deg (14.1 with every gap left) when they were left NaN;
    no marker of the 11 other masks qualifies. A threshold on the estimate itself cost more than
    it saved on top of this rule: samples left NaN above 20 mm, above 30 mm, or above 30 mm and
    10 mm where the marker's segment keeps three markers seen in the frame took the mean over
    the 12 masks from 2.16 to 3.98, 3.09 and 3.14 deg (on the masks with many markers missing
    together the estimate is above 40 mm where the fills err by 12-32 mm, and IK has nothing
    better for those segments); ``fill(reject=...)`` still offers it.
    """
    missing = np.asarray(missing, dtype=bool)
    seen = ~missing
    moving = (seen[1:] & seen[:-1]).any(axis=0)                       # (J,) one observed step
    std = np.asarray(std, dtype=np.float64)
    return missing & ~moving[None] & seen.any(axis=0)[None] & np.isfinite(std)


def alone(present, missing, std, segments, units: str = "mm") -> np.ndarray:
    """``(T, J)`` filled samples that the default leaves NaN because their marker is alone on its
    segments: no other marker of any segment it belongs to is observed anywhere in the recording,
    and the fill's estimated 3-D error (sqrt(3) x ``std``) is above ``EST_CHECK_MM`` (the level
    from which this module flags a gap on its estimate). ``present``: the samples that are
    finite in the fill; ``missing``: those that were missing; ``segments``: ``name -> marker
    indices`` (markers in no segment are never named); ``units``: the data's (arrays: mm).

    OpenSim IK poses each body from its markers and the joints. A marker alone on its segment
    has nothing in the recording that ties it to the segment -- no rigid donor for the fill, no
    segment shape -- and in IK it is the only thing that poses the segment and the joints above
    it that no other marker holds, so IK fits that chain to the fill exactly and the fill's error
    goes whole into those angles, where leaving the sample NaN holds them at the last frame's
    pose. On the OpenSim IK benchmark (docs/ik.md) only the heaviest mask (Hamner run <-
    ktk_basket_sprint, 57 % missing) has such samples: R.Wrist.Lat, the only right-arm marker
    ever seen there, with no torso marker seen, filled 55 mm RMS off (estimate 50 mm median).
    With it filled IK bent the trunk to reach it (lumbar extension 21.3 deg RMS off against 14.8
    with it left NaN) and the mask's joint-angle RMSE was 14.58 deg against 14.07 with every gap
    left; left NaN, 13.88. Judged per frame instead (no segment-mate seen or filled in that
    frame), the rule also took L.Thigh.Front there, whose mates are seen only in isolated frames:
    13.93 deg, that marker's fill having helped a little (its hip and knee neighbours are held by
    other markers), and it named 5-36 samples on three of ten real recordings of the data folder
    with real gaps, where nothing shows the fill to be worse than none. A threshold on the estimate alone raised the
    mean over the 12 masks by 1-2 deg.
    """
    present = np.asarray(present, dtype=bool)
    missing = np.asarray(missing, dtype=bool)
    std = np.asarray(std, dtype=np.float64)
    seen = (~missing).any(axis=0)
    member = np.zeros(missing.shape[1], dtype=bool)
    mated = np.zeros(missing.shape[1], dtype=bool)      # a segment-mate observed somewhere
    for markers in segments.values():
        idx = np.unique(np.asarray(list(markers), dtype=int))
        if idx.size < 2:
            continue
        member[idx] = True
        mated[idx] |= (int(seen[idx].sum()) - seen[idx]) > 0
    with np.errstate(invalid="ignore"):
        uncertain = np.sqrt(3.0) * std > EST_CHECK_MM * per_mm(units)
    return missing & present & (member & ~mated)[None] & uncertain


def verdict(row: dict, th: Thresholds) -> tuple[str, list[str]]:
    """``(verdict, reasons)`` of one gap row (see :func:`gap_table`) under ``th``."""
    u, reasons, level = th.units, [], 0

    def flag(lvl: int, text: str) -> None:
        nonlocal level
        level = max(level, lvl)
        reasons.append(text)

    if row["filled_frames"] == 0:
        flag(2, "left unfilled")
        return VERDICTS[level], reasons
    est, dis = row["est_rmse"], row.get("disagree", math.nan)
    if np.isfinite(est) and np.isfinite(dis) and th.same < dis <= th.agree and (
            est > th.est_reject or est > th.est_check and not est <= th.est_relative):
        reasons.append(f"estimated error {est:.3g} {u}, but the fill stays within {dis:.3g} {u} "
                       f"of the interpolation across this short gap (<= {th.agree:.3g} {u})")
    elif np.isfinite(est):
        if est > th.est_reject:
            flag(2, f"estimated error {est:.3g} {u} > {th.est_reject:.3g} {u}")
        elif est > th.est_check and not est <= th.est_relative:
            flag(1, f"estimated error {est:.3g} {u} > {th.est_check:.3g} {u} and > "
                    f"{EST_RELATIVE:g} x median")
    if np.isfinite(dis) and dis > th.disagree:
        flag(1, f"fill departs {dis:.3g} {u} from the interpolation across this short gap "
                f"(> {th.disagree:.3g} {u})")
    step = row["max_step"]
    end = row["kind"] in ("start", "end")
    cap = th.end_step_cap if end else th.step_cap
    if np.isfinite(step) and step > th.step_cap * (1 + STEP_ROUNDING):
        flag(2, f"step {step:.3g} {u} above the cap {th.step_cap:.3g} {u}")
    elif np.isfinite(step) and step >= STEP_AT_CAP * cap:
        flag(1, f"step {step:.3g} {u} at the {'trial-end ' if end else ''}cap {cap:.3g} {u}")
    ratio = row["rigid_ratio"]
    if np.isfinite(ratio) and ratio > th.rigid_check:
        flag(2 if ratio > th.rigid_reject else 1,
             f"distance to {row['rigid_partner']} off by {row['rigid_dev']:.3g} {u} = "
             f"{ratio:.1f} x its spread (> {th.rigid_reject if ratio > th.rigid_reject else th.rigid_check:g})")
    if row["at_volume_bound"]:
        flag(1, f"{row['at_volume_bound']} sample(s) at or beyond the observed volume")
    if row["extrapolated"]:
        text = (f"{row['extrapolated']} trial-end frame(s) extrapolated in time "
                f"({row['extrapolated_s']:.3g} s without spatial support)")
        if row["extrapolated"] > th.extrapolated_frames():
            flag(1, text + f" > {th.extrapolated_s:g} s")
        else:
            reasons.append(text)
    if row["blackout"]:
        flag(1, f"{row['blackout']} frame(s) with no marker observed")
    if row["unfilled"]:
        reasons.append(f"{row['unfilled']} frame(s) left unfilled")
    return VERDICTS[level], reasons


def gap_table(points, filled, rate: float | None = None, names=None, std=None, *,
              units: str = "mm", first_frame: int = 0, support=None, spatial: bool = False,
              segments=None, prior=None) -> list[dict]:
    """One row per gap of ``points`` (the input, (T, J, D) with NaN), judged on ``filled`` (the
    fill's output) and ``std`` ((T, J), the fill's error estimate per coordinate, optional).

    ``first_frame`` is the file's number of frame 0: rows carry ``first_frame``/``last_frame`` in
    the file's numbering and ``start``/``stop`` as indices (``stop`` exclusive). A filled sample
    has spatial support (is not extrapolated in time) where the rigid donors of the constraints
    fill it (segment-mates, ``segments`` as ``fill()`` takes them), where ``support`` (T, J) says
    so, or -- with ``spatial`` (the fill came from a method that places markers from the same
    frame) -- in frames with ``SPATIAL_MIN`` or more markers observed. Each row has ``verdict``
    and ``reasons`` (see :func:`verdict`); ``table_thresholds(rows)`` gives the thresholds.
    ``prior`` (T, J): samples the file marks as filled by earlier software (C3D residual 0):
    not gaps, and not observations for the thresholds -- as ``fill()`` treats them.
    """
    X = np.asarray(points, dtype=np.float64)
    F = np.asarray(filled, dtype=np.float64)
    if F.shape != X.shape:
        raise ValueError(f"filled has shape {F.shape}, the input {X.shape}")
    T, J, D = X.shape
    missing = ~np.isfinite(X).all(axis=2)
    observed = ~missing & ~(np.asarray(prior, dtype=bool) if prior is not None else False)
    partners, donors, seg_names, scale = {}, np.zeros((T, J), dtype=bool), {}, None
    if observed.any() and D == 3:
        pairs = rigid_pairs(np.where(observed[..., None], X, np.nan), observed)
        scale = pairs.scale
        partners = rigid_partners(pairs)
        seg = index_segments(segments if segments is not None else
                             ("auto" if names is not None else "data"), names, X, observed)
        _, donors = rigid_donors(X, observed, pairs, seg, names)
        for name, members in seg.items():
            for m in members:
                seg_names.setdefault(int(m), []).append(name)
    elif observed.any():
        scale = _keypoint_scale(X, observed)
    support = donors | (np.asarray(support, dtype=bool) if support is not None else False)
    if spatial:
        support = support | (observed.sum(axis=1) >= SPATIAL_MIN)[:, None]
    given = std
    if std is not None and donors.any():
        # the constraints put the rigid-donor fill at these samples, used only where its
        # hold-out error is at most tol x scale (3-D RMS): that bounds their error
        std = np.asarray(std, dtype=np.float64)
        std = np.where(donors & np.isfinite(std),
                       np.minimum(std, pairs.tol * pairs.scale / np.sqrt(D)), std)
    per = per_mm(units, D, scale)
    cap = metrics.step_limit(F, observed, q=STEP_PERCENTILE, factor=STEP_FACTOR) \
        if observed.any() else np.inf
    bounds = metrics.volume(X, observed, VOLUME_MARGIN) if observed.any() else \
        (np.full(D, -np.inf), np.full(D, np.inf))
    black = ~observed.any(axis=1)
    rows = []
    for j, a, b in metrics.gap_runs(missing):
        if missing[:, j].all():
            continue
        row = _gap_row(X, F, j, a, b, rate, names, partners.get(int(j)), support, bounds, black)
        # a short gap filled by the interpolation across it holds no rigid-donor fill
        on_interpolation = row["disagree"] <= SAME_MM * per
        row["est_rmse"] = est_rmse(given if on_interpolation else std, j, a, b, D)
        if donors[a:b, j].any() and len(seg_names.get(int(j), [])) == 1:
            row["segment"] = seg_names[int(j)][0]          # the one segment that can hold it
        row["first_frame"], row["last_frame"] = first_frame + a, first_frame + b - 1
        rows.append(row)
    ests = [r["est_rmse"] for r in rows if np.isfinite(r["est_rmse"])]
    med = float(np.median(ests)) if ests else math.nan
    th = thresholds(units, per, cap, bounds, med, rate, D)
    for row in rows:
        row["verdict"], row["reasons"] = verdict(row, th)
        row["thresholds"] = th
    return rows


def drop_rejected(filled, rows: list[dict], std=None):
    """``(filled, std, dropped)``: copies of the fill ``filled`` (T, J, D) and its ``std``
    (T, J, or None) with the filled samples of every ``reject`` gap of ``rows`` (see
    :func:`gap_table`) left NaN, and the rows of the gaps so emptied. Only samples that were
    missing change: a gap's frames hold no observed sample of its marker."""
    F = np.array(filled, dtype=np.float64, copy=True)
    S = None if std is None else np.array(std, dtype=np.float64, copy=True)
    dropped = [r for r in rows if r["verdict"] == "reject" and r["filled_frames"] > 0]
    for r in dropped:
        F[r["start"]:r["stop"], r["j"]] = np.nan
        if S is not None:
            S[r["start"]:r["stop"], r["j"]] = np.nan
    return F, S, dropped


def sample_verdicts(rows: list[dict], filled, prior=None) -> np.ndarray:
    """``(T, J)`` int8: the code (index into ``VERDICTS``) of the verdict of the gap of ``rows``
    that holds each sample finite in ``filled`` (T, J, D), -1 elsewhere; ``prior`` (T, J) codes
    kept where no row speaks (fills of an earlier run). ``meta["verdict"]`` of a sequence:
    what a C3D writer records (:mod:`torchfill.io.c3d_marks`)."""
    F = np.asarray(filled)
    out = (np.array(prior, dtype=np.int8, copy=True) if prior is not None
           else np.full(F.shape[:2], -1, dtype=np.int8))
    present = np.isfinite(F).all(axis=2)
    for r in rows:
        a, b, j = r["start"], r["stop"], r["j"]
        out[a:b, j] = np.where(present[a:b, j], VERDICTS.index(r["verdict"]), -1)
    return out


def table_thresholds(rows: list[dict]) -> Thresholds | None:
    return rows[0]["thresholds"] if rows else None


def rigid_partners(pairs) -> dict:
    """``j -> (k, median distance, spread)`` of each marker's rigid partners (duplicates left
    out; spread = the 95th percentile of the pair's observed deviations from its median, at least
    the rigidity tolerance), from the sparse pairs of :func:`~torchfill.solvers.rigid.rigid_pairs`."""
    keep = np.asarray(pairs.rigid & ~pairs.duplicate, dtype=bool)
    wide = pairs.wide if pairs.wide is not None else pairs.spread
    spread = np.maximum(np.nan_to_num(np.asarray(wide, dtype=np.float64), nan=np.inf),
                        pairs.tol * pairs.scale)
    out: dict = {}
    for a, b, d, s in zip(pairs.j[keep], pairs.k[keep], pairs.distance[keep], spread[keep]):
        for x, y in ((int(a), int(b)), (int(b), int(a))):
            out.setdefault(x, ([], [], []))
            out[x][0].append(y)
            out[x][1].append(d)
            out[x][2].append(s)
    return {x: tuple(np.asarray(v) for v in lists) for x, lists in out.items()}


def _disagreement(X, F, j, a, b, side: int = 4) -> float:
    """RMS distance between the fill of ``j`` over ``a:b`` and the PCHIP interpolation through
    up to ``side`` observed samples on each side of the gap (NaN with fewer than 2 in all)."""
    from scipy.interpolate import PchipInterpolator

    T = X.shape[0]
    lo, hi = max(0, a - side), min(T, b + side)
    t = np.r_[np.arange(lo, a), np.arange(b, hi)]
    t = t[np.isfinite(X[t, j]).all(axis=1)]
    if t.size < 2 or not (t < a).any() or not (t >= b).any():
        return math.nan
    P = PchipInterpolator(t, X[t, j], axis=0)(np.arange(a, b))
    return float(np.sqrt(np.mean(np.sum((F[a:b, j] - P) ** 2, axis=1))))


def _keypoint_scale(X, observed) -> float:
    """Median distance between the keypoints of a frame, over up to 200 evenly spaced frames
    with every keypoint seen (else the frames with the most): the body's size in pixels."""
    count = observed.sum(axis=1)
    frames = np.flatnonzero(count == count.max())
    frames = frames[np.linspace(0, frames.size - 1, min(200, frames.size)).round().astype(int)]
    P = np.where(observed[frames, :, None], X[frames], np.nan)
    a, b = np.triu_indices(X.shape[1], 1)
    d = np.linalg.norm(P[:, a] - P[:, b], axis=2)
    return float(np.nanmedian(d)) if np.isfinite(d).any() else math.nan


def _gap_row(X, F, j, a, b, rate, names, partners, support, bounds, black) -> dict:
    T = X.shape[0]
    seg = F[max(a - 1, 0):min(b + 1, T), j]
    steps = np.linalg.norm(np.diff(seg, axis=0), axis=1)
    fin = np.isfinite(F[a:b, j]).all(axis=1)
    row = {"marker": names[j] if names is not None else str(j), "j": int(j),
           "start": int(a), "stop": int(b), "frames": int(b - a),
           "seconds": (b - a) / rate if rate else math.nan,
           "kind": ("whole" if a == 0 and b == T else "start" if a == 0 else
                    "end" if b == T else "interior"),
           "filled_frames": int(fin.sum()), "unfilled": int((~fin).sum()),
           "support": float(support[a:b, j].mean()),
           "max_step": float(np.nanmax(steps)) if np.isfinite(steps).any() else math.nan,
           "rigid_dev": math.nan, "rigid_ratio": math.nan, "rigid_partner": "",
           "at_volume_bound": 0, "extrapolated": 0, "extrapolated_s": 0.0,
           "blackout": int(black[a:b].sum()), "segment": None, "disagree": math.nan}
    if row["kind"] == "interior" and rate and (b - a) / rate <= SHORT_SECONDS and fin.all():
        row["disagree"] = _disagreement(X, F, j, a, b)
    if partners is not None and fin.any():
        ks, ref, spread = partners
        d = np.linalg.norm(F[a:b, j][:, None] - F[a:b][:, ks], axis=2)
        ratio = np.abs(d - ref) / spread
        if np.isfinite(ratio).any():
            t, k = np.unravel_index(np.nanargmax(ratio), ratio.shape)
            row["rigid_ratio"] = float(ratio[t, k])
            row["rigid_dev"] = float(abs(d[t, k] - ref[k]))
            row["rigid_partner"] = names[ks[k]] if names is not None else str(ks[k])
    if fin.any():
        lo, hi = bounds
        P = F[a:b, j][fin]
        tol = 1e-9 * np.maximum(hi - lo, 1e-12)
        # at or beyond: the constraints clamp a fill onto the bound, so a sample there counts;
        # metrics.outside_volume counts only those strictly beyond it (none from the default)
        row["at_volume_bound"] = int(((P <= lo + tol) | (P >= hi - tol)).any(axis=1).sum())
    if row["kind"] in ("start", "end"):
        n = int((fin & ~support[a:b, j]).sum())
        row["extrapolated"] = n
        row["extrapolated_s"] = n / rate if rate else float(n)
    return row
