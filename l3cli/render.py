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

import os
from pathlib import Path

import numba as nb
import numpy as np

from l3cli.classify import _class_of, _features, band_rows, pad_mosaic
from l3cli.errors import TableError
from l3cli.table import TransformTable

__all__ = ["check_fits", "render_mosaic", "render_raw", "render_file"]


@nb.njit(cache=True, parallel=True, fastmath=False)
def _render_band(band, y0, chan, wk, cnt_inv, wc, group, level_cuts, contrast_cuts,
                 sat_thr, eps, n_sat, ph, pw, S, kernels, out):
    H, W, n_out = out.shape
    nch = cnt_inv.shape[1]
    P = S * S
    for i in nb.prange(H):
        vals = np.empty(P, dtype=np.float64)
        csum = np.empty(nch, dtype=np.float64)
        acc = np.empty(n_out, dtype=np.float32)
        prow = ((y0 + i) % ph) * pw
        for x in range(W):
            pos = prow + x % pw
            k = 0
            for dy in range(S):
                for dx in range(S):
                    vals[k] = band[i + dy, x + dx]
                    k += 1
            level, contrast, sat = _features(vals, pos, chan, wk, cnt_inv, wc, sat_thr, eps, csum)
            c = _class_of(level, contrast, sat, group[pos], level_cuts, contrast_cuts, n_sat)
            for o in range(n_out):
                acc[o] = kernels[c, P, o]
            for k in range(P):
                v = np.float32(vals[k])
                for o in range(n_out):
                    acc[o] += v * kernels[c, k, o]
            for o in range(n_out):
                out[i, x, o] = acc[o]


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
    (chan, wk, cnt_inv, wc, group, lc, cc, thr, eps, n_sat, ph, pw, S) = d.kernel_args()
    r = S // 2
    for y0, y1 in band_rows(h, w, max_pixels=band_pixels):
        band = pad_mosaic(mosaic, r, (ph, pw), rows=(y0, y1))
        _render_band(band, y0, chan, wk, cnt_inv, wc, group, lc, cc, thr, eps, n_sat, ph, pw, S,
                     table.kernels, out[y0:y1])
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
