"""Building blocks shared by the solvers, one home each (see DESIGN.md).

* :mod:`.tensor` -- unfoldings, mode products, Tucker/CP reconstructions, Khatri-Rao, MTTKRP, HOSVD,
  a floor for divisions that holds in every dtype;
* :mod:`.spectral` -- singular value thresholding, the Gram-matrix SVD, energy rank, soft threshold;
* :mod:`.time` -- interpolation starts, temporal difference operators, run-lengths of masks.

How the work runs (threads, the cache, memory) lives in :mod:`torchfill.runtime`.

Plain functions of torch tensors (device and dtype follow the input); nothing here imports
another torchfill module.
"""
from .spectral import energy_rank, gram_svd, orthonormalize, soft_threshold, svt, thin_side
from .tensor import (clamp_tiny, cp_to_tensor, fold, hosvd, khatri_rao, mode_dot, mttkrp,
                     multi_mode_dot, tucker_to_tensor, unfold)
from .time import (difference, difference_adjoint, difference_gram, interp_linear,
                   interp_relative, runs)

__all__ = ["clamp_tiny", "cp_to_tensor", "difference", "difference_adjoint", "difference_gram",
           "energy_rank", "fold", "gram_svd", "hosvd", "interp_linear", "interp_relative",
           "khatri_rao", "mode_dot", "mttkrp", "multi_mode_dot", "orthonormalize", "runs",
           "soft_threshold", "svt", "thin_side", "tucker_to_tensor", "unfold"]
