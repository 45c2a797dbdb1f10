"""Render raw mosaics with a transform table.

Every output pixel is ``out = K[class]ᵀ [patch, 1]``: the pixel is classified
by the shared classifier (:mod:`l3cli.classify`) and the affine kernel of its
class is applied to its patch. A table with a learned tone curve
(:mod:`l3cli.tonecurve`) then maps each channel through its look-up table.
The output has the raw's full size and is pixel-aligned with it: borders are
padded by a mirror that keeps the CFA phase
(:func:`l3cli.classify.mirror_indices`). Empty classes already hold the
kernel of their fallback class in the table, so the kernel is branch-free.

Classification and the affine kernels run in one numba-compiled, parallel
pass over tiles of output pixels (:func:`l3cli.classify.run_tiles`): a tile's
padded band is classified and rendered while it is in the core's cache, and
beside the mosaic and the output only a few tile buffers per thread are held,
so memory stays bounded for any frame size. The kernels of a table are packed
once (:func:`pack_kernels`) so that a tap of two patch rows, 4 output lanes
each, is one 8-lane multiply-add (:func:`l3cli.render_rows.affine4`).
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
from contextlib import AbstractContextManager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from l3cli import buffers
from l3cli.classify import MODE_DISPLAY, MODE_RENDER, check_mosaic, run_tiles
from l3cli.errors import InputError, TableError
from l3cli.render_rows import RENDER_LANES, pack_lanes
from l3cli.table import TransformTable

if TYPE_CHECKING:
    from l3cli.io.raw import RawImage

__all__ = ["check_fits", "pack_kernels", "render_display", "render_mosaic", "render_raw",
           "render_file",
           "render_task", "render_files", "table_for_task"]


def pack_kernels(table: TransformTable) -> np.ndarray:
    """The table's kernels in the render kernel's layout (a copy: ~1 MB, < 1 ms).

    Returns
    -------
    numpy.ndarray
        float32 (n_classes, (S*S + 1) * L). Tables of up to 4 outputs: ``L = 4``
        lanes (zero-padded), in the row-pair layout of
        :func:`l3cli.render_rows.pack_lanes`; otherwise ``L = n_out``,
        tap-major (patch row-major, then the constant).
    """
    k = np.asarray(table.kernels, dtype=np.float32)  # (n_classes, q, n_out)
    nc, q, n_out = k.shape
    if n_out > RENDER_LANES:
        return np.ascontiguousarray(k.reshape(nc, q * n_out))
    packed = np.zeros((nc, q, RENDER_LANES), dtype=np.float32)
    packed[:, :, :n_out] = k
    return pack_lanes(packed)


def check_fits(table: TransformTable, raw: RawImage, *, table_name: str = "table") -> None:
    """Raise :class:`TableError` when ``table`` cannot render ``raw``.

    The table's CFA (with its phase) must equal the raw's, and the raw must be
    at least one patch and one CFA period large; the message names both.
    """
    name = getattr(raw, "path", None) or "raw"
    if raw.cfa.spec != table.cfa.spec:
        raise TableError(
            f"{table_name} is for CFA {table.cfa.spec} but {name} has CFA {raw.cfa.spec}"
        )
    h, w = raw.mosaic.shape
    s = table.patch
    if h < max(s, table.cfa.period[0]) or w < max(s, table.cfa.period[1]):
        raise TableError(
            f"{table_name} uses {s}x{s} patches but {name} is only {w}x{h} pixels"
        )


def render_mosaic(table: TransformTable, mosaic: np.ndarray, *, out: np.ndarray | None = None,
                  rows: tuple[int, int] | None = None) -> np.ndarray:
    """Render a normalised mosaic (CFA phase as the table's) in the table's space.

    Parameters
    ----------
    table
        The transform table.
    mosaic
        float32 (H, W), 0 = black, 1 = white level.
    out
        Optional float32 C-contiguous (H, W, n_out) output array (or
        (y1 - y0, W, n_out) with ``rows``).
    rows
        Optional ``(y0, y1)``: render only these rows (their patches still
        see the rows around them).

    Returns
    -------
    numpy.ndarray
        float32 (H, W, n_out) in ``table.output_space``.
    """
    d = table.definition
    mosaic = check_mosaic(mosaic, d.cfa, d.patch)
    h, w = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    shape = (y1 - y0, w, table.n_out)
    if out is None:
        out = buffers.empty(shape, np.float32)
    elif out.shape != shape or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous float32 array of shape {shape}")
    run_tiles(mosaic, d, MODE_RENDER, rows=(y0, y1), kernels=pack_kernels(table),
              n_out=table.n_out, out=out, curve=tone_curve_arrays(table))
    return out


def tone_curve_arrays(table: TransformTable) -> tuple[np.ndarray, ...] | None:
    """The table's learned tone curve as the tile kernel reads it (None: no curve).

    The kernels render the curve's linear space; the kernel maps each output
    row through the curve (:func:`l3cli.tonecurve.curve_row`).
    """
    if table.tone_lut is None:
        return None
    from l3cli.tonecurve import curve_arrays

    return curve_arrays(*table.tone_lut)


#: Pixels of one float band of :func:`render_display`'s two-step path (``lab`` tables).
DISPLAY_BAND_PIXELS = 1 << 20


def render_display(table: TransformTable, mosaic: np.ndarray, bits: int, *,
                   out: np.ndarray | None = None,
                   rows: tuple[int, int] | None = None,
                   render_lock: AbstractContextManager | None = None) -> np.ndarray:
    """Render a normalised mosaic straight to display integers (as TIFF, PNG and JPEG hold).

    The tile kernel renders each row and display-encodes it while it is in
    cache (:func:`l3cli.render_rows.encode_row`), 8 or 16 bits: no float
    image is held and no second pass is made. Only ``lab`` tables (whose
    conversion is colour-science's) render bands of about
    :data:`DISPLAY_BAND_PIXELS` to float and encode them one after another.
    Either way the integers are those of
    :func:`l3cli.io.encode.display_encode` applied to :func:`render_mosaic`'s
    output (a test checks it).

    Parameters
    ----------
    table
        The transform table.
    mosaic
        float32 (H, W), 0 = black, 1 = white level.
    bits
        8 (uint8 out) or 16 (uint16 out).
    out
        Optional C-contiguous output of that dtype, (H, W, n_out) (or
        (y1 - y0, W, n_out) with ``rows``).
    rows
        Optional ``(y0, y1)``: render only these rows.
    render_lock
        Held around each call of the (parallel) render kernel (the file
        pipeline's lock); a ``lab`` band's encoding runs outside it.

    Returns
    -------
    numpy.ndarray
        uint8 or uint16 (H, W, n_out) display values (sRGB for 3-channel tables).
    """
    from l3cli.io.encode import display_encode, display_params, encode_into

    if bits not in (8, 16):
        raise ValueError(f"bits must be 8 or 16, got {bits}")
    d = table.definition
    mosaic = check_mosaic(mosaic, d.cfa, d.patch)
    h, w = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    shape = (y1 - y0, w, table.n_out)
    dtype = np.uint16 if bits == 16 else np.uint8
    if out is None:
        out = buffers.empty(shape, dtype)
    elif out.shape != shape or out.dtype != dtype or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous {np.dtype(dtype)} array of shape {shape}")
    lock = render_lock if render_lock is not None else contextlib.nullcontext()
    with lock:  # the encoder's tables (cached per process) are built once, not beside
        params = display_params(table.output_space, table.n_out, bits)  # a warm-up's build
    kernels = pack_kernels(table)
    curve = tone_curve_arrays(table)
    if params is not None:
        with lock:
            run_tiles(mosaic, d, MODE_DISPLAY, rows=(y0, y1), kernels=kernels,
                      n_out=table.n_out, out=out, curve=curve, display=params)
        return out
    # lab (colour-science's conversion): float bands of ~1 M pixels, each
    # encoded after its render
    step = max(1, DISPLAY_BAND_PIXELS // max(w, 1))
    band = buffers.empty((min(step, y1 - y0), w, table.n_out), np.float32)  # reused per file
    for b0 in range(y0, y1, step):
        b1 = min(y1, b0 + step)
        part = band[: b1 - b0]
        with lock:
            run_tiles(mosaic, d, MODE_RENDER, rows=(b0, b1), kernels=kernels,
                      n_out=table.n_out, out=part, curve=curve)
        if params is None:  # lab
            out[b0 - y0:b1 - y0] = display_encode(part, table.output_space, bits)
        else:
            encode_into(part, params, bits, out[b0 - y0:b1 - y0])
    del part
    buffers.release(band)
    return out


def render_raw(table: TransformTable, raw: RawImage, *, table_name: str = "table",
               white_balance: np.ndarray | None = None) -> np.ndarray:
    """Render a :class:`l3cli.io.raw.RawImage` (checks that the table fits).

    A table that expects white-balanced input (``table.white_balance``)
    normalises the mosaic by the raw's as-shot gains, or ``white_balance``
    when given, and adapts the output to that white (:mod:`l3cli.whitebalance`).

    Returns
    -------
    numpy.ndarray
        float32 (H, W, n_out) in ``table.output_space``.

    Raises
    ------
    InputError
        The table expects a white balance and the raw has none (and none is
        given), or one is given for a table trained without.
    """
    check_fits(table, raw, table_name=table_name)
    if table.conditions is not None:  # per-bin kernels, interpolated for this raw
        import dataclasses

        from l3cli.conditions import LABELS, kernels_for, raw_condition

        value = raw_condition(raw, table.conditions.by)
        if value is None:
            logging.getLogger(__name__).warning(
                "%s: no %s in the metadata; rendering with the pooled kernels",
                raw.path, LABELS[table.conditions.by])
        k = kernels_for(table, value)
        table = dataclasses.replace(table, kernels=k, conditions=None)
    if table.white_balance is None:
        if white_balance is not None:
            raise InputError(f"{table_name}: the table was trained without white balance; "
                             "--white-balance does not apply to it")
        return render_mosaic(table, raw.mosaic)
    from l3cli.whitebalance import WhiteBalanceModel, adapt_image, apply_gains, gains_or_error

    gains = gains_or_error(raw, white_balance)
    mosaic = apply_gains(raw.mosaic, raw.cfa, gains, table.definition.saturation_threshold)
    model = WhiteBalanceModel.from_dict(table.white_balance)
    img = render_mosaic(table, mosaic)
    return adapt_image(img, model.matrix(gains), table.output_space, model.space)


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
    from l3cli.pipeline import render_one

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
    from l3cli.whitebalance import file_gains

    for raw in raws:
        if file_gains(raw) is None:
            raise InputError(
                f"{raw}: no white balance in the raw's metadata, and the table expects "
                "white-balanced input; give one with --white-balance R,G,B")



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
        from l3cli.pipeline import render_pipeline

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
