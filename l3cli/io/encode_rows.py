"""The display encoder's loops: float rows to sRGB display integers, in numba.

:func:`encode_row` is the one encoding loop: :func:`encode_rows` runs it
over an image for :func:`l3cli.io.encode.display_encode`, and the tile
kernel (:data:`l3cli.classify.MODE_DISPLAY`) runs it on each rendered row
(through :mod:`l3cli.render_rows`, which re-exports it). It lives in the file
layer, below the model, so that :mod:`l3cli.io.encode` imports nothing from
the model; :mod:`l3cli.io.encode` imports this module only on first use, so
that importing it does not import numba.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from l3cli.startup import lean_cache

__all__ = ["encode_row", "encode_rows"]


@lean_cache
@nb.njit(cache=True, nogil=True)
def encode_row(src, n, use_matrix, m, thr, buckets, interp, shift, lin, out8, out16, bits, o):
    """Display-encode ``n`` float values of ``src`` into ``out8``/``out16`` from ``o``.

    The fused half of :func:`l3cli.io.encode.display_encode` (which runs it
    row by row) and of the display render (:data:`l3cli.classify.MODE_DISPLAY`):
    per value (after the 3x3 ``m`` in float64 when ``use_matrix``, pixels of 3
    values) clip to [0, 1] (NaN gives 0), then look the code up by the
    value's bucket (its float32 bits shifted right by ``shift``): for 8 bits
    the bucket's first code and one comparison with the next threshold; for
    16 bits the floor of the linear estimate of
    :func:`l3cli.io.encode.interpolation_table` in the low bits (within 0.1
    of the unrounded code, so the code or the one below it), settled by one
    comparison with the next threshold. ``lin`` is scratch of at least ``n``
    float32; ``bits`` (8 or 16) picks the output array. No fast-math here: the matrix product is the
    plain float64 one, as numpy computes it.
    """
    if use_matrix:
        for x in range(n // 3):
            a = np.float64(src[3 * x])
            b = np.float64(src[3 * x + 1])
            d = np.float64(src[3 * x + 2])
            lin[3 * x] = np.float32(m[0, 0] * a + m[0, 1] * b + m[0, 2] * d)
            lin[3 * x + 1] = np.float32(m[1, 0] * a + m[1, 1] * b + m[1, 2] * d)
            lin[3 * x + 2] = np.float32(m[2, 0] * a + m[2, 1] * b + m[2, 2] * d)
    else:
        for k in range(n):
            lin[k] = src[k]
    for k in range(n):  # clip to [0, 1]; NaN gives 0
        v = lin[k]
        v = v if v > np.float32(0.0) else np.float32(0.0)
        lin[k] = v if v < np.float32(1.0) else np.float32(1.0)
    lb = lin.view(np.uint32)  # unsigned indices: no negative-index wrap-around code
    ou = np.uint64(o)
    if bits == 8:
        for k in range(n):
            q = np.uint64(buckets[lb[k] >> shift])
            q += np.uint64(lin[k] >= thr[q + np.uint64(1)])
            out8[ou + np.uint64(k)] = q
    else:
        low = np.uint32((1 << shift) - 1)
        for k in range(n):  # the estimate is in [0, 2**16 - 1] (the table's ends are exact)
            b = lb[k]
            j = np.uint64(2) * np.uint64(b >> shift)
            q = np.uint64(np.uint32(interp[j] + interp[j + np.uint64(1)] * np.float32(b & low)))
            out16[ou + np.uint64(k)] = q + np.uint64(lin[k] >= thr[q + np.uint64(1)])


@lean_cache
@nb.njit(cache=True, nogil=True)
def encode_rows(img, use_matrix, matrix, thr, buckets, interp, shift, out8, out16, bits):
    """Display-encode a float32 (H, W, C) image row by row (:func:`encode_row`) into the
    flat ``out8`` (8 bits) or ``out16`` (16 bits); the kernel of
    :func:`l3cli.io.encode.display_encode`."""
    h, w, c = img.shape
    flat = img.reshape(h, w * c)
    lin = np.empty(w * c, dtype=np.float32)
    for y in range(h):
        encode_row(flat[y], w * c, use_matrix, matrix, thr, buckets, interp, shift, lin,
                   out8, out16, bits, y * w * c)
