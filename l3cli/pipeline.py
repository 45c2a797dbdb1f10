"""Render many raw files in one process: decode, render, encode and write overlap.

A folder is a pipeline, not a loop. Each file goes through

1. decode (LibRaw through rawpy: C code, the GIL released),
2. render (the numba tile kernel, parallel over every core),
3. encode (display sRGB integers: :func:`l3cli.io.encode.display_encode`, a
   ``nogil`` numba kernel; or float EXR) and write (OpenImageIO's encoders,
   the GIL released), atomically,

on a small pool of threads: while one file renders, the next decodes and the
previous one is encoded and written. Memory stays bounded: at most
``in_flight`` files (default 3) are between decode and write at any time, and
a file's buffers are freed as soon as its stage is done. The render stage runs
one file at a time (it already uses every core, and numba's default threading
layer must not be entered from two threads at once).

Results come back in input order. A file that fails does not stop the others:
they are all written, and the first failure (in input order) is raised at the
end, naming its file; a failed file leaves no output (writes are atomic).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

from l3cli.errors import L3Error
from l3cli.progress import progress

__all__ = ["IN_FLIGHT", "render_pipeline"]

#: Files between decode and write at a time (one decoding, one rendering, one
#: being written): about 3 x (mosaic + float output) of memory at the peak.
IN_FLIGHT = 3

_RENDER_LOCK = threading.Lock()


def _one(table: Any, table_name: str, raw_path: str | os.PathLike, out_path: str | os.PathLike,
         options: dict[str, Any]) -> Path:
    from l3cli.io.image import write_image
    from l3cli.io.raw import read_raw
    from l3cli.render import check_fits, render_mosaic

    raw = read_raw(raw_path)
    check_fits(table, raw, table_name=table_name)
    with _RENDER_LOCK:
        img = render_mosaic(table, raw.mosaic)
    del raw
    return write_image(out_path, img, space=table.output_space,
                       attributes={"l3:table": str(table_name)}, **options)


def render_pipeline(table: Any, jobs: Sequence[tuple[str | os.PathLike, str | os.PathLike]], *,
                    table_name: str = "table", options: dict[str, Any] | None = None,
                    in_flight: int = IN_FLIGHT, show_progress: bool | None = False) -> list[Path]:
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
    show_progress
        Progress bar on stderr (files finished, in input order).

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
    errors: list[tuple[int, BaseException]] = []
    with ThreadPoolExecutor(max_workers=max(1, int(in_flight)),
                            thread_name_prefix="l3-render") as pool:
        futures: list[Future[Path]] = [
            pool.submit(_one, table, table_name, raw, out, options) for raw, out in jobs
        ]
        try:
            for i, fut in enumerate(progress(futures, label="render", length=len(futures),
                                             enabled=show_progress)):
                try:
                    results[i] = fut.result()
                except Exception as exc:  # noqa: BLE001 - re-raised below, first in order
                    errors.append((i, exc))
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
    if errors:
        _, first = errors[0]
        if len(errors) > 1 and isinstance(first, L3Error):
            raise type(first)(f"{first} (and {len(errors) - 1} more of {len(jobs)} files "
                              "failed)") from first
        raise first
    return [p for p in results if p is not None]
