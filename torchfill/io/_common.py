"""Helpers shared by the readers and writers: atomic writes, the filled-sample rule, checks."""
from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

from . import FileFormatError
from ..sequence import MarkerSequence


def atomic_write(path: Path, write: Callable) -> None:
    """Call ``write(handle)`` on a temporary file in ``path``'s folder, then rename it to ``path``.

    Nothing is left behind on error: the temporary file is removed and ``path`` is untouched.
    Where the system allows (Linux ``O_TMPFILE``) the data is written to a file with no name,
    which is linked under a temporary name only once complete and renamed at once, so even a
    SIGKILL during the write leaves nothing. An existing ``path`` without write permission is
    refused (it would be silently replaced otherwise). An ``OSError`` becomes a one-line
    :class:`FileFormatError`.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise FileFormatError(f"{path}: cannot write, folder {folder} does not exist")
    refuse_read_only(path)
    try:
        fd, tmp = _unnamed(folder), None
    except OSError:
        fd = None
    try:
        if fd is None:
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    except OSError as err:
        raise FileFormatError(f"{path}: cannot write ({err.strerror or err})") from None
    try:
        with os.fdopen(fd, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
            os.chmod(handle.fileno(), _mode_for(path))
            if tmp is None:
                tmp = _link(handle.fileno(), folder, path.name)
        os.replace(tmp, path)
    except BaseException as err:
        try:
            if tmp is not None:
                os.unlink(tmp)
        except OSError:
            pass
        if isinstance(err, OSError):
            raise FileFormatError(f"{path}: cannot write ({err.strerror or err})") from None
        raise


def refuse_read_only(path: Path) -> None:
    """``FileFormatError`` if ``path`` exists without write permission (a rename would replace
    it silently)."""
    if path.exists() and not (path.stat().st_mode & 0o222 and os.access(path, os.W_OK)):
        raise FileFormatError(f"{path}: cannot write, the file is read-only")


def _unnamed(folder: Path) -> int:
    """A file descriptor of a new file with no name in ``folder`` (``OSError`` if unsupported)."""
    if not hasattr(os, "O_TMPFILE") or _linkat() is None:
        raise OSError("O_TMPFILE unsupported")
    return os.open(folder, os.O_TMPFILE | os.O_WRONLY, 0o600)


def _linkat():
    """libc ``linkat`` (os.link cannot pass AT_SYMLINK_FOLLOW for /proc/self/fd links), or None."""
    global _LINKAT
    if _LINKAT is False:
        try:
            import ctypes
            _LINKAT = ctypes.CDLL(None, use_errno=True).linkat
        except (OSError, AttributeError, ImportError):
            _LINKAT = None
    return _LINKAT


_LINKAT = False


def _link(fd: int, folder: Path, name: str) -> str:
    """Give the unnamed file ``fd`` a temporary name in ``folder``; returns that name."""
    for _ in range(100):
        tmp = os.path.join(folder, f".{name}.{os.urandom(4).hex()}.tmp")
        import ctypes
        if _linkat()(-100, f"/proc/self/fd/{fd}".encode(), -100, os.fsencode(tmp), 0x400) == 0:
            return tmp                            # AT_FDCWD = -100, AT_SYMLINK_FOLLOW = 0x400
        errno = ctypes.get_errno()
        if errno != 17:                           # EEXIST: try another name
            raise OSError(errno, os.strerror(errno))
    raise FileExistsError(f"no free temporary name for {name}")


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


def storable_labels(labels: list[str], store: Callable[[str, int], str], reads: Callable,
                    path: Path) -> list[str]:
    """Labels as a fresh file of some format will hold them.

    ``store(label, j)`` is what the writer puts in the file, ``reads(stored)`` the labels a reader
    gets back. One warning names every label that does not come back unchanged, and duplicates
    (kept: they are stored as they are, but markers are then known by position only).
    """
    stored = [store(label, j) for j, label in enumerate(labels)]
    back = reads(stored)
    changed = [f"{a!r} -> {b!r}" for a, b in zip(labels, back) if a != b]
    seen, dups = set(), []
    for label in labels:
        if label in seen and label not in dups:
            dups.append(label)
        seen.add(label)
    parts = []
    if changed:
        parts.append(f"{len(changed)} label(s) changed to fit {path.suffix}: "
                     + ", ".join(changed[:10]) + (" ..." if len(changed) > 10 else ""))
    if dups:
        parts.append(f"duplicate label(s) {', '.join(map(repr, dups[:10]))}")
    if parts:
        warnings.warn(f"{path.name}: " + "; ".join(parts), stacklevel=4)
    return stored
