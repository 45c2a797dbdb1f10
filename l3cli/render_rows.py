"""The render loops: one tile row of affine kernels applied to its patches.

The tile kernel (:mod:`l3cli.classify.kernel`) classifies a row of a tile
and, in render mode, hands the row's classes to one of these loops while the
tile's padded band is still in cache; :func:`l3cli.render.pack_kernels` lays
the table's kernels out for them.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["RENDER_LANES", "render_row4", "render_row_any"]

#: Output lanes of the vectorised render path (tables with up to 4 outputs).
RENDER_LANES = 4


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
