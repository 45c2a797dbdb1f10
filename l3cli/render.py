"""Render raw files with a transform table: the public face of ``l3 render``.

Every output pixel is ``out = K[class]ᵀ [patch, 1]``: the pixel is classified
by the shared classifier (:mod:`l3cli.classify`) and the affine kernel of its
class is applied to its patch. A table with a learned tone curve
(:mod:`l3cli.tone.curve`) then maps each channel through its look-up table.
The output has the raw's full size and is pixel-aligned with it: borders are
padded by a mirror that keeps the CFA phase
(:func:`l3cli.classify.mirror_indices`). Empty classes already hold the
kernel of their fallback class in the table, so the kernel is branch-free.

The layers, one way down:

* this module: files (:func:`render_file`, :func:`render_files`, dask tasks);
* :mod:`l3cli.pipeline`: a folder's decode / render / encode / write overlapped,
  one file's render (:func:`l3cli.pipeline.render_one`);
* :mod:`l3cli.prepared`: the one per-raw step (:func:`prepare`: the fit check,
  the raw's white balance, adaptation, condition bins, lens shading and GainMaps
  folded into a kernel set) and the one render path from it to float or display
  integers (:meth:`Prepared.render`, the multi-scale stage included), re-exported here;
* :mod:`l3cli.kernelset`: the kernel set and the renders of a mosaic
  (:func:`render_mosaic`, :func:`render_display`);
* :mod:`l3cli.classify` and :mod:`l3cli.render_rows`: the tile kernel.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.errors import InputError
from l3cli.kernelset import (
    DISPLAY_BAND_PIXELS,
    KernelSet,
    pack_kernels,
    prepare_kernels,
    render_display,
    render_mosaic,
    tone_curve_arrays,
)
from l3cli.pipeline import render_one, render_pipeline
from l3cli.prepared import Prepared, check_fits, prepare, render_raw
from l3cli.table import TransformTable

__all__ = ["DISPLAY_BAND_PIXELS", "KernelSet", "Prepared", "check_fits", "check_white_balance",
           "pack_kernels", "prepare", "prepare_kernels", "render_display", "render_file", "render_files",
           "render_mosaic", "render_raw", "render_task", "table_for_task", "tone_curve_arrays"]


def render_file(table: TransformTable, raw_path: str | os.PathLike, out_path: str | os.PathLike,
                *, table_name: str = "table", white_balance: np.ndarray | None = None,
                **options: Any) -> Path:
    """Read a raw file, render it and write ``out_path`` (format by suffix).

    EXR keeps the table's space (linear values as rendered); TIFF/PNG/JPEG
    receive display sRGB (:func:`l3cli.io.image.write_image`, which also takes
    ``options``: ``compression``, ``half``, ``quality``). The output keeps
    the raw's pixel grid and carries the raw's shot metadata
    (:mod:`l3cli.io.metadata`): the EXIF Orientation, so viewers show it
    upright, and Make, Model, DateTimeOriginal, ISO, exposure time, f-number
    and lens where known.
    """
    return render_one(table, table_name, raw_path, out_path, options,
                      white_balance=white_balance)[0]


# ------------------------------------------------------- many files (map tasks)
@functools.lru_cache(maxsize=2)
def _cached_table(path: str, mtime_ns: int, size: int) -> TransformTable:
    from l3cli.table import load_table

    return load_table(path)


def table_for_task(path: str | os.PathLike) -> TransformTable:
    """The table at ``path``, loaded once per process (reloaded when the file changes)."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        from l3cli.table import load_table

        return load_table(p)  # raises the usual one-line TableError
    return _cached_table(str(p), st.st_mtime_ns, st.st_size)


def check_white_balance(table: TransformTable, raws: list[str | os.PathLike],
                        white_balance: np.ndarray | None, *, table_name: str = "table") -> None:
    """Check before any output that every raw has the white balance the table needs.

    Raises
    ------
    InputError
        The table expects white-balanced input and a raw carries no white
        balance (and none is given), or its metadata contradict themselves; or
        ``white_balance`` is given for a table trained without.
    """
    if table.white_balance is None:
        if white_balance is not None:
            raise InputError(f"{table_name}: the table was trained without white balance; "
                             "--white-balance does not apply to it")
        return
    if white_balance is not None:
        return
    from l3cli.whitebalance.model import file_gains

    for raw in raws:
        if _dng_tag_gains(raw) is None and file_gains(raw) is None:
            raise InputError(
                f"{raw}: no white balance in the raw's metadata, and the table expects "
                "white-balanced input; give one with --white-balance R,G,B")


def _dng_tag_gains(path: str | os.PathLike) -> np.ndarray | None:
    """A DNG's as-shot gains from its tags alone (AsShotNeutral, AsShotWhiteXY), or None.

    :func:`l3cli.whitebalance.model.file_gains` asks LibRaw for its camera white
    balance, and rawpy unpacks (decodes) the whole raw to give it: a second
    decode of every file before the render (0.1-0.6 s per 9-MP DNG). A DNG's
    tags say it without decoding, and the two tags are checked against each
    other as :func:`~l3cli.whitebalance.model.raw_gains` does; LibRaw's value (for
    a DNG, ``1 / AsShotNeutral`` itself) is compared when each file is read.
    """
    from types import SimpleNamespace

    from l3cli.io.metadata import read_shot_metadata
    from l3cli.io.raw import sidecar_path
    from l3cli.whitebalance.model import raw_gains

    p = Path(path)
    if p.suffix.lower() != ".dng" or sidecar_path(p).exists():
        return None
    try:
        shot = read_shot_metadata(p)
    except Exception:  # noqa: BLE001 - file_gains (and the read) report unreadable files
        return None
    return raw_gains(SimpleNamespace(metadata={"shot": shot}, path=p))



def render_task(item: tuple) -> str:
    """Render one file (a map task): ``(table_path, raw_path, out_path, table_name[, options[, gains]])``.

    The task reads the table (once per process) and the raw itself and writes
    the output atomically (``options``: :func:`l3cli.io.image.write_image`
    keywords); it returns the output path. ``gains`` (a tuple of 3, or None)
    overrides the raw's white balance.
    """
    table_path, raw_path, out_path, table_name, *rest = item
    options = dict(rest[0]) if rest and rest[0] else {}
    gains = np.asarray(rest[1], dtype=np.float64) if len(rest) > 1 and rest[1] else None
    table = table_for_task(table_path)
    return str(render_file(table, raw_path, out_path, table_name=table_name,
                           white_balance=gains, **options))


def render_files(table_path: str | os.PathLike, jobs: list[tuple[str | os.PathLike,
                                                                str | os.PathLike]], *,
                 workers: int | None = None, scheduler: str | None = None,
                 show_progress: bool | None = False,
                 options: dict[str, Any] | None = None,
                 white_balance: np.ndarray | None = None,
                 prefetch: Any = None) -> list[Path]:
    """Render ``(raw, output)`` pairs with the table at ``table_path``.

    In process, the files go through a pipeline that overlaps decoding,
    rendering, encoding and writing across files (:mod:`l3cli.pipeline`);
    on a dask cluster, one :func:`render_task` per file
    (:func:`l3cli.parallel.map_reduce`). The table is checked here first, so a
    bad table fails before any work. Each output is written atomically: a
    failed file leaves no partial output (in process, the other files are
    still written before the first failure is raised).

    Parameters
    ----------
    table_path
        The table ``.npz``.
    jobs
        ``(raw path, output path)`` pairs.
    workers, scheduler
        Local cluster size or running scheduler address (default: in process).
    show_progress
        Progress bar on stderr.
    options
        Output options (:func:`l3cli.io.image.write_image` keywords:
        ``compression``, ``half``, ``quality``).
    white_balance
        Gains ``[r, g, b]`` for every raw instead of their own (tables that
        expect white-balanced input only).
    prefetch
        In process: the first raws' decodes, already started
        (:class:`l3cli.pipeline.Prefetch`).

    Returns
    -------
    list of Path
        The outputs, in input order.

    Raises
    ------
    InputError
        For a table that expects white-balanced input: a raw without a white
        balance when none is given (checked for every raw before any output
        is written), or contradictory white-balance metadata.
    """
    table = table_for_task(table_path)  # a bad table fails now, with its one-line message
    check_white_balance(table, [raw for raw, _ in jobs], white_balance,
                        table_name=Path(table_path).name)
    gains = None if white_balance is None else tuple(float(v) for v in white_balance)
    name = Path(table_path).name
    remote = workers is not None or scheduler is not None
    options = dict(options or {})
    if not remote:
        return render_pipeline(table, jobs, table_name=name, options=options,
                               show_progress=show_progress, white_balance=white_balance,
                               prefetch=prefetch)
    from l3cli.parallel import map_reduce

    def sent(p: str | os.PathLike) -> str:
        return str(Path(p).absolute()) if remote else str(p)

    items = [(sent(table_path), sent(raw), sent(out), name, options, gains) for raw, out in jobs]
    done = map_reduce(render_task, items, workers=workers, scheduler=scheduler,
                      label="render", show_progress=show_progress)
    return [Path(p) for p in done]
