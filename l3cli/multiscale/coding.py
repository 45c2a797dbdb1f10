"""The multi-scale stage's coding (:mod:`l3cli.multiscale.stage`): the sRGB transfer
curve, extended as an odd function, from a table (:func:`code_table`, :func:`encode`,
:func:`decode`), and the 8-bit display codes straight from a value in that coding
(:func:`direct_table`)."""

from __future__ import annotations

import functools

import numpy as np

from l3cli.multiscale._exec import split

__all__ = ["CODE_SHIFT", "CODE_TOP", "DIRECT_CELLS", "code_table", "code_values", "decode", "direct_table",
           "encode"]

#: Bits of a float32 dropped to number a bucket of the coding's table: 512 per octave.
CODE_SHIFT = 14
#: The coding's table reaches this value; beyond it the formula is evaluated.
CODE_TOP = 64.0


def _iec(x: np.ndarray, inverse: bool) -> np.ndarray:
    """The IEC 61966-2-1 sRGB curve (``inverse``: its inverse) in float64, ``x >= 0``."""
    x = np.asarray(x, dtype=np.float64)
    if inverse:
        return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


@functools.cache
def code_table(inverse: bool) -> tuple[np.ndarray, np.ndarray, int, int]:
    """The table of the stage's coding (``inverse``: of its inverse).

    Above the curve's linear segment, a value ``v`` falls in the bucket
    ``b = bits(v) >> CODE_SHIFT`` (512 per octave); its coding is
    ``base[b - first] + slope[b - first] * (v - start_b)`` in float32, the line
    through the IEC curve's values (float64) at the bucket's ends ``start_b``
    and ``start_{b+1}``: within 2e-6 of the curve relative to the value.

    Returns
    -------
    base, slope
        float32 (last - first + 1,).
    first, last
        The buckets of the linear segment's end and of :data:`CODE_TOP`.
    """
    lo = np.float32(0.04045 if inverse else 0.0031308)
    first = int(lo.view(np.uint32)) >> CODE_SHIFT
    last = int(np.float32(CODE_TOP).view(np.uint32)) >> CODE_SHIFT
    b = np.arange(first, last + 2, dtype=np.uint32)
    starts = (b << np.uint32(CODE_SHIFT)).view(np.float32).astype(np.float64)
    vals = _iec(starts, inverse)
    slope = (vals[1:] - vals[:-1]) / (starts[1:] - starts[:-1])
    return vals[:-1].astype(np.float32), slope.astype(np.float32), first, last


def encode(v: np.ndarray, transfer: str) -> np.ndarray:
    """The stage's coding of ``v`` (float32): for ``"srgb"`` the sRGB transfer curve
    (IEC 61966-2-1) extended to an odd function on all reals, its linear segment exact
    and above it from :func:`code_table` (:func:`l3cli.multiscale._loops.code_rows`);
    ``v`` itself for ``"none"``."""
    v = np.asarray(v, dtype=np.float32)
    return v if transfer == "none" else code_values(v, inverse=False)


def decode(u: np.ndarray, transfer: str) -> np.ndarray:
    """The inverse of :func:`encode` (the inverse curve, from its own table)."""
    u = np.asarray(u, dtype=np.float32)
    return u if transfer == "none" else code_values(u, inverse=True)


def code_values(v: np.ndarray, *, inverse: bool, out: np.ndarray | None = None) -> np.ndarray:
    """The sRGB coding of ``v`` (``inverse``: its inverse) into ``out`` (a new array when
    None; may be ``v``), row by row on l3's threads (:func:`l3cli.multiscale._loops.code_rows`)."""
    src = np.asarray(v, order="C")  # (ascontiguousarray would make a 0-d array 1-d)
    out = np.empty_like(src) if out is None else out
    rows = src.shape[0] if src.ndim > 1 else 1
    split("code_rows", (src.reshape(rows, -1), out.reshape(rows, -1), *code_table(inverse),
                         inverse), rows)
    return out


#: Cells of [0, 1] of the direct 8-bit look-up (:func:`direct_table`).
DIRECT_CELLS = 1024


@functools.cache
def direct_table() -> tuple[np.ndarray, np.ndarray]:
    """The 8-bit display code of a value in the sRGB coding, without decoding it.

    ``uthr[k]``: the smallest float32 ``v`` whose :func:`decode` the display
    encoder (:func:`l3cli.io.encode.srgb_thresholds`) gives code ``k`` or more
    (bisection over float32 bit patterns; ``uthr[256] = inf``); ``cell_code[i]``:
    the code of ``i / DIRECT_CELLS``. So ``code(v) = cell_code[cell] + (v >=
    uthr[cell_code[cell] + 1])``, with no cell holding two thresholds (checked).
    """
    from l3cli.io.encode import srgb_thresholds

    thr = srgb_thresholds(8, True)[0]
    one = int(np.float32(1.0).view(np.int32))
    lo = np.zeros(255, np.int64)  # bit patterns below each threshold ...
    hi = np.full(255, one, np.int64)  # ... and reaching it (decode(1) = 1)
    while np.any(hi - lo > 1):
        mid = (lo + hi) // 2
        ge = decode(mid.astype(np.int32).view(np.float32), "srgb") >= thr[1:256]
        hi = np.where(ge, mid, hi)
        lo = np.where(ge, lo, mid)
    uthr = np.concatenate([[0.0], hi.astype(np.int32).view(np.float32), [np.inf]])
    uthr = uthr.astype(np.float32)
    starts = np.arange(DIRECT_CELLS + 1, dtype=np.float32) / np.float32(DIRECT_CELLS)
    cell_code = (np.searchsorted(uthr[:256], starts, side="right") - 1).astype(np.uint8)
    if np.any(np.diff(np.searchsorted(uthr, starts, side="left")) > 1):
        raise RuntimeError("a cell of the direct 8-bit look-up holds two thresholds")
    return cell_code, uthr
