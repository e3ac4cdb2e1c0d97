"""Markers never observed in a recording placed from the training recordings' local coordinates
(the rigid reconstruction of :func:`torchfill.solvers.rigid.segment_fill`), where its own error
estimate is as small as ``auto`` asks of its rigid candidate."""
from __future__ import annotations

import numpy as np
import torch

from .selection.candidates import PARTIAL
from .rigid import HOLDOUT_LAGS, segment_fill
from .rigid_pairs import body_size
from .session import TRAINING_FRAMES, spread_runs


def place_from_training(P: torch.Tensor, never: torch.Tensor, training: list[torch.Tensor],
                        segments: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(placed, est, std)``: the samples (T, J) of the never-observed markers ``never`` (J,)
    rebuilt in every frame with three or more segment-mates observed, from the local coordinates
    of the recording's observed frames ``P`` (T, J, 3; NaN where not seen) stacked with the
    ``training`` recordings' (aligned to ``P``'s markers), and their estimates (T, J, 3) and
    error std (T, J), on ``P``'s device. ``placed`` is False where the rigid fill's own error
    estimate is above ``auto``'s limit for its rigid candidate (``PARTIAL``)."""
    train = [spread_runs(t, TRAINING_FRAMES // len(training)) for t in training]
    P = P.double().cpu()
    apart = torch.full((HOLDOUT_LAGS[-1], *P.shape[1:]), float("nan"), dtype=P.dtype)
    S = torch.cat([P, apart, *train]).numpy()   # another trial is far in time: its error too
    est, std, _ = segment_fill(S, None, segments)
    T = P.shape[0]
    limit = PARTIAL["rigid"]["max_error"] * body_size(S[:T], np.isfinite(S[:T]).all(axis=2))
    put = np.sqrt(3.0) * np.nan_to_num(std[:T], nan=np.inf) <= limit   # as auto's rigid
    put &= never.cpu().numpy()[None, :]
    device = never.device
    return (torch.from_numpy(put).to(device), torch.from_numpy(est[:T]).to(device),
            torch.from_numpy(std[:T]).to(device))
