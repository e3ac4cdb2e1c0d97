"""Factorized tensors as ``nn.Module``s, shared by closed-form and autograd solvers.

As in TensorLy-Torch, one class holds the structure and registers its tensors either as
``nn.Parameter`` (``learn=True``: autograd fits) or as buffers (closed-form solvers update them
in place under ``torch.no_grad()``). ``forward()`` returns the full tensor.
"""
from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from .. import ops


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

    @property
    def core(self) -> torch.Tensor:
        return self.core_tensor

    @core.setter
    def core(self, value: torch.Tensor) -> None:
        self._put("core_tensor", value)

    @property
    def rank(self) -> tuple[int, ...]:
        return tuple(self.core.shape)

    def forward(self) -> torch.Tensor:
        return ops.tucker_to_tensor(self.core, self.factors)


class CPTensor(_Factorized):
    """``sum_r w_r a_r(1) o a_r(2) o a_r(3)``: weights (R,), factors ``A(n)`` (I_n x R)."""

    def __init__(self, weights: torch.Tensor, factors: Sequence[torch.Tensor], *, learn: bool = False):
        super().__init__(learn)
        self.weights = weights
        self.factors = factors

    @property
    def weights(self) -> torch.Tensor:
        return self.weight_vector

    @weights.setter
    def weights(self, value: torch.Tensor) -> None:
        self._put("weight_vector", value)

    @property
    def rank(self) -> tuple[int, ...]:
        return (int(self.weights.shape[0]),)

    def forward(self) -> torch.Tensor:
        return ops.cp_to_tensor(self.weights, self.factors)
