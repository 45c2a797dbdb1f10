"""l3's own threads: a compiled loop over ranges of tiles or rows, shared by the CPUs.

The tile kernel (:func:`l3cli.classify.run_tiles`) and the multi-scale stage's
loops (:mod:`l3cli.multiscale.stage`) are compiled functions ``fn(*args, lo, hi)``
that release the GIL; :func:`run_split` runs one over ``0..n`` in ranges that
:func:`tile_threads` daemon threads share (a few ranges per thread, so a slow
one does not hold up the rest). The threads are l3's own, not numba's OpenMP
pool: nothing spins between two calls.
"""

from __future__ import annotations

import os
import queue
import threading
from typing import Any

import numpy as np

__all__ = ["run_split", "tile_threads"]

#: Ranges per thread of one call (load balance against per-range overhead).
_CHUNKS_PER_THREAD = 4


def tile_threads() -> int:
    """Threads that share an image's tiles: ``NUMBA_NUM_THREADS`` when set, else the
    CPUs this process may run on (:func:`l3cli.parallel.cpu_count`)."""
    from l3cli.parallel import cpu_count

    try:
        return max(1, int(os.environ["NUMBA_NUM_THREADS"]))
    except (KeyError, ValueError):
        return cpu_count()


class _Batch:
    """The tile ranges of one kernel call: how many are left, the first error."""

    def __init__(self, n: int) -> None:
        self.left = n
        self.error: BaseException | None = None
        self.cancelled = False
        self.lock = threading.Lock()
        self.done = threading.Event()

    def finish(self, error: BaseException | None) -> None:
        with self.lock:
            if error is not None and self.error is None:
                self.error = error
            self.left -= 1
            if self.left == 0:
                self.done.set()


# The threads are l3's own daemon threads, not a ThreadPoolExecutor's: an executor's
# threads are not daemons, and a live one makes startup.exit_now fall back to the
# interpreter's full teardown.
_work: queue.SimpleQueue = queue.SimpleQueue()
_workers: list[threading.Thread] = []
_workers_lock = threading.Lock()


def _worker() -> None:
    while True:
        fn, args, batch = _work.get()
        error = None
        if not batch.cancelled:
            try:
                fn(*args)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller
                error = exc
        batch.finish(error)


def _ensure_workers(n: int) -> None:
    with _workers_lock:
        while len(_workers) < n:  # daemon threads: they never hold up the exit
            t = threading.Thread(target=_worker, name=f"l3-tiles-{len(_workers)}", daemon=True)
            t.start()
            _workers.append(t)


def _forget_workers() -> None:  # a forked child has none of its parent's threads
    global _work
    _workers.clear()
    _work = queue.SimpleQueue()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_workers)


def run_split(fn: Any, args: tuple, n_tiles: int) -> None:
    """``fn(*args, t_lo, t_hi)`` over tiles ``0..n_tiles``, in ranges shared by the threads
    (``fn``: the compiled kernel, resolved once for the call)."""
    k = min(tile_threads(), n_tiles)
    if k <= 1:
        fn(*args, 0, n_tiles)
        return
    bounds = np.linspace(0, n_tiles, min(n_tiles, _CHUNKS_PER_THREAD * k) + 1).astype(int)
    ranges = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]
    _ensure_workers(k)
    batch = _Batch(len(ranges))
    for lo, hi in ranges:
        _work.put((fn, (*args, lo, hi), batch))
    try:
        batch.done.wait()
    except BaseException:
        batch.cancelled = True  # ranges not yet started are skipped
        raise
    if batch.error is not None:
        raise batch.error


