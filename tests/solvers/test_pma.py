"""Gløersen PCA and the Tits et al. (2018) models: exact where their model holds, and better than
the originals where those fail (no never-missing marker, markers mostly absent)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

import torchfill
from torchfill import metrics
from torchfill.solvers.pma import (local_frame, space_constraint, symfilter, to_global, to_local,
                                   window_median)

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"


def rotation(t: np.ndarray) -> np.ndarray:
    """Smooth rotations (T, 3, 3) from three sinusoidal Euler angles."""
    a, b, c = 0.8 * np.sin(1.3 * t), 0.5 * np.sin(0.7 * t + 1), 0.6 * np.cos(0.9 * t)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    one, zero = np.ones_like(t), np.zeros_like(t)
    Rz = np.stack([np.stack([ca, -sa, zero], -1), np.stack([sa, ca, zero], -1), np.stack([zero, zero, one], -1)], -2)
    Ry = np.stack([np.stack([cb, zero, sb], -1), np.stack([zero, one, zero], -1), np.stack([-sb, zero, cb], -1)], -2)
    Rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, cc, -sc], -1), np.stack([zero, sc, cc], -1)], -2)
    return Rz @ Ry @ Rx


def rigid_body(T: int = 240, J: int = 8, seed: int = 0) -> np.ndarray:
    """One rigid body (markers +-150 mm apart) rotating and translating smoothly, (T, J, 3) mm."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / 60.0
    body = rng.normal(0.0, 150.0, size=(J, 3))
    shift = np.stack([400 * np.sin(0.5 * t), 300 * np.cos(0.4 * t), 900 + 50 * t], -1)
    return np.einsum("tik,jk->tji", rotation(t), body) + shift[:, None] + 1000.0


def gaps(T: int, J: int) -> np.ndarray:
    mask = np.zeros((T, J), dtype=bool)
    mask[40:90, 0] = True
    mask[150:200, 0] = True
    mask[100:160, 3] = True
    mask[0:20, 5] = True                                   # at the start
    mask[220:, 6] = True                                   # at the end
    return mask


RIGID = rigid_body()
MASK = gaps(*RIGID.shape[:2])


def fill(method: str, X: np.ndarray, **params) -> np.ndarray:
    return torchfill.fill(np.where(MASK[..., None], np.nan, X) if X.shape[:2] == MASK.shape else X,
                          method=method, constraints=False, **params)   # the method's own fill


@pytest.mark.parametrize("method", ["glr", "li", "lpr", "lgrnn", "pma"])
def test_exact_on_a_rigid_body(method):
    """On one rigid body a marker's local coordinates are constant (LI, LPR, LGRNN exact) and an
    affine combination of four other markers (GLR exact); the average and the distance ranges
    then change nothing (PMA exact). Filtering off: a median of rotating points is not rigid."""
    out = fill(method, RIGID, filtering=False)
    err = np.abs(out - RIGID)[MASK].max()
    assert err < 1e-6, f"{method}: max error {err:.3g} mm on a rigid body"


def test_glr_exact_on_a_linear_marker_relation():
    """A marker that is a fixed affine combination of the others (not rigid) is recovered by GLR."""
    rng = np.random.default_rng(3)
    t = np.arange(300) / 60.0
    X = np.stack([np.sin(f * t + p) for f, p in rng.uniform(0.3, 3.0, (7 * 3, 2))], -1).reshape(300, 7, 3) * 200
    X = X + rng.normal(0, 500, (1, 7, 3))
    coef = rng.normal(0, 0.4, 7)
    coef += (1 - coef.sum()) / 7                     # affine: moves with the body
    target = np.einsum("j,tjc->tc", coef, X)[:, None] + 40.0
    P = np.concatenate([target, X], axis=1)                                 # marker 0 is linear
    mask = np.zeros(P.shape[:2], dtype=bool)
    mask[60:160, 0] = True
    out = torchfill.fill(np.where(mask[..., None], np.nan, P), method="glr", filtering=False,
                         constraints=False)
    assert np.abs(out - P)[mask].max() < 1e-4                      # mm; SVD cut-off 1e-10


def test_pca_gloersen_recovers_low_rank_motion():
    """Federolf's map (Eq. 1, gapped marker weighted 0.02) is an approximation, not a projection:
    not exact even on rank-4 motion, but far closer than interpolation over 70-frame gaps."""
    rng = np.random.default_rng(1)
    t = np.arange(300) / 60.0
    B = np.stack([np.sin(2 * np.pi * 0.9 * t), np.cos(2 * np.pi * 0.9 * t),
                  np.sin(2 * np.pi * 1.8 * t + 0.3), t], 1)
    X = np.einsum("tk,kjc->tjc", B, rng.normal(0, 60, (4, 10, 3))) + rng.normal(0, 300, (1, 10, 3))
    mask = np.zeros((300, 10), dtype=bool)
    mask[50:120, 0] = mask[150:220, 3] = True
    gappy = np.where(mask[..., None], np.nan, X)
    ours = metrics.rmse_missing(torchfill.fill(gappy, method="pca_gloersen", constraints=False), X, mask)
    base = metrics.rmse_missing(torchfill.fill(gappy, method="linear", constraints=False), X, mask)
    assert ours < 0.3 * base, f"{ours:.1f} mm vs linear {base:.1f} mm"


def test_local_frame_round_trip_and_space_constraint():
    P = torch.from_numpy(RIGID)
    R = local_frame(P[:, 1], P[:, 2], P[:, 4])
    assert torch.allclose(R.transpose(1, 2) @ R, torch.eye(3, dtype=R.dtype).expand_as(R), atol=1e-12)
    L = to_local(P[:, 0], P[:, 1], R)
    assert torch.allclose(to_global(L, P[:, 1], R), P[:, 0], atol=1e-9)
    assert torch.allclose(L, L[:1].expand_as(L), atol=1e-9)                # rigid: constant
    # a point pushed away is brought back into each distance range
    Q = P[:, 0] + 500.0
    refs = [P[:, 1], P[:, 2], P[:, 4]]
    ranges = [(d.min(), d.max()) for d in (torch.linalg.vector_norm(P[:, 0] - r, dim=-1) for r in refs)]
    out = space_constraint(Q, refs, ranges, rounds=50)
    d = torch.linalg.vector_norm(out - refs[0], dim=-1)
    assert bool((d <= ranges[0][1] + 1e-6).all())


def test_symfilter_keeps_nan_and_constant():
    X = torch.ones(50, 2, dtype=torch.float64)
    X[10:15, 0] = float("nan")
    Y = symfilter(X, 9)
    assert torch.equal(torch.isnan(Y), torch.isnan(X))
    assert torch.allclose(Y[~torch.isnan(Y)], torch.ones(1, dtype=torch.float64))
    ramp = torch.arange(30, dtype=torch.float64)[:, None]
    assert torch.allclose(symfilter(ramp, 9), ramp)                        # symmetric: no delay


@pytest.mark.parametrize("T", [3, 6, 8, 200])
def test_symfilter_of_complete_columns_is_the_gapped_columns_filter_bit_for_bit(T):
    """Complete columns take a shorter route (windows shrunk at the ends only): the same bits as
    beside a gapped column, which takes the general one."""
    g = torch.Generator().manual_seed(1)
    X = torch.randn(T, 4, generator=g, dtype=torch.float64).cumsum(0)
    gapped = torch.cat([X, X[:, :1].clone()], 1)
    gapped[T // 2, -1] = float("nan")
    assert torch.equal(symfilter(X, 9), symfilter(gapped, 9)[:, :4])


def test_density_is_the_gaussian_kernel_mean_bit_for_bit():
    """The density skips libm's slow underflow path where the kernel is exactly 0 and computes it
    where it is not (37 to 39 bandwidths away): the bits of the plain formula."""
    from torchfill.solvers.pma import Density
    g = torch.Generator().manual_seed(2)
    s = 100 + 10 * torch.randn(300, generator=g, dtype=torch.float64)
    density = Density(s)
    u = density.u
    x = torch.cat([100 + 30 * torch.randn(500, generator=g, dtype=torch.float64),
                   s[:50] + u * torch.linspace(36, 40, 50, dtype=torch.float64),   # the band
                   s[:50] - u * torch.linspace(36, 40, 50, dtype=torch.float64),
                   torch.tensor([1e4], dtype=torch.float64)])                      # far: 0
    plain = torch.exp(-0.5 * ((x[:, None] - s[None]) / u) ** 2).mean(1) / (u * (2 * torch.pi) ** 0.5)
    assert bool((plain[500:] > 0).any()) and bool((plain == 0).any())
    assert torch.equal(density(x), plain)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_window_median_is_the_windows_median_bit_for_bit(dtype):
    g = torch.Generator().manual_seed(0)
    for T, C in ((1, 1), (7, 3), (200, 5)):
        for P in (torch.randn(T + 8, C, generator=g, dtype=dtype),
                  torch.randint(0, 3, (T + 8, C), generator=g).to(dtype)):      # ties
            want = P.unfold(0, 9, 1).median(-1).values
            assert torch.equal(window_median(P, 4), want)
            assert torch.equal(window_median(P.T.contiguous().T, 4), want)   # a transposed layout
    P = torch.randn(20, 2, generator=g, dtype=dtype)
    assert torch.equal(window_median(P, 3), P.unfold(0, 7, 1).median(-1).values)


def _real(name: str, a: int, b: int) -> np.ndarray:
    path = DATA / f"{name}.c3d"
    if not path.exists():
        pytest.skip(f"{path} not available")
    P = torchfill.read(path).points[a:b]
    if np.isnan(P).any():
        pytest.skip("window has real gaps")
    return P


def _dense_mask(P: np.ndarray, seed: int) -> np.ndarray:
    """Every marker gets a 40-80-frame gap together with its 2 nearest neighbours."""
    T, J, _ = P.shape
    D = np.linalg.norm(P[:, :, None] - P[:, None], axis=3).mean(0)
    rng = np.random.default_rng(seed)
    mask = np.zeros((T, J), dtype=bool)
    for j in range(J):
        if mask[:, j].any():
            continue
        L = int(rng.integers(40, 81))
        s = int(rng.integers(0, T - L))
        mask[s:s + L, np.argsort(D[j])[:3]] = True
    return mask


@pytest.mark.parametrize("method,share", [("pca_gloersen", 0.8), ("pma", 0.3)])
def test_every_marker_gapped_is_filled(method, share):
    """The originals fill nothing when no marker is complete; these fill it all, PMA far below
    linear (its local frames survive clustered occlusions), Gløersen's R2 only somewhat below
    (a marker's neighbours vanish with it and are dropped; distal gapped markers are dropped)."""
    P = _real("cmu_02_01", 0, 343)
    mask = _dense_mask(P, seed=0)
    assert mask.any(0).all()
    gappy = np.where(mask[..., None], np.nan, P)
    out = torchfill.fill(gappy, method=method, constraints=False)
    lin = torchfill.fill(gappy, method="linear", constraints=False)
    np.testing.assert_array_equal(out[~mask], P[~mask])
    ours, base = metrics.rmse_missing(out, P, mask), metrics.rmse_missing(lin, P, mask)
    assert ours < share * base, f"{method}: {ours:.1f} mm vs linear {base:.1f} mm"


def test_pma_fills_a_mostly_absent_marker():
    """The original drops markers under 30 % presence (returned empty); here they are filled."""
    P = _real("cmu_02_01", 0, 343)
    mask = np.zeros(P.shape[:2], dtype=bool)
    mask[40:320, 5] = True                                                   # 18 % present
    gappy = np.where(mask[..., None], np.nan, P)
    out = torchfill.fill(gappy, method="pma", constraints=False)
    lin = torchfill.fill(gappy, method="linear", constraints=False)
    assert np.isfinite(out).all()
    assert metrics.rmse_missing(out, P, mask) < 0.5 * metrics.rmse_missing(lin, P, mask)


def test_kept_pieces_give_the_bits_of_a_fresh_fill():
    """pca_gloersen, li and lgrnn then pma on one recording (pma reuses the Gløersen fill, the
    rigidity score, the filtered tracks and the local frames kept from the first fits) equals pma
    computed afresh."""
    from torchfill.solvers import gloersen, pma
    X = rigid_body(T=240, J=8)
    mask = gaps(240, 8)
    given = np.where(mask[..., None], np.nan, X)
    torchfill.fill(given, method="pca_gloersen", constraints=False)
    torchfill.fill(given, method="li", constraints=False)
    torchfill.fill(given, method="lgrnn", constraints=False)
    warm = torchfill.fill(given, method="pma", constraints=False)
    for memo in (gloersen._KEPT, pma._KEPT_SCORE, pma._KEPT_TRACK, pma._KEPT_FRAME):
        memo.clear()
    fresh = torchfill.fill(given, method="pma", constraints=False)
    assert np.array_equal(warm, fresh)


def test_space_constraint_stops_only_when_a_round_moves_nothing():
    """Stopping early gives the bits of all five rounds."""
    from torchfill.solvers.pma import space_constraint
    g = torch.Generator().manual_seed(3)
    P = torch.randn(50, 3, generator=g, dtype=torch.float64)
    refs = [torch.randn(50, 3, generator=g, dtype=torch.float64) * 0.3 for _ in range(3)]
    ranges = [(torch.tensor(0.8, dtype=torch.float64), torch.tensor(1.2, dtype=torch.float64))] * 3

    def five_rounds(P):
        for _ in range(5):
            for Q, (r, R) in zip(reversed(refs), reversed(ranges)):
                v = P - Q
                d = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
                t = d.clamp(min=r, max=R)
                P = torch.where((d > 0) & (t != d), Q + v / d.clamp(min=1e-300) * t, P)
        return P
    assert torch.equal(space_constraint(P, refs, ranges), five_rounds(P))
    inside = refs[0] + torch.nn.functional.normalize(P - refs[0], dim=-1)
    one = [refs[0]], [ranges[0]]
    assert torch.equal(space_constraint(inside, *one), inside)      # nothing to move


def test_lstsq_is_the_minimum_norm_solution_on_collinear_predictors():
    from torchfill.solvers.pma import lstsq
    g = torch.Generator().manual_seed(0)
    B = torch.randn(200, 5, generator=g, dtype=torch.float64)
    A = torch.cat([torch.ones(200, 1, dtype=torch.float64), B @ torch.randn(5, 30, generator=g,
                                                                           dtype=torch.float64)], 1)
    y = torch.randn(200, 3, generator=g, dtype=torch.float64)
    ref = torch.linalg.pinv(A, rtol=1e-10) @ y
    assert torch.allclose(lstsq(A, y), ref, atol=1e-10)
    assert torch.allclose(lstsq(A[:4], y[:4]), torch.linalg.pinv(A[:4], rtol=1e-10) @ y[:4],
                          atol=1e-10)                      # fewer rows than predictors


@pytest.mark.skipif(not (DATA / "hdm05_bd_05-01_01_120.c3d").exists(), reason="needs ../shared/data")
@pytest.mark.parametrize("method", ["pca_gloersen", "pma"])
def test_float32_data_fit_as_float64(method):
    """A float32 tensor (an ML user's) fits as float64 does. The Gram matrix's eigh ran in
    float32 and failed to converge on this recording (5920 frames; its first 4448 at one
    thread), and ``auto`` dropped pma and pca_gloersen without a word; pma's model weights fell
    below float32's range (a 1e-200 floor that is 0 there), 0 / 0 put NaN into the next marker's
    regression and MKL's gelsd raised."""
    from torchfill import gaps as sim
    from torchfill.solvers import get_solver
    P = torchfill.read(DATA / "hdm05_bd_05-01_01_120.c3d").points
    P = P[:, np.isfinite(P).all(axis=(0, 2))]
    mask = sim.multi_gap(*P.shape[:2], n_markers=20, gap_length=150, seed=0)
    X = torch.from_numpy(np.where(mask[..., None], np.nan, P))
    out = {dt: get_solver(method).fit_transform(X.to(dt), torch.from_numpy(mask)).double()
           for dt in (torch.float32, torch.float64)}
    e32, e64 = (metrics.rmse_missing(out[dt].numpy(), P, mask) for dt in out)
    assert e32 <= 1.05 * e64 + 0.1, (e32, e64)
