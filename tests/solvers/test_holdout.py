"""The one hold-out component (solvers/holdout.py) and the one vocabulary of its hyperparameters."""
import math
import warnings

import pytest
import torch

from torchfill import gaps
from torchfill.solvers import get_solver
from torchfill.solvers.holdout import HoldOut, select_holdout


def _omega(T=300, J=8, seed=0):
    mask = gaps.multi_gap(T, J, n_markers=4, gap_length=25, max_gaps=2, seed=seed)
    return torch.from_numpy(~mask)[..., None].expand(T, J, 3).clone()


def test_holdout_hides_scores_keeps_the_best_and_gives_the_data_back():
    Omega = _omega()
    V = select_holdout("shifted_gaps", Omega, torch.Generator().manual_seed(0), share=0.2)
    h = HoldOut(Omega, V, min_gain=0.1)
    assert h.active and torch.equal(h.fit_mask, Omega & ~V) and not bool((V & ~Omega).any())
    M = torch.randn(Omega.shape, dtype=torch.float64)
    E = torch.zeros_like(M)
    E[V] = 2.0
    assert math.isclose(h.rmse(M + E, M), 2.0)          # the error on the hidden entries only
    assert h.offer(1.0, lambda: "a", 1) and not h.offer(0.95, lambda: "b", 2)   # gain < 10 %
    assert h.offer(0.5, lambda: "c", 3) and h.n_bad == 0 and h.best_iter == 3
    assert h.release() == "c" and not h.active and torch.equal(h.fit_mask, Omega)


@pytest.mark.parametrize("kind", ["shifted_gaps", "segments", "runs"])
def test_every_kind_holds_out_observed_entries_only(kind):
    Omega = _omega()
    V = select_holdout(kind, Omega, torch.Generator().manual_seed(1), share=0.1)
    assert V is not None and bool(V.any()) and not bool((V & ~Omega).any())
    assert select_holdout(None, Omega, torch.Generator(), share=0.1) is None


@pytest.mark.parametrize("method, old, new", [
    ("tucker", {"rank_max": 7}, {"max_rank": 7}),
    ("tucker", {"selection": "last"}, {"holdout": None}),
    ("tucker", {"val_segments": 3, "val_length": 9}, {"holdout_segments": 3, "holdout_length": 9}),
    ("cp", {"rank_max": 5, "holdout": False}, {"max_rank": 5, "holdout": None}),
    ("smooth_cp", {"holdout": True}, {"holdout": "shifted_gaps"}),
    ("grad_tucker", {"holdout": 0.05}, {"holdout": "runs", "holdout_share": 0.05}),
    ("grad_cp", {"holdout": 0.0}, {"holdout": None}),
])
def test_old_spellings_warn_and_mean_the_new_ones(method, old, new):
    with pytest.warns(DeprecationWarning):
        solver = get_solver(method, **old)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert solver.get_params() == get_solver(method, **new).get_params()
    renamed = type(solver)._merged("renamed")
    for key in set(old) & set(renamed):              # reading an old name warns too
        with pytest.warns(DeprecationWarning):
            assert getattr(solver, key) == getattr(solver, renamed[key])


def test_old_fitted_attribute_names_warn():
    X = torch.randn(40, 5, 3, dtype=torch.float64)
    X[5:12, 1] = float("nan")
    solver = get_solver("cp", max_rank=3, max_iter=20).fit(X)
    with pytest.warns(DeprecationWarning):
        assert solver.cp_ is solver.decomposition_
    with pytest.raises(AttributeError):
        solver.no_such_attribute_
