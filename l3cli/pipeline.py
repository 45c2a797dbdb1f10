"""Render many raw files in one process: decode, render, encode and write overlap.

A folder is a pipeline, not a loop. Each file goes through

1. decode (LibRaw through rawpy: C code, the GIL released),
2. render (the numba tile kernel, parallel over every core) and, for
   TIFF/PNG/JPEG, display-encode (:func:`l3cli.kernelset.render_display`: rows
   are encoded inside the kernel as they are rendered), straight into
   8/16-bit integers: no full-size float image is held;
3. write (OpenImageIO's encoders, the GIL released), atomically,

on a small pool of threads: while one file renders, the next decodes and the
previous one is written. Memory stays bounded: at most ``in_flight`` files
(default 3) are between decode and write at any time, and a file's buffers
are freed as soon as its stage is done. Files take the render stage one at
a time and in input order (:class:`RenderTurns`: each render already uses
every core, numba's default threading layer must not be entered from two
threads at once, and a file that finishes its render early is written
early). Before the first file, the kernels
are loaded from numba's on-disk cache on a tiny input beside the first decode
(:func:`warm_up`).

Results come back in input order. A file that fails does not stop the others:
they are all written, and the first failure (in input order) is raised at the
end, naming its file; a failed file leaves no output (writes are atomic).
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from l3cli import buffers
from l3cli.errors import L3Error
from l3cli.progress import progress
from l3cli.startup import signals_deferred

__all__ = ["IN_FLIGHT", "Prefetch", "RenderTurns", "render_one",
           "render_pipeline", "warm_up"]

#: Files between decode and write at a time (one decoding, one rendering, one
#: being written): at the peak about 3 x (mosaic + output), the output being
#: 8/16-bit integers for TIFF/PNG/JPEG and float32 for EXR.
IN_FLIGHT = 3

_RENDER_LOCK = threading.Lock()
T = TypeVar("T")


class RenderTurns:
    """Files take the render stage in input order, one at a time.

    Without an order the render lock goes to whichever thread asks: a later
    file can render before an earlier one (whose write, and the decode
    after it, then wait), and files rendered in bands (``lab`` tables) take
    turns band by band and all finish together, late.
    In order, file ``i`` renders alone while file ``i - 1`` is written and
    file ``i + 2`` decodes. A file that fails (or is skipped) before its
    render passes its turn on (:meth:`done`), so no later file waits for it.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._next = 0
        self._done: set[int] = set()

    @contextlib.contextmanager
    def turn(self, i: int) -> Iterator[None]:
        """Wait for file ``i``'s turn, hold it, then pass it on."""
        with self._cond:
            self._cond.wait_for(lambda: self._next >= i)
        try:
            yield
        finally:
            self.done(i)

    def done(self, i: int) -> None:
        """File ``i`` is past the render stage (idempotent)."""
        with self._cond:
            if i >= self._next:
                self._done.add(i)
            while self._next in self._done:
                self._done.discard(self._next)
                self._next += 1
            self._cond.notify_all()

log = logging.getLogger(__name__)


class _Slot:
    """One prefetched decode: done when the raw (or its error) is there."""

    def __init__(self) -> None:
        self.done = threading.Event()
        self.raw: Any = None
        self.error: BaseException | None = None
        self.taken = False
        self.started = False


class Prefetch:
    """The first raws' decodes, started in a thread before a render's heavy imports.

    ``l3 render`` starts it before importing the render code, so the first
    files decode (LibRaw releases the GIL) on the core that start-up leaves
    idle. Lossy DNGs take l3's own decoder only where its machine code is
    stored (:func:`l3cli.io.raw.read_raw`: this thread never imports numba);
    uncompressed and lossless-JPEG DNGs are read by
    :mod:`l3cli.io.dng_direct` (numpy and imagecodecs). The files are decoded one after another, at most ``count`` of them (the
    pipeline's :data:`IN_FLIGHT`, so memory stays bounded). :meth:`take`
    hands a result (or raises its error) to the pipeline job of that file.
    Use it as a context manager: leaving stops the decodes not yet started
    and waits for the running one, so no fd 2 capture outlives the command.
    """

    def __init__(self, paths: str | os.PathLike | Sequence[str | os.PathLike],
                 count: int = 1) -> None:
        if isinstance(paths, str | os.PathLike):
            paths = [paths]
        self.paths = list(dict.fromkeys(str(p) for p in list(paths)[:max(0, int(count))]))
        self._slots = {p: _Slot() for p in self.paths}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name="l3-prefetch", daemon=True)
        try:
            self._thread.start()
        except BaseException:  # a signal inside start: the thread runs, and nobody would stop it
            self.__exit__()
            raise

    @property
    def path(self) -> str | None:
        """The first prefetched path."""
        return self.paths[0] if self.paths else None

    def _read(self) -> None:
        from l3cli.io.raw import read_raw

        for p in self.paths:
            slot = self._slots[p]
            with self._lock:
                # a job that came for its file before the decode began decodes it itself
                slot.started = not (self._stop.is_set() or slot.taken)
            try:
                if slot.started:
                    slot.raw = read_raw(p)
            except BaseException as exc:  # noqa: BLE001 - handed to the job that takes it
                slot.error = exc
            finally:
                slot.done.set()

    def take(self, path: str | os.PathLike) -> Any:
        """The decoded :class:`~l3cli.io.raw.RawImage` of ``path``, once; else None.

        Waits for a decode that is running; None (the caller decodes) when
        ``path`` is not prefetched, its decode has not begun, it was taken
        already, or the prefetch stopped.
        """
        slot = self._slots.get(str(path))
        if slot is None:
            return None
        with self._lock:
            if slot.taken:
                return None
            slot.taken = True
            if not slot.started and not slot.done.is_set():
                return None
        slot.done.wait()
        raw, error, slot.raw, slot.error = slot.raw, slot.error, None, None
        if error is not None:
            raise error
        return raw

    def __enter__(self) -> Prefetch:
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        self._thread.join()
        for slot in self._slots.values():
            slot.raw = slot.error = None


def warm_up(table: Any, out_path: str | os.PathLike | None = None) -> None:
    """Load the render kernel (and the encoder's tables) on a tiny input.

    Run beside the first file's decode, this moves the first call's cost off
    the critical path of a one-file render: loading the kernel's stored
    machine code (:mod:`l3cli.kernel_store`, ~0.05 s with llvmlite's import),
    or, the first time on a machine, numba's import and compile. The tile
    kernel is one compiled
    function for float (EXR) and display (TIFF/PNG/JPEG) outputs, with or
    without a kernel set's post matrix.
    """
    from l3cli.io.image import display_bits, format_of
    from l3cli.prepared import plain

    s = max(table.patch, *table.cfa.period) * 2
    tiny = np.zeros((s, s), dtype=np.float32)
    bits = None if out_path is None else display_bits(format_of(out_path))
    with _RENDER_LOCK:  # the multi-scale stage's loops too
        plain(table, tiny, stage=True).render(bits)


def render_one(table: Any, table_name: str, raw_path: str | os.PathLike,
               out_path: str | os.PathLike, options: dict[str, Any],
               white_balance: np.ndarray | None = None, prefetch: Prefetch | None = None,
               turn: contextlib.AbstractContextManager | None = None,
               ) -> tuple[Path, tuple[float, float, float]]:
    """Read, render and write one file; the output path and the stage times (s).

    The one implementation of a file's render, used by the pipeline's threads
    and by :func:`l3cli.render.render_file` (dask tasks, library callers).
    Every table takes the same path, the library's (:mod:`l3cli.prepared`):
    the raw is prepared once (:func:`~l3cli.prepared.prepare`: condition bins,
    white-balance gains and adaptation, lens shading, the DNG's gain maps) and
    rendered by :meth:`~l3cli.prepared.Prepared.render`, the gains applied to
    each band as the fused tile kernel copies it, straight to integers for
    display outputs.
    ``turn`` is held around the render stage (the pipeline's
    :meth:`RenderTurns.turn`).
    """
    from l3cli.io.image import display_bits, format_of, write_image
    from l3cli.io.metadata import exif_attributes
    from l3cli.io.raw import read_raw
    from l3cli.prepared import prepare

    fmt = format_of(out_path)
    t0 = time.perf_counter()
    raw = prefetch.take(raw_path) if prefetch is not None else None
    if raw is None:
        raw = read_raw(raw_path)
    # the raw's gains (its DNG gain maps, the table's lens shading, white balance) are
    # applied by the tile kernel as it copies each band (l3cli.lens.gainmaps), not here
    prepared = prepare(table, raw, white_balance=white_balance, table_name=table_name,
                       inplace=True)  # the decode is ours
    shot = exif_attributes(raw.metadata.get("shot", {}))
    mosaic = prepared.mosaic
    t1 = time.perf_counter()
    with turn if turn is not None else contextlib.nullcontext():
        img = prepared.render(display_bits(fmt), lock=_RENDER_LOCK)
    del prepared
    t2 = time.perf_counter()
    decoded = raw.mosaic
    del raw
    buffers.release(decoded)  # the next file's decode reuses its pages
    if mosaic is not decoded:
        buffers.release(mosaic)
    del mosaic, decoded
    out = write_image(out_path, img, space=table.output_space,
                      attributes={"l3:table": str(table_name)}, metadata=shot,
                      source=raw_path, **options)
    buffers.release(img)
    return out, (t1 - t0, t2 - t1, time.perf_counter() - t2)


def _locked(items: Iterator[T]) -> Iterator[T]:
    """``items`` with each step taken under the stderr lock (a bar draws in its steps)."""
    from l3cli.io.raw import STDERR_LOCK

    it = iter(items)
    while True:
        with STDERR_LOCK:
            try:
                item = next(it)
            except StopIteration:
                return
        yield item


def _quiet_warm_up(table: Any, out_path: str | os.PathLike) -> None:
    from l3cli.startup import resume_gc

    try:
        warm_up(table, out_path)
    except Exception as exc:  # noqa: BLE001 - the real render reports real errors
        log.debug("warm-up failed: %s", exc)
    finally:
        resume_gc()  # start-up is over (l3 render paused the collector)


def render_pipeline(table: Any, jobs: Sequence[tuple[str | os.PathLike, str | os.PathLike]], *,
                    table_name: str = "table", options: dict[str, Any] | None = None,
                    in_flight: int = IN_FLIGHT, show_progress: bool | None = False,
                    white_balance: np.ndarray | None = None,
                    prefetch: Prefetch | None = None) -> list[Path]:
    """Render ``(raw, output)`` pairs with ``table``, stages overlapped across files.

    Parameters
    ----------
    table
        A :class:`l3cli.table.TransformTable`.
    jobs
        ``(raw path, output path)`` pairs; the output format follows the suffix.
    table_name
        Name recorded in each output (``l3:table``) and used in messages.
    options
        Keyword options of :func:`l3cli.io.image.write_image` (``compression``,
        ``half``, ``quality``).
    in_flight
        Files in progress at a time (>= 1; 1 is a plain loop).
    white_balance
        Gains ``[r, g, b]`` for every raw instead of their own (tables that
        expect white-balanced input only).
    show_progress
        Progress bar on stderr (files finished, in input order).
    prefetch
        The first raws' decodes, already started (:class:`Prefetch`); each job
        takes its file's decode from it when there is one.

    Returns
    -------
    list of Path
        The outputs, in input order.

    Raises
    ------
    L3Error
        The first file that failed, in input order, once every other file is
        written (the message says how many more failed).
    """
    options = dict(options or {})
    jobs = list(jobs)
    if not jobs:
        return []
    results: list[Path | None] = [None] * len(jobs)
    first: BaseException | None = None  # the first failure in input order (later ones: counted,
    failed = 0                          # not kept: a traceback holds its file's arrays)
    with (buffers.recycling(2 * (int(in_flight) + 1)),  # mosaics and outputs
          ThreadPoolExecutor(max_workers=max(1, int(in_flight)),
                             thread_name_prefix="l3-render") as pool):
        warm = threading.Thread(target=_quiet_warm_up, args=(table, jobs[0][1]),
                                name="l3-warm-up", daemon=True)
        warm.start()
        turns = RenderTurns()

        def job(i: int, raw: str | os.PathLike, out: str | os.PathLike
                ) -> tuple[Path, tuple[float, float, float]]:
            try:
                return render_one(table, table_name, raw, out, options, white_balance,
                                  prefetch, turn=turns.turn(i))
            finally:
                turns.done(i)  # also when it failed before its render

        futures: list[Future[tuple[Path, tuple[float, float, float]]] | None] = []
        try:
            for i, (raw, out) in enumerate(jobs):
                # a signal inside submit, after it started a worker thread and before the
                # pool recorded it, would leave a thread that the pool's shutdown does not
                # wait for: its file written after the interrupted run's clean-up
                with signals_deferred():
                    futures.append(pool.submit(job, i, raw, out))
            for i, fut in enumerate(_locked(progress(futures, label="render",
                                                     length=len(futures),
                                                     enabled=show_progress))):
                futures[i] = None  # done with it (a failure's traceback holds its arrays)
                try:
                    results[i], times = fut.result()
                except Exception as exc:  # noqa: BLE001 - re-raised below, first in order
                    failed += 1
                    first = first if first is not None else exc
                    del exc
                    continue
                finally:
                    del fut
                if log.isEnabledFor(logging.DEBUG):
                    from l3cli.io.raw import STDERR_LOCK

                    with STDERR_LOCK:
                        log.debug("%s: decode %.3f s, render (+ encode) %.3f s, write %.3f s",
                                  jobs[i][0], *times)
        except BaseException:
            for fut in futures:
                if fut is not None:
                    fut.cancel()
            raise
        finally:
            warm.join()
    if first is not None:
        if failed > 1 and isinstance(first, L3Error):
            raise type(first)(f"{first} (and {failed - 1} more of {len(jobs)} files "
                              "failed)") from first
        raise first
    return [p for p in results if p is not None]
