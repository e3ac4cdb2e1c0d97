"""The common contract every registered method must meet (DESIGN.md, "A solver").

Parametrized over ``torchfill.methods()``, so a solver that registers later is covered
automatically. Each method runs on a small smooth low-rank motion (120 frames x 8 markers, a few
gaps) with cheap hyperparameters from ``CHEAP`` (the contract, not the accuracy, is tested here).
"""
from __future__ import annotations

import copy
import functools
import io
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
                                        params=cheap(method), **FIT_DATA.get(method, {}))
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
    assert "seed" in params
    assert ({"max_iter", "tol"} <= set(params)) == type(solver).iterative    # one-shot: neither
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
    assert torch.equal(torchfill.fill(X, method=method, params=cheap(method)), X)


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
        torchfill.fill(GAPPY, method=method, params={"not_a_param": 1})
    with pytest.raises(ValueError, match="unknown hyperparameter"), \
            pytest.warns(DeprecationWarning, match="params"):
        torchfill.fill(GAPPY, method=method, not_a_param=1)


FILL_ARGS = set(inspect.signature(torchfill.fill).parameters)


@pytest.mark.parametrize("method", METHODS)
def test_fill_never_swallows_a_hyperparameter(method):
    """A name that is both ``fill()``'s argument and the method's hyperparameter is an error
    unless ``params`` says which is meant; a hyperparameter as a keyword argument warns."""
    declared = type(get_solver(method)).declared_params()
    passed_on = {"constraints", "training", "segments"}          # fill() passes these on
    for name in sorted(set(declared) & FILL_ARGS - passed_on):
        value = declared[name].default
        with pytest.raises(ValueError, match=f"{name} is both"):
            torchfill.fill(GAPPY, method=method, **{name: value})
    with pytest.warns(DeprecationWarning, match="params="):
        torchfill.fill(GAPPY, method=method, seed=declared["seed"].default, params=cheap(method),
                       constraints=False, **FIT_DATA.get(method, {}))
    assert inspect.signature(torchfill.fill).parameters["params"].kind is inspect.Parameter.KEYWORD_ONLY


def test_pma_window_goes_where_it_is_meant():
    from torchfill.solvers.pma import _Tits

    seen = []
    original = _Tits._initialize

    def spy(self):
        seen.append(self.window)
        return original(self)

    _Tits._initialize = spy
    try:
        torchfill.fill(GAPPY, "pma", params={"window": 15}, constraints=False)
        torchfill.fill(GAPPY, "pma", params={"window": 15}, window=60, constraints=False)
        with pytest.warns(DeprecationWarning):
            torchfill.fill(GAPPY, "pma", smooth=0.3, constraints=False)
    finally:
        _Tits._initialize = original
    assert seen[:2] == [15, 15] and seen[2] == 9
    with pytest.raises(ValueError, match="window is both"):
        torchfill.fill(GAPPY, "pma", window=15)


@pytest.mark.parametrize("method,old,new", [("tucker_tnn", "lam", "lam_tnn"),
                                            ("pca_train", "variance", "energy"),
                                            ("pca_blackout", "variance", "energy"),
                                            ("cp", "patience", "rank_patience"),
                                            ("spc", "patience", "rank_patience")])
def test_one_name_per_idea_old_names_deprecated(method, old, new):
    with pytest.warns(DeprecationWarning, match=f"{old}.*{new}"):
        solver = get_solver(method, **{old: 0.5 if new != "rank_patience" else 3})
    assert getattr(solver, new) == (0.5 if new != "rank_patience" else 3)
    assert old not in type(solver).declared_params()


def test_public_face_exports_and_not_converged_warning():
    assert torchfill.Solver is Solver and torchfill.get_solver("tucker").name == "tucker"
    assert issubclass(torchfill.NotConvergedWarning, UserWarning)
    with pytest.warns(torchfill.NotConvergedWarning, match="max_iter=2"):
        get_solver("svt", max_iter=2).fit(torch.from_numpy(GAPPY))
    with warnings.catch_warnings():
        warnings.simplefilter("error", torchfill.NotConvergedWarning)
        get_solver("linear").fit(torch.from_numpy(GAPPY))          # one-shot: converged


# -- solvers as modules: buffers, devices and dtypes, state_dict, other data, threads, batches ----
def _fitted_tensors(solver: Solver) -> dict[str, torch.Tensor]:
    """Every tensor the fitted solver holds as a plain attribute (should be none)."""
    found = {}
    for module in solver.modules():
        for key, value in vars(module).items():
            if isinstance(value, torch.Tensor):
                found[key] = value
    return found


@pytest.mark.parametrize("method", METHODS)
def test_fitted_tensors_are_buffers_and_move_with_to(method):
    solver, out = fitted(method, "float64")
    assert _fitted_tensors(solver) == {}, "fitted tensors outside buffers/parameters"
    names = dict(solver.named_buffers())
    assert {"M_", "Omega_", "mu_", "sigma_"} <= set(names)
    moved = copy.deepcopy(solver).to(torch.float32)
    for name, buf in moved.named_buffers():
        assert not buf.is_floating_point() or buf.dtype == torch.float32, name
    for name, par in moved.named_parameters():
        assert par.dtype == torch.float32, name
    est = moved.forward()
    assert est.dtype == torch.float32
    torch.testing.assert_close(est.double(), solver.forward(), rtol=1e-4, atol=1e-2)


@pytest.mark.parametrize("method", METHODS)
def test_transform_after_a_dtype_move_fills_the_fitted_data(method):
    """``s.fit_transform(x); s.to(torch.float64); s.transform(x)``: the fit stays usable (the
    observed samples are compared at the precision the fit was made in)."""
    for kind, dtype in (("float32", torch.float64), ("float64", torch.float32)):
        solver, out = fitted(method, kind)
        X = torch.from_numpy(GAPPY).to(out.dtype)
        moved = copy.deepcopy(solver).to(dtype)
        again = moved.transform(X)
        assert again.dtype == X.dtype
        assert_observed_kept(again, X)
        torch.testing.assert_close(again.double(), out.double(), rtol=1e-4, atol=1e-2)


@pytest.mark.parametrize("method", ["pchip", "svt", "grad_tucker", "grad_cp"])
def test_data_that_require_grad_are_refused_with_one_line(method):
    """No fill is differentiable with respect to its data (the gradient variants differentiate
    their own factors): a tensor that requires grad is refused, not silently detached."""
    X = torch.from_numpy(GAPPY).requires_grad_()
    with pytest.raises(ValueError, match="require grad.*X.detach") as err:
        make(method).fit(X)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("method", METHODS)
def test_state_dict_loads_into_a_fresh_solver_and_transform_agrees(method):
    solver, out = fitted(method, "float64")
    buf = io.BytesIO()
    torch.save(solver.state_dict(), buf)
    buf.seek(0)
    state = torch.load(buf, weights_only=True)                      # no pickle needed
    fresh = get_solver(method, **solver.get_params())
    fresh.load_state_dict(state)
    X = torch.from_numpy(GAPPY)
    assert torch.equal(fresh.transform(X), out)
    assert fresh.n_iter_ == solver.n_iter_ and fresh.history_ == solver.history_


@pytest.mark.parametrize("method", METHODS)
def test_transform_on_other_data_raises_clearly(method):
    solver, _ = fitted(method, "float64")
    X = torch.from_numpy(GAPPY)
    with pytest.raises(ValueError, match="fitted on.*found shape"):
        solver.transform(X[:1])                                     # one frame, not the fitted 120
    other = X.clone()
    other[~torch.from_numpy(MASK)] += 10.0
    with pytest.raises(ValueError, match="other data"):
        solver.transform(other)
    with pytest.raises(RuntimeError, match="not fitted"):
        make(method).transform(X)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16], ids=["float16", "bfloat16"])
@pytest.mark.parametrize("method", METHODS)
def test_half_precision_in_caller_dtype_out(method, dtype):
    """float16/bfloat16 data are computed in float32; the fill comes back in the caller's dtype,
    observed samples bit for bit, every gap filled close to the float32 fill."""
    X = torch.from_numpy(GAPPY).to(dtype)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = make(method).fit_transform(X, **FIT_DATA.get(method, {}))
        filled = torchfill.fill(X, method=method, constraints=False, params=cheap(method),
                                **FIT_DATA.get(method, {}))
        ref = make(method).fit_transform(X.float(), **FIT_DATA.get(method, {}))
    for result in (out, filled):
        assert result.dtype == dtype and result.shape == X.shape
        assert_observed_kept(result, X)
        assert bool(torch.isfinite(result).all()), "a gap left NaN in half precision"
    scale = float(torch.nan_to_num(X.float()).abs().max())
    assert float((out.float() - ref).abs().max()) <= 0.02 * scale


@pytest.mark.parametrize("method", METHODS)
def test_batch_of_sequences_in_one_call(method):
    B = 3
    masks = np.stack([np.roll(MASK, 7 * b, axis=0) for b in range(B)])
    truths = np.stack([motion(seed=b) for b in range(B)])
    X = torch.from_numpy(np.where(masks[..., None], np.nan, truths))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solver = make(method)
        out = solver.fit_transform(X, **FIT_DATA.get(method, {}))
        one = make(method).fit_transform(X[1], **FIT_DATA.get(method, {}))
    assert out.shape == X.shape and out.dtype == X.dtype
    keep = torch.from_numpy(~masks)
    assert torch.equal(out[keep], X[keep]) and bool(torch.isfinite(out).all())
    assert torch.equal(out[1], one)                                 # = the sequence on its own
    fresh = get_solver(method, **solver.get_params())
    fresh.load_state_dict(solver.state_dict())
    assert torch.equal(fresh.transform(X), out)


def test_fill_takes_a_batch_of_eight_sequences():
    B = 8
    masks = np.stack([np.roll(MASK, 5 * b, axis=0) for b in range(B)])
    X = np.where(masks[..., None], np.nan, np.stack([motion(seed=b) for b in range(B)]))
    out = torchfill.fill(X, "svt", constraints=False)
    assert out.shape == X.shape and np.isfinite(out).all()
    np.testing.assert_array_equal(out[~masks], X[~masks])
    np.testing.assert_array_equal(out[3], torchfill.fill(X[3], "svt", constraints=False))
    T32 = torch.from_numpy(X).float()
    out32 = torchfill.fill(T32, "linear", mask=torch.zeros(masks.shape, dtype=torch.bool))
    assert out32.dtype == torch.float32 and out32.shape == T32.shape


def test_one_solver_from_two_threads_gives_each_its_own_fill():
    """fit_transform holds the solver's lock: two threads sharing one solver each get the fill of
    their own data (without it one got the other's estimate, or crashed mid-fit)."""
    import threading

    data = [torch.from_numpy(np.where(MASK[..., None], np.nan, motion(seed=s))) for s in (0, 3)]
    refs = [get_solver("svt", max_iter=30).fit_transform(x) for x in data]
    solver = get_solver("svt", max_iter=30)
    results, errors = {}, []

    def run(k):
        try:
            for _ in range(3):
                results[k] = solver.fit_transform(data[k])
                assert torch.equal(results[k], refs[k])
        except Exception as err:                                  # noqa: BLE001 - reported below
            errors.append(err)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        threads = [threading.Thread(target=run, args=(k,)) for k in (0, 1)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert errors == []


def test_state_dict_round_trip_in_a_fresh_process(tmp_path):
    """A fitted solver saved here loads into a fresh solver in a new Python process, whose
    transform gives the same fill bit for bit."""
    import subprocess
    import sys

    X = torch.from_numpy(GAPPY)
    for method, params in (("tucker_tnn", {"max_iter": 20}), ("grad_cp", cheap("grad_cp"))):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            solver = get_solver(method, **params)
            out = solver.fit_transform(X)
        torch.save({"state": solver.state_dict(), "X": X, "out": out}, tmp_path / f"{method}.pt")
        code = (
            "import sys, torch, torchfill\n"
            f"saved = torch.load({str(tmp_path / (method + '.pt'))!r}, weights_only=True)\n"
            f"fresh = torchfill.get_solver({method!r}, **{params!r})\n"
            "fresh.load_state_dict(saved['state'])\n"
            "sys.exit(0 if torch.equal(fresh.transform(saved['X']), saved['out']) else 3)\n")
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-2000:]


def test_cli_param_goes_to_the_method_not_to_fill(tmp_path, monkeypatch):
    """``-p window=15`` with pma sets pma's window; ``--window`` stays fill()'s."""
    from torchfill.cli import main

    src = tmp_path / "gappy.npy"
    np.save(src, GAPPY)
    calls = []
    real = torchfill.fill

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(torchfill, "fill", spy)
    code = main(["fill", str(src), "-o", str(tmp_path / "out.npy"), "-m", "pma", "-p", "window=15",
                 "--window", "0", "--no-constraints", "-q"])
    assert code == 0
    options = calls[0]["options"]                        # the CLI passes its FillOptions
    assert options.params == {"window": 15} and options.window is None


@pytest.mark.parametrize("method", METHODS)
def test_max_iter_is_declared_only_where_it_caps_the_loop(method):
    """A one-shot method (:class:`OneShotSolver`: one ``step()`` makes its fill) declares no
    ``max_iter`` or ``tol``; a method that declares ``max_iter`` iterates up to it: with the
    stopping rule off (``tol=0``) a fit capped at two iterations takes two."""
    from torchfill.solvers.base import OneShotSolver

    cls = type(get_solver(method))
    declared = cls.declared_params()
    if issubclass(cls, OneShotSolver):
        assert "max_iter" not in declared and "tol" not in declared and cls.max_iter == 1
        assert fitted(method, "float64")[0].n_iter_ == 1
        return
    assert "max_iter" in declared and cls.iterative
    extra = {"tol": 0.0} if "tol" in declared else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solver = make(method, max_iter=2, **extra).fit(torch.from_numpy(GAPPY),
                                                       **FIT_DATA.get(method, {}))
    assert solver.n_iter_ == 2
