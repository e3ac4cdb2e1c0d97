"""The common contract every registered method must meet (DESIGN.md, "A solver").

Parametrized over ``torchfill.methods()``, so a solver that registers later is covered
automatically. Each method runs on a small smooth low-rank motion (120 frames x 8 markers, a few
gaps) with cheap hyperparameters from ``CHEAP`` (the contract, not the accuracy, is tested here).
"""
from __future__ import annotations

import functools
import inspect
import math
import warnings

import numpy as np
import pytest
import torch
from torch import nn

import torchfill
from torchfill.solvers import get_solver
from torchfill.solvers.base import Param, Solver

T, J = 120, 8


def motion(seed: int = 0) -> np.ndarray:
    """Smooth rank-4 motion in mm around a per-marker offset, (T, J, 3)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / 60.0
    basis = np.stack([np.sin(2 * np.pi * 0.9 * t), np.cos(2 * np.pi * 0.9 * t),
                      np.sin(2 * np.pi * 1.8 * t + 0.3), t], axis=1)
    B = rng.normal(0.0, 60.0, size=(4, J, 3))
    return np.einsum("tk,kjc->tjc", basis, B) + rng.normal(0.0, 300.0, size=(1, J, 3))


def gap_mask() -> np.ndarray:
    mask = np.zeros((T, J), dtype=bool)
    mask[20:35, 1] = mask[50:58, 1] = True
    mask[60:80, 4] = True
    mask[90:100, 6] = True
    mask[0:6, 7] = True                                  # a gap at the start
    mask[112:, 2] = True                                 # and one at the end
    return mask


TRUTH = motion()
MASK = gap_mask()
GAPPY = np.where(MASK[..., None], np.nan, TRUTH)

#: Cheap hyperparameters per method (contract checks only, not accuracy). A method not listed
#: runs with ``DEFAULT_CHEAP``; ``max_iter`` is dropped for methods that do not declare it.
DEFAULT_CHEAP = {"max_iter": 3}
CHEAP = {
    "linear": {}, "spline": {}, "pchip": {},
    "trnn": {"max_iter": 3, "inner_iter": 5},
    "trnn_d2": {"max_iter": 3, "inner_iter": 5},
    "pca_blackout": {},                                  # no training data: the complete frames
    "grad_tucker": {"max_iter": 3, "rank": [3, 3, 3]},
    "grad_cp": {"max_iter": 3, "rank": 3},
    "auto": {"candidates": ["pchip", "svt", "pca_train"]},
}


#: Data besides X and mask that ``fit`` takes (a solver's ``fit_data``).
FIT_DATA = {"pca_train": {"training": [motion(seed=1)]}}   # a separate complete training recording


def cheap(method: str) -> dict:
    params = dict(CHEAP.get(method, DEFAULT_CHEAP))
    declared = get_solver(method).declared_params()
    return {k: v for k, v in params.items() if k in declared}


def make(method: str, **extra) -> Solver:
    return get_solver(method, **{**cheap(method), **extra})


@functools.lru_cache(maxsize=None)
def fitted(method: str, kind: str):
    """One fit per (method, input kind), shared by the tests below."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if kind == "float64":
            solver = make(method)
            return solver, solver.fit_transform(torch.from_numpy(GAPPY), **FIT_DATA.get(method, {}))
        if kind == "float32":
            solver = make(method)
            return solver, solver.fit_transform(torch.from_numpy(GAPPY).float(),
                                                **FIT_DATA.get(method, {}))
        if kind == "masked":
            # garbage at the masked samples: the solver must never see it
            X = torch.from_numpy(np.where(MASK[..., None], 1e6, TRUTH))
            solver = make(method)
            return solver, solver.fit_transform(X, torch.from_numpy(MASK), **FIT_DATA.get(method, {}))
        if kind == "fill_ndarray":
            return None, torchfill.fill(GAPPY.copy(), method=method, constraints=False,
                                        **cheap(method), **FIT_DATA.get(method, {}))
        if kind == "complete":
            solver = make(method)
            return solver, solver.fit_transform(torch.from_numpy(TRUTH), **FIT_DATA.get(method, {}))
    raise AssertionError(kind)


METHODS = torchfill.methods()
OBSERVED = torch.from_numpy(~MASK)


def assert_observed_kept(out: torch.Tensor, X: torch.Tensor) -> None:
    keep = OBSERVED.to(out.device)
    assert torch.equal(out[keep], X.to(out.device)[keep]), "observed samples changed"


def test_registry_is_not_empty():
    assert {"linear", "spline", "pchip"} <= set(METHODS)


@pytest.mark.parametrize("method", METHODS)
def test_solver_is_module_with_declared_keyword_params(method):
    solver = get_solver(method)
    assert isinstance(solver, nn.Module) and isinstance(solver, Solver)
    assert solver.name == method
    params = solver.get_params()
    assert set(params) == set(type(solver).declared_params())
    assert {"max_iter", "tol", "seed"} <= set(params)
    signature = inspect.signature(type(solver))           # help() and IDEs show the hyperparameters
    assert list(signature.parameters) == list(type(solver).declared_params())
    doc = type(solver).__doc__
    assert doc.count("\nParameters\n----------\n") == 1
    for key, spec in type(solver).declared_params().items():
        assert isinstance(spec, Param)
        assert spec.doc, f"{method}.{key} has no doc"
        assert signature.parameters[key].kind is inspect.Parameter.KEYWORD_ONLY
        assert signature.parameters[key].default == spec.default
        assert f"\n{key} : " in doc, f"{method}.{key} missing from the generated Parameters"
    with pytest.raises(TypeError):
        type(solver)(3)                                  # keyword-only


@pytest.mark.parametrize("method", METHODS)
def test_fit_transform_float64(method):
    solver, out = fitted(method, "float64")
    X = torch.from_numpy(GAPPY)
    assert isinstance(out, torch.Tensor)
    assert out.shape == X.shape and out.dtype == torch.float64 and out.device == X.device
    assert_observed_kept(out, X)
    assert bool(torch.isfinite(out).all()), "NaN or inf left in the filled gaps"
    # the state is there
    assert isinstance(solver.history_, list) and len(solver.history_) == solver.n_iter_
    assert 1 <= solver.n_iter_ <= solver.max_iter
    for entry in solver.history_:
        assert isinstance(entry, dict) and "iter" in entry
        assert all(isinstance(v, (int, float)) for v in entry.values()), entry   # no tensors
    est = solver.forward()
    assert est.shape == X.shape and bool(torch.isfinite(est).all())


@pytest.mark.parametrize("method", METHODS)
def test_fit_transform_float32(method):
    _, out = fitted(method, "float32")
    X = torch.from_numpy(GAPPY).float()
    assert out.dtype == torch.float32 and out.shape == X.shape
    assert_observed_kept(out, X)
    assert bool(torch.isfinite(out).all())


@pytest.mark.parametrize("method", METHODS)
def test_mask_argument_hides_values_and_seed_reproduces(method):
    """``mask`` True = missing even where X is finite; with the same seed the result is the
    same as with NaN there, bit for bit (so the solver never looked at the masked values)."""
    _, out = fitted(method, "masked")
    _, ref = fitted(method, "float64")
    assert bool((out[torch.from_numpy(MASK)].abs() < 1e5).all()), "a masked value leaked"
    assert torch.equal(out, ref)


@pytest.mark.parametrize("method", METHODS)
def test_fill_ndarray_in_ndarray_out(method):
    _, out = fitted(method, "fill_ndarray")
    single = get_solver(method).fill_dtype == torch.float32
    _, ref = fitted(method, "float32" if single else "float64")    # fill() computes in fill_dtype
    assert isinstance(out, np.ndarray) and out.dtype == np.float64 and out.shape == GAPPY.shape
    np.testing.assert_array_equal(out[~MASK], TRUTH[~MASK])
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out[MASK], ref.double().numpy()[MASK])   # = the solver, same seed


@pytest.mark.parametrize("method", METHODS)
def test_all_observed_returned_unchanged(method):
    _, out = fitted(method, "complete")
    assert torch.equal(out, torch.from_numpy(TRUTH))
    X = torch.from_numpy(TRUTH).float()
    assert torch.equal(torchfill.fill(X, method=method, **cheap(method)), X)


@pytest.mark.parametrize("method", METHODS)
def test_step_is_one_update(method):
    solver = make(method)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solver.initialize(torch.from_numpy(GAPPY), **FIT_DATA.get(method, {}))
        assert solver.n_iter_ == 0 and solver.history_ == []
        info = solver.step()
    assert isinstance(info, dict)
    assert not any(math.isnan(float(v)) for v in info.values()), info   # inf delta is fine
    assert solver.forward().shape == GAPPY.shape


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
@pytest.mark.parametrize("method", METHODS)
def test_device_follows_input(method):
    X = torch.from_numpy(GAPPY).cuda()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = make(method).fit_transform(X, **FIT_DATA.get(method, {}))
    assert out.device == X.device and out.dtype == X.dtype
    assert_observed_kept(out, X)
    assert bool(torch.isfinite(out).all())


# -- hyperparameter validation -------------------------------------------------------------------
def _bad_value(spec: Param):
    """A value ``spec`` must reject, or None if none is obvious."""
    types = spec.types if isinstance(spec.types, tuple) else (spec.types,)
    numeric = float in types or int in types
    if spec.choices is not None:
        return "__not_a_choice__"
    if bool in types:
        return "yes"
    if numeric and spec.low is not None:
        return spec.low - 1 if int in types and float not in types else spec.low - 1.5
    if numeric and spec.high is not None:
        return spec.high + 1
    return object()                                      # wrong type for anything else


CASES = [(m, k) for m in METHODS for k in get_solver(m).declared_params()]


@pytest.mark.parametrize("method,param", CASES, ids=[f"{m}-{k}" for m, k in CASES])
def test_invalid_hyperparameter_says_expected_and_found(method, param):
    spec = type(get_solver(method)).declared_params()[param]
    bad = _bad_value(spec)
    with pytest.raises(ValueError) as err:
        get_solver(method, **{param: bad})
    text = str(err.value)
    assert param in text and "expected" in text and "found" in text, text
    assert "\n" not in text


@pytest.mark.parametrize("method", METHODS)
def test_unknown_hyperparameter_rejected(method):
    with pytest.raises(ValueError, match="unknown hyperparameter"):
        get_solver(method, not_a_param=1)
    with pytest.raises(ValueError, match="unknown hyperparameter"):
        torchfill.fill(GAPPY, method=method, not_a_param=1)


def test_public_face_exports_and_not_converged_warning():
    assert torchfill.Solver is Solver and torchfill.get_solver("tucker").name == "tucker"
    assert issubclass(torchfill.NotConvergedWarning, UserWarning)
    with pytest.warns(torchfill.NotConvergedWarning, match="max_iter=2"):
        get_solver("svt", max_iter=2).fit(torch.from_numpy(GAPPY))
    with warnings.catch_warnings():
        warnings.simplefilter("error", torchfill.NotConvergedWarning)
        get_solver("linear").fit(torch.from_numpy(GAPPY))          # one-shot: converged
