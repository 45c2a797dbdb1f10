"""Render raw mosaics with a transform table.

Every output pixel is ``out = K[class]ᵀ [patch, 1]``: the pixel is classified
by the shared classifier (:mod:`l3cli.classify`) and the affine kernel of its
class is applied to its patch. The output has the raw's full size and is
pixel-aligned with it: borders are padded by a mirror that keeps the CFA
phase (:func:`l3cli.classify.mirror_indices`). Empty classes already hold the
kernel of their fallback class in the table, so the kernel is branch-free.

The work runs in a numba-compiled, parallel kernel over bands of rows: only
one padded band (``rows + S - 1`` rows) is held besides the mosaic and the
output, so memory stays bounded for any frame size.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numba as nb
import numpy as np

from l3cli.classify import band_classes, band_rows, pad_mosaic
from l3cli.errors import TableError
from l3cli.table import TransformTable

__all__ = ["check_fits", "render_mosaic", "render_raw", "render_file"]


@functools.cache
def _apply_kernel(S: int, n_out: int):
    """Per-pixel affine kernel, compiled for patch size S and n_out outputs
    (compile-time constants: the tap loops unroll; for three outputs the
    accumulators stay in registers)."""
    P = S * S

    if n_out == 3:

        @nb.njit(cache=True, parallel=True, fastmath={"contract"})
        def apply(band, cls, K, out):
            H, W = cls.shape
            for i in nb.prange(H):
                for x in range(W):
                    Kc = K[cls[i, x]]
                    a0 = Kc[P, 0]
                    a1 = Kc[P, 1]
                    a2 = Kc[P, 2]
                    k = 0
                    for dy in range(S):
                        for dx in range(S):
                            v = band[i + dy, x + dx]
                            a0 += v * Kc[k, 0]
                            a1 += v * Kc[k, 1]
                            a2 += v * Kc[k, 2]
                            k += 1
                    out[i, x, 0] = a0
                    out[i, x, 1] = a1
                    out[i, x, 2] = a2

        return apply

    @nb.njit(cache=True, parallel=True, fastmath={"contract"})
    def apply_any(band, cls, K, out):
        H, W = cls.shape
        for i in nb.prange(H):
            acc = np.empty(n_out, dtype=np.float32)
            for x in range(W):
                Kc = K[cls[i, x]]
                for o in range(n_out):
                    acc[o] = Kc[P, o]
                k = 0
                for dy in range(S):
                    for dx in range(S):
                        v = band[i + dy, x + dx]
                        for o in range(n_out):
                            acc[o] += v * Kc[k, o]
                        k += 1
                for o in range(n_out):
                    out[i, x, o] = acc[o]

    return apply_any


def check_fits(table: TransformTable, raw, *, table_name: str = "table") -> None:
    """Raise :class:`TableError` when ``table`` cannot render ``raw`` (CFA, size)."""
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
                  band_pixels: int = 1 << 20) -> np.ndarray:
    """Render a normalised mosaic (CFA phase as the table's) in the table's space.

    Parameters
    ----------
    table
        The transform table.
    mosaic
        float32 (H, W), 0 = black, 1 = white level.
    out
        Optional float32 (H, W, n_out) output array.
    band_pixels
        Pixels per band of rows (bounds the padded-band memory).

    Returns
    -------
    numpy.ndarray
        float32 (H, W, n_out) in ``table.output_space``.
    """
    d = table.definition
    mosaic = np.asarray(mosaic, dtype=np.float32)
    h, w = mosaic.shape
    if out is None:
        out = np.empty((h, w, table.n_out), dtype=np.float32)
    args = d.kernel_args()
    S = d.patch
    apply = _apply_kernel(S, table.n_out)
    cls = None
    for y0, y1 in band_rows(h, w, max_pixels=band_pixels):
        band = pad_mosaic(mosaic, S // 2, d.cfa.period, rows=(y0, y1))
        if cls is None or cls.shape[0] != y1 - y0:
            cls = np.empty((y1 - y0, w), dtype=np.int32)
        band_classes(band, y0, y1 - y0, w, args, out=cls)
        apply(band, cls, table.kernels, out[y0:y1])
    return out


def render_raw(table: TransformTable, raw, *, table_name: str = "table") -> np.ndarray:
    """Render a :class:`l3cli.io.raw.RawImage` (checks that the table fits)."""
    check_fits(table, raw, table_name=table_name)
    return render_mosaic(table, raw.mosaic)


def render_file(table: TransformTable, raw_path: str | os.PathLike, out_path: str | os.PathLike,
                *, table_name: str = "table") -> Path:
    """Read a raw file, render it and write ``out_path`` (format by suffix).

    EXR keeps the table's space (linear values as rendered); TIFF/PNG/JPEG
    receive display sRGB (:func:`l3cli.io.image.write_image`).
    """
    from l3cli.io.image import write_image
    from l3cli.io.raw import read_raw

    raw = read_raw(raw_path)
    img = render_raw(table, raw, table_name=table_name)
    del raw
    return write_image(out_path, img, space=table.output_space,
                       attributes={"l3:table": str(table_name)})
