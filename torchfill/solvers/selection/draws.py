"""The default's hold-out draws: observed samples hidden like the recording's own gaps, each
candidate's fill of them through the post-step, and its squared errors there per gap kind. Why
two draws and more for a recording with few gaps: docs/real-gaps.md."""
from __future__ import annotations

from concurrent.futures import Future

import torch

from ... import ops
from ..holdout import mirrored_edge_holdout, shifted_gap_holdout
from .candidates import INTERIOR, PARTIAL, SESSION, Fits
from .kinds import gap_index, sample_kinds

Tensor = torch.Tensor

#: Most hold-out draws that ``min_gaps`` asks for.
MAX_DRAWS = 4
#: One draw is enough where its held-out gaps take this many distinct windows (:func:`windows`):
#: many independent events (measured: experiments/results/auto.md).
ENOUGH_WINDOWS = 20
#: A ``+session`` twin's place in a later hold-out draw: not fitted there, its errors NaN, so
#: its gap kinds' mean squared errors are those of the first draw alone (the twins fit the
#: training trials' frames too, most of a session's time).
NOT_DRAWN = RuntimeError("not fitted in this draw")


def holdout(seen: Tensor, generator: torch.Generator) -> Tensor:
    """Held-out (T, J) samples of the observed ``seen`` (T, J): mirrored trial-end gaps, then the
    shifted gap pattern (drawn with ``generator``), each added to a marker only while it keeps
    half of its observed samples (and two at least). Part by part, not the union at once: a
    marker missing its last quarter would get both a mirrored and a shifted copy of that gap,
    half its samples together, and drop out of the hold-out altogether."""
    Omega3 = seen[..., None]
    V = torch.zeros_like(seen)
    n_seen = seen.sum(dim=0)
    shifted = shifted_gap_holdout(Omega3, generator)               # the generator's draw first
    for part in (mirrored_edge_holdout(Omega3), shifted):
        if part is None:
            continue
        W = V | part[..., 0]
        n = W.sum(dim=0)
        V = torch.where((n <= 0.5 * n_seen) & (n_seen - n >= 2), W, V)
    return V


def scored(fits: Fits, names: list[str], outs, missing: Tensor, Xt: Tensor, V: Tensor
           ) -> tuple[tuple[Tensor, Tensor, Tensor], Tensor, Tensor]:
    """The candidates' fits ``outs`` (in ``names``' order; an exception: the candidate
    failed) of ``Xt`` (T, J, D) with ``missing`` hidden, after the post-step, scored on
    the held-out samples ``V``: their squared errors (C, N), kinds (N,) and gap ids (N,) on
    the samples they fill themselves (not rigid donors); the squared errors on all of ``V``
    (C, N_V); and which of ``V``'s samples those are (N_V,). A failed candidate's errors are
    NaN."""
    C = len(names)
    fills = torch.full((C, *Xt.shape), float("nan"), dtype=fits.M.dtype, device=V.device)
    for c, out in enumerate(outs):
        if not isinstance(out, Exception):
            fills[c] = out
    donor = fits.post(missing).donor
    kinds = sample_kinds([n in PARTIAL for n in names], fills, missing, Xt)[-1]
    err2 = ((fills - Xt) ** 2).mean(dim=3)[:, V]
    decide = ~donor[V]
    return (err2[:, decide], kinds[V][decide], gap_index(V)[V][decide]), err2, decide


def first_scores(fills: Tensor, donor: Tensor, kinds: Tensor, Xt: Tensor, V: Tensor
                 ) -> tuple[tuple[Tensor, Tensor, Tensor], Tensor]:
    """The first draw's scores (as :func:`scored`) from its constrained ``fills`` (C, T, J, D),
    the samples rigid donors fill and the samples' kinds."""
    err2 = ((fills - Xt) ** 2).mean(dim=3)[:, V]                # (C, N), NaN: not filled
    decide = ~donor[V]                      # held-out samples the candidates fill themselves
    return (err2[:, decide], kinds[V][decide], gap_index(V)[V][decide]), err2


def draw(fits: Fits, names: list[str], seen: Tensor, V0: Tensor, generator: torch.Generator,
         skip: tuple = (), behind: tuple = ()) -> tuple[tuple[Tensor, Tensor, Tensor], list]:
    """Another hold-out draw, scored like the first (:func:`scored`; none when the draw
    repeats ``V0``), and what is still running. The ``+session`` twins and the candidates in
    ``skip`` are not fitted again (see ``NOT_DRAWN``). The candidates in ``behind`` run on in
    the background while the others are scored and the next draws made (:meth:`Fits.fit_all`):
    their errors are NaN until :func:`settle` scores them."""
    V = holdout(seen, generator)
    if bool((V == V0).all()):
        empty = torch.empty(0, dtype=torch.long, device=V.device)
        return (torch.empty(len(names), 0, dtype=fits.M.dtype, device=V.device), empty, empty), []
    fit_missing = ~seen | V
    Xt = fits.M.reshape(fits.M.shape[0], fits.M.shape[1], -1)
    run = [name for name in names if not name.endswith(SESSION) and name not in skip]
    fitted = dict(zip(run, fits.fit_all(run, fit_missing, "draw", behind=behind,
                                        then=fits.constrained(fit_missing))))
    pending = [(names.index(n), out) for n, out in fitted.items() if isinstance(out, Future)]
    outs = [NOT_DRAWN if isinstance(out, Future) else out
            for out in (fitted.get(name, NOT_DRAWN) for name in names)]
    scores, _, decide = scored(fits, names, outs, fit_missing, Xt, V)
    return scores, [(c, future, V, decide) for c, future in pending]


def settle(fits: Fits, err2: Tensor, pending: list) -> None:
    """The fits :func:`draw` left running (through the post-step in their lane), each scored
    into its row of that draw's squared errors ``err2`` (C, N) as :func:`scored` scores it (a
    failed one stays NaN)."""
    for c, future, V, decide in pending:
        out = future.result()
        if isinstance(out, Exception) or not bool(torch.isfinite(out).any()):
            continue
        err2[c] = alone(fits, out, V)[decide]


def alone(fits: Fits, F: Tensor, V: Tensor) -> Tensor:
    """One candidate's constrained fill ``F`` (T, J, D): its squared errors on the held-out
    samples ``V`` (N_V,), as :func:`scored` scores them."""
    Xt = fits.M.reshape(fits.M.shape[0], fits.M.shape[1], -1)
    return ((F - Xt) ** 2).mean(dim=2)[V]


def settle_first(fits: Fits, names: list[str], fills: Tensor, err2: Tensor, pooled: tuple,
                 running: dict[int, Future], V: Tensor, donor: Tensor,
                 dropped: dict[str, str]) -> tuple[list[str], Tensor, Tensor, tuple]:
    """The first draw's fits left running (``running``: candidate index -> future; the
    ``INTERIOR`` ones run on while the others are scored and the next draws made, if any),
    each (through the post-step in its lane) into its row of the draw's ``fills`` (C, T, J, D) and squared
    errors ``err2`` (C, N_V) and of the ``pooled`` errors (the first draw's columns come
    first), as :func:`first_scores` scores them. A failed one leaves every row (its error goes
    to ``dropped``)."""
    decide = ~donor[V]
    E, kinds, gaps = pooled
    failed = []
    for c, future in running.items():
        out = future.result()
        if isinstance(out, Exception):
            dropped[names[c]] = str(out)
            failed.append(c)
            continue
        fills[c], err2[c] = out, alone(fits, out, V)
        E[c, :int(decide.sum())] = err2[c][decide]
    if not failed:
        return names, fills, err2, pooled
    keep = [c for c in range(len(names)) if c not in failed]
    return [names[c] for c in keep], fills[keep], err2[keep], (E[keep], kinds, gaps)


def windows(V: Tensor, gap_ids: Tensor) -> int:
    """How many distinct windows (start and stop frames) the held-out gaps ``gap_ids`` (indices
    of ``V``'s runs, :func:`~.kinds.gap_index`) take: gaps of several markers hidden together
    are one event of the recording, whatever the number of markers."""
    runs = list(ops.runs(V))
    return len({runs[i][1:] for i in gap_ids.unique().tolist()})


def pooled(first: tuple, fits: Fits, names: list[str], seen: Tensor, V: Tensor,
           generator: torch.Generator, draws: int, min_gaps: int
           ) -> tuple[Tensor, Tensor, Tensor]:
    """The first draw's scores ``first`` and those of more draws, until ``draws`` are pooled and
    (up to ``MAX_DRAWS``) they hold out ``min_gaps`` gaps: the squared errors (C, N), kinds (N,)
    and gap ids (N,; apart between the draws). One draw is enough where its held-out gaps
    take ``ENOUGH_WINDOWS`` distinct windows or more (:func:`windows`): many independent events,
    not one window of many markers (``min_gaps=0``: exactly ``draws``). The extra draws for
    ``min_gaps`` leave the ``INTERIOR`` candidates (``tucker_tnn``, the costliest) out; where
    they are drawn, they run on beside the next draws and are scored at the end (:func:`settle`)."""
    pool, pending = [first], []
    enough = min_gaps > 0 and windows(V, first[2]) >= ENOUGH_WINDOWS
    while not enough and (len(pool) < draws or (len(pool) < MAX_DRAWS and sum(
            int(p[2].unique().numel()) for p in pool) < min_gaps)):
        skip = INTERIOR if len(pool) >= draws else ()            # an extra draw: cheap ones
        scores, running = draw(fits, names, seen, V, generator, skip, behind=INTERIOR)
        pool.append(scores)
        pending.append((scores[0], running))
    for err2, running in pending:           # the costly fits ran on beside the later draws
        settle(fits, err2, running)
    return (torch.cat([p[0] for p in pool], dim=1), torch.cat([p[1] for p in pool]),
            torch.cat([p[2] + i * seen.numel() for i, p in enumerate(pool)]))
