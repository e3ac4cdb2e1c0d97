"""The trial-end hold-out: gaps at the trial ends mirrored onto observed samples at the other end."""
import torch

from torchfill.solvers.holdout import mirrored_edge_holdout


def test_edge_gaps_mirrored_onto_observed_ends_only():
    Omega = torch.ones(40, 4, 3, dtype=torch.bool)
    Omega[:6, 0] = False                    # start gap -> held out at the end
    Omega[33:, 1] = False                   # end gap -> held out at the start
    Omega[10:15, 2] = False                 # interior gap: not an edge gap, nothing held out
    Omega[:3, 3] = Omega[37:, 3] = False    # gaps at both ends: the mirror lands on gaps
    V = mirrored_edge_holdout(Omega)
    S = V.all(dim=2)
    assert bool((V <= Omega).all()), "only observed entries may be held out"
    assert S[:, 0].nonzero().flatten().tolist() == list(range(34, 40))
    assert S[:, 1].nonzero().flatten().tolist() == list(range(0, 7))
    assert not bool(S[:, 2].any()) and not bool(S[:, 3].any())


def test_no_edge_gaps_gives_none():
    Omega = torch.ones(40, 2, 3, dtype=torch.bool)
    Omega[10:20, 0] = False
    assert mirrored_edge_holdout(Omega) is None
