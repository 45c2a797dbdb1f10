"""The tile kernel: the one implementation of the classification rule.

Render and train both come through :func:`run_tiles`. Per tile of pixels the
numba kernel (:mod:`l3cli.classify.tile_kernel`) computes S-tap horizontal
then vertical sums of each channel's ``x`` and ``x²`` and an OR of the
saturated-channel bits, then level, contrast and class per pixel, and hands
each finished row to its entry point's row function: the features, the
classes, or (render and display) the render loops (:mod:`l3cli.render_rows`)
while the tile is in cache. Each mode is an entry point of its own
(``features``, ``classes``, ``render``, ``display``: compiled and stored
apart, each with only its own outputs), all taking ``(mosaic, yi, xi, y0,
nrows, tc, tables, guide, gains, outs, t_lo, t_hi)``.

The kernel's inputs that depend on the class definition only are built in
one place, :func:`l3cli.classify.layout.kernel_tables`, as a
:class:`~l3cli.classify.layout.KernelTables`, passed as the tuple ``tables``
that the kernel unpacks in its field order.

The kernel runs without the GIL on a range of tiles; :func:`run_tiles`
shares an image's tiles among :func:`tile_threads` threads. Its machine code
comes from :mod:`l3cli.kernel_store` when it is stored for this machine
(this module and the code it runs import no numba), else from numba, which
then stores it: a render's start-up does not pay for importing numba.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

from l3cli import defaults
from l3cli.cfa import CFA
from l3cli.classify.definition import DEFAULT_CONTRAST_EPS, ClassDefinition
from l3cli.classify.features import ContextGuide, context_guide
from l3cli.classify.layout import (
    MODE_CLASSES,
    MODE_DISPLAY,
    MODE_FEATURES,
    MODE_RENDER,
    TILE_COLS,
    TILE_ROWS,
    KernelTables,
    kernel_tables,
)
from l3cli.classify.mosaic import band_rows, check_mosaic
from l3cli.lens.gainmaps import NO_GAINS
from l3cli.threads import run_split, tile_threads

__all__ = ["KERNEL_SOURCES", "MODE_CLASSES", "MODE_DISPLAY", "MODE_FEATURES", "MODE_RENDER",
           "KernelTables", "kernel_tables", "check_mosaic", "band_rows", "run_tiles",
           "classify", "patch_features", "run_split", "tile_threads"]

_HERE = Path(__file__).resolve().parent
#: The source files the tile kernel's machine code comes from: the kernel, its
#: constants, the render loops and the encoder's loop.
KERNEL_SOURCES = tuple(str(p) for p in (
    _HERE / "tile_kernel.py", _HERE / "layout.py", _HERE.parent / "render_rows.py",
    _HERE.parent / "io" / "encode_rows.py"))


#: The tile kernel's entry point of each mode (:data:`l3cli.classify.tile_kernel.ENTRIES`).
_ENTRY = {MODE_CLASSES: "classes", MODE_FEATURES: "features", MODE_RENDER: "render",
          MODE_DISPLAY: "display"}


@functools.cache
def _kernel(S: int, PW: int, entry: str) -> Any:
    """The tile kernel's entry point ``entry`` for patch ``S`` and CFA period width ``PW``:
    stored machine code when there is some for the arguments' types, else numba's
    (:mod:`l3cli.kernel_store`)."""
    from l3cli.kernel_store import Stored

    def dispatcher() -> Any:
        from l3cli.classify.tile_kernel import tile_kernel

        return tile_kernel(S, PW, entry)

    def compiling() -> Any:
        from l3cli.classify.tile_kernel import slp_vectorize

        return slp_vectorize()

    return Stored(f"tile-{entry}-{S}-{PW}", KERNEL_SOURCES, dispatcher, context=compiling)


_NO_F32 = np.zeros((1, 1), dtype=np.float32)
#: The display entry's output of the other bit depth (never written).
_NO_U8, _NO_U16 = np.zeros(1, np.uint8), np.zeros(1, np.uint16)
#: No tone curve (a table of one entry per channel: the kernel tests ``shape[1] > 1``).
_NO_CURVE = (_NO_F32, _NO_F32, np.zeros(1, np.float32), np.zeros(1, np.float32))
#: No composed curve-and-encoding table (:mod:`l3cli.tone.code`): ``walk`` -1 (0 is an
#: interpolated table).
_NO_CODES = (np.zeros((1, 1), np.uint8), _NO_F32, np.zeros(1, np.float32),
             np.zeros(1, np.float32), -1)
#: No context guide (a definition without one never reads it).
_NO_GUIDE = tuple(ContextGuide(_NO_F32, *(np.zeros(1, np.int64),) * 2,
                               np.zeros(1, np.float32), *(np.zeros(1, np.int64),) * 2,
                               np.zeros(1, np.float32)))


def run_tiles(mosaic: np.ndarray, definition: ClassDefinition, mode: int, *,
              rows: tuple[int, int] | None = None, out_cls: np.ndarray | None = None,
              out_features: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
              kernels: np.ndarray | None = None, n_out: int = 0,
              out: np.ndarray | None = None,
              curve: tuple[np.ndarray, ...] | None = None, display: Any = None,
              codes: Any = None, gains: tuple | None = None) -> None:
    """Run the tile kernel over output rows ``rows`` (default: all) of a mosaic.

    The one entry point to the classifier; :func:`classify`,
    :func:`patch_features`, training and :func:`l3cli.render.render_mosaic`
    all come through here.

    Parameters
    ----------
    mosaic
        float32 (H, W) normalised mosaic, C-contiguous, CFA phase as the definition.
    definition
        The class definition.
    mode
        ``MODE_CLASSES`` (int32 classes into ``out_cls``), ``MODE_FEATURES``
        (float32 level, float32 contrast, int32 saturation bits into
        ``out_features``), ``MODE_RENDER`` (``out`` = affine kernels of the
        classes applied to the patches) or ``MODE_DISPLAY`` (``out`` = the
        render display-encoded); each runs its own entry point of the kernel
        (:data:`l3cli.classify.tile_kernel.ENTRIES`).
    rows
        ``(y0, y1)``: output rows; the output arrays have ``y1 - y0`` rows.
    kernels
        Render only: float32 packed kernels (:func:`l3cli.render.pack_kernels`).
    n_out
        Render only: outputs per pixel.
    out
        Render: float32 C-contiguous (y1 - y0, W, n_out). Display: uint8 or
        uint16 C-contiguous (y1 - y0, W, n_out).
    curve
        Render and display: a learned tone curve's look-up table
        (:func:`l3cli.tone.curve.curve_arrays`), applied to each output row
        (before the display encoding).
    display
        ``MODE_DISPLAY`` only: the encoder's
        :class:`~l3cli.io.encode.DisplayParams`; each rendered row is
        display-encoded into ``out`` (the same integers as
        :func:`~l3cli.io.encode.display_encode` of the float render).
    codes
        ``MODE_DISPLAY`` only: the curve and the encoding as one lookup
        (:func:`l3cli.tone.code.code_table`, for this curve and encoder without
        a matrix), used instead of ``curve`` and ``display``'s tables.
    gains
        The raw's gains on the mosaic (:meth:`l3cli.lens.gainmaps.MosaicGains.kernel_args`),
        applied to each tile's band as it is copied: the kernel sees the mosaic
        times its gains without a pass over it. None: the mosaic as it is.
    """
    S = definition.patch
    h, w = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    yi, xi = definition.mirror_maps(h, w)
    pw = definition.cfa.period[1]
    tc = pw * max(1, TILE_COLS // pw)
    curve = tuple(curve) if curve is not None else _NO_CURVE
    if mode == MODE_FEATURES:
        if out_features is None:
            raise ValueError("features mode needs out_features")
        outs: tuple = tuple(out_features)
    elif mode == MODE_CLASSES:
        if out_cls is None:
            raise ValueError("classes mode needs out_cls")
        outs = (out_cls,)
    elif mode == MODE_RENDER:
        if out is None or kernels is None:
            raise ValueError("render mode needs kernels and a float32 out")
        outs = (kernels, n_out, out.reshape(-1), *curve)
    elif mode == MODE_DISPLAY:
        if (out is None or kernels is None or display is None
                or out.dtype not in (np.uint8, np.uint16)):
            raise ValueError("display mode needs a uint8/uint16 out and the encoder's parameters")
        bits = 8 if out.dtype == np.uint8 else 16
        # both output kinds always passed (the other a stand-in): one compile serves 8 and
        # 16 bits, which the row picks by ``bits``
        flat = out.reshape(-1)
        out8, out16 = (flat, _NO_U16) if bits == 8 else (_NO_U8, flat)
        outs = (kernels, n_out, out8, out16, *curve, *display, bits,
                *(codes if codes is not None else _NO_CODES))
    else:
        raise ValueError(f"no tile kernel mode {mode}")
    guide = _NO_GUIDE
    if definition.context_block and mode != MODE_FEATURES:
        guide = tuple(context_guide(mosaic, definition.cfa, definition.context_block))
    n_tiles = -(-(y1 - y0) // TILE_ROWS) * -(-w // tc)
    args = (mosaic, yi, xi, y0, y1 - y0, tc, tuple(kernel_tables(definition)), guide,
            tuple(gains) if gains is not None else NO_GAINS, outs)
    # resolved once (argument types, loaded code), not once per range
    run_split(_kernel(S, pw, _ENTRY[mode]).function(*args, 0, n_tiles), args, n_tiles)


def classify(mosaic: np.ndarray, definition: ClassDefinition, *,
             rows: tuple[int, int] | None = None) -> np.ndarray:
    """Class index of every pixel of a mosaic.

    Parameters
    ----------
    mosaic
        float32 (H, W) normalised raw mosaic whose CFA phase is ``definition.cfa``.
    definition
        The class definition.
    rows
        Optional ``(y0, y1)``: classify only these rows.

    Returns
    -------
    numpy.ndarray
        int32 (H, W) (or (y1 - y0, W)) flat class indices (see :class:`ClassDefinition`).

    Examples
    --------
    A flat mosaic at level 0.05: unsaturated, the middle of three levels, flat.

    >>> d = ClassDefinition.build("RGGB", level_cuts=[0.01, 0.1], contrast_cuts=0.2)
    >>> cls = classify(np.full((8, 8), 0.05, np.float32), d)
    >>> [int(v) for v in d.class_tuple(cls[4, 4])]  # (group, saturation, level, contrast)
    [0, 0, 1, 0]
    >>> [int(v) for v in d.class_tuple(cls[4, 5])]  # the G next to R: group 1
    [1, 0, 1, 0]
    """
    mosaic = check_mosaic(mosaic, definition.cfa, definition.patch)
    h, w = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    out = np.empty((y1 - y0, w), dtype=np.int32)
    run_tiles(mosaic, definition, MODE_CLASSES, rows=(y0, y1), out_cls=out)
    return out


def patch_features(mosaic: np.ndarray, cfa: CFA | str, *, patch: int = defaults.PATCH,
                   saturation_threshold: float = defaults.SATURATION,
                   contrast_eps: float = DEFAULT_CONTRAST_EPS
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Response level, relative contrast and saturation bits of every pixel's patch.

    Returns
    -------
    level, contrast, sat
        float32 (H, W), float32 (H, W), int32 (H, W) (bit ``c`` = channel
        ``cfa.channels[c]`` saturated somewhere in the patch).
    """
    cfa = CFA.from_spec(cfa)
    d = ClassDefinition.build(cfa, patch=patch, level_cuts=np.array([0.5]),
                              saturation_threshold=saturation_threshold,
                              contrast_eps=contrast_eps, merge_positions=False)
    mosaic = check_mosaic(mosaic, cfa, patch)
    h, w = mosaic.shape
    lev = np.empty((h, w), dtype=np.float32)
    con = np.empty((h, w), dtype=np.float32)
    sat = np.empty((h, w), dtype=np.int32)
    run_tiles(mosaic, d, MODE_FEATURES, out_features=(lev, con, sat))
    return lev, con, sat


# ---------------------------------------------------- data-driven cut points
