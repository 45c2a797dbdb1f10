"""The tile kernel: the one implementation of the classification rule.

Render and train both come through :func:`run_tiles`. Per tile of pixels the
numba kernel computes S-tap horizontal then vertical sums of each channel's
``x`` and ``x²`` and an OR of the saturated-channel bits, then level,
contrast and class per pixel; in render mode it hands each row's classes to
the render loops (:mod:`l3cli.render_rows`) while the tile is in cache.

The kernel's inputs that depend on the class definition only are built in
one place, :func:`l3cli.classify.layout.kernel_tables`, as a
:class:`~l3cli.classify.layout.KernelTables` whose field order is the
kernel's argument order.
"""

from __future__ import annotations

import contextlib
import functools
import os
from typing import Any

# OpenMP threads that wait passively instead of spinning: on a shared or busy
# machine spinning workers steal the cores the kernels need (2x slower
# training measured under load); set OMP_WAIT_POLICY yourself to override.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba as nb  # noqa: E402
import numpy as np  # noqa: E402

from l3cli import defaults  # noqa: E402
from l3cli.cfa import CFA  # noqa: E402
from l3cli.classify.definition import DEFAULT_CONTRAST_EPS, ClassDefinition  # noqa: E402
from l3cli.classify.features import ContextGuide, context_guide  # noqa: E402
from l3cli.classify.layout import KernelTables, kernel_tables  # noqa: E402
from l3cli.classify.mosaic import band_rows, check_mosaic  # noqa: E402
from l3cli.render_rows import encode_row, render_row4, render_row_any, row_pairs  # noqa: E402
from l3cli.startup import lean_cache  # noqa: E402
from l3cli.tonecode import curve_encode_row  # noqa: E402
from l3cli.tonecurve import curve_row  # noqa: E402

__all__ = ["MODE_CLASSES", "MODE_DISPLAY", "MODE_FEATURES", "MODE_RENDER", "KernelTables",
           "kernel_tables", "check_mosaic", "band_rows", "run_tiles", "classify",
           "patch_features"]

#: Output rows and columns of one parallel tile. A tile's padded band, its
#: ring of horizontal sums and its output rows stay in the core's L2 cache.
#: 64 rows rather than 32: the S - 1 rows of horizontal sums a tile shares with
#: the tile above are computed twice, and halving that cost 4-5 % less CPU
#: per render (9 MP, patch 5 and 7; 128 rows gave no more).
_TILE_ROWS = 64
_TILE_COLS = 512

#: What the tile kernel does with each pixel's class (see :func:`run_tiles`).
MODE_CLASSES, MODE_FEATURES, MODE_RENDER, MODE_DISPLAY = 0, 1, 2, 3


@contextlib.contextmanager
def _slp_vectorize():
    """Compile with LLVM's SLP vectoriser (numba leaves it off by default).

    It turns the render kernel's per-output multiply-adds into one SIMD
    multiply-add over the output lanes. Only the tile kernel is compiled
    inside this context; the classification arithmetic has no fast-math
    flags, so vectorised and scalar code give bit-identical features.
    """
    old = nb.config.SLP_VECTORIZE
    nb.config.SLP_VECTORIZE = 1
    try:
        yield
    finally:
        nb.config.SLP_VECTORIZE = old


def _callee_stamp() -> tuple[int, ...]:
    """Size and modification time of the modules compiled into the tile kernel.

    numba's cache checks only the kernel's own source file, not those of the
    functions it calls (:mod:`l3cli.render_rows`, :mod:`l3cli.tonecurve`,
    :mod:`l3cli.tonecode`, :mod:`l3cli.io.encode_rows`).
    The kernel holds this stamp as a closure constant, which is part of
    numba's cache key, so an edit there recompiles it instead of loading a
    stale kernel.
    """
    from l3cli import render_rows, tonecode, tonecurve
    from l3cli.io import encode_rows

    stamp: list[int] = []
    for module in (render_rows, tonecurve, tonecode, encode_rows):
        st = os.stat(module.__file__)
        stamp += [st.st_size, st.st_mtime_ns]
    return tuple(stamp)


@functools.cache
def _tile_kernel(S: int, PW: int):
    """The classifier (and renderer) compiled for patch size ``S``.

    ``S`` (and the CFA period's width ``PW``, for the structure tensor's
    ``S - PW``-tap sums) are compile-time constants, so the tap loops unroll
    and the loops along a row vectorise. Parallel over tiles of ``_TILE_ROWS`` x
    ``_TILE_COLS`` output pixels; each tile copies its padded band from the
    mosaic (mirror indices at the image borders), reduces every band row to
    horizontal S-tap sums of ``x`` and ``x²`` per channel present in the row
    (channel masks along the row) and an OR of saturated-channel bits, kept
    in a ring of S rows, and finishes each output row from its S ring rows:
    per channel mean and standard deviation, response level, relative
    contrast, saturation pattern, class. Every sum runs in a fixed order in
    float32 without fast-math, so a pixel's features and class depend on its
    patch only, never on the tiling or on vectorisation.
    """
    r = S // 2
    TR = _TILE_ROWS
    stamp = _callee_stamp()

    @lean_cache  # loads from numba's cache without its registry refresh
    @nb.njit(cache=True, parallel=True)
    def kernel(mosaic, yi, xi, y0, nrows, tc, idx_pattern, cnt_inv, wc, group, lut, lut_shift,
               lut_base, cuts, ccuts, sat_thr, eps, n_sat, n_or, ori_c, ori_s, coh2, ctx_mode,
               xcuts, ctx_eps, n_hl, hl_cnt, ctx, ctx_r0, ctx_r1, ctx_wy, ctx_c0, ctx_c1, ctx_wx,
               mode, out_cls, out_lev, out_con, out_sat, K, n_out, outf, cv_base, cv_slope,
               cv_lo, cv_step, use_matrix, matrix, thr, buckets, interp, shift, enc_bits, out8,
               out16, ct_first, ct_thr, ct_lo, ct_scale, ct_walk):
        if stamp[0] < 0:  # never: holds the stamp in the kernel's closure (cache key)
            return
        W = mosaic.shape[1]
        ph, pw = idx_pattern.shape
        nch = cnt_inv.shape[1]
        nl = ccuts.shape[0]
        ncc = ccuts.shape[1]
        nlut = lut.shape[0]
        ccf = ccuts.ravel()
        n_cx = xcuts.shape[0] + 1 if ctx_mode else 1
        n_ob = ori_c.shape[0]
        extra = n_or > 1 or n_cx > 1 or n_hl > 1
        n_ext = n_or * n_cx * n_hl
        twp_max = tc + S - 1
        # along-row tables in tile coordinates (tile columns start at multiples of pw)
        mask = np.zeros((ph, nch, twp_max), dtype=np.float32)
        bitv = np.zeros((ph, twp_max), dtype=np.int32)
        row_has = np.zeros((ph, nch), dtype=np.bool_)  # channel present in a row phase
        for py in range(ph):
            for xx in range(twp_max):
                c = idx_pattern[py, (xx - r) % pw]
                mask[py, c, xx] = 1.0
                bitv[py, xx] = 1 << c
                row_has[py, c] = True
        ci_row = np.zeros((ph, nch, tc), dtype=np.float32)
        wc_row = np.zeros((ph, nch, tc), dtype=np.float32)
        g_row = np.zeros((ph, tc), dtype=np.int32)
        for py in range(ph):
            for x in range(tc):
                pos = py * pw + x % pw
                g_row[py, x] = group[pos]
                for c in range(nch):
                    ci_row[py, c, x] = cnt_inv[pos, c]
                    wc_row[py, c, x] = wc[pos, c]
        n_rt = (nrows + TR - 1) // TR
        n_ct = (W + tc - 1) // tc
        for t in nb.prange(n_rt * n_ct):
            i0 = (t // n_ct) * TR
            i1 = min(nrows, i0 + TR)
            x0 = (t % n_ct) * tc
            x1 = min(W, x0 + tc)
            tw = x1 - x0
            twp = tw + S - 1
            nbr = i1 - i0 + S - 1
            # padded band of the tile: row k is padded row y0 + i0 + k (image row - r)
            pb = np.empty((nbr, twp), dtype=np.float32)
            inner = x0 - r >= 0 and x0 - r + twp <= W
            for k in range(nbr):
                src = yi[y0 + i0 + k]
                if inner:
                    for xx in range(twp):
                        pb[k, xx] = mosaic[src, x0 - r + xx]
                else:
                    for xx in range(twp):
                        pb[k, xx] = mosaic[src, xi[x0 + xx]]
            if n_out <= 4 and (mode == MODE_RENDER or mode == MODE_DISPLAY):
                pb2 = np.empty((nbr - 1, 2 * twp), dtype=np.float32)  # row pairs (render_rows)
                row_pairs(pb, pb2, nbr - 1)
            else:
                pb2 = pb
            ring_s = np.empty((S, nch, tw), dtype=np.float32)
            ring_q = np.empty((S, nch, tw), dtype=np.float32)
            ring_b = np.empty((S, tw), dtype=np.int32)
            mv = np.empty(twp, dtype=np.float32)
            mq = np.empty(twp, dtype=np.float32)
            bits = np.empty(twp, dtype=np.int32)
            lev = np.empty(tw, dtype=np.float32)
            levi = lev.view(np.int32)
            spr = np.empty(tw, dtype=np.float32)
            va = np.empty(tw, dtype=np.float32)
            vq = np.empty(tw, dtype=np.float32)
            satr = np.empty(tw, dtype=np.int32)
            clsr = np.empty(tw, dtype=np.int32)
            lbr = np.empty(tw, dtype=np.int32)
            kbr = np.empty(tw, dtype=np.int32)
            ccr = np.empty(tw, dtype=np.float32)
            rows_c = np.empty(S, dtype=np.int64)
            if n_or > 1:  # structure-tensor sums (see classify.features)
                ring_xx = np.empty((S, tw), dtype=np.float32)
                ring_yy = np.empty((S, tw), dtype=np.float32)
                ring_xy = np.empty((S, tw), dtype=np.float32)
            else:
                ring_xx = np.empty((1, 1), dtype=np.float32)
                ring_yy = ring_xx
                ring_xy = ring_xx
            gxx = np.empty(twp, dtype=np.float32)
            gyy = np.empty(twp, dtype=np.float32)
            gxy = np.empty(twp, dtype=np.float32)
            exb = np.empty(tw, dtype=np.int32)
            ring_n = np.empty((S if n_hl > 1 else 1, tw), dtype=np.float32)
            ind = np.empty(twp, dtype=np.float32)
            jxx = np.empty(tw, dtype=np.float32)
            jyy = np.empty(tw, dtype=np.float32)
            jxy = np.empty(tw, dtype=np.float32)
            bst = np.empty(tw, dtype=np.float32)
            crow = np.empty(ctx.shape[1], dtype=np.float32)
            # display mode: a row's float outputs (+ 1 lane of spill), then its encoding
            rowf = np.empty(tw * n_out + 4 if mode == MODE_DISPLAY else 1, dtype=np.float32)
            lin = np.empty(tw * n_out if mode == MODE_DISPLAY else 1, dtype=np.float32)
            for k in range(nbr):
                slot = k % S
                py = (y0 + i0 + k - r) % ph
                for c in range(nch):
                    if not row_has[py, c]:
                        continue  # the ring slot is never read for this channel
                    for xx in range(twp):
                        u = pb[k, xx] * mask[py, c, xx]
                        mv[xx] = u
                        mq[xx] = u * pb[k, xx]
                    for x in range(tw):
                        a = mv[x]
                        q = mq[x]
                        for dx in range(1, S):
                            a += mv[x + dx]
                            q += mq[x + dx]
                        ring_s[slot, c, x] = a
                        ring_q[slot, c, x] = q
                for xx in range(twp):
                    bits[xx] = bitv[py, xx] if pb[k, xx] >= sat_thr else 0
                for x in range(tw):
                    b = bits[x]
                    for dx in range(1, S):
                        b |= bits[x + dx]
                    ring_b[slot, x] = b
                if n_hl > 1:  # saturated pixels per row window
                    for xx in range(twp):
                        ind[xx] = np.float32(1.0) if pb[k, xx] >= sat_thr else np.float32(0.0)
                    for x in range(tw):
                        a = ind[x]
                        for dx in range(1, S):
                            a += ind[x + dx]
                        ring_n[slot, x] = a
                if n_or > 1 and k >= ph:
                    # quads of band rows k - ph and k: same-colour differences
                    for xx in range(twp - PW):
                        gx = (pb[k - ph, xx + PW] - pb[k - ph, xx]) + (pb[k, xx + PW] - pb[k, xx])
                        gy = (pb[k, xx] - pb[k - ph, xx]) + (pb[k, xx + PW] - pb[k - ph, xx + PW])
                        gxx[xx] = gx * gx
                        gyy[xx] = gy * gy
                        gxy[xx] = gx * gy
                    for x in range(tw):
                        a = gxx[x]
                        q = gyy[x]
                        e = gxy[x]
                        for dx in range(1, S - PW):
                            a += gxx[x + dx]
                            q += gyy[x + dx]
                            e += gxy[x + dx]
                        ring_xx[slot, x] = a
                        ring_yy[slot, x] = q
                        ring_xy[slot, x] = e
                i = k - (S - 1)  # tile output row whose window is now complete
                if i < 0:
                    continue
                po = (y0 + i0 + i) % ph
                for x in range(tw):
                    lev[x] = 0.0
                    spr[x] = 0.0
                for c in range(nch):
                    # rows of the window that hold channel c (others are all zero)
                    nrow = 0
                    for dy in range(S):
                        if row_has[(y0 + i0 + i + dy - r) % ph, c]:
                            rows_c[nrow] = (i + dy) % S
                            nrow += 1
                    if nrow == 0:
                        continue
                    sl = rows_c[0]
                    for x in range(tw):
                        va[x] = ring_s[sl, c, x]
                        vq[x] = ring_q[sl, c, x]
                    for kk in range(1, nrow):  # rows outside, pixels inside: vectorised
                        sl = rows_c[kk]
                        for x in range(tw):
                            va[x] += ring_s[sl, c, x]
                            vq[x] += ring_q[sl, c, x]
                    for x in range(tw):
                        ci = ci_row[po, c, x]
                        m = va[x] * ci
                        var = vq[x] * ci - m * m
                        lev[x] += m * wc_row[po, c, x]
                        spr[x] += np.sqrt(max(var, np.float32(0.0))) * wc_row[po, c, x]
                for x in range(tw):
                    b = ring_b[i % S, x]
                    for dy in range(1, S):
                        b |= ring_b[(i + dy) % S, x]
                    satr[x] = b
                    spr[x] = spr[x] / (max(lev[x], np.float32(0.0)) + eps)  # now the contrast
                if mode == MODE_FEATURES:
                    for x in range(tw):
                        out_lev[i0 + i, x0 + x] = lev[x]
                        out_con[i0 + i, x0 + x] = spr[x]
                        out_sat[i0 + i, x0 + x] = satr[x]
                    continue
                # level bin: a lookup on the float's leading bits, then at most two
                # comparisons with the cut points of the bucket (see levels.level_lookup);
                # the table reads cannot vectorise (gathers), the rest does
                for x in range(tw):
                    kb = (levi[x] >> lut_shift) - lut_base
                    kbr[x] = min(max(kb, 0), nlut - 1)
                for x in range(tw):
                    kb = kbr[x]
                    lv = lev[x]
                    lbr[x] = lut[kb] + np.int32(cuts[kb, 0] <= lv) + np.int32(cuts[kb, 1] <= lv)
                for x in range(tw):
                    clsr[x] = ((g_row[po, x] * n_sat + satr[x]) * nl + lbr[x]) * (ncc + 1)
                for j in range(ncc):  # contrast bin
                    for x in range(tw):
                        kbr[x] = lbr[x] * ncc + j
                    for x in range(tw):
                        ccr[x] = ccf[kbr[x]]
                    for x in range(tw):
                        clsr[x] += np.int32(spr[x] >= ccr[x])
                if extra:
                    for x in range(tw):
                        exb[x] = 0
                    if n_or > 1:
                        # structure tensor: vertical sums of the quad rows (vectorised
                        # along the row), then the nearest angle-bin centre
                        sl = (i + ph) % S
                        for x in range(tw):
                            jxx[x] = ring_xx[sl, x]
                            jyy[x] = ring_yy[sl, x]
                            jxy[x] = ring_xy[sl, x]
                        for dy in range(ph + 1, S):
                            sl = (i + dy) % S
                            for x in range(tw):
                                jxx[x] += ring_xx[sl, x]
                                jyy[x] += ring_yy[sl, x]
                                jxy[x] += ring_xy[sl, x]
                        for x in range(tw):
                            u = jxx[x] - jyy[x]
                            v = np.float32(2.0) * jxy[x]
                            tt = jxx[x] + jyy[x]
                            jxx[x] = u
                            jyy[x] = v
                            jxy[x] = u * u + v * v - coh2 * (tt * tt)  # > 0: oriented
                            bst[x] = u * ori_c[0] + v * ori_s[0]
                            exb[x] = 1
                        for j in range(1, n_ob):
                            cj = ori_c[j]
                            sj = ori_s[j]
                            for x in range(tw):
                                pr = jxx[x] * cj + jyy[x] * sj
                                take = pr > bst[x]
                                bst[x] = pr if take else bst[x]
                                exb[x] = np.int32(j + 1) if take else exb[x]
                        for x in range(tw):
                            exb[x] = exb[x] if jxy[x] > np.float32(0.0) else np.int32(0)
                    if n_cx > 1:
                        # context guide: rows interpolated once per row, columns per pixel
                        yy = y0 + i0 + i
                        r0 = ctx_r0[yy]
                        r1 = ctx_r1[yy]
                        wy = ctx_wy[yy]
                        for j in range(ctx.shape[1]):
                            crow[j] = ctx[r0, j] * (np.float32(1.0) - wy) + ctx[r1, j] * wy
                        for x in range(tw):
                            xx = x0 + x
                            wx = ctx_wx[xx]
                            bst[x] = (crow[ctx_c0[xx]] * (np.float32(1.0) - wx)
                                      + crow[ctx_c1[xx]] * wx)
                        if ctx_mode == 2:
                            for x in range(tw):
                                bst[x] = max(lev[x], np.float32(0.0)) / (
                                    max(bst[x], np.float32(0.0)) + ctx_eps)
                        for x in range(tw):
                            exb[x] = exb[x] * n_cx
                        for j in range(n_cx - 1):
                            cj = xcuts[j]
                            for x in range(tw):
                                exb[x] += np.int32(bst[x] >= cj)
                    if n_hl > 1:
                        for x in range(tw):
                            bst[x] = ring_n[i % S, x]
                        for dy in range(1, S):
                            sl = (i + dy) % S
                            for x in range(tw):
                                bst[x] += ring_n[sl, x]
                        for x in range(tw):
                            exb[x] = exb[x] * n_hl + np.int32(bst[x] >= hl_cnt)
                    for x in range(tw):
                        clsr[x] = clsr[x] * n_ext + exb[x]
                o = ((i0 + i) * W + x0) * n_out
                if mode == MODE_CLASSES:
                    for x in range(tw):
                        out_cls[i0 + i, x0 + x] = clsr[x]
                elif mode == MODE_DISPLAY:  # render the row, then encode it while in cache
                    if n_out <= 4:
                        render_row4(pb2, pb, i, tw, S, clsr, K, rowf, 0, n_out)
                    else:
                        render_row_any(pb, i, tw, S, clsr, K, rowf, 0, n_out)
                    if ct_walk > 0:  # tone curve and encoding as one lookup (l3cli.tonecode)
                        curve_encode_row(rowf, tw, n_out, ct_first, ct_thr, ct_lo, ct_scale,
                                         ct_walk, out8, out16, enc_bits, o)
                    else:
                        if cv_base.shape[1] > 1:  # learned tone curve, then the encoding
                            curve_row(rowf, 0, tw, n_out, cv_base, cv_slope, cv_lo, cv_step)
                        encode_row(rowf, tw * n_out, use_matrix, matrix, thr, buckets, interp,
                                   shift, lin, out8, out16, enc_bits, o)
                elif n_out <= 4:
                    render_row4(pb2, pb, i, tw, S, clsr, K, outf, o, n_out)
                else:
                    render_row_any(pb, i, tw, S, clsr, K, outf, o, n_out)
                if mode == MODE_RENDER and cv_base.shape[1] > 1:  # learned tone curve
                    curve_row(outf, o, tw, n_out, cv_base, cv_slope, cv_lo, cv_step)

    return kernel


_NO_F32 = np.zeros((1, 1), dtype=np.float32)
_NO_I32 = np.zeros((1, 1), dtype=np.int32)
_NO_OUT = np.zeros(1, dtype=np.float32)
_NO_CURVE = (_NO_F32, _NO_F32, np.zeros(1, np.float32), np.zeros(1, np.float32))
_NO_U8 = np.zeros(1, dtype=np.uint8)
_NO_U16 = np.zeros(1, dtype=np.uint16)
#: Encoder arguments when not in display mode (the order of ``DisplayParams``).
_NO_DISPLAY = (False, np.eye(3), np.zeros(2, np.float32), np.zeros(1, np.uint16),
               np.zeros(2, np.float32), 0)
#: No composed curve-and-encoding table (:mod:`l3cli.tonecode`): ``walk`` 0.
_NO_CODES = (np.zeros((1, 1), np.uint8), _NO_F32, np.zeros(1, np.float32),
             np.zeros(1, np.float32), 0)
_NO_GUIDE = ContextGuide(_NO_F32, *(np.zeros(1, np.int64),) * 2, np.zeros(1, np.float32),
                         *(np.zeros(1, np.int64),) * 2, np.zeros(1, np.float32))


def run_tiles(mosaic: np.ndarray, definition: ClassDefinition, mode: int, *,
              rows: tuple[int, int] | None = None, out_cls: np.ndarray | None = None,
              out_features: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
              kernels: np.ndarray | None = None, n_out: int = 0,
              out: np.ndarray | None = None,
              curve: tuple[np.ndarray, ...] | None = None, display: Any = None,
              codes: Any = None) -> None:
    """Run the tile kernel over output rows ``rows`` (default: all) of a mosaic.

    The one entry point to the classifier; :func:`classify`,
    :func:`patch_features`, training and :func:`l3cli.render.render_mosaic`
    all come through here.

    Parameters
    ----------
    mosaic
        float32 (H, W) normalised mosaic, C-contiguous, CFA phase as the definition.
    definition
        The class definition.
    mode
        ``MODE_CLASSES`` (int32 classes into ``out_cls``), ``MODE_FEATURES``
        (float32 level, float32 contrast, int32 saturation bits into
        ``out_features``) or ``MODE_RENDER`` (``out`` = affine kernels of the
        classes applied to the patches).
    rows
        ``(y0, y1)``: output rows; the output arrays have ``y1 - y0`` rows.
    kernels
        Render only: float32 packed kernels (:func:`l3cli.render.pack_kernels`).
    n_out
        Render only: outputs per pixel.
    out
        Render: float32 C-contiguous (y1 - y0, W, n_out). Display: uint8 or
        uint16 C-contiguous (y1 - y0, W, n_out).
    curve
        Render and display: a learned tone curve's look-up table
        (:func:`l3cli.tonecurve.curve_arrays`), applied to each output row
        (before the display encoding).
    display
        ``MODE_DISPLAY`` only: the encoder's
        :class:`~l3cli.io.encode.DisplayParams`; each rendered row is
        display-encoded into ``out`` (the same integers as
        :func:`~l3cli.io.encode.display_encode` of the float render).
    codes
        ``MODE_DISPLAY`` only: the curve and the encoding as one lookup
        (:func:`l3cli.tonecode.code_table`, for this curve and encoder without
        a matrix), used instead of ``curve`` and ``display``'s tables.
    """
    S = definition.patch
    h, w = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    tables = kernel_tables(definition)
    yi, xi = definition.mirror_maps(h, w)
    pw = definition.cfa.period[1]
    tc = pw * max(1, _TILE_COLS // pw)
    cls_o = out_cls if out_cls is not None else _NO_I32
    lev_o, con_o, sat_o = out_features if out_features is not None else (_NO_F32, _NO_F32,
                                                                         _NO_I32)
    K = kernels if kernels is not None else _NO_F32
    out8, out16, bits, outf = _NO_U8, _NO_U16, 0, _NO_OUT
    if mode == MODE_DISPLAY:
        if out is None or display is None or out.dtype not in (np.uint8, np.uint16):
            raise ValueError("display mode needs a uint8/uint16 out and the encoder's parameters")
        bits = 8 if out.dtype == np.uint8 else 16
        if bits == 8:
            out8 = out.reshape(-1)
        else:
            out16 = out.reshape(-1)
    else:
        display = _NO_DISPLAY
        if out is not None:
            outf = out.reshape(-1)
    guide = _NO_GUIDE
    if definition.context_block and mode != MODE_FEATURES:
        guide = context_guide(mosaic, definition.cfa, definition.context_block)
    with _slp_vectorize():
        _tile_kernel(S, pw)(mosaic, yi, xi, y0, y1 - y0, tc, *tables, *guide, mode, cls_o,
                            lev_o, con_o, sat_o, K, n_out, outf,
                            *(curve if curve is not None else _NO_CURVE), *display, bits, out8,
                            out16, *(codes if codes is not None and mode == MODE_DISPLAY
                                     else _NO_CODES))


def classify(mosaic: np.ndarray, definition: ClassDefinition, *,
             rows: tuple[int, int] | None = None) -> np.ndarray:
    """Class index of every pixel of a mosaic.

    Parameters
    ----------
    mosaic
        float32 (H, W) normalised raw mosaic whose CFA phase is ``definition.cfa``.
    definition
        The class definition.
    rows
        Optional ``(y0, y1)``: classify only these rows.

    Returns
    -------
    numpy.ndarray
        int32 (H, W) (or (y1 - y0, W)) flat class indices (see :class:`ClassDefinition`).

    Examples
    --------
    A flat mosaic at level 0.05: unsaturated, the middle of three levels, flat.

    >>> d = ClassDefinition.build("RGGB", level_cuts=[0.01, 0.1], contrast_cuts=0.2)
    >>> cls = classify(np.full((8, 8), 0.05, np.float32), d)
    >>> [int(v) for v in d.class_tuple(cls[4, 4])]  # (group, saturation, level, contrast)
    [0, 0, 1, 0]
    >>> [int(v) for v in d.class_tuple(cls[4, 5])]  # the G next to R: group 1
    [1, 0, 1, 0]
    """
    mosaic = check_mosaic(mosaic, definition.cfa, definition.patch)
    h, w = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    out = np.empty((y1 - y0, w), dtype=np.int32)
    run_tiles(mosaic, definition, MODE_CLASSES, rows=(y0, y1), out_cls=out)
    return out


def patch_features(mosaic: np.ndarray, cfa: CFA | str, *, patch: int = defaults.PATCH,
                   saturation_threshold: float = defaults.SATURATION,
                   contrast_eps: float = DEFAULT_CONTRAST_EPS
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Response level, relative contrast and saturation bits of every pixel's patch.

    Returns
    -------
    level, contrast, sat
        float32 (H, W), float32 (H, W), int32 (H, W) (bit ``c`` = channel
        ``cfa.channels[c]`` saturated somewhere in the patch).
    """
    cfa = CFA.from_spec(cfa)
    d = ClassDefinition.build(cfa, patch=patch, level_cuts=np.array([0.5]),
                              saturation_threshold=saturation_threshold,
                              contrast_eps=contrast_eps, merge_positions=False)
    mosaic = check_mosaic(mosaic, cfa, patch)
    h, w = mosaic.shape
    lev = np.empty((h, w), dtype=np.float32)
    con = np.empty((h, w), dtype=np.float32)
    sat = np.empty((h, w), dtype=np.int32)
    run_tiles(mosaic, d, MODE_FEATURES, out_features=(lev, con, sat))
    return lev, con, sat


# ---------------------------------------------------- data-driven cut points
