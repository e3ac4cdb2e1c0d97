"""Cases as data: recordings with simulated gaps, served to a solver through a LightningDataModule.

A case is (recording x gap-protocol grid point x seed). Only markers observed in every frame of the
recording count as ground truth (the others are dropped and reported). The DataModule keeps the truth
to itself for evaluation; what it serves as a batch holds only the incomplete tensor (NaN where
missing) and the gap mask, so no solver ever receives the truth of the missing entries.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader, Dataset

from .. import gaps
from ..sequence import MarkerSequence


@dataclass
class Recording:
    """A recording reduced to its complete markers: the ground truth of every simulated case."""

    name: str
    truth: np.ndarray                 # (T, J, 3), finite everywhere
    labels: list[str]                 # short labels of the kept markers
    dropped: list[str] = field(default_factory=list)   # markers with a missing frame
    rate: float = 100.0
    units: str = "mm"

    @property
    def shape(self) -> tuple[int, int]:
        return self.truth.shape[0], self.truth.shape[1]

    def note(self) -> str:
        T, J = self.shape
        text = f"{self.name}: {T} frames x {J} complete markers, {self.rate:g} Hz, {self.units}"
        if self.dropped:
            text += f" ({len(self.dropped)} dropped for missing frames: {', '.join(self.dropped)})"
        return text


def read_sequence(path: Path, projection: str | None = None) -> MarkerSequence:
    """The recording at ``path``, through ``torchfill.read``; ``projection="side_view"`` gives its
    2-D side view (:func:`torchfill.projection.side_view`)."""
    from .. import io
    from ..projection import side_view

    seq = io.read(path)
    return side_view(seq) if projection == "side_view" else seq


@functools.lru_cache(maxsize=16)
def load_recording(path: Path, frames: tuple[int, int] | None = None,
                   projection: str | None = None) -> Recording:
    """Read ``path`` and keep the markers observed in every frame (of ``frames``, if given)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: recording not found")
    seq = read_sequence(path, projection)
    points = seq.points if frames is None else seq.points[frames[0]:frames[1]]
    complete = np.isfinite(points).all(axis=(0, 2))
    labels = seq.short_labels()
    if not complete.any():
        raise ValueError(f"{path}: no marker is observed in every frame; nothing to use as truth")
    return Recording(name=path.name, truth=np.ascontiguousarray(points[:, complete]),
                     labels=[l for l, c in zip(labels, complete) if c],
                     dropped=[l for l, c in zip(labels, complete) if not c], rate=seq.rate,
                     units=seq.units)


def segment_starts(T: int, length: int, count: int) -> list[int]:
    """First frames of ``count`` test segments of ``length`` frames spread evenly over ``T`` frames
    (Li et al. 2020 cut test segments from longer recordings); fewer when they would coincide."""
    if T < length:
        return []
    if T == length:
        return [0]
    return sorted(set(np.linspace(0, T - length, count + 2)[1:-1].round().astype(int).tolist()))


def cut_segment(rec: Recording, length: int, count: int, index: int) -> tuple[Recording, list]:
    """Test segment ``index`` of ``rec`` and the rest of the recording (a list of the complete
    stretches before and after it: the self-training set, which never overlaps the segment)."""
    starts = segment_starts(rec.shape[0], length, count)
    if index >= len(starts):
        raise ValueError(f"{rec.name}: {rec.shape[0]} frames hold {len(starts)} distinct segments "
                         f"of {length} frames, not {index + 1}")
    s0 = starts[index]
    seg = Recording(name=rec.name, truth=rec.truth[s0:s0 + length], labels=rec.labels,
                    dropped=rec.dropped, rate=rec.rate, units=rec.units)
    rest = [part for part in (rec.truth[:s0], rec.truth[s0 + length:]) if part.shape[0]]
    return seg, rest


@functools.lru_cache(maxsize=16)
def _read_cached(path: Path, projection: str | None = None) -> MarkerSequence:
    return read_sequence(path, projection)


def align_training(path: Path, labels: list[str], projection: str | None = None) -> np.ndarray:
    """A training recording as ``(T_i, J, D)`` with its markers in the order of ``labels`` (short
    labels of the test recording); a marker it lacks is NaN throughout. A new array every call."""
    seq = _read_cached(Path(path), projection)
    index = {label: j for j, label in enumerate(seq.short_labels())}
    out = np.full((seq.n_frames, len(labels), seq.points.shape[2]), np.nan)
    for j, label in enumerate(labels):
        if label in index:
            out[:, j] = seq.points[:, index[label]]
    return out


def make_mask(protocol: str, shape: tuple[int, int], point: dict, seed: int) -> np.ndarray:
    """The gap mask ``(T, J)`` of one case (True = missing)."""
    T, J = shape
    return gaps.generate(protocol, T, J, **point, seed=seed)


class _Repeat(Dataset):
    """The same observed batch, ``n`` times: one item per solver step."""

    def __init__(self, batch: dict, n: int) -> None:
        self.batch, self.n = batch, n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, index: int) -> dict:
        return self.batch


class CaseDataModule(pl.LightningDataModule):
    """One case: the incomplete tensor and its gap mask for the solver, the truth for evaluation.

    Parameters
    ----------
    truth : array (T, J, 3)
        The complete recording. Kept here; never part of a batch.
    mask : array (T, J) of bool
        True where the simulated gaps are.
    n_steps : int
        How many batches one epoch serves (the solver's ``max_iter``): one per ``training_step``.
    X : tensor (T, J, 3), optional
        The incomplete tensor to serve (NaN at least where ``mask``; its dtype and device are the
        case's), as ``fill_case`` prepared it; default: the truth with NaN where ``mask``.
    """

    def __init__(self, truth, mask, *, n_steps: int = 1, dtype=torch.float64,
                 device: str | torch.device = "cpu", X: torch.Tensor | None = None) -> None:
        super().__init__()
        if X is not None:
            dtype, device = X.dtype, X.device
        truth = torch.as_tensor(np.asarray(truth), dtype=dtype, device=device)
        mask = torch.as_tensor(np.asarray(mask.cpu() if isinstance(mask, torch.Tensor) else mask,
                                          dtype=bool), device=device)
        if truth.ndim != 3 or mask.shape != truth.shape[:2] or (
                X is not None and X.shape != truth.shape):
            raise ValueError(f"expected truth (T, J, 3) and mask (T, J), found "
                             f"{tuple(truth.shape)} and {tuple(mask.shape)}")
        self._truth = truth
        self.mask = mask
        self.X = torch.where(mask[..., None], torch.full_like(truth, torch.nan),
                             truth if X is None else X)
        self.n_steps = int(n_steps)

    def evaluation_truth(self) -> torch.Tensor:
        """The ground truth, for evaluation callbacks only."""
        return self._truth

    def observed_batch(self) -> dict:
        return {"X": self.X, "mask": self.mask}

    def train_dataloader(self) -> DataLoader:
        return DataLoader(_Repeat(self.observed_batch(), self.n_steps), batch_size=None,
                          shuffle=False, num_workers=0)
