"""What a fill leaves NaN, each with one warning: markers never observed, samples whose
estimated error is too large (``reject``), markers with no observed motion or no observed
segment-mate (the extrapolation limit), gaps longer than ``max_gap``; and the default's short
gaps kept on the interpolation across them (:mod:`torchfill.qc.finish`)."""
from __future__ import annotations

import warnings

import numpy as np
import torch

from .metrics import gap_runs
from .qc import EST_CHECK_MM, alone, untested
from .qc import per_mm as qc_per_mm
from .qc.finish import finish
from .sequence import MarkerSequence, per_mm


class UnfilledWarning(UserWarning):
    """Some gaps were left unfilled (a marker never observed, or a gap longer than ``max_gap``)."""


def warn_never(data, never: torch.Tensor) -> None:
    warnings.warn(f"{int(never.sum())} marker(s) never observed, left unfilled: "
                  f"{marker_names(data, never)}", UnfilledWarning, stacklevel=5)


def reject(out: torch.Tensor, std: torch.Tensor, missing: torch.Tensor, units: str,
            limit_mm: float) -> int:
    """Leave NaN the filled samples whose estimated 3-D error (sqrt(3) x the per-coordinate std)
    is above ``limit_mm`` -- at a trial end from the first such sample to the end of the trial,
    inside a trial the whole gap when its RMS estimate is above it; returns how many were left NaN
    (one warning says how many)."""
    if str(units).strip().lower() not in ("mm", "cm", "m") or not bool(torch.isfinite(std).any()):
        return 0                                    # e.g. pixels: no threshold in mm
    scale = 1.0 / per_mm(units)
    T = out.shape[0]
    err = (3.0 ** 0.5 * std * scale).cpu().numpy()
    count = 0
    for j, a, b in gap_runs(missing.cpu().numpy()):         # the gaps, parts left NaN or not
        e = np.nan_to_num(err[a:b, j], nan=0.0)
        bad = np.flatnonzero(e > limit_mm)
        if bad.size == 0:
            continue
        if a == 0 and b < T:                        # trial start: far part, up to the worst
            drop = slice(a, a + int(bad.max()) + 1)
        elif b == T and a > 0:                      # trial end: from the first bad to the end
            drop = slice(a + int(bad.min()), b)
        elif float(np.sqrt(np.mean(e ** 2))) > limit_mm:
            drop = slice(a, b)
        else:
            continue
        count += int(torch.isfinite(out[drop, j]).all(dim=1).sum())     # not those already NaN
        out[drop, j] = float("nan")
    if count:
        warnings.warn(f"{count} filled sample(s) left unfilled: their estimated error is above "
                      f"{limit_mm:g} mm (reject=None fills them)", UnfilledWarning,
                      stacklevel=5)
    return count


def leave_untested(out: torch.Tensor, std: torch.Tensor, missing: torch.Tensor, data) -> int:
    """Leave NaN the filled samples :func:`torchfill.qc.untested` names (markers never seen in two
    consecutive frames; only where the fill has an error estimate); returns how many, with one
    warning naming the markers."""
    drop = torch.as_tensor(untested(missing.cpu().numpy(), std.cpu().numpy()), device=out.device)
    return leave_nan(out, drop & torch.isfinite(out).all(dim=2), data,
                      "never seen in two consecutive frames, so neither the fill nor its error "
                      "estimate has observed motion to go on")


def leave_alone(out: torch.Tensor, std: torch.Tensor, missing: torch.Tensor, data,
                 segments: dict) -> int:
    """Leave NaN the filled samples :func:`torchfill.qc.alone` names (markers whose segment-mates
    are never observed, estimate above the QC's check level); returns how many, with one warning
    naming the markers."""
    units = data.units if isinstance(data, MarkerSequence) else "mm"
    drop = torch.as_tensor(alone(torch.isfinite(out).all(dim=2).cpu().numpy(),
                                 missing.cpu().numpy(), std.cpu().numpy(), segments, units),
                           device=out.device)
    return leave_nan(out, drop, data,
                      f"no other marker of their segment is ever observed and their estimated "
                      f"error is above {EST_CHECK_MM:g} mm, so the fill alone would pose the "
                      f"segment")


def leave_nan(out: torch.Tensor, drop: torch.Tensor, data, why: str) -> int:
    """Set the (T, J) samples ``drop`` of ``out`` to NaN; one UnfilledWarning says how many, of
    which markers, and ``why``. Returns how many."""
    count = int(drop.sum())
    if count:
        out[drop] = float("nan")
        which = drop.any(dim=0)
        warnings.warn(f"{count} filled sample(s) of {int(which.sum())} marker(s) left NaN: {why} "
                      f"({marker_names(data, which, 8)}; extrapolate=None fills them)",
                      UnfilledWarning, stacklevel=6)
    return count


def unfill_long_gaps(out: torch.Tensor, given: torch.Tensor, missing: torch.Tensor,
                      max_gap: int) -> torch.Tensor:
    """Put the long gaps back as they were given (NaN, except finite coordinates of a sample
    that was only partly missing: those are observed and stay)."""
    long = [(j, a, b) for j, a, b in gap_runs(missing.cpu().numpy()) if b - a > max_gap]
    for j, a, b in long:
        out[a:b, j] = given[a:b, j]
    if long:
        warnings.warn(f"{len(long)} gap(s) longer than max_gap={max_gap} frames left unfilled",
                      UnfilledWarning, stacklevel=5)
    return out


def marker_names(data, which: torch.Tensor, most: int | None = None) -> str:
    idx = torch.nonzero(which).flatten().tolist()
    names = [data.labels[i] for i in idx] if isinstance(data, MarkerSequence) else list(map(str, idx))
    more = most is not None and len(names) > most
    return ", ".join(names[:most] if more else names) + (" ..." if more else "")


def short_gaps_and_bound(out: torch.Tensor, std: torch.Tensor, missing: torch.Tensor,
                         own: torch.Tensor, data, info: dict):
    """The default's short interior gaps kept on the interpolation across them where its fill
    departs from it, and its estimate bounded by what the fill can be off
    (:mod:`torchfill.qc.finish`); observed coordinates (``own``) stay bit for bit."""
    X = torch.where(missing[..., None], float("nan"), out).cpu().numpy()
    seq = isinstance(data, MarkerSequence)
    F = out.cpu().numpy()                   # out itself on the CPU (float64 where fill() runs)
    in_place = F.dtype == np.float64 and out.device.type == "cpu"
    F, S, changed = finish(X, F, std.cpu().numpy(), data.rate if seq else None,
                           qc_per_mm(data.units if seq else "mm", X.shape[2]),
                           keep=own.cpu().numpy() if in_place else None)
    info["short_gaps"] = len(changed)
    if changed and not in_place:
        out = torch.where(own, out, torch.as_tensor(F, dtype=out.dtype, device=out.device))
    return out, torch.as_tensor(S, dtype=std.dtype, device=std.device)
