"""The learned tone curve and the display encoding as one lookup per value.

A table with a learned tone curve renders the curve's linear space; each
output value ``v`` is mapped through the curve (:func:`l3cli.render_rows.curve_row`,
an interpolation in a 1024-entry table) and then display-encoded
(:func:`l3cli.io.encode_rows.encode_row`: clip, a bucket lookup, one
comparison). When nothing mixes the channels between the two (no 3x3 after
the curve: the table's output is ``linear-srgb`` or ``srgb`` and its
white-balance adaptation is the identity), the code of a value is a
monotone function of ``v`` alone, per channel, and is fully described by
the smallest float32 ``v`` that reaches each code (its threshold, found by
bisection over float32 bit patterns with the curve's own float32
arithmetic and the encoder's thresholds, so the codes are those of
curve-then-encode).

:func:`code_table` builds, per channel, a uniform grid over the curve's
input range (the fewest cells of :data:`CELL_CHOICES` that give one
comparison per value for 8 bits): the code of each cell's first value and
the thresholds; :func:`l3cli.render_rows.curve_encode_row` looks a value's cell up (a
subtraction, a multiplication, a clamp) and finishes with as many
comparisons with the next thresholds as a cell spans codes at most
(``walk``, 1-2 for 8 bits). Two table reads per value instead of the curve's
two and the encoder's two, and no float pass between them.
"""

from __future__ import annotations

import hashlib
from typing import NamedTuple

import numpy as np

__all__ = ["CELL_CHOICES", "MAX_WALK", "CodeTable", "code_table", "code_table_for", "curve_codes"]

#: Cells of the uniform grid per channel, the fewest that give one comparison per value
#: (:func:`code_table`): the table shares the L1 cache with the kernels' rows (1536 cells
#: suffice for the Blackmagic table's curve; 8-bit codes are one byte).
CELL_CHOICES = (1024, 2048, 4096, 8192)
#: Most comparisons per value; a curve whose cells span more codes keeps curve-then-encode.
MAX_WALK = 4


class CodeTable(NamedTuple):
    """What :func:`l3cli.render_rows.curve_encode_row` reads (the order of its arguments)."""

    #: uint8 (8 bits) or uint16 (n_out, cells): the code of each cell's first value.
    first: np.ndarray
    #: float32 (n_out, 2**bits + walk): ``thr[c, k]`` the smallest ``v`` of code >= k
    #: (NaN where no ``v`` reaches it, and as padding).
    thr: np.ndarray
    #: float32 (n_out,): the grid's start per channel.
    lo: np.ndarray
    #: float32 (n_out,): cells per unit of ``v``.
    scale: np.ndarray
    #: Comparisons per value.
    walk: int


def _key(v: np.ndarray) -> np.ndarray:
    """float32 -> int64 keys in the floats' order (-0.0 and 0.0 both 0)."""
    b = np.asarray(v, np.float32).view(np.int32).astype(np.int64)
    return np.where(b >= 0, b, -(b & 0x7FFFFFFF))


def _unkey(k: np.ndarray) -> np.ndarray:
    k = np.asarray(k, np.int64)
    b = np.where(k >= 0, k, (-k) | 0x80000000).astype(np.uint32)
    return b.view(np.float32)


def curve_codes(v: np.ndarray, c: int, curve: tuple[np.ndarray, ...], thr: np.ndarray
                ) -> np.ndarray:
    """Codes of float32 values ``v`` of channel ``c``: the curve, then the encoder's thresholds.

    The reference for the tests: the same :func:`l3cli.render_rows.curve_row`
    the tile kernel runs, then the code :func:`l3cli.io.encode_rows.encode_row`
    gives a value (clip to [0, 1], the number of thresholds at or below it).
    """
    from l3cli.render_rows import curve_row

    base, slope, lo, step = curve
    x = np.array(v, dtype=np.float32).reshape(-1)
    curve_row(x, 0, x.size, 1, base[c:c + 1], slope[c:c + 1], lo[c:c + 1], step[c:c + 1])
    return _codes(x, thr)


def _codes(x: np.ndarray, thr: np.ndarray) -> np.ndarray:
    x = np.where(x > 0, x, np.float32(0))
    x = np.minimum(x, np.float32(1))
    return (np.searchsorted(thr, x, side="right") - 1).astype(np.int64)


def _curve_codes_np(v: np.ndarray, c: int, curve: tuple[np.ndarray, ...], thr: np.ndarray
                    ) -> np.ndarray:
    """:func:`curve_codes` in numpy (calling the compiled curve in a new process costs
    0.1 s of numba's cache loading; this costs nothing). ``curve_row``'s multiply-add
    is fused (fast-math): the product of two float32 is exact in float64, so one
    float64 add and the cast round as the fused operation does (checked against
    :func:`curve_codes` by the tests; a double rounding could move a value by one
    ulp, its code by at most one)."""
    base, slope, lo, step = curve
    top = np.float32(base.shape[1] - 1) - np.float32(1e-3)
    x = np.asarray(v, dtype=np.float32).reshape(-1)
    t = np.minimum(np.maximum((x - lo[c]) * step[c], np.float32(0.0)), top)
    i = t.astype(np.int32)
    f = t - i.astype(np.float32)
    y = f.astype(np.float64) * slope[c, i].astype(np.float64) + base[c, i].astype(np.float64)
    return _codes(y.astype(np.float32), thr)


def code_table(curve: tuple[np.ndarray, ...], thr: np.ndarray, bits: int, *,
               cells: int | None = None, max_walk: int = MAX_WALK) -> CodeTable | None:
    """The composed lookup of a curve (:func:`l3cli.tonecurve.curve_arrays`) and an encoder.

    Parameters
    ----------
    curve
        The curve's arrays, as the tile kernel reads them.
    thr
        The encoder's thresholds (:attr:`l3cli.io.encode.DisplayParams.thr`, no matrix).
    bits
        8 or 16.
    cells
        Cells of the grid per channel; None: the fewest of :data:`CELL_CHOICES` whose
        cells span at most two codes (one comparison), else the most.

    Returns
    -------
    CodeTable or None
        None when a cell would span more than ``max_walk`` codes.
    """
    base, slope, lo, step = curve
    n_out, n_lut = base.shape
    n = 1 << bits
    codes = np.arange(1, n, dtype=np.int64)
    t_all = np.full((n_out, n + max_walk), np.nan, dtype=np.float32)
    spans, found = [], []
    for c in range(n_out):
        top = np.float32(n_lut - 1) - np.float32(1e-3)
        hi = np.float32(lo[c] + np.float64(top) / np.float64(step[c]))
        a = np.float32(lo[c] - abs(lo[c]) - 1)  # every value below: the bottom code
        b = np.float32(hi + abs(hi) + 1)  # above: the top code
        c_lo = int(_curve_codes_np(a, c, curve, thr)[0])
        c_hi = int(_curve_codes_np(b, c, curve, thr)[0])
        # bisection over bit patterns for the codes reached inside (a, b]
        inside = codes[(codes > c_lo) & (codes <= c_hi)]
        klo = np.full(inside.size, _key(a)[()])
        khi = np.full(inside.size, _key(b)[()])
        todo = np.arange(inside.size)
        while todo.size:
            mid = (klo[todo] + khi[todo]) // 2
            ge = _curve_codes_np(_unkey(mid), c, curve, thr) >= inside[todo]
            khi[todo] = np.where(ge, mid, khi[todo])
            klo[todo] = np.where(ge, klo[todo], mid)
            todo = todo[khi[todo] - klo[todo] > 1]
        t = _unkey(khi)
        t_all[c, inside] = t
        t_all[c, 1:c_lo + 1] = -np.inf
        spans.append(max(float(hi) - float(lo[c]), 1e-12))
        found.append((t, c_lo))
    for size in ([cells] if cells else CELL_CHOICES):
        # the grid: cell i = int((v - lo) * scale), clamped to [0, size - 1]
        first = np.empty((n_out, size), dtype=np.uint8 if bits == 8 else np.uint16)
        scale = np.empty(n_out, dtype=np.float32)
        walk = 1
        for c, (t, c_lo) in enumerate(found):
            scale[c] = np.float32(size / spans[c])
            counts = np.bincount(_cell(t, lo[c], scale[c], size), minlength=size)
            first[c] = c_lo + np.concatenate([[0], np.cumsum(counts)[:-1]])
            walk = max(walk, int(counts.max()) if counts.size else 0)
        if walk == 1:
            break
    if walk > max_walk:
        return None
    return CodeTable(first, np.ascontiguousarray(t_all[:, :n + walk]),
                     np.ascontiguousarray(lo, dtype=np.float32), scale, walk)


_TABLES: dict[tuple, CodeTable | None] = {}


def code_table_for(curve: tuple[np.ndarray, ...], thr: np.ndarray, bits: int
                   ) -> CodeTable | None:
    """:func:`code_table`, kept per process for each curve and encoder (every raw a table
    renders has the same curve: built once, about 6 ms for 8 bits)."""
    h = hashlib.sha1()
    for a in (*curve, thr):
        h.update(np.ascontiguousarray(a).tobytes())
    key = (h.hexdigest(), bits)
    if key not in _TABLES:
        if len(_TABLES) > 8:
            _TABLES.clear()
        _TABLES[key] = code_table(curve, thr, bits)
    return _TABLES[key]


def _cell(v: np.ndarray, lo: np.float32, scale: np.float32, cells: int) -> np.ndarray:
    """:func:`l3cli.render_rows.curve_encode_row`'s cell of float32 values (the same float32 arithmetic)."""
    t = (np.asarray(v, np.float32) - np.float32(lo)) * np.float32(scale)
    t = np.minimum(np.maximum(t, np.float32(0)), np.float32(cells - 1))
    return t.astype(np.int64)
