"""The lossy DNG tile decoder's numba code (:mod:`l3cli.io.dng_lossy` runs it).

Imported only where numba compiles or loads the decoder; otherwise its
machine code comes from :mod:`l3cli.kernel_store`, without numba.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from l3cli.io.dng_lossy_tables import FAST_BITS

__all__ = ["decode_tile", "idct"]

_F32 = ir.FloatType()
_I32 = ir.IntType(32)


@intrinsic
def idct(typingctx, w0_t, basis_t, out_t):
    """dcraw's 8x8 IDCT of ``w0`` into ``out`` (float32[64] each, row-major), vectorised.

    ``w1[r, :] = sum_c w0[r, c] * basis[c, :]`` and then
    ``out[r, :] = sum_c w1[c, :] * basis[c, r]``, each sum starting at 0 and
    taken over ``c = 0..7`` in order, one multiply and one add per term (no
    fused multiply-add): in each of the 8 lanes exactly dcraw's operations,
    so exactly its values.
    """
    sig = types.void(w0_t, basis_t, out_t)

    def codegen(context, builder, sig, args):
        vt = ir.VectorType(_F32, 8)
        ptrs = [context.make_array(t)(context, builder, a).data
                for t, a in zip(sig.args, args, strict=True)]
        w0, basis, out = ptrs

        def row(ptr, r):
            p = builder.gep(ptr, [ir.Constant(ir.IntType(64), 8 * r)])
            return builder.load(builder.bitcast(p, vt.as_pointer()), align=4)

        def splat(value):
            v = builder.insert_element(ir.Constant(vt, ir.Undefined), value,
                                       ir.Constant(_I32, 0))
            return builder.shuffle_vector(v, ir.Constant(vt, ir.Undefined),
                                          ir.Constant(ir.VectorType(_I32, 8), [0] * 8))

        B = [row(basis, c) for c in range(8)]
        W0 = [row(w0, r) for r in range(8)]
        W1 = []
        for r in range(8):
            acc = ir.Constant(vt, None)
            for c in range(8):
                term = builder.fmul(splat(builder.extract_element(W0[r], ir.Constant(_I32, c))),
                                    B[c])
                acc = builder.fadd(acc, term)
            W1.append(acc)
        for r in range(8):
            acc = ir.Constant(vt, None)
            for c in range(8):
                term = builder.fmul(W1[c], splat(builder.extract_element(B[c],
                                                                         ir.Constant(_I32, r))))
                acc = builder.fadd(acc, term)
            p = builder.gep(out, [ir.Constant(ir.IntType(64), 8 * r)])
            builder.store(acc, builder.bitcast(p, vt.as_pointer()), align=4)
        return context.get_dummy_value()

    return sig, codegen


@nb.njit(inline="always")
def _fill(buf, pos, end, acc, nbits, stopped):  # pragma: no cover - numba
    """Top the bit buffer up to more than 56 bits; stop at a marker or the end."""
    while nbits <= 56 and not stopped:
        if pos >= end:
            stopped = True
        elif buf[pos] == 0xFF:
            if pos + 1 < end and buf[pos + 1] == 0:  # a stuffed 0xFF data byte
                acc = (acc << np.uint64(8)) | np.uint64(0xFF)
                nbits += 8
                pos += 2
            else:
                stopped = True
        else:
            acc = (acc << np.uint64(8)) | np.uint64(buf[pos])
            nbits += 8
            pos += 1
    return pos, acc, nbits, stopped


@nb.njit(inline="always")
def _peek(acc, nbits, n):  # pragma: no cover - numba
    """The next ``n`` bits (zeros past the end of the data: looked at, never consumed)."""
    if n == 0:
        return np.int64(0)
    mask = np.uint64((1 << n) - 1)
    if nbits >= n:
        return np.int64((acc >> np.uint64(nbits - n)) & mask)
    return np.int64((acc << np.uint64(n - nbits)) & mask)


@nb.njit(inline="always")
def _extend(v, length):  # pragma: no cover - numba
    """JPEG's sign extension of a ``length``-bit magnitude (T.81 F.2.2.1)."""
    top = (1 << length) - 1
    return v - (top if v <= top >> 1 else 0)  # no branch: the sign is a coin toss


@nb.njit(nogil=True)  # no numba cache: l3cli.kernel_store keeps the machine code
def decode_tile(buf, pos, end, quant, dc, ac, fast, lines, samples, tile_width, trow, tcol,
                 curve, out, zigzag, basis, sqrt1_2):  # pragma: no cover - numba
    """Decode one tile's scan into ``out``: 0 when done, -1 if the data ran out."""
    raw_height, raw_width = out.shape
    dc_bits = np.int64(dc[0])
    ac_bits = np.int64(ac[0])
    acc = np.uint64(0)
    nbits = np.int64(0)  # valid bits at the bottom of acc
    stopped = False  # a marker (or the end of the data) was reached
    vpred = np.int64(16384)  # dcraw's DC predictor: 8 x the 12-bit level shift 2048
    w0 = np.zeros(64, dtype=np.float32)
    w2 = np.zeros(64, dtype=np.float32)
    codes = np.zeros(64, dtype=np.int64)
    for jrow in range(0, lines - 7, 8):
        for jcol in range(0, samples - 7, 8):
            w0[:] = 0
            # ---- DC: a Huffman-coded length, then that many bits of difference
            if nbits < 32:
                pos, acc, nbits, stopped = _fill(buf, pos, end, acc, nbits, stopped)
            entry = np.int64(dc[1 + _peek(acc, nbits, dc_bits)])
            nbits -= entry >> 8
            length = entry & 0xFF
            if length == 16:  # DNG >= 1.1: the code for -32768
                diff = np.int64(-32768)
            else:
                if length > 16 or nbits < length:
                    return -1
                diff = _extend(_peek(acc, nbits, length), length)
                nbits -= length
            if nbits < 0:
                return -1
            vpred += diff * quant[0]
            if vpred < -(1 << 30) or vpred > 1 << 30:
                return -1  # dcraw's int would near overflow: LibRaw's own path
            w0[0] = np.float32(vpred)
            # ---- AC: (run, length) codes, each followed by `length` bits
            k = 1
            while k < 64:
                if nbits < 32:
                    pos, acc, nbits, stopped = _fill(buf, pos, end, acc, nbits, stopped)
                f = np.int64(fast[_peek(acc, nbits, FAST_BITS)])
                if f != 0:  # code and value within the next FAST_BITS bits
                    nbits -= f & 0xFF
                    k += (f >> 8) & 15
                    if nbits < 0 or k > 63:
                        return -1
                    w0[zigzag[k]] = np.float32((f >> 16) * quant[k])
                    k += 1
                    continue
                entry = np.int64(ac[1 + _peek(acc, nbits, ac_bits)])
                nbits -= entry >> 8
                if nbits < 0:
                    return -1
                skip = (entry >> 4) & 15
                length = entry & 15
                k += skip
                if length == 0 and skip < 15:
                    break  # end of block
                if k > 63 or nbits < length:
                    return -1  # past the block (dcraw would read past its tables)
                coef = _extend(_peek(acc, nbits, length), length)
                nbits -= length
                w0[zigzag[k]] = np.float32(coef * quant[k])
                k += 1
            # ---- IDCT (dcraw's float32 operations, in its order), round, linearise
            for c in range(8):
                w0[c] *= sqrt1_2
            for c in range(8):
                w0[8 * c] *= sqrt1_2
            idct(w0, basis, w2)
            # dcraw's CLIP((int)(v + 0.5)): the double sum truncated, clipped to 0..65535
            inside = True
            for q in range(64):
                d = np.float64(w2[q]) + 0.5
                inside &= (d > -2147483649.0) & (d < 2147483648.0)  # an int, as in C
                codes[q] = min(max(np.int64(d), 0), 65535)
            if not inside:
                return -1  # C's conversion would be undefined: LibRaw's own path
            y0 = trow + jcol // tile_width + jrow * 2
            x0 = tcol + jcol % tile_width
            if y0 + 14 < raw_height and x0 + 7 < raw_width:
                for r in range(8):
                    for j in range(8):
                        out[y0 + 2 * r, x0 + j] = curve[codes[8 * r + j]]
            else:  # a block over the raw's right or bottom edge
                for r in range(8):
                    for j in range(8):
                        if y0 + 2 * r < raw_height and x0 + j < raw_width:
                            out[y0 + 2 * r, x0 + j] = curve[codes[8 * r + j]]
    return 0
