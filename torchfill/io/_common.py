"""Helpers shared by the readers and writers: atomic writes, the filled-sample rule, checks."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

from . import FileFormatError
from ..sequence import MarkerSequence


def atomic_write(path: Path, write: Callable) -> None:
    """Call ``write(handle)`` on a temporary file in ``path``'s folder, then rename it to ``path``.

    Nothing is left behind on error: the temporary file is removed and ``path`` is untouched.
    An ``OSError`` becomes a one-line :class:`FileFormatError`.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise FileFormatError(f"{path}: cannot write, folder {folder} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    except OSError as err:
        raise FileFormatError(f"{path}: cannot write ({err.strerror or err})") from None
    try:
        with os.fdopen(fd, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, _mode_for(path))
        os.replace(tmp, path)
    except BaseException as err:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(err, OSError):
            raise FileFormatError(f"{path}: cannot write ({err.strerror or err})") from None
        raise


def _mode_for(path: Path) -> int:
    """Permission bits for a new file: the replaced file's, else 0o666 minus the umask."""
    try:
        return path.stat().st_mode & 0o777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def check_writable(seq, path: Path, dims: tuple[int, ...] = (3,)) -> MarkerSequence:
    """Validate what is about to be written: a MarkerSequence of finite-or-NaN points with a
    coordinate count the format holds (``dims``)."""
    if not isinstance(seq, MarkerSequence):
        raise FileFormatError(f"{path}: expected a MarkerSequence to write, found "
                              f"{type(seq).__name__}")
    if seq.points.shape[2] not in dims:
        raise FileFormatError(f"{path}: this format holds {' or '.join(map(str, dims))}-D points, "
                              f"found {seq.points.shape[2]}-D (write 2-D keypoints as .npy, .npz "
                              "or an OpenPose folder)")
    if np.isinf(seq.points).any():
        raise FileFormatError(f"{path}: cannot write infinite coordinates (use NaN for missing)")
    if seq.n_frames == 0:
        raise FileFormatError(f"{path}: cannot write a recording with no frames")
    return seq


def filled_samples(seq: MarkerSequence, source_valid: np.ndarray, path: Path) -> np.ndarray:
    """The ``(T, J)`` samples a write-back must change.

    ``seq.meta["filled"]`` (set by :func:`torchfill.fill`) when present, else the samples invalid
    in the source and finite in ``seq``; in both cases only samples finite in ``seq``.
    """
    finite = np.isfinite(seq.points).all(axis=2)
    filled = seq.meta.get("filled")
    if filled is None:
        return finite & ~source_valid
    filled = np.asarray(filled, dtype=bool)
    if filled.shape != finite.shape:
        raise FileFormatError(f"{path}: meta['filled'] has shape {filled.shape}, expected "
                              f"{finite.shape} (frames x markers)")
    return filled & finite


def unwritten_edits(seq: MarkerSequence, source_points: np.ndarray, filled: np.ndarray) -> int:
    """How many samples differ from the source outside ``filled`` (these are not written back)."""
    src_ok = np.isfinite(source_points).all(axis=2)
    seq_ok = np.isfinite(seq.points).all(axis=2)
    differ = (src_ok != seq_ok) | (src_ok & seq_ok & (source_points != seq.points).any(axis=2))
    return int((differ & ~filled).sum())


def reject_inf(points: np.ndarray, path: Path) -> None:
    """``FileFormatError`` if any coordinate is +-inf (missing must be NaN)."""
    bad = np.isinf(points)
    if bad.any():
        t = int(np.argwhere(bad)[0][0])
        raise FileFormatError(f"{path}: {int(bad.sum())} infinite value(s), first in frame {t} "
                              f"(missing samples must be NaN or empty)")


def default_labels(n: int) -> list[str]:
    return [f"M{j + 1}" for j in range(n)]
