"""Results kept for inputs seen again, by a fingerprint of the inputs' bytes: the one cache of
the package (every :class:`Memo` is forgotten at once by :func:`clear_all`, between the windows
of a long recording).

``auto`` fits several candidates on one recording and one mask, and some of them compute the
same pieces from the same data (the Gløersen fill inside ``pma`` and as ``pca_gloersen``, the PMA
rigidity score, the filtered reference tracks of ``li``, ``lgrnn`` and ``pma``): a :class:`Memo`
makes the repeat a lookup of the very same result. Only CPU inputs are kept (hashing a GPU tensor
would copy it to the host); a result larger than the memo's byte budget is computed and not kept.
Callers treat a returned result as read-only.
"""
from __future__ import annotations

import hashlib
import threading
import weakref
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import numpy as np
import torch


def fingerprint(*parts: Any) -> bytes | None:
    """A digest of ``parts`` (tensors and arrays by dtype, shape and bytes; anything else by its
    ``repr``), or None when a tensor is not on the CPU."""
    h = hashlib.blake2b(digest_size=20)
    for p in parts:
        if isinstance(p, torch.Tensor):
            if p.device.type != "cpu":
                return None
            h.update(repr((str(p.dtype), tuple(p.shape))).encode())
            p = p.detach().resolve_conj().resolve_neg().contiguous().reshape(-1)
            h.update(p.view(torch.uint8).numpy().data)          # any dtype, bfloat16 too
        elif isinstance(p, np.ndarray):
            h.update(repr((p.dtype.str, p.shape)).encode())
            h.update(np.ascontiguousarray(p).view(np.uint8).reshape(-1).data)
        else:
            h.update(repr(p).encode())
        h.update(b"|")
    return h.digest()


def _nbytes(value: Any) -> int:
    if isinstance(value, torch.Tensor):
        return value.element_size() * value.nelement()
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, (tuple, list)):
        return sum(_nbytes(v) for v in value)
    return 0


class Memo:
    """The last ``entries`` results of one function, at most ``max_bytes`` of tensors and arrays
    in all; thread-safe (two threads may both compute a missing entry: the same result)."""

    def __init__(self, entries: int, max_bytes: int = 64 << 20) -> None:
        _ALL.add(self)
        self.entries, self.max_bytes = entries, max_bytes
        self._kept: OrderedDict[bytes, tuple[Any, int]] = OrderedDict()
        self._bytes = 0                                  # the kept results' size in all
        self._lock = threading.Lock()

    def __call__(self, compute: Callable[[], Any], *parts: Any) -> Any:
        """``compute()``, or the result kept for the same ``parts``."""
        return self.keyed(fingerprint(*parts), compute)

    def keyed(self, key: bytes | None, compute: Callable[[], Any]) -> Any:
        """``compute()``, or the result kept under ``key`` (a caller's own fingerprint; None:
        not kept)."""
        if key is None:
            return compute()
        with self._lock:
            hit = self._kept.get(key)
            if hit is not None:
                self._kept.move_to_end(key)
                return hit[0]
        value = compute()
        size = _nbytes(value)
        if size <= self.max_bytes:
            with self._lock:
                if key not in self._kept:
                    self._kept[key] = (value, size)
                    self._bytes += size
                while len(self._kept) > self.entries or self._bytes > self.max_bytes:
                    self._bytes -= self._kept.popitem(last=False)[1][1]
        return value

    def clear(self) -> None:
        with self._lock:
            self._kept.clear()
            self._bytes = 0


_ALL: "weakref.WeakSet[Memo]" = weakref.WeakSet()


def clear_all() -> None:
    """Forget every :class:`Memo`'s results (a long recording's next window is other data)."""
    for memo in list(_ALL):
        memo.clear()
