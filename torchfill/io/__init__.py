"""Reading and writing recordings: C3D, TRC, plain arrays (.npy, .npz, .csv), OpenPose folders.

``read(path)`` and ``write(seq, path)`` dispatch on the file suffix; a folder (or, to write, a path
without suffix) is an OpenPose output folder of ``*_keypoints.json`` files. Every failure to read or write
raises :class:`FileFormatError`, whose message is one line naming the file and the problem.
"""
from __future__ import annotations

from importlib import import_module
from pathlib import Path

import numpy as np

from ..sequence import MarkerSequence


class FileFormatError(ValueError):
    """A file could not be read or written; the message names the file and the problem."""


def read(path, **kwargs) -> MarkerSequence:
    """Read a recording (.c3d, .trc, .npy, .npz, .csv, OpenPose folder) into a
    :class:`MarkerSequence`."""
    from .outputs import source_stamp

    path = Path(path)
    reader = _pick(path, "read")
    if not path.is_file() and not path.is_dir():
        raise FileFormatError(f"{path}: no such file")
    stamp = source_stamp(path)
    seq = reader(path, **kwargs)
    if isinstance(seq, MarkerSequence) and seq.source is not None and path.is_file():
        seq.meta["source_stamp"] = stamp     # a write-back refuses a source changed since
    return seq


def write(seq: MarkerSequence, path, **kwargs) -> Path:
    """Write ``seq`` to ``path`` atomically (through :class:`torchfill.io.outputs.Outputs`: a
    temporary file beside it, synced, then renamed; a symbolic link there is replaced, not
    followed); returns the path.

    ``seq`` may also be an array of shape ``(T, J, 3)`` (labels M1..MJ, 100 Hz, mm). A C3D or TRC
    written from a sequence read from a file of the same kind keeps that file and changes only the
    filled samples (see :mod:`torchfill.io.c3d`, :mod:`torchfill.io.trc`); it is refused (one
    line, nothing written) when that source file changed on disk since it was read.
    """
    from .outputs import Outputs

    path = Path(path)
    _pick(path, "write")
    if not isinstance(seq, MarkerSequence):
        seq = _wrap(seq, path)
    with Outputs() as out:
        out.write_sequence(seq, path, **kwargs)
    return path


def check_target(path) -> Path:
    """``FileFormatError`` now if ``path`` cannot be written later (type, folder, read-only), so
    a long fill is not wasted on an output that would be refused."""
    path = Path(path)
    _pick(path, "write")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise FileFormatError(f"{path}: cannot write, folder {folder} does not exist")
    from ._common import refuse_read_only
    refuse_read_only(path)
    return path


def _wrap(points, path: Path) -> MarkerSequence:
    """A bare ``(T, J, 3)`` array (NumPy or torch) as a MarkerSequence with default labels."""
    if hasattr(points, "detach"):
        points = points.detach().cpu().numpy()
    try:
        points = np.asarray(points, dtype=np.float64)
        return MarkerSequence(points=points,
                              labels=[f"M{j + 1}" for j in range(points.shape[1])])
    except (ValueError, TypeError, IndexError) as err:
        raise FileFormatError(f"{path}: cannot write {type(points).__name__}: {err}") from None


def _pick(path: Path, verb: str):
    if path.is_dir() or (verb == "write" and not path.suffix):
        return getattr(import_module(".openpose", __name__), verb)
    table = {".c3d": "c3d", ".trc": "trc", ".npy": "arrays", ".npz": "arrays", ".csv": "arrays"}
    module = table.get(path.suffix.lower())
    if module is None:
        raise FileFormatError(f"{path}: unsupported file type {path.suffix!r}; "
                              f"expected one of {', '.join(table)}")
    return getattr(import_module(f".{module}", __name__), verb)


__all__ = ["FileFormatError", "check_target", "read", "write"]
