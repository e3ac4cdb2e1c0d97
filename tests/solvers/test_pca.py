"""PCA gap filling with a training set (Li et al. 2020): exact recovery on synthetic low-rank data,
training-set errors, observed samples kept, and a real cross-recording fill."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import torchfill
from torchfill import gaps, metrics
from torchfill.solvers import get_solver
from torchfill.solvers.pca import _KEPT, edge_weights, explained_rank, temporal_estimate

J = 12


def _rel(out, truth, mask) -> float:
    mask = torch.as_tensor(mask)
    return float((out - truth)[mask].norm() / truth[mask].norm())


def spatial_data(r: int = 5, seed: int = 0):
    """Frames in one r-dimensional affine subspace of R^{3J} (equal variance per direction)."""
    g = torch.Generator().manual_seed(seed)
    U = torch.linalg.qr(torch.randn(3 * J, r, generator=g, dtype=torch.float64))[0]
    mean = 500 * torch.randn(3 * J, generator=g, dtype=torch.float64)

    def draw(n):
        return (mean + 80 * torch.randn(n, r, generator=g, dtype=torch.float64) @ U.T).reshape(n, J, 3)

    return draw


def temporal_data(T: int = 200, r: int = 6, seed: int = 0):
    """Trajectories (columns) in one r-dimensional subspace of R^T, plus a constant offset."""
    g = torch.Generator().manual_seed(seed)
    V = torch.linalg.qr(torch.randn(T, r, generator=g, dtype=torch.float64))[0]

    def draw():
        C = 300 * torch.randn(r, 3 * J, generator=g, dtype=torch.float64)
        offset = 1000 * torch.randn(1, 3 * J, generator=g, dtype=torch.float64)
        return (V @ C + offset).reshape(T, J, 3)

    return draw


@pytest.mark.parametrize("centre", [True, False])
def test_pca_train_exact_on_subspace(centre):
    draw = spatial_data()
    X = draw(200)
    mask = gaps.evenly_spaced(200, J, n_gaps=5, gap_length=60, seed=3)
    Xg = X.clone()
    Xg[torch.as_tensor(mask)] = float("nan")
    out = get_solver("pca_train", centre=centre).fit_transform(Xg, training=[draw(150), draw(120)])
    assert _rel(out, X, mask) < 1e-6
    assert torch.equal(out[torch.as_tensor(~mask)], X[torch.as_tensor(~mask)])


def test_pca_train_self_training_exact():
    """training=None: the complete frames of the recording itself."""
    X = spatial_data(seed=1)(600)
    mask = np.zeros((600, J), dtype=bool)
    mask[200:400] = gaps.evenly_spaced(200, J, n_gaps=6, gap_length=80, seed=0)
    Xg = X.clone()
    Xg[torch.as_tensor(mask)] = float("nan")
    out = get_solver("pca_train").fit_transform(Xg)
    assert _rel(out, X, mask) < 1e-6


def test_pca_blackout_exact_on_temporal_subspace():
    draw = temporal_data()
    B = draw()
    mask = gaps.blackout(200, J, gap_length=60, seed=0)
    Bg = B.clone()
    Bg[torch.as_tensor(mask)] = float("nan")
    training = [draw() for _ in range(3)]
    for edge in (1.0, None):
        for prior in (True, False):
            out = get_solver("pca_blackout", edge_scale=edge,
                             prior=prior).fit_transform(Bg, training=training)
            assert _rel(out, B, mask) < 1e-6


def test_pca_blackout_with_partial_gaps_exact():
    """Partial gaps are filled first (spatial step, Eq. 4), then the blackout (Eq. 16): exact on
    data low-rank in both time (r=6) and space (q=5)."""
    g = torch.Generator().manual_seed(5)
    V = torch.linalg.qr(torch.randn(200, 6, generator=g, dtype=torch.float64))[0]
    W = torch.linalg.qr(torch.randn(3 * J, 5, generator=g, dtype=torch.float64))[0]

    def draw():
        return (V @ (300 * torch.randn(6, 5, generator=g, dtype=torch.float64)) @ W.T).reshape(200, J, 3)

    B = draw()
    mask = gaps.blackout(200, J, gap_length=30, seed=1)
    mask[20:24, 3] = mask[150:170, 5] = True
    Bg = B.clone()
    Bg[torch.as_tensor(mask)] = float("nan")
    out = get_solver("pca_blackout").fit_transform(Bg, training=[draw() for _ in range(4)])
    assert torch.equal(out[torch.as_tensor(~mask)], B[torch.as_tensor(~mask)])
    assert _rel(out, B, mask) < 1e-6


def test_pca_train_horizontal_exact_on_temporal_subspace():
    draw = temporal_data(seed=2)
    B = draw()
    mask = np.zeros((200, J), dtype=bool)
    mask[60:100, 2] = mask[120:150, 7] = True
    Bg = B.clone()
    Bg[torch.as_tensor(mask)] = float("nan")
    out = get_solver("pca_train", layout="horizontal",
                     window=200).fit_transform(Bg, training=[draw() for _ in range(2)])
    assert _rel(out, B, mask) < 1e-6


def test_too_few_complete_training_frames():
    draw = spatial_data()
    X = draw(100)
    X[10:30, 0] = float("nan")
    train = draw(50)
    train[5:, 4] = float("nan")                            # only 5 complete frames remain
    with pytest.raises(ValueError, match="5 complete frames"):
        get_solver("pca_train").fit(X, training=[train])
    with pytest.raises(ValueError, match="complete frames"):
        bad = X.clone()
        bad[::2, 1] = bad[1::2, 2] = float("nan")          # no complete frame in the recording
        get_solver("pca_train").fit(bad)


def test_blackout_needs_long_enough_stretches():
    draw = temporal_data()
    B = draw()
    B[80:100] = float("nan")
    with pytest.raises(ValueError, match="at least 200 frames.*longest found has 150"):
        get_solver("pca_blackout").fit(B, training=[draw()[:150]])


def test_training_marker_mismatch():
    draw = spatial_data()
    X = draw(100)
    X[10:30, 0] = float("nan")
    with pytest.raises(ValueError, match=r"training\[1\] expected shape \(T, 12, 3\).*found \(80, 11, 3\)"):
        get_solver("pca_train").fit(X, training=[draw(80), draw(80)[:, :11]])


def test_training_hyperparameter_is_deprecated_but_still_used():
    with pytest.raises(ValueError, match="training expected list or tuple"), \
            pytest.warns(DeprecationWarning):
        get_solver("pca_train", training="walk.c3d")
    draw = spatial_data()
    X = draw(100)
    X[10:30, 0] = float("nan")
    train = [draw(150)]
    with pytest.warns(DeprecationWarning, match="fit"):
        old = get_solver("pca_train", training=train).fit_transform(X)
    assert torch.equal(old, get_solver("pca_train").fit_transform(X, training=train))
    with pytest.raises(ValueError, match="unexpected data"):
        get_solver("tucker").fit(X, training=train)


def test_eigenspace_cached_across_fills():
    draw = spatial_data(seed=4)
    training = [draw(300)]
    _KEPT.clear()
    for seed in range(3):
        X = draw(100)
        X[torch.as_tensor(gaps.evenly_spaced(100, J, n_gaps=3, gap_length=30, seed=seed))] = float("nan")
        torchfill.fill(X.numpy(), method="pca_train", training=training)
    assert len(_KEPT._kept) == 1                    # one training set: one spatial eigenspace


def test_explained_rank_and_weights():
    lam = torch.tensor([50.0, 30.0, 15.0, 4.0, 1.0, 0.0], dtype=torch.float64)
    assert explained_rank(lam, 0.95) == 3
    assert explained_rank(lam, 0.99) == 4
    assert explained_rank(lam, 1.0) == 5
    w = edge_weights(torch.tensor([False, False, True, True, False]), 1.0)
    assert w[2] == w[3] == 1.0 and w[1] == w[4] and w[0] < w[1] < 1.0


def test_weighted_estimate_interpolates_observed_subspace():
    """Eq. 16 with any positive W is exact when the observed rows determine the coefficients."""
    g = torch.Generator().manual_seed(0)
    V = torch.linalg.qr(torch.randn(30, 4, generator=g, dtype=torch.float64))[0]
    Y = V @ torch.randn(4, 5, generator=g, dtype=torch.float64)
    obs = torch.ones(30, dtype=torch.bool)
    obs[10:18] = False
    out = temporal_estimate(V, torch.where(obs[:, None], Y, 0), obs, torch.rand(30, generator=g,
                                                                               dtype=torch.float64) + 0.1)
    assert torch.allclose(out, Y, atol=1e-10)


def test_real_recordings_beat_linear(recording):
    """A 200-frame segment of one HDM05 actor filled from another actor's recording + a CMU one,
    and from the rest of its own recording."""
    test = torchfill.read(recording("hdm05_mm_01-02_03_120.c3d"))
    labels = test.short_labels()
    training = []
    for name in ("HDM_bd_01-02_01_120.c3d", "cmu_135_02.c3d"):
        seq = torchfill.read(recording(name))
        training.append(seq.points[::2, [seq.short_labels().index(lab) for lab in labels]])
    X = test.points[2000:2200]
    mask = gaps.evenly_spaced(200, X.shape[1], n_gaps=5, gap_length=50, seed=0)
    Xg = X.copy()
    Xg[mask] = np.nan
    lin = metrics.gap_error(torchfill.fill(Xg, method="linear"), X, mask)
    out = torchfill.fill(Xg, method="pca_train", training=training)
    err = metrics.gap_error(out, X, mask)
    assert np.array_equal(out[~mask], X[~mask])
    assert err < lin, (err, lin)                           # measured: 65.6 vs 82.6 mm
    # the paper's long-sequence scenario: the rest of the same recording as training
    own = [test.points[:1900:2], test.points[2300::2]]
    err_own = metrics.gap_error(torchfill.fill(Xg, method="pca_train", training=own), X, mask)
    assert err_own < 0.25 * lin, (err_own, lin)            # measured: about 10 vs 82.6 mm


def test_self_share_uses_own_complete_frames():
    """self_share=1 learns from the recording's own complete frames only (exact here, though the
    training set comes from another subspace); self_share=0 from the training set only."""
    X = spatial_data(seed=6)(300)
    wrong = spatial_data(seed=7)(300)
    mask = np.zeros((300, J), dtype=bool)
    mask[100:200] = gaps.evenly_spaced(100, J, n_gaps=4, gap_length=30, seed=0)
    Xg = X.clone()
    Xg[torch.as_tensor(mask)] = float("nan")
    own = get_solver("pca_train", self_share=1.0).fit_transform(Xg, training=[wrong])
    other = get_solver("pca_train", self_share=0.0).fit_transform(Xg, training=[wrong])
    assert _rel(own, X, mask) < 1e-6
    assert _rel(other, X, mask) > 1e-2
