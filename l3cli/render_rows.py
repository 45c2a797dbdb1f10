"""The render loops: one tile row of affine kernels applied to its patches.

The tile kernel (:mod:`l3cli.classify.kernel`) classifies a row of a tile
and, in render mode, hands the row's classes to one of these loops while the
tile's padded band is still in cache; :func:`l3cli.render.pack_kernels` lays
the table's kernels out for them.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from l3cli.startup import lean_cache

__all__ = ["RENDER_LANES", "encode_row", "encode_rows", "render_row4", "render_row_any"]

#: Output lanes of the vectorised render path (tables with up to 4 outputs).
RENDER_LANES = 4


@lean_cache
@nb.njit(cache=True, fastmath={"contract"})
def render_row4(pb, i, x, tw, S, cls_row, K, outf, o, n_out):
    """Render pixels ``x .. tw-1`` of tile row ``i`` for tables of <= 4 outputs.

    ``K`` is (n_classes, 4 * (S*S + 1)): per tap (row-major over the patch,
    then the constant) the 4 output lanes. The 4 lanes are one SIMD register;
    the partial sums per patch row keep the multiply-add chains short.
    """
    P = S * S
    for x in range(tw):
        c = cls_row[x]
        a0 = K[c, 4 * P]
        a1 = K[c, 4 * P + 1]
        a2 = K[c, 4 * P + 2]
        a3 = K[c, 4 * P + 3]
        for dy in range(S):
            r0 = np.float32(0.0)
            r1 = np.float32(0.0)
            r2 = np.float32(0.0)
            r3 = np.float32(0.0)
            for dx in range(S):
                v = pb[i + dy, x + dx]
                k = 4 * (dy * S + dx)
                r0 += v * K[c, k]
                r1 += v * K[c, k + 1]
                r2 += v * K[c, k + 2]
                r3 += v * K[c, k + 3]
            a0 += r0
            a1 += r1
            a2 += r2
            a3 += r3
        # kept as separate branches on purpose: merging the two 4-store cases
        # costs the SLP vector store (render ~10 % slower, measured)
        if n_out == 3:
            if x < tw - 1:  # the 4th lane lands on the next pixel, written next
                outf[o] = a0
                outf[o + 1] = a1
                outf[o + 2] = a2
                outf[o + 3] = a3
            else:
                outf[o] = a0
                outf[o + 1] = a1
                outf[o + 2] = a2
        elif n_out == 4:
            outf[o] = a0
            outf[o + 1] = a1
            outf[o + 2] = a2
            outf[o + 3] = a3
        else:
            outf[o] = a0
            if n_out > 1:
                outf[o + 1] = a1
        o += n_out


@lean_cache
@nb.njit(cache=True, fastmath={"contract"})
def render_row_any(pb, i, tw, S, cls_row, K, outf, o, n_out):
    """Render a tile row for tables of any number of outputs (``K`` (n_classes,
    (S*S + 1) * n_out), tap-major)."""
    P = S * S
    acc = np.empty(n_out, dtype=np.float32)
    for x in range(tw):
        c = cls_row[x]
        for q in range(n_out):
            acc[q] = K[c, P * n_out + q]
        for dy in range(S):
            for dx in range(S):
                v = pb[i + dy, x + dx]
                k = (dy * S + dx) * n_out
                for q in range(n_out):
                    acc[q] += v * K[c, k + q]
        for q in range(n_out):
            outf[o + q] = acc[q]
        o += n_out


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
