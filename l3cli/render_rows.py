"""The render loops: one tile row of affine kernels applied to its patches.

The tile kernel (:mod:`l3cli.classify.kernel`) classifies a row of a tile
and, in render mode, hands the row's classes to one of these loops while the
tile's padded band is still in cache; :func:`l3cli.render.pack_kernels` lays
the table's kernels out for them (:func:`pack_taps` for up to 4 outputs).

For up to 4 outputs a pixel is :func:`affine_taps`, vectorised over the
*taps* of a patch row: the row's ``S`` values are one unaligned load of
``L`` lanes (:func:`tap_lanes`: 8 for patches up to 7; the lanes past the
patch meet zero taps), and per output one multiply-add per patch row
accumulates lane by lane (the first row's product, then the next rows'
fused multiply-adds, in row order). The 4 outputs' lanes are then summed as
one horizontal-add tree (per output ``((l0 + l1) + (l2 + l3)) + ((l4 + l5)
+ (l6 + l7))``, after adding lanes ``j`` and ``8 + j`` for 16 lanes) and the
constant added last. Patch 9 (:func:`tap_tail`) loads 8 lanes per row (its
columns 0-7), then its 9th column's rows 0-7 as one more vector and its last
tap as another (lane 0, zeros), each one more multiply-add per output, before
the tree: 11 per output instead of 18 over 16 lanes. A 7x7 three-output pixel
is 7 loads of the patch, 21
multiply-adds and 21 kernel loads and one tree: about half the instructions
of the former layout (patch rows in pairs, the 4 outputs as lanes; 25
broadcasts, 25 multiply-adds and 25 kernel loads per pixel, then the rows'
sums one by one). numba cannot express this (LLVM's vectorisers leave the
chains scalar), hence the LLVM intrinsic. The order of every rounded
operation is fixed, so a pixel depends on its patch and class only (a test
checks a plain loop of the same order, bit for bit).
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils, errors
from numba.extending import intrinsic

from l3cli.classify.layout import RENDER_LANES, pack_taps, tap_lanes, tap_tail  # re-exported
from l3cli.io.encode_rows import encode_row, encode_rows  # re-exported: the tile kernel's
from l3cli.startup import lean_cache

__all__ = ["RENDER_LANES", "affine_taps", "curve_code16_row", "curve_encode_row", "curve_row",
           "encode_row", "encode_rows", "pack_taps", "render_row4", "render_row_any",
           "tap_lanes", "tap_tail"]

_F32 = ir.FloatType()
_I32 = ir.IntType(32)


@intrinsic
def affine_taps(typingctx, pb_t, i_t, x_t, cls_t, k_t, s_t, n_t):
    """The 4 output values of the pixel at column ``x`` of tile row ``i``.

    ``affine_taps(pb, i, x, cls_row, K, S, NOUT)``: ``pb`` the tile's padded
    band (float32, C order, at least ``tap_lanes(S) - S`` columns past the
    last patch, finite), ``cls_row`` the row's classes, ``K`` the kernels in
    :func:`pack_taps`' layout for ``NOUT`` (3 or 4) outputs, ``S`` the patch
    size and ``NOUT`` compile-time constants (with 3 the 4th value is the
    4th constant alone). Returns 4 float32.
    """
    for t in (s_t, n_t):
        if not isinstance(t, types.IntegerLiteral):
            raise errors.RequireLiteralValue(t)
    S, NOUT = s_t.literal_value, n_t.literal_value
    L = tap_lanes(S)
    TAIL = tap_tail(S)
    sig = types.UniTuple(types.float32, 4)(pb_t, i_t, x_t, cls_t, k_t, s_t, n_t)

    def codegen(context, builder, sig, args):
        pb, i, x, cls_row, K, _, _ = args
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

        def shuffle(a, b, lanes):
            return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(_I32, len(lanes)),
                                                            lanes))

        i, x = idx(i, sig.args[1]), idx(x, sig.args[2])
        cls = context.make_array(sig.args[3])(context, builder, cls_row)
        c = builder.load(builder.gep(cls.data, [x]))
        krow = at(K, sig.args[4], idx(c, sig.args[3].dtype), const(0))
        vt = ir.VectorType(_F32, L)
        # fmuladd: fused where the CPU has FMA, else multiply then add, as numba's
        # `contract` flag makes the scalar loop (same pixels on any CPU)
        fma = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(vt, [vt, vt, vt]), f"llvm.fmuladd.v{L}f32")
        accs = [None] * NOUT
        for dy in range(S):
            p = vload(at(pb, sig.args[0], builder.add(i, const(dy)), x), L)
            for o in range(NOUT):
                kv = vload(builder.gep(krow, [const((dy * NOUT + o) * L)]), L)
                accs[o] = builder.fmul(p, kv) if dy == 0 else builder.call(fma, [p, kv, accs[o]])
        n_vec = S  # kernel vectors per output so far
        if TAIL:  # patch 9: the 9th column's rows 0-7 as one vector, its row 8 as another
            xl = builder.add(x, const(L))
            col = ir.Constant(vt, None)
            for j in range(L):
                v = builder.load(at(pb, sig.args[0], builder.add(i, const(j)), xl))
                col = builder.insert_element(col, v, ir.Constant(_I32, j))
            corner = builder.insert_element(
                ir.Constant(vt, [0.0] * L),
                builder.load(at(pb, sig.args[0], builder.add(i, const(L)), xl)),
                ir.Constant(_I32, 0))
            for extra in (col, corner):
                for o in range(NOUT):
                    kv = vload(builder.gep(krow, [const((n_vec * NOUT + o) * L)]), L)
                    accs[o] = builder.call(fma, [extra, kv, accs[o]])
                n_vec += 1
        v8 = ir.VectorType(_F32, 8)
        sums = []
        for o in range(RENDER_LANES):
            if o >= NOUT:
                sums.append(ir.Constant(v8, None))  # +0 lanes: the 4th output's constant alone
            elif L == 8:
                sums.append(accs[o])
            else:  # 16 lanes: lane j + lane 8 + j
                sums.append(builder.fadd(shuffle(accs[o], accs[o], list(range(8))),
                                         shuffle(accs[o], accs[o], list(range(8, 16)))))

        def hadd(a, b):  # [a0+a1, a2+a3, b0+b1, b2+b3, a4+a5, a6+a7, b4+b5, b6+b7]
            return builder.fadd(shuffle(a, b, [0, 2, 8, 10, 4, 6, 12, 14]),
                                shuffle(a, b, [1, 3, 9, 11, 5, 7, 13, 15]))

        h = hadd(hadd(sums[0], sums[1]), hadd(sums[2], sums[3]))
        total = builder.fadd(shuffle(h, h, [0, 1, 2, 3]), shuffle(h, h, [4, 5, 6, 7]))
        kc = vload(builder.gep(krow, [const(NOUT * n_vec * L)]), RENDER_LANES)
        res = builder.fadd(total, kc)
        out = [builder.extract_element(res, ir.Constant(_I32, lane))
               for lane in range(RENDER_LANES)]
        return context.make_tuple(builder, sig.return_type, out)

    return sig, codegen


@lean_cache
@nb.njit(cache=True)
def render_row4(pb, i, tw, S, cls_row, K, outf, o, n_out):
    """Render the ``tw`` pixels of tile row ``i`` for tables of <= 4 outputs
    (:func:`affine_taps`; ``S`` must be a compile-time constant of the caller)."""
    nb.literally(S)
    ou = np.uint64(o)  # unsigned: no negative-index wrap-around code in the stores
    if n_out == 3:
        for x in range(tw):
            a0, a1, a2, _ = affine_taps(pb, i, x, cls_row, K, S, 3)
            outf[ou] = a0
            outf[ou + np.uint64(1)] = a1
            outf[ou + np.uint64(2)] = a2
            ou += np.uint64(3)
        return
    for x in range(tw):
        a0, a1, a2, a3 = affine_taps(pb, i, x, cls_row, K, S, 4)
        outf[ou] = a0
        if n_out > 1:
            outf[ou + np.uint64(1)] = a1
        if n_out > 2:
            outf[ou + np.uint64(2)] = a2
        if n_out > 3:
            outf[ou + np.uint64(3)] = a3
        ou += np.uint64(n_out)


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
    n = np.uint64(base.shape[1])
    bf = base.ravel()
    sf = slope.ravel()
    step = np.uint64(n_out)
    for c in range(n_out):  # unsigned indices: no negative-index wrap-around code (25 % faster)
        l0 = lo[c]
        si = step_inv[c]
        off = np.uint64(c) * n
        k = np.uint64(o) + np.uint64(c)
        for _ in range(tw):
            t = (outf[k] - l0) * si
            t = min(max(t, np.float32(0.0)), top)
            i = np.uint64(np.uint32(np.int32(t)))
            outf[k] = bf[off + i] + (t - np.float32(i)) * sf[off + i]
            k += step


@lean_cache
@nb.njit(cache=True, nogil=True)
def curve_code16_row(src, tw, tab, lo, scale, out16, o):  # pragma: no cover - compiled
    """16-bit codes of the ``tw`` pixels of 3 values at ``src[0:]`` into ``out16`` from ``o``.

    Per value its position on the grid of :func:`l3cli.tone.code.interpolated_codes`,
    clamped to the grid's nodes ``[0, cells]`` (a NaN gives 0: the clamps are
    written so that an unordered comparison picks the bound, so no index needs a
    second clamp), then its node's code + 1/2 plus the fraction times the step to
    the next node (the last node's step is 0), clamped to [0, 65535] and floored
    (the nodes continue the encoder's end pieces past 0 and 1): the code of the
    curve followed by the encoder, or one next to it. A loop over pixels with
    the channels written out and unsigned indices, as :func:`curve_encode_row`'s.
    """
    top = np.float32(tab.shape[1] // 2 - 1)
    zero = np.float32(0.0)
    hi = np.float32(65535.0)
    tf = tab.ravel()
    two = np.uint64(2)
    one = np.uint64(1)
    c1 = np.uint64(tab.shape[1])
    c2 = c1 + c1
    l0, l1, l2 = lo[0], lo[1], lo[2]
    s0, s1, s2 = scale[0], scale[1], scale[2]
    ou = np.uint64(o)
    k = np.uint64(0)
    for _ in range(tw):
        ta = (src[k] - l0) * s0
        tb = (src[k + one] - l1) * s1
        td = (src[k + two] - l2) * s2
        ta = ta if ta > zero else zero  # NaN: 0
        tb = tb if tb > zero else zero
        td = td if td > zero else zero
        ta = ta if ta < top else top
        tb = tb if tb < top else top
        td = td if td < top else top
        ia = np.uint32(np.int32(ta))
        ib = np.uint32(np.int32(tb))
        id_ = np.uint32(np.int32(td))
        ja = two * np.uint64(ia)
        jb = c1 + two * np.uint64(ib)
        jd = c2 + two * np.uint64(id_)
        xa = tf[ja] + (ta - np.float32(ia)) * tf[ja + one]
        xb = tf[jb] + (tb - np.float32(ib)) * tf[jb + one]
        xd = tf[jd] + (td - np.float32(id_)) * tf[jd + one]
        xa = xa if xa > zero else zero
        xb = xb if xb > zero else zero
        xd = xd if xd > zero else zero
        out16[ou + k] = np.uint32(np.int32(xa if xa < hi else hi))
        out16[ou + k + one] = np.uint32(np.int32(xb if xb < hi else hi))
        out16[ou + k + two] = np.uint32(np.int32(xd if xd < hi else hi))
        k += np.uint64(3)


@lean_cache
@nb.njit(cache=True, nogil=True)
def curve_encode_row(src, tw, n_out, first, thr, lo, scale, walk, out8, out16, bits, o):
    """Codes of the ``tw`` pixels of ``n_out`` values at ``src[0:]`` into ``out8``/``out16``
    from ``o``: per value its cell's first code, then ``walk`` comparisons with the next
    thresholds (:func:`l3cli.tone.code.code_table`; the codes of the curve followed by the encoder).

    Three outputs and one comparison (an 8-bit encoding) take a loop over pixels with
    the channels written out (1.6-2x faster than a loop per channel, measured), with
    unsigned indices (no wrap-around code: 15-40 % faster again) clamped after the
    conversion too (a NaN converts to an arbitrary integer).
    """
    cells = first.shape[1]
    top = np.float32(cells - 1)
    last = np.uint32(cells - 1)
    ou = np.uint64(o)
    if n_out == 3 and walk == 1 and bits == 8:
        f = first.ravel()
        th = thr.ravel()
        nt = np.uint32(thr.shape[1])
        c1 = np.uint32(cells)
        c2 = np.uint32(2 * cells)
        l0, l1, l2 = lo[0], lo[1], lo[2]
        s0, s1, s2 = scale[0], scale[1], scale[2]
        one = np.uint32(1)
        k = np.uint64(0)
        for _ in range(tw):
            a = src[k]
            b = src[k + np.uint64(1)]
            d = src[k + np.uint64(2)]
            ia = min(np.uint32(np.int32(min(max((a - l0) * s0, np.float32(0.0)), top))), last)
            ib = min(np.uint32(np.int32(min(max((b - l1) * s1, np.float32(0.0)), top))), last)
            id_ = min(np.uint32(np.int32(min(max((d - l2) * s2, np.float32(0.0)), top))), last)
            qa = np.uint32(f[ia])
            qb = np.uint32(f[ib + c1])
            qd = np.uint32(f[id_ + c2])
            qa += np.uint32(a >= th[qa + one])
            qb += np.uint32(b >= th[qb + nt + one])
            qd += np.uint32(d >= th[qd + nt + nt + one])
            out8[ou + k] = qa
            out8[ou + k + np.uint64(1)] = qb
            out8[ou + k + np.uint64(2)] = qd
            k += np.uint64(3)
        return
    for c in range(n_out):
        l0 = lo[c]
        s = scale[c]
        for x in range(tw):
            k = np.uint64(x * n_out + c)
            v = src[k]
            t = min(max((v - l0) * s, np.float32(0.0)), top)
            q = np.int32(first[c, min(np.uint32(np.int32(t)), last)])
            for _ in range(walk):
                q += np.int32(v >= thr[c, q + 1])
            if bits == 8:
                out8[ou + k] = q
            else:
                out16[ou + k] = q
