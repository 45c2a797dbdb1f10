"""The render loops: one tile row of affine kernels applied to its patches.

The tile kernel (:mod:`l3cli.classify.kernel`) classifies a row of a tile
and, in render mode, hands the row's classes to one of these loops while the
tile's padded band is still in cache; :func:`l3cli.render.pack_kernels` lays
the table's kernels out for them (:func:`pack_lanes` for up to 4 outputs).

For up to 4 outputs a pixel is :func:`affine4`: per patch row a chain of
multiply-adds over the row's taps, 4 output lanes wide, and the rows' sums
added to the constant in row order. Two patch rows' chains run side by side
in one 8-lane register (:func:`row_groups`): their patch values come from
the band's *row pairs* (``pb2[k, 2 * x + j] = pb[k + j, x]``, one 8-byte load
broadcast to the 8 lanes) and their kernels are interleaved to match. Every
lane computes the very same sequence of rounded operations as one row at a
time does, so the pixels are bit for bit those of the one-row loop; the
loads and multiply-adds per pixel fall by about a third (the affine part of
a render 30 % faster, measured). numba cannot express this layout (LLVM's
SLP vectoriser leaves the 8 chains scalar), hence the LLVM intrinsic.

Three-output tables (every RGB table) render four pixels per call, their
instructions interleaved tap by tap: a pixel's chains are serial (each
multiply-add waits for the one before), four pixels' chains are not, so the
CPU overlaps them (the default table's 7x7 display render of a 9-MP raw on
one AVX2 core: 0.264-0.295 s before, 0.232-0.246 s after, docs/performance.md;
the pixels are unchanged, bit for bit).
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils, errors
from numba.extending import intrinsic

from l3cli.classify.layout import RENDER_LANES, pack_lanes, row_groups  # re-exported
from l3cli.io.encode_rows import encode_row, encode_rows  # re-exported: the tile kernel's
from l3cli.startup import lean_cache

__all__ = ["RENDER_LANES", "affine4", "curve_encode_row", "curve_row", "encode_row", "encode_rows",
           "pack_lanes", "render_row4", "render_row_any", "row_groups", "row_pairs"]

@nb.njit(cache=True)
def row_pairs(pb, pb2, nrows):
    """``pb2[k, 2 x + j] = pb[k + j, x]`` for band rows ``k < nrows`` (:func:`affine4`'s input)."""
    w = pb.shape[1]
    for k in range(nrows):
        for x in range(w):
            pb2[k, 2 * x] = pb[k, x]
            pb2[k, 2 * x + 1] = pb[k + 1, x]


_F32 = ir.FloatType()
_I32 = ir.IntType(32)


@intrinsic
def affine4(typingctx, pb2_t, pb_t, i_t, x_t, cls_t, k_t, s_t, n_t):
    """The 4 output lanes of each of the ``N`` pixels from column ``x`` of tile row ``i``.

    ``affine4(pb2, pb, i, x, cls_row, K, S, N)``: ``pb`` the tile's padded band
    (float32, C order), ``pb2`` its row pairs (:func:`row_pairs`), ``cls_row``
    the row's classes (pixel ``x + p`` has class ``cls_row[x + p]``), ``K`` the
    kernels in :func:`pack_lanes`' layout, ``S`` the patch size and ``N`` the
    pixels, compile-time constants. Returns a ``4 N``-tuple of float32, pixel
    after pixel. The pixels' instructions are interleaved (tap after tap, one
    multiply-add of each pixel), so their independent chains overlap in the
    CPU; each pixel's own sequence of rounded operations is the one-pixel one.
    """
    for t in (s_t, n_t):
        if not isinstance(t, types.IntegerLiteral):
            raise errors.RequireLiteralValue(t)
    S, N = s_t.literal_value, n_t.literal_value
    sig = types.UniTuple(types.float32, 4 * N)(pb2_t, pb_t, i_t, x_t, cls_t, k_t, s_t, n_t)

    def codegen(context, builder, sig, args):
        pb2, pb, i, x, cls_row, K, _, _ = args
        intp = context.get_value_type(types.intp)

        def idx(v, t):  # an index as intp
            return builder.sext(v, intp) if t.bitwidth < intp.width else v

        def const(v):
            return ir.Constant(intp, v)

        def at(arr, ty, row, col):  # pointer to arr[row, col] (C order, float32)
            a = context.make_array(ty)(context, builder, arr)
            stride = builder.sdiv(cgutils.unpack_tuple(builder, a.strides, 2)[0], const(4))
            return builder.gep(a.data, [builder.add(builder.mul(row, stride), col)])

        def vload(ptr, n):
            vt = ir.VectorType(_F32, n)
            return builder.load(builder.bitcast(ptr, vt.as_pointer()), align=4)

        def lanes(values):
            return ir.Constant(ir.VectorType(_I32, len(values)), values)

        i, x = idx(i, sig.args[2]), idx(x, sig.args[3])
        cls = context.make_array(sig.args[4])(context, builder, cls_row)
        xs = [builder.add(x, const(p)) for p in range(N)]
        krows = []
        for xp in xs:
            c = builder.load(builder.gep(cls.data, [xp]))
            krows.append(at(K, sig.args[5], idx(c, sig.args[4].dtype), const(0)))
        accs = [vload(builder.gep(kr, [const(4 * S * S)]), 4) for kr in krows]  # constants
        base = 0
        for r0, m in row_groups(S):
            vt = ir.VectorType(_F32, 4 * m)
            # fmuladd: fused where the CPU has FMA, else multiply then add, as numba's
            # `contract` flag makes the scalar loop (same pixels on any CPU)
            fma = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(vt, [vt, vt, vt]), f"llvm.fmuladd.v{4 * m}f32")
            sums = [ir.Constant(vt, None)] * N  # +0: the first multiply-add is the product
            for dx in range(S):
                for p in range(N):
                    col = builder.add(xs[p], const(dx))
                    if m == 2:
                        v = vload(at(pb2, sig.args[0], builder.add(i, const(r0)),
                                     builder.mul(col, const(2))), 2)
                    else:
                        one = builder.load(at(pb, sig.args[1], builder.add(i, const(r0)), col),
                                           align=4)
                        v = builder.insert_element(
                            ir.Constant(ir.VectorType(_F32, 1), ir.Undefined), one,
                            ir.Constant(_I32, 0))
                    v = builder.shuffle_vector(v, ir.Constant(v.type, ir.Undefined),
                                               lanes([j for _ in range(4) for j in range(m)]))
                    kv = vload(builder.gep(krows[p], [const(base + 4 * m * dx)]), 4 * m)
                    sums[p] = builder.call(fma, [v, kv, sums[p]])
            for j in range(m):  # the group's rows, in order, onto the sum
                for p in range(N):
                    row = sums[p] if m == 1 else builder.shuffle_vector(
                        sums[p], ir.Constant(vt, ir.Undefined),
                        lanes([m * lane + j for lane in range(4)]))
                    accs[p] = builder.fadd(accs[p], row)
            base += 4 * m * S
        out = [builder.extract_element(acc, ir.Constant(_I32, lane))
               for acc in accs for lane in range(4)]
        return context.make_tuple(builder, sig.return_type, out)

    return sig, codegen


@lean_cache
@nb.njit(cache=True, fastmath={"contract"})
def render_row4(pb2, pb, i, tw, S, cls_row, K, outf, o, n_out):
    """Render the ``tw`` pixels of tile row ``i`` for tables of <= 4 outputs
    (:func:`affine4`: 3 outputs four pixels per call while a pixel follows, the
    rest one; ``S`` must be a compile-time constant of the caller)."""
    nb.literally(S)
    x = 0
    if n_out == 3:
        while x + 4 < tw:  # a pixel follows: every 4th lane lands on a value written next
            r = affine4(pb2, pb, i, x, cls_row, K, S, 4)
            for k in range(16):
                outf[o + k - k // 4] = r[k]
            o += 12
            x += 4
    while x < tw:
        a0, a1, a2, a3 = affine4(pb2, pb, i, x, cls_row, K, S, 1)
        o = _store(outf, o, n_out, a0, a1, a2, a3, x + 1 < tw)
        x += 1


@nb.njit(inline="always")
def _store(outf, o, n_out, a0, a1, a2, a3, more):
    """One pixel's ``n_out`` values at ``outf[o:]``; returns the next pixel's offset. With
    3 outputs and ``more`` (a pixel follows) the 4th lane is stored too (the SLP vector
    store): it lands on the next pixel's first value, which is written next."""
    if n_out == 3:
        outf[o] = a0
        outf[o + 1] = a1
        outf[o + 2] = a2
        if more:
            outf[o + 3] = a3
    elif n_out == 4:
        outf[o] = a0
        outf[o + 1] = a1
        outf[o + 2] = a2
        outf[o + 3] = a3
    else:
        outf[o] = a0
        if n_out > 1:
            outf[o + 1] = a1
    return o + n_out


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
@nb.njit(cache=True, fastmath=True)
def curve_row(outf, o, tw, n_out, base, slope, lo, step_inv):  # pragma: no cover - compiled
    """Map ``tw`` pixels of ``n_out`` values at ``outf[o:]`` through the look-up table.

    Called by the render tile kernel on each output row while it is in cache
    (:func:`l3cli.classify.kernel.run_tiles`, ``curve``); ``base``/``slope``
    are :func:`curve_arrays`'s. Branch-free: values outside the table's range
    take its end entries.
    """
    top = np.float32(base.shape[1] - 1) - np.float32(1e-3)
    for c in range(n_out):
        l0 = lo[c]
        si = step_inv[c]
        for x in range(tw):
            k = o + x * n_out + c
            t = (outf[k] - l0) * si
            t = min(max(t, np.float32(0.0)), top)
            i = np.int32(t)
            outf[k] = base[c, i] + (t - np.float32(i)) * slope[c, i]


@lean_cache
@nb.njit(cache=True, nogil=True)
def curve_encode_row(src, tw, n_out, first, thr, lo, scale, walk, out8, out16, bits, o):
    """Codes of the ``tw`` pixels of ``n_out`` values at ``src[0:]`` into ``out8``/``out16``
    from ``o``: per value its cell's first code, then ``walk`` comparisons with the next
    thresholds (:func:`l3cli.tonecode.code_table`; the codes of the curve followed by the encoder).

    Three outputs and one comparison (an 8-bit encoding) take a loop over pixels with
    the channels written out (1.6-2x faster than a loop per channel, measured), with
    unsigned indices (no wrap-around code) clamped after the conversion too (a NaN
    converts to an arbitrary integer).
    """
    cells = first.shape[1]
    top = np.float32(cells - 1)
    last = np.uint32(cells - 1)
    if n_out == 3 and walk == 1 and bits == 8:
        f = first.ravel()
        th = thr.ravel()
        nt = np.uint32(thr.shape[1])
        l0, l1, l2 = lo[0], lo[1], lo[2]
        s0, s1, s2 = scale[0], scale[1], scale[2]
        one = np.uint32(1)
        for x in range(tw):
            k = 3 * x
            a = src[k]
            b = src[k + 1]
            d = src[k + 2]
            ia = min(np.uint32(np.int32(min(max((a - l0) * s0, np.float32(0.0)), top))), last)
            ib = min(np.uint32(np.int32(min(max((b - l1) * s1, np.float32(0.0)), top))), last)
            id_ = min(np.uint32(np.int32(min(max((d - l2) * s2, np.float32(0.0)), top))), last)
            qa = np.uint32(f[ia])
            qb = np.uint32(f[ib + np.uint32(cells)])
            qd = np.uint32(f[id_ + np.uint32(2 * cells)])
            qa += np.uint32(a >= th[qa + one])
            qb += np.uint32(b >= th[qb + nt + one])
            qd += np.uint32(d >= th[qd + nt + nt + one])
            out8[o + k] = qa
            out8[o + k + 1] = qb
            out8[o + k + 2] = qd
        return
    for c in range(n_out):
        l0 = lo[c]
        s = scale[c]
        for x in range(tw):
            k = x * n_out + c
            v = src[k]
            t = min(max((v - l0) * s, np.float32(0.0)), top)
            q = np.int32(first[c, min(np.uint32(np.int32(t)), last)])
            for _ in range(walk):
                q += np.int32(v >= thr[c, q + 1])
            if bits == 8:
                out8[o + k] = q
            else:
                out16[o + k] = q
