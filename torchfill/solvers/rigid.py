"""Rigid segments found in the data, and the rigid-body fill (Kabsch / SVD).

A marker on a rigid segment (head, pelvis, a foot with three markers) is best filled from the
other markers of its segment: the segment's motion is a rotation and a translation, which three
observed markers determine. This is what Vicon Nexus' rigid-body fill and QTM's kinematic fill do.

**Which markers are rigid with which** is read from the recording itself. For every pair, the
distance while both are observed has a median ``d`` and a robust spread ``s`` (1.4826 x MAD). The
pair is rigid when ``s <= tol * scale``, where ``scale`` is the median of ``d`` over all pairs (the
body's size, so the rule is free of units); ``tol = 0.005`` is about 3 mm on an adult body (0.01
lets neck and shoulder pairs in; chosen on simulated gaps of HDM05, CMU and Kinetics Toolkit
recordings, observed frames only define the pairs). A pair
whose median distance is below ``tol * scale`` is one marker stored twice (a *duplicate*): it is
filled by translation from its twin. The partners of a marker are the largest set of its rigid
pairs that are also rigid with one another (a clique), so that a marker seen only while the body
was still is not tied to markers of two different segments.

**The fill** of marker ``j`` at a missing frame ``t`` uses the partners observed at ``t`` (three or
more, not duplicates of one another): the nearest frames before and after ``t`` in which ``j`` and
those partners were all observed are the references; the least-squares rotation and translation
taking the partners from a reference frame to frame ``t`` (Kabsch 1976) carries ``j`` along, and the
two estimates are blended linearly in time. At a trial end only one reference exists, and the fill
extrapolates correctly with the segment. A partner set is used only if it passes a hold-out on
observed frames: carrying the observed marker over the same number of frames as the fill reaches
(median distance to its reference) must have an RMS error <= ``tol * scale`` (about 3 mm). With fewer than three partners a sample is left to other
methods (the ``rigid`` method falls back on PCHIP for them; ``fill()``'s constraints keep the
distances to one or two partners softly, see :mod:`torchfill.constraints`).

References
----------
Kabsch, W. (1976). A solution for the best rotation to relate two sets of vectors.
Acta Crystallographica A 32(5), 922-923.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .base import Param, Solver, register
from .interp import Pchip

Tensor = torch.Tensor


@dataclass
class RigidPairs:
    """Pairwise rigidity of a recording's markers (all ``(J, J)``)."""

    distance: Tensor    # median distance while both are observed (NaN: never together)
    spread: Tensor      # robust spread of that distance (1.4826 x MAD)
    rigid: Tensor       # bool: spread <= tol * scale (diagonal False)
    duplicate: Tensor   # bool: one marker stored twice (distance <= tol * scale)
    scale: float        # median pairwise distance: the body's size
    tol: float = 0.005  # the rigidity tolerance, relative to ``scale``
    wide: Tensor | None = None  # 95th percentile of |distance - median| while both are observed

    def partners(self, j: int, max_partners: int = 6) -> list[int]:
        """The largest clique of markers rigid with ``j`` and with one another, most rigid first
        (duplicates of ``j`` and of one another excluded)."""
        rigid = self.rigid.cpu().numpy()
        dup = self.duplicate.cpu().numpy()
        spread = self.spread[j].cpu().numpy()
        cand = [k for k in np.argsort(spread) if rigid[j, k] and not dup[j, k]]
        best: list[int] = []
        for seed in cand:
            clique = [seed]
            for k in cand:
                if k != seed and all(rigid[k, m] and not dup[k, m] for m in clique):
                    clique.append(k)
            if len(clique) > len(best):
                best = clique
        return sorted(best, key=lambda k: spread[k])[:max_partners]


#: Pair distances are measured this many (frame, pair) entries at a time (8 MB per float64
#: array), so a 120 000-frame recording needs well under 1 GB here instead of the 7 GB of all
#: (T, J, J, 3) differences at once.
PAIR_BLOCK = 1 << 20
#: Pair statistics read at most this many frames, evenly spaced: their sort took 23 of the
#: constraints' 30 s at 120 000 frames; 12 000 leaves every recording of ../shared/data whole.
PAIR_FRAMES = 12000
#: The hold-out error of a rigid fill is measured on at most this many evenly spaced reference
#: frames (its batched 3 x 3 SVDs were 0.38 of the constraints' 1.3 s at 3 000 frames).
HOLDOUT_FRAMES = 500


def rigid_pairs(X: Tensor, observed: Tensor | None = None, *, tol: float = 0.005,
                min_frames: int = 20) -> RigidPairs:
    """Find rigid marker pairs from the frames where both markers are observed.

    Parameters
    ----------
    X : tensor (T, J, 3)
        Marker positions; NaN where missing.
    observed : bool tensor (T, J), optional
        Observed samples (default: the finite ones).
    tol : float
        Rigid when the distance's robust spread is at most ``tol`` times the median pairwise
        distance (see the module docstring).
    min_frames : int
        Pairs seen together in fewer frames are never rigid.

    A recording longer than ``PAIR_FRAMES`` frames is read at every ``stride``-th frame (the fewest
    that leave at most ``PAIR_FRAMES``; frames counted for ``min_frames`` too).
    """
    X = torch.as_tensor(X)
    if observed is None:
        observed = torch.isfinite(X).all(dim=-1)
    stride = -(-X.shape[0] // PAIR_FRAMES)         # long recordings: evenly spaced frames
    X, observed = X[::stride], observed[::stride]
    X = torch.where(observed[..., None], X, torch.nan)
    T, J = X.shape[:2]
    seen = torch.where(observed.any(dim=0), 0.0, torch.nan).to(X.dtype)   # a marker to itself
    med, mad, wide = torch.diag(seen), torch.diag(seen), torch.diag(seen)
    n = torch.diag(observed.sum(dim=0))
    j, k = torch.triu_indices(J, J, 1, device=X.device)
    block = max(1, PAIR_BLOCK // max(T, 1))              # pairs at a time: memory ~ T x block
    for a in range(0, j.numel(), block):
        jb, kb = j[a:a + block], k[a:a + block]
        D = torch.linalg.vector_norm(X[:, jb] - X[:, kb], dim=-1)              # (T, pairs)
        m = torch.nanmedian(D, dim=0).values
        dev = (D - m).abs()
        s = 1.4826 * torch.nanmedian(dev, dim=0).values
        w = _upper_nanquantile(dev, 0.95)
        c = (observed[:, jb] & observed[:, kb]).sum(dim=0)
        for out, v in ((med, m), (mad, s), (wide, w), (n, c)):
            out[jb, kb] = out[kb, jb] = v
    enough = n >= min_frames
    off = ~torch.eye(J, dtype=torch.bool, device=X.device)
    finite = enough & off & torch.isfinite(med)
    scale = float(torch.median(med[finite])) if bool(finite.any()) else 1.0
    duplicate = finite & (med <= tol * scale)
    rigid = finite & (mad <= tol * scale)
    return RigidPairs(med, mad, rigid, duplicate, scale, tol, wide)


def _upper_nanquantile(D: Tensor, q: float) -> Tensor:
    """``torch.nanquantile(D, q, dim=0)`` (linear interpolation) for ``q >= 0.5`` from the top
    ``(1 - q) T + 2`` values of each column (a partial selection, not a full sort: 72 vs 223 ms
    for 3 000 frames x 820 pairs); the same values."""
    T = D.shape[0]
    n = (~torch.isnan(D)).sum(dim=0)
    k = min(T, int((1 - q) * (T - 1)) + 2)
    top = torch.topk(torch.nan_to_num(D, nan=-torch.inf), k, dim=0).values     # descending
    p = q * (n - 1).clamp(min=0).to(D.dtype)
    lo, hi = p.floor().long(), p.ceil().long()
    below, above = (top.gather(0, ((n - 1) - i).clamp(0, k - 1)[None])[0] for i in (lo, hi))
    return torch.where(n > 0, torch.lerp(below, above, p - lo.to(D.dtype)), torch.nan)


def kabsch(P: Tensor, Q: Tensor) -> tuple[Tensor, Tensor]:
    """Least-squares rotation ``R`` and translation ``t`` with ``Q ~ P @ R.T + t``, batched.

    ``P``, ``Q``: ``(n, k, 3)`` corresponding points (k >= 3, not collinear). Returns ``R``
    ``(n, 3, 3)`` (a proper rotation, det +1) and ``t`` ``(n, 3)``.
    """
    cp, cq = P.mean(dim=1), Q.mean(dim=1)
    H = (P - cp[:, None]).transpose(1, 2) @ (Q - cq[:, None])       # cross-covariance
    U, _, Vh = torch.linalg.svd(H)
    V, Ut = Vh.transpose(1, 2), U.transpose(1, 2)
    d = torch.sign(torch.linalg.det(V @ Ut))
    E = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], dim=-1))
    R = V @ E @ Ut
    t = cq - (cp[:, None] @ R.transpose(1, 2))[:, 0]
    return R, t


def _carry(X: Tensor, j: int, S: list[int], ref: np.ndarray, frames: np.ndarray) -> Tensor:
    """Marker ``j`` carried from reference frames ``ref`` to ``frames`` by its partners ``S``."""
    R, t = kabsch(X[ref][:, S], X[frames][:, S])
    return (X[ref, j][:, None] @ R.transpose(1, 2))[:, 0] + t


def _holdout_error(X: Tensor, j: int, S: list[int], refs: np.ndarray, reach: int) -> float:
    """RMS error of carrying observed ``j`` over ``reach`` frames between reference frames: the
    rigid fill's error at that distance, measured on observed samples only."""
    if refs.size < 2:
        return np.inf
    later = np.searchsorted(refs, refs + max(reach, 1))
    ok = later < refs.size
    if not ok.any():
        return np.inf
    src, dst = refs[ok], refs[later[ok]]
    pick = np.unique(np.linspace(0, src.size - 1, min(src.size, HOLDOUT_FRAMES)).round().astype(int))
    src, dst = src[pick], dst[pick]
    err = _carry(X, j, S, src, dst) - X[dst, j]
    return float(torch.sqrt((err ** 2).sum(dim=1).mean()))


def _fill_pattern(X: Tensor, seen: np.ndarray, j: int, S: list[int], frames: np.ndarray,
                  max_error: float = np.inf) -> Tensor | None:
    """Rigid estimates of marker ``j`` at ``frames`` from partners ``S`` (all seen there); None
    when no reference frame exists or the hold-out error at the fill's reach exceeds
    ``max_error``."""
    refs = np.flatnonzero(seen[:, j] & seen[:, S].all(axis=1))
    if refs.size == 0:
        return None
    pos = np.searchsorted(refs, frames)
    before = refs[np.clip(pos - 1, 0, refs.size - 1)]
    after = refs[np.clip(pos, 0, refs.size - 1)]
    has_b, has_a = pos > 0, pos < refs.size
    before = np.where(has_b, before, after)
    after = np.where(has_a, after, before)
    reach = int(np.median(np.minimum(np.abs(frames - before), np.abs(after - frames))))
    if np.isfinite(max_error) and _holdout_error(X, j, S, refs, reach) > max_error:
        return None
    est_b, est_a = _carry(X, j, S, before, frames), _carry(X, j, S, after, frames)
    span = np.maximum(after - before, 1)
    w = torch.as_tensor(np.where(after > before, (frames - before) / span, 0.0),
                        dtype=X.dtype, device=X.device)[:, None]
    return (1 - w) * est_b + w * est_a


def rigid_fill(X: Tensor, observed: Tensor | None = None, pairs: RigidPairs | None = None, *,
               min_partners: int = 3) -> tuple[Tensor, Tensor]:
    """Fill every missing sample that has ``min_partners`` rigid partners observed (or an
    observed duplicate).

    Returns the filled tensor (NaN where no rigid estimate exists) and the bool ``(T, J)`` mask of
    the samples filled here. Observed samples are returned unchanged.
    """
    X = torch.as_tensor(X)
    if observed is None:
        observed = torch.isfinite(X).all(dim=-1)
    pairs = pairs if pairs is not None else rigid_pairs(X, observed)
    out = torch.where(observed[..., None], X, torch.nan)
    done = torch.zeros_like(observed)
    seen = observed.cpu().numpy()
    dup = pairs.duplicate.cpu().numpy()
    for j in np.flatnonzero((~seen).any(axis=0) & seen.any(axis=0)):
        _fill_duplicates(out, done, X, seen, j, np.flatnonzero(dup[j]))
        _fill_marker(out, done, X, seen, j, pairs.partners(int(j)), min_partners,
                     pairs.tol * pairs.scale)
    return out, done


def _fill_duplicates(out, done, X, seen, j, twins) -> None:
    """A marker stored twice: translate the twin by their median offset while both were seen."""
    for k in twins:
        both = seen[:, j] & seen[:, k]
        todo = np.flatnonzero(~seen[:, j] & seen[:, k] & ~done[:, j].cpu().numpy())
        if todo.size == 0 or not both.any():
            continue
        offset = torch.nanmedian(X[both, j] - X[both, k], dim=0).values
        out[todo, j] = X[todo, k] + offset
        done[todo, j] = True


def _fill_marker(out, done, X, seen, j, partners, min_partners, max_error) -> None:
    """Kabsch fill of marker ``j`` where at least ``min_partners`` of its partners are seen."""
    if len(partners) < min_partners:
        return
    todo = ~seen[:, j] & ~done[:, j].cpu().numpy()
    P = seen[:, partners]
    todo &= P.sum(axis=1) >= min_partners
    codes = P[todo] @ (1 << np.arange(len(partners)))
    frames_all = np.flatnonzero(todo)
    for code in np.unique(codes):
        frames = frames_all[codes == code]
        S = [p for i, p in enumerate(partners) if code >> i & 1]
        while len(S) >= min_partners:
            est = _fill_pattern(X, seen, int(j), S, frames, max_error)
            if est is not None:
                out[frames, j] = est.to(out.dtype)
                done[frames, j] = True
                break
            S = S[:-1]                      # drop the least rigid partner and try again


@register
class Rigid(Solver):
    """Rigid-body fill (Kabsch) from >= 3 rigid partners found in the data; PCHIP elsewhere."""

    name = "rigid"
    iterative = False
    spatial = True
    params = {
        "max_iter": Param(1, int, low=1, doc="unused: one shot"),
        "tol": Param(0.005, float, low=0.0, low_open=True,
                     doc="rigid when the distance spread <= tol x median pairwise distance"),
        "min_partners": Param(3, int, low=3, doc="observed rigid partners needed"),
    }

    def _initialize(self) -> None:
        self.require_3d("rigid bodies move in 3-D; a 2-D projection is not rigid")
        self.X_ = self.M_.clone()

    def step(self) -> dict[str, float]:
        seen = self.Omega_.all(dim=2)
        X = torch.where(seen[..., None], self.M_, torch.nan)
        self.pairs_ = rigid_pairs(X, seen, tol=self.tol)
        R, self.rigid_done_ = rigid_fill(X, seen, self.pairs_, min_partners=self.min_partners)
        T = X.shape[0]
        base = Pchip()._interpolate(self.M_.reshape(T, -1), self.Omega_.reshape(T, -1))
        self.X_ = torch.where(self.rigid_done_[..., None], R, base.reshape(self.M_.shape))
        return {"delta": 0.0, "rigid_share": float(self.rigid_done_.sum() / (~seen).sum().clamp(min=1))}

    def _estimate(self) -> Tensor:
        return self.X_
