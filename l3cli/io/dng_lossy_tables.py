"""The lossy DNG decoder's tables: JPEG's zig-zag order, dcraw's IDCT basis, the
Huffman lookup tables (:mod:`l3cli.io.dng_lossy` builds them per tile,
:mod:`l3cli.io.dng_lossy_tile` reads them)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["BASIS", "FAST_BITS", "SQRT1_2", "ZIGZAG", "fast_ac", "huffman_table"]

#: JPEG zig-zag order: position in the 8x8 block (row-major) of the i-th coefficient.
ZIGZAG = np.array([
    0, 1, 8, 16, 9, 2, 3, 10, 17, 24, 32, 25, 18, 11, 4, 5,
    12, 19, 26, 33, 40, 48, 41, 34, 27, 20, 13, 6, 7, 14, 21, 28,
    35, 42, 49, 56, 57, 50, 43, 36, 29, 22, 15, 23, 30, 37, 44, 51,
    58, 59, 52, 45, 38, 31, 39, 46, 53, 60, 61, 54, 47, 55, 62, 63], dtype=np.int64)

#: dcraw's IDCT basis, ``(float) (cos((k & 31) pi / 16) / 2)`` with ``k = (2x + 1) u``,
#: as ``BASIS[u, x]``.
BASIS = np.array([[math.cos((((2 * x + 1) * u) & 31) * math.pi / 16) / 2 for x in range(8)]
                   for u in range(8)], dtype=np.float32)
SQRT1_2 = np.float32(math.sqrt(0.5))


def huffman_table(counts: bytes, values: bytes) -> np.ndarray:
    """dcraw's lookup table for one DHT table: ``[max_len, (len << 8 | value) x 2**max_len]``."""
    longest = 16
    while longest and not counts[longest - 1]:
        longest -= 1
    table = np.zeros(1 + (1 << longest), dtype=np.uint16)
    table[0] = longest
    h, k = 1, 0
    for length in range(1, longest + 1):
        for _ in range(counts[length - 1]):
            if k >= len(values):
                raise ValueError("DHT values run short")
            span = 1 << (longest - length)
            stop = min(h + span, (1 << longest) + 1)
            table[h:stop] = length << 8 | values[k]
            h, k = stop, k + 1
    return table


#: Bits looked at by the AC decoder's one-step table (:func:`fast_ac`).
FAST_BITS = 10


def fast_ac(ac: np.ndarray) -> np.ndarray:
    """One lookup per AC coefficient whose code and value bits fit in :data:`FAST_BITS`.

    For each ``FAST_BITS``-bit prefix: ``coef << 16 | run << 8 | bits used``,
    from the Huffman table ``ac`` (:func:`huffman_table`) and the sign
    extension of T.81 F.2.2.1; 0 where the prefix holds no whole
    (code, value) pair, or an end-of-block or run-of-16 code (the full path
    decodes those).
    """
    longest = int(ac[0])
    prefix = np.arange(1 << FAST_BITS, dtype=np.int64)
    idx = (prefix << (longest - FAST_BITS) if longest >= FAST_BITS
           else prefix >> (FAST_BITS - longest))
    entry = ac[1 + idx].astype(np.int64)
    code_len, size, run = entry >> 8, entry & 15, (entry >> 4) & 15
    total = code_len + size
    ok = (code_len > 0) & (code_len <= longest) & (size > 0) & (total <= FAST_BITS)
    bits = (prefix >> np.maximum(FAST_BITS - total, 0)) & ((1 << size) - 1)
    top = (1 << size) - 1
    coef = np.where(bits <= top >> 1, bits - top, bits)
    return np.where(ok, (coef << 16) | (run << 8) | total, 0).astype(np.int64)
