"""Reuse of the large per-file arrays while a folder renders.

A 9-MP file needs a float32 mosaic (36 MB) and an output image (27-108 MB).
Freshly allocated, every page of them is faulted in and zeroed by the
kernel on first write: in a virtual machine that costs 0.03-0.05 s of CPU per
file, about a tenth of a file's whole render (``perf``: ``clear_page_erms``
7.6 % of an eight-file ``l3 render``). While a pool is active
(:func:`recycling`), :func:`empty` hands out an array a finished file gave
back (:func:`release`) when one of that shape and dtype is free, so pages
are touched once per process rather than once per file.

Only arrays that :func:`empty` lent are taken back, and only by the code
that knows it holds the last reference (the file pipeline, after a file's
render or write). The free arrays are bounded in number (``keep``) and in
bytes (:data:`MAX_FREE_BYTES`), the oldest going first, so a folder of
mixed sizes does not hoard arrays of every size; leaving :func:`recycling`
frees them all. Outside it, :func:`empty` is :func:`numpy.empty`.
"""

from __future__ import annotations

import contextlib
import threading
import weakref
from collections.abc import Iterator

import numpy as np

__all__ = ["MAX_FREE_BYTES", "available_memory", "empty", "recycling", "release"]

#: Most bytes of free arrays a pool holds (a 24-MP folder to 16-bit TIFF
#: keeps 3 mosaics and 3 outputs: 0.72 GB).
MAX_FREE_BYTES = 1 << 30

_lock = threading.RLock()  # re-entrant: a weakref callback may run inside (gc)
_free: list[np.ndarray] | None = None  # oldest first
_lent: dict[int, weakref.ref] = {}  # id -> the lent array (not kept alive)
_keep = 0
_depth = 0


def empty(shape: tuple[int, ...], dtype: np.dtype | type) -> np.ndarray:
    """An uninitialised C-contiguous array: a recycled one when a pool has it."""
    shape = tuple(int(s) for s in shape)
    dtype = np.dtype(dtype)
    with _lock:
        if _free is None:
            return np.empty(shape, dtype=dtype)
        for i in range(len(_free) - 1, -1, -1):  # the most recent match
            if _free[i].shape == shape and _free[i].dtype == dtype:
                arr = _free.pop(i)
                break
        else:
            arr = np.empty(shape, dtype=dtype)
        _lent[id(arr)] = weakref.ref(arr, _forget(id(arr)))
        return arr


def _forget(key: int):
    def gone(ref: weakref.ref) -> None:  # a lent array died without coming back
        with _lock:
            if _lent.get(key) is ref:
                del _lent[key]
    return gone


def release(arr: np.ndarray | None) -> None:
    """Give ``arr`` back for reuse; the caller must hold its last reference.

    Arrays the active pool did not lend (views, other allocations, arrays
    from before the pool) are left alone.
    """
    if arr is None:
        return
    with _lock:
        ref = _lent.get(id(arr))
        if _free is None or ref is None or ref() is not arr:
            return
        del _lent[id(arr)]
        _free.append(arr)
        while _free and (len(_free) > _keep
                         or sum(a.nbytes for a in _free) > MAX_FREE_BYTES):
            _free.pop(0)


@contextlib.contextmanager
def recycling(keep: int = 8) -> Iterator[None]:
    """Activate the pool, holding at most ``keep`` free arrays (nested activations
    share the outer one's)."""
    global _free, _keep, _depth
    with _lock:
        _depth += 1
        if _free is None:
            _free, _keep = [], max(0, int(keep))
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                _free = None
                _lent.clear()


def available_memory() -> int:
    """Bytes of memory this process may still use (psutil's "available", else the
    physical memory)."""
    try:
        import psutil

        return int(psutil.virtual_memory().available)
    except Exception:  # noqa: BLE001 - psutil absent or /proc unreadable
        import os

        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
