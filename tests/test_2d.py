"""2-D keypoint tracks (T, J, 2): every registered method fills them, observed samples unchanged,
and the default fill beats linear interpolation on a side-view projection of a real recording."""
from __future__ import annotations

import warnings
import numpy as np
import pytest

import torchfill
from torchfill import gaps, metrics
from torchfill.projection import side_view

T, J = 120, 8
#: Cheap hyperparameters (the contract, not the accuracy, is tested on the synthetic motion).
CHEAP = {"linear": {}, "spline": {}, "pchip": {}, "pca_blackout": {},
         "trnn": {"max_iter": 3, "inner_iter": 5}, "trnn_d2": {"max_iter": 3, "inner_iter": 5},
         "grad_tucker": {"max_iter": 3, "rank": [3, 3, 2]}, "grad_cp": {"max_iter": 3, "rank": 3}}


def motion(seed: int = 0) -> np.ndarray:
    """Smooth rank-4 image motion in pixels around a per-keypoint offset, (T, J, 2)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / 30.0
    basis = np.stack([np.sin(2 * np.pi * 0.9 * t), np.cos(2 * np.pi * 0.9 * t),
                      np.sin(2 * np.pi * 1.8 * t + 0.3), t], axis=1)
    B = rng.normal(0.0, 40.0, size=(4, J, 2))
    return np.einsum("tk,kjc->tjc", basis, B) + rng.normal(500.0, 200.0, size=(1, J, 2))


MASK = np.zeros((T, J), dtype=bool)
MASK[20:35, 1] = MASK[60:80, 4] = MASK[90:100, 6] = MASK[:6, 7] = MASK[112:, 2] = True
XY = motion()
GAPPY = np.where(MASK[..., None], np.nan, XY)


#: Methods that model 3-D bodies: rigid segments, local frames of three markers.
ONLY_3D = {"rigid", "li", "lpr", "lgrnn", "glr", "pma"}


@pytest.mark.parametrize("method", sorted(ONLY_3D & set(torchfill.methods())))
def test_3d_only_methods_refuse_2d_in_one_line(method):
    with pytest.raises(ValueError, match=r"expected 3-D markers \(T, J, 3\), found \(120, 8, 2\)"):
        torchfill.fill(GAPPY, method)


@pytest.mark.parametrize("method", [m for m in torchfill.methods() if m not in ONLY_3D])
def test_every_method_fills_2d_and_keeps_observed(method):
    declared = torchfill.get_solver(method).declared_params()    # one-shot methods: no max_iter
    params = {k: v for k, v in CHEAP.get(method, {"max_iter": 3}).items() if k in declared}
    if method == "pca_train":
        params["training"] = [motion(seed=1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = torchfill.fill(GAPPY, method, **params)
    assert out.shape == XY.shape
    assert np.isfinite(out).all()
    assert np.array_equal(out[~MASK], XY[~MASK])                # bit for bit


def test_2d_sequence_and_tensor_in_same_kind_out():
    import torch

    seq = torchfill.MarkerSequence(points=GAPPY, labels=[f"K{j}" for j in range(XY.shape[1])],
                                   units="px")
    out = torchfill.fill(seq, "linear")
    assert isinstance(out, torchfill.MarkerSequence) and out.points.shape == XY.shape
    assert np.array_equal(out.meta["filled"], MASK)
    tensor = torchfill.fill(torch.from_numpy(GAPPY), "linear")
    assert isinstance(tensor, torch.Tensor) and np.array_equal(tensor.numpy(), out.points)


def test_pca_training_must_match_the_coordinate_count():
    with pytest.raises(ValueError, match=r"\(T, 8, 2\)"):
        torchfill.fill(GAPPY, "pca_train", training=[np.zeros((T, J, 3))])


def test_default_fill_of_a_real_side_view_beats_linear(data_dir):
    """CMU 02_01 (walk) seen from the side: 60-frame gaps on 8 keypoints. The bound (0.5 x linear
    RMSE) is the issue's target; measured 0.19, 0.14, 0.07 x for seeds 0, 1, 2."""
    seq = side_view(torchfill.read(data_dir / "cmu_02_01.c3d"))
    T, J = seq.points.shape[:2]
    mask = gaps.generate("multi_gap", T, J, n_markers=8, gap_length=60, max_gaps=2, seed=0)
    gappy = np.where(mask[..., None], np.nan, seq.points)
    out = torchfill.fill(gappy)
    linear = torchfill.fill(gappy, "linear")
    assert np.array_equal(out[~mask], seq.points[~mask])
    ours, base = (metrics.rmse_missing(x, seq.points, mask) for x in (out, linear))
    assert ours <= 0.5 * base, (ours, base)


def test_rmse_missing_counts_two_coordinates_per_keypoint():
    truth = np.zeros((4, 2, 2))
    filled = truth.copy()
    filled[1, 0] = [3.0, 4.0]                      # one missing keypoint, 2-D error 5
    mask = np.zeros((4, 2), dtype=bool)
    mask[1, 0] = True
    assert metrics.rmse_missing(filled, truth, mask) == pytest.approx(np.sqrt(25 / 2))
    assert metrics.gap_error(filled, truth, mask) == pytest.approx(5.0)


def test_2d_arrays_round_trip_as_npz_and_3d_formats_refuse_them(tmp_path):
    seq = torchfill.MarkerSequence(points=GAPPY, labels=[f"K{j}" for j in range(J)], units="px")
    back = torchfill.read(torchfill.write(seq, tmp_path / "kp.npz"))
    assert np.array_equal(back.points, GAPPY, equal_nan=True) and back.labels == seq.labels
    for name in ("kp.c3d", "kp.trc", "kp.csv"):
        with pytest.raises(torchfill.FileFormatError, match="2-D"):
            torchfill.write(seq, tmp_path / name)
        assert not (tmp_path / name).exists()


def test_experiment_config_serves_side_views(data_dir, tmp_path):
    from pathlib import Path

    from torchfill.lightning.config import load_config
    from torchfill.lightning.data import align_training, load_recording

    cfg = load_config(Path(__file__).resolve().parents[1] / "experiments" / "pca_2d.yaml")
    assert cfg.projection == "side_view"
    rec = load_recording(cfg.recording_path(cfg.recordings[0]), cfg.frames, cfg.projection)
    assert rec.truth.shape == (200, 41, 2)
    train = align_training(cfg.recording_path(cfg.training[0]), rec.labels, cfg.projection)
    assert train.shape[1:] == (41, 2) and np.isfinite(train).all()
    bad = tmp_path / "bad.yaml"
    bad.write_text((Path(cfg.path).read_text()).replace("projection: side_view", "projection: top"))
    with pytest.raises(ValueError, match="projection expected"):
        load_config(bad)


def test_side_view_is_the_projection_on_up_and_the_walking_direction():
    t = np.arange(50.0)
    walk = np.stack([-3.0 * t, 0.5 * t, 1000 + 10 * np.sin(t)], axis=1)     # walks towards -x
    points = walk[:, None, :] + np.array([[0.0, 0, 0], [0, 0, 100], [0, 0, 500]])[None]
    points[5:9, 1] = np.nan
    seq = torchfill.MarkerSequence(points=points, labels=["a", "b", "c"])
    view = side_view(seq)
    u = np.array([-3.0, 0.5, 0.0]) / np.hypot(3.0, 0.5)
    assert view.points.shape == (50, 3, 2)
    assert np.allclose(view.points[..., 1], points[..., 2], equal_nan=True)   # v = up (z)
    assert np.allclose(view.points[:, 0, 0], walk @ u)                        # u = travel, signed
    assert np.isnan(view.points[5:9, 1]).all() and not np.isnan(view.points[9:, 1]).any()
