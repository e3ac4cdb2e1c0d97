"""Factorized tensors as ``nn.Module``s, shared by closed-form and autograd solvers.

As in TensorLy-Torch, one class holds the structure and registers its tensors either as
``nn.Parameter`` (``learn=True``: autograd fits) or as buffers (closed-form solvers update them
in place under ``torch.no_grad()``). ``forward()`` returns the full tensor.
"""
from __future__ import annotations

import warnings
from collections.abc import Sequence

import torch
from torch import nn

from .. import ops


def _stored(attr: str, doc: str) -> property:
    """A tensor held as ``attr`` (a parameter or a buffer, see :meth:`_Factorized._put`)."""
    return property(lambda self: getattr(self, attr), lambda self, v: self._put(attr, v), doc=doc)


class _Factorized(nn.Module):
    def __init__(self, learn: bool) -> None:
        super().__init__()
        self.learn = learn

    def _put(self, name: str, value: torch.Tensor) -> None:
        if self.learn:
            setattr(self, name, nn.Parameter(value))
        elif name in self._buffers:
            self._buffers[name] = value
        else:
            self.register_buffer(name, value)

    @classmethod
    def empty(cls) -> "_Factorized":
        """A structure with no tensors yet, to ``load_state_dict`` a fitted one into."""
        obj = cls.__new__(cls)
        _Factorized.__init__(obj, learn=False)
        obj.n_modes = 0
        return obj

    def _load_from_state_dict(self, state_dict, prefix, local_metadata, strict, missing_keys,
                              unexpected_keys, error_msgs) -> None:
        """An :meth:`empty` structure takes its tensors' shapes from the saved state first (as
        buffers: a loaded fit is for ``forward()``; refit to learn again)."""
        for key, value in state_dict.items():
            name = key[len(prefix):]
            if (key.startswith(prefix) and "." not in name
                    and name not in self._buffers and name not in self._parameters):
                self._put(name, torch.empty_like(value))
        self.n_modes = max(self.n_modes, sum(1 for k in self._parameters if k.startswith("factor_"))
                           + sum(1 for k in self._buffers if k.startswith("factor_")))
        super()._load_from_state_dict(state_dict, prefix, local_metadata, strict, missing_keys,
                                      unexpected_keys, error_msgs)

    @property
    def factors(self) -> list[torch.Tensor]:
        return [getattr(self, f"factor_{n}") for n in range(self.n_modes)]

    @factors.setter
    def factors(self, values: Sequence[torch.Tensor]) -> None:
        self.n_modes = len(values)
        for n, A in enumerate(values):
            self._put(f"factor_{n}", A)

    @property
    def rank(self) -> tuple[int, ...]:
        raise NotImplementedError


class TuckerTensor(_Factorized):
    """``G x_1 A(1) x_2 A(2) x_3 A(3)``: core ``core`` (R1 x R2 x R3), factors ``A(n)`` (I_n x R_n)."""

    def __init__(self, core: torch.Tensor, factors: Sequence[torch.Tensor], *, learn: bool = False):
        super().__init__(learn)
        self.core = core
        self.factors = factors

    core = _stored("core_tensor", "the core G (R1 x R2 x R3)")

    @classmethod
    def from_tensor(cls, X: torch.Tensor, rank: Sequence[int], *, learn: bool = False) -> "TuckerTensor":
        """The truncated HOSVD of a full tensor ``X`` (e.g. the interpolation-filled data)."""
        G, A = ops.hosvd(X, rank)
        if learn:
            G, A = G.detach().clone(), [a.detach().clone() for a in A]
        return cls(G, A, learn=learn)

    @property
    def rank(self) -> tuple[int, ...]:
        return tuple(self.core.shape)

    def forward(self) -> torch.Tensor:
        return ops.tucker_to_tensor(self.core, self.factors)

    def to_tensorly(self):
        """TensorLy's ``TuckerTensor`` of the same core and factors (detached, sharing memory):
        ``tl.tucker_to_tensor`` of it is :meth:`forward`'s tensor."""
        from tensorly.tucker_tensor import TuckerTensor as TLTucker
        return TLTucker((self.core.detach(), [A.detach() for A in self.factors]))


class CPTensor(_Factorized):
    """``sum_r w_r a_r(1) o a_r(2) o a_r(3)``: weights (R,), factors ``A(n)`` (I_n x R)."""

    def __init__(self, weights: torch.Tensor, factors: Sequence[torch.Tensor], *, learn: bool = False):
        super().__init__(learn)
        self.weights = weights
        self.factors = factors

    weights = _stored("weight_vector", "the weights w (R,)")

    @classmethod
    def from_tensor(cls, X: torch.Tensor, rank: int, *, seed: int = 0, n_iter: int = 50,
                    learn: bool = False) -> "CPTensor":
        """A CP-ALS fit of a full tensor ``X`` (TensorLy ``parafac``: SVD init, ``n_iter`` sweeps,
        normalized factors). TensorLy's SVD init pads ``R > I_n`` with random columns but breaks
        when ``prod(other dims) < R <= I_n``: a random init is used there."""
        import tensorly as tl
        from tensorly.decomposition import parafac

        if not bool((X != 0).any()):         # nothing to fit (constant data): zero weights
            gen = torch.Generator(device="cpu").manual_seed(seed)
            A = [torch.randn(I, rank, generator=gen, dtype=X.dtype).to(X.device) for I in X.shape]
            A = [a / torch.linalg.vector_norm(a, dim=0) for a in A]
            return cls(X.new_zeros(rank), A, learn=learn)
        broken = any(X.numel() // I < rank <= I for I in X.shape)
        with tl.backend_context("pytorch"), warnings.catch_warnings():
            warnings.simplefilter("ignore")   # SVD init pads R > I_n with random columns
            try:
                w, A = parafac(X, rank=rank, init="random" if broken else "svd", n_iter_max=n_iter,
                               tol=1e-8, normalize_factors=True, random_state=seed)
            except torch.linalg.LinAlgError:  # a rank-deficient X (ALS normal equations singular)
                w, A = parafac(X, rank=rank, init="random", n_iter_max=n_iter, tol=1e-8,
                               normalize_factors=True, random_state=seed)
        return cls(w.detach().clone(), [a.detach().clone() for a in A], learn=learn)

    @property
    def rank(self) -> tuple[int, ...]:
        return (int(self.weights.shape[0]),)

    def forward(self) -> torch.Tensor:
        return ops.cp_to_tensor(self.weights, self.factors)

    def to_tensorly(self):
        """TensorLy's ``CPTensor`` of the same weights and factors (detached, sharing memory):
        ``tl.cp_to_tensor`` of it is :meth:`forward`'s tensor."""
        from tensorly.cp_tensor import CPTensor as TLCP
        return TLCP((self.weights.detach(), [A.detach() for A in self.factors]))
