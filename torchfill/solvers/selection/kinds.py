"""Gap kinds: where a gap lies (trial end or inside), how long it is and how fast its frames move;
the per-sample geometry of a (T, J) gap mask. Why these kinds: experiments/results/auto.md."""
from __future__ import annotations

import torch

from ... import ops

Tensor = torch.Tensor

#: Gap-length bucket edges in frames (a gap's kind: trial end or not x length bucket).
LENGTH_EDGES = (20, 80)
#: A gap is "fast" when the frames it spans move this many times the recording's median frame
#: motion (squared step): real occlusions cluster in fast phases, which a time-shifted hold-out
#: mostly misses (see experiments/results/auto.md).
FAST = 3.0
#: Gap kinds without a partial candidate (see :func:`gap_kind`), and all of them: a sample a
#: partial candidate fills has the kind ``N_BASE`` higher.
N_BASE = 4 * (len(LENGTH_EDGES) + 1)
N_KINDS = 2 * N_BASE


def interior_share(Omega: Tensor) -> float:
    """Share of the missing samples (a sample: any coordinate of a marker in a frame) that lie in
    gaps longer than ``LENGTH_EDGES[0]`` frames touching neither trial end."""
    missing = ~Omega.reshape(Omega.shape[0], Omega.shape[1], -1).all(dim=2)
    n = int(missing.sum())
    if n == 0:
        return 0.0
    _, L, edge = run_geometry(missing)
    return float((missing & ~edge & (L > LENGTH_EDGES[0])).sum()) / n


def run_bounds(missing: Tensor) -> tuple[Tensor, Tensor]:
    """Per sample of the (T, J) mask: the last observed frame before it (-1: none) and the next
    observed frame after it (T: none)."""
    T = missing.shape[0]
    t = torch.arange(T, device=missing.device)[:, None].expand_as(missing)
    obs = ~missing
    prev = torch.cummax(torch.where(obs, t, -1), dim=0).values
    nxt = T - 1 - torch.cummax(torch.where(obs, T - 1 - t, -1).flip(0), dim=0).values.flip(0)
    return prev, torch.where(nxt > T - 1, torch.full_like(nxt, T), nxt)


def run_geometry(missing: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Per sample of the (T, J) ``missing`` mask: distance in frames to the nearest observed frame
    of its marker, the length of its gap, and whether its gap touches a trial end (0 / 0 / False
    where observed)."""
    T = missing.shape[0]
    t = torch.arange(T, device=missing.device)[:, None].expand_as(missing)
    prev, nxt = run_bounds(missing)
    edge = (prev < 0) | (nxt >= T)
    far = torch.full_like(t, 2 * T)
    d = torch.minimum(torch.where(prev >= 0, t - prev, far), torch.where(nxt < T, nxt - t, far))
    L = nxt - prev - 1
    return (torch.where(missing, d.clamp(max=T), 0), torch.where(missing, L, 0),
            edge & missing)


def gap_kind(L: Tensor, edge: Tensor, fast: Tensor) -> Tensor:
    """Kind index per sample: ``4 * length bucket + 2 * fast + trial end``."""
    bucket = torch.zeros_like(L)
    for e in LENGTH_EDGES:
        bucket = bucket + (L > e).to(L.dtype)
    return 4 * bucket + 2 * fast.to(L.dtype) + edge.to(L.dtype)


def kind_name(k: int) -> str:
    partial, k = divmod(k, N_BASE)
    length = (LENGTH_EDGES + ("inf",))[k // 4]
    return (f"{'end' if k % 2 else 'inner'}{',fast' if k // 2 % 2 else ''}<={length}"
            f"{',segment' if partial else ''}")


def gap_motion(missing: Tensor, Y: Tensor) -> Tensor:
    """Per sample of a gap: the mean over its gap's frames of the frame motion (mean squared step
    of the markers seen in both frames, ``Y`` (T, J, D)), over the recording's median frame motion;
    0 where observed."""
    T = missing.shape[0]
    both = ~missing[1:] & ~missing[:-1]
    step = torch.diff(Y, dim=0).pow(2).mean(dim=2)
    m = torch.where(both, step, 0.0).sum(dim=1) / both.sum(dim=1).clamp(min=1)
    has = both.any(dim=1)
    m = ops.interp_linear(m[:, None], has[:, None])[:, 0] if bool(has.any()) else m
    m = torch.cat([m, m[-1:]])
    m = m / m.median().clamp(min=1e-12)
    C = torch.cat([m.new_zeros(1), torch.cumsum(m, dim=0)])[:, None].expand(T + 1, missing.shape[1])
    prev, nxt = run_bounds(missing)
    total = C.gather(0, nxt) - C.gather(0, prev + 1)
    return torch.where(missing, total / (nxt - prev - 1).clamp(min=1), 0.0)


def gap_index(mask: Tensor) -> Tensor:
    """(T, J) index of each sample's run of ``mask`` (one per marker-gap), -1 outside."""
    idx = torch.full(mask.shape, -1, dtype=torch.long, device=mask.device)
    for i, (j, a, b) in enumerate(ops.runs(mask)):
        idx[a:b, j] = i
    return idx


def partial_samples(partial: list[bool], fills: Tensor) -> Tensor:
    """(T, J) samples that a partial candidate (``partial[c]``) of ``fills`` (C, T, J, D) fills,
    as 0/1."""
    got = torch.zeros(fills.shape[1:3], dtype=torch.long, device=fills.device)
    for c, is_partial in enumerate(partial):
        if is_partial:
            got = got | torch.isfinite(fills[c]).all(dim=-1).long()
    return got


def sample_kinds(partial: list[bool], fills: Tensor, missing: Tensor, Xt: Tensor
                 ) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Per sample of ``missing`` (T, J) in ``Xt`` (T, J, D): its distance, gap length and
    trial end (:func:`run_geometry`), its gap's frame motion (:func:`gap_motion`) and its
    kind (:func:`gap_kind`, ``N_BASE`` higher where a partial candidate of ``fills`` fills
    it)."""
    d, L, edge = run_geometry(missing)
    motion = gap_motion(missing, Xt)
    kinds = gap_kind(L, edge, motion > FAST) + N_BASE * partial_samples(partial, fills)
    return d, L, edge, motion, kinds
