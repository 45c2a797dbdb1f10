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

For 16 bits a cell spans hundreds of codes near black, and thresholds for
all 65 536 codes per channel (768 kB for three) do not stay in cache.
:func:`interpolated_codes` instead subdivides each of the curve's cells
(within which the curve is linear) into ``m`` sub-cells and keeps, at each
node, the code as a continuous number and its step to the next node;
:func:`l3cli.render_rows.curve_code16_row` takes the floor of the linear
interpolation (two reads of one table per value, no comparison). Between
nodes the composed function (the curve's line, then the encoder's transfer
curve) is smooth, so the interpolation error is bounded by its bend; the
fewest sub-cells of :data:`SUBCELL_CHOICES` whose error, measured inside
every sub-cell, stays under :data:`MAX_INTERP_ERROR` are used. A code is
then the one curve-then-encode gives, or one next to it (a test sweeps the
curve's range): about 0.25 % of the values of a real render move by one
code in 65 535.
"""

from __future__ import annotations

import hashlib
from typing import NamedTuple

import numpy as np

__all__ = ["CELL_CHOICES", "MAX_INTERP_ERROR", "MAX_WALK", "SUBCELL_CHOICES", "CodeTable",
           "code_table", "code_table_for", "curve_codes", "interpolated_codes"]

#: Cells of the uniform grid per channel, the fewest that give one comparison per value
#: (:func:`code_table`): the table shares the L1 cache with the kernels' rows (1536 cells
#: suffice for the Blackmagic table's curve; 8-bit codes are one byte).
CELL_CHOICES = (1024, 2048, 4096, 8192)
#: Most comparisons per value; a curve whose cells span more codes keeps curve-then-encode.
MAX_WALK = 4
#: Sub-cells per curve cell tried for 16-bit interpolated codes (:func:`interpolated_codes`),
#: fewest first: 8 KB per channel per sub-cell (8: 192 kB for three channels, which
#: the trained Blackmagic and Infinite-ISP curves take; in a 9-MP render no slower than 4).
SUBCELL_CHOICES = (8, 16, 32)
#: Largest interpolation error accepted, in codes. Any error under 1 - 0.1 (the float32
#: roundings of the grid position and of the curve's value) keeps a code within one of
#: curve-then-encode. The error is largest in the one sub-cell per channel that holds
#: the transfer curve's bend between its linear and power segments (0.12 for the
#: trained curves with 8 sub-cells; elsewhere under 0.03), and about the mean error's
#: fraction of the values move by one code.
MAX_INTERP_ERROR = 0.5


class CodeTable(NamedTuple):
    """What :func:`l3cli.render_rows.curve_encode_row` reads (the order of its arguments)."""

    #: uint8 (8 bits) or uint16 (n_out, cells): the code of each cell's first value
    #: (interpolated: unused).
    first: np.ndarray
    #: float32 (n_out, 2**bits + walk): ``thr[c, k]`` the smallest ``v`` of code >= k
    #: (NaN where no ``v`` reaches it, and as padding). Interpolated (``walk`` 0):
    #: (n_out, 2 (cells + 1)), per node its code + 1/2 and the step to the next node.
    thr: np.ndarray
    #: float32 (n_out,): the grid's start per channel.
    lo: np.ndarray
    #: float32 (n_out,): cells per unit of ``v``.
    scale: np.ndarray
    #: Comparisons per value; 0: the codes are interpolated (:func:`interpolated_codes`).
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
    """The composed lookup of a curve (:func:`l3cli.tone.curve.curve_arrays`) and an encoder.

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


def _continuous_code(y: np.ndarray, thr: np.ndarray) -> np.ndarray:
    """The encoder's code of values ``y`` as a continuous number (float64), before its clip.

    Piecewise linear through ``k - 1/2`` at each threshold ``thr[k]`` (the smallest
    value of code ``k``) and through the transfer curve's ends (0 at 0, ``2**bits - 1``
    at 1), and continued past them along its end pieces: clipped to
    ``[0, 2**bits - 1]``, ``floor(code + 1/2)`` is the encoder's code of ``y``,
    exactly (the encoder clips ``y`` to [0, 1] first, where the curve is linear at
    both ends). Between thresholds it follows the transfer curve to within the
    curve's bend over one code; continued, it has no kink where a tone curve
    crosses 0 or 1 inside a cell, and the interpolation stays exact there.
    """
    n = thr.size - 1
    xp = np.concatenate([[0.0], thr[1:n].astype(np.float64), [1.0]])
    fp = np.concatenate([[0.0], np.arange(1, n, dtype=np.float64) - 0.5, [n - 1.0]])
    y = np.asarray(y, np.float64)
    lo_slope = (fp[1] - fp[0]) / (xp[1] - xp[0])
    hi_slope = (fp[-1] - fp[-2]) / (xp[-1] - xp[-2])
    return np.where(y < 0, y * lo_slope,
                    np.where(y > 1, fp[-1] + (y - 1) * hi_slope, np.interp(y, xp, fp)))


def interpolated_codes(curve: tuple[np.ndarray, ...], thr: np.ndarray, *,
                       subcells: int | None = None,
                       max_error: float = MAX_INTERP_ERROR) -> CodeTable | None:
    """The curve and a 16-bit encoder as one interpolated lookup per value.

    Parameters
    ----------
    curve
        The curve's arrays (:func:`l3cli.tone.curve.curve_arrays`), as the tile kernel
        reads them.
    thr
        The encoder's thresholds (:attr:`l3cli.io.encode.DisplayParams.thr`, no matrix).
    subcells
        Sub-cells per curve cell; None: the fewest of :data:`SUBCELL_CHOICES` whose
        interpolation error stays under ``max_error``.
    max_error
        Largest error accepted (codes), measured at 7 points inside every sub-cell.

    Returns
    -------
    CodeTable or None
        ``walk`` 0; None when no choice meets ``max_error`` (the caller keeps
        curve-then-encode).

    Examples
    --------
    A linear curve over [0, 1] and the sRGB encoder: the code of 0.5 is
    ``round(65535 * srgb(0.5))``, and the table gives it or a code next to it.

    >>> from l3cli.io.encode import display_params, quantise_reference
    >>> from l3cli.tone.curve import curve_arrays
    >>> lut = np.repeat(np.linspace(0, 1, 1024, dtype=np.float32)[:, None], 3, axis=1)
    >>> curve = curve_arrays(lut, np.array([[0.0] * 3, [1.0] * 3]))
    >>> ct = interpolated_codes(curve, display_params("linear-srgb", 3, 16).thr)
    >>> t = (np.float32(0.5) - ct.lo[0]) * ct.scale[0]
    >>> i = int(t)
    >>> code = int(ct.thr[0, 2 * i] + (t - i) * ct.thr[0, 2 * i + 1])
    >>> abs(code - int(quantise_reference(np.float32(0.5), 16))) <= 1
    True
    """
    base, slope, lo, step = curve
    n_out, n_lut = base.shape
    thr = np.asarray(thr)
    for m in ([subcells] if subcells else SUBCELL_CHOICES):
        cells = (n_lut - 1) * m
        tab = np.empty((n_out, cells + 1, 2), np.float32)
        err = 0.0
        for c in range(n_out):
            nodes = _continuous_code(_curve64(np.arange(cells + 1) / m, base[c], slope[c]), thr)
            nodes32 = (nodes + 0.5).astype(np.float32)
            d = np.diff(nodes32.astype(np.float64))
            tab[c, :, 0] = nodes32
            tab[c, :-1, 1] = d.astype(np.float32)
            tab[c, -1, 1] = 0.0
            f = np.arange(1, 8) / 8.0  # inside every sub-cell
            t = (np.arange(cells)[:, None] + f[None, :]) / m
            exact = _continuous_code(_curve64(t, base[c], slope[c]), thr) + 0.5
            approx = tab[c, :-1, 0:1].astype(np.float64) + f * tab[c, :-1, 1:2]
            err = max(err, float(np.abs(approx - exact).max()))
        if err <= max_error:
            scale = (np.asarray(step, np.float64) * m).astype(np.float32)
            return CodeTable(np.zeros((n_out, 1), np.uint8),  # unused (the 8-bit type: one
                             # compiled kernel for 16 bits with and without the table)
                             np.ascontiguousarray(tab.reshape(n_out, -1)),
                             np.ascontiguousarray(lo, dtype=np.float32), scale, 0)
    return None


def _curve64(t: np.ndarray, base: np.ndarray, slope: np.ndarray) -> np.ndarray:
    """The curve at grid positions ``t`` (in cells), in float64: what
    :func:`l3cli.render_rows.curve_row` computes before its float32 rounding."""
    i = np.minimum(np.floor(t).astype(np.int64), base.size - 1)
    return base[i].astype(np.float64) + (t - i) * slope[i].astype(np.float64)


_TABLES: dict[tuple, CodeTable | None] = {}


def code_table_for(curve: tuple[np.ndarray, ...], thr: np.ndarray, bits: int
                   ) -> CodeTable | None:
    """The composed lookup the display render takes, kept per process for each curve and
    encoder (every raw a table renders has the same curve: built once, about 6 ms for
    8 bits, :func:`code_table`; 16 bits: :func:`interpolated_codes`, about 30 ms)."""
    h = hashlib.sha1()
    for a in (*curve, thr):
        h.update(np.ascontiguousarray(a).tobytes())
    key = (h.hexdigest(), bits)
    if key not in _TABLES:
        if len(_TABLES) > 8:
            _TABLES.clear()
        _TABLES[key] = code_table(curve, thr, bits) if bits == 8 else interpolated_codes(
            curve, thr)
    return _TABLES[key]


def _cell(v: np.ndarray, lo: np.float32, scale: np.float32, cells: int) -> np.ndarray:
    """:func:`l3cli.render_rows.curve_encode_row`'s cell of float32 values (the same float32 arithmetic)."""
    t = (np.asarray(v, np.float32) - np.float32(lo)) * np.float32(scale)
    t = np.minimum(np.maximum(t, np.float32(0)), np.float32(cells - 1))
    return t.astype(np.int64)
