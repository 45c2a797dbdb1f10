"""The tile kernel's numba source: classification, and in render modes the render.

Imported only where the kernel is compiled or loaded by numba;
:func:`l3cli.classify.kernel.run_tiles` runs it, preferably from stored
machine code (:mod:`l3cli.kernel_store`), which does not import numba.
"""

from __future__ import annotations

import contextlib
import functools
import os

# OpenMP threads that wait passively instead of spinning: on a shared or busy
# machine spinning workers steal the cores the kernels need (2x slower
# training measured under load); set OMP_WAIT_POLICY yourself to override.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba as nb  # noqa: E402
import numpy as np  # noqa: E402

from l3cli.classify.layout import TILE_ROWS  # noqa: E402
from l3cli.render_rows import (  # noqa: E402
    curve_code16_row,
    curve_encode_row,
    curve_row,
    encode_row,
    render_row4,
    render_row_any,
    tap_lanes,
)

__all__ = ["ENTRIES", "row_gains", "slp_vectorize", "tile_gains", "tile_kernel"]


@contextlib.contextmanager
def slp_vectorize():
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


@nb.njit(nogil=True, error_model="numpy")
def tile_gains(x0, twp, xi, yi, yb, nbr, ph, g_mode, g_idx, g_frac, g_cap, g_grid, g_gdiff,
               g_iv, f_b, f_cx, w_x):
    """A tile's columns of the raw's per-column gain tables (:mod:`l3cli.lens.gainmaps`),
    contiguous for the band's columns ``xi[x0 + xx]`` (mirrored at the image's edges)
    and rows ``yi[yb + k]`` (``k < nbr``): per DNG map layer and row phase the grid
    rows the band's rows lie between, interpolated at the columns (float64 (layers, ph,
    rows, twp), from grid row ``base`` (layers, ph)), and the clip (layers, ph, twp);
    the field's ``b`` (twp,) and coefficients (ph, k, twp); the white balance (ph, twp)."""
    n_ly = g_idx.shape[0] if g_mode & 1 else 0
    nk = f_cx.shape[1] if g_mode & 2 else 0
    nw = ph if g_mode & 4 else 0
    n_i = g_grid.shape[2]
    t_base = np.zeros((n_ly, ph), dtype=np.int64)
    n_r = 2
    for ly in range(n_ly):
        lo = np.full(ph, n_i, dtype=np.int64)
        hi = np.zeros(ph, dtype=np.int64)
        for k in range(nbr):
            yy = yi[yb + k]
            qy = yy % ph
            v = g_iv[ly, yy]
            lo[qy] = min(lo[qy], v)
            hi[qy] = max(hi[qy], v)
        for qy in range(ph):
            t_base[ly, qy] = min(lo[qy], hi[qy])
            n_r = max(n_r, hi[qy] - t_base[ly, qy] + 2)
    t_rows = np.empty((n_ly, ph, n_r, twp), dtype=np.float64)
    t_cap = np.empty((n_ly, ph, twp), dtype=np.float32)
    for ly in range(n_ly):
        for qy in range(ph):
            for rr in range(n_r):
                gi = min(t_base[ly, qy] + rr, n_i - 1)
                gg = g_grid[ly, qy, gi]
                gd = g_gdiff[ly, qy, gi]
                tr = t_rows[ly, qy, rr]
                for xx in range(twp):
                    xs = xi[x0 + xx]
                    j = g_idx[ly, qy, xs]
                    tr[xx] = gg[j] + g_frac[ly, qy, xs] * gd[j]
            for xx in range(twp):
                t_cap[ly, qy, xx] = g_cap[ly, qy, xi[x0 + xx]]
    t_b = np.empty(twp if nk else 0, dtype=np.float64)
    t_c = np.empty((ph if nk else 0, nk, twp), dtype=np.float64)
    t_wb = np.empty((nw, twp), dtype=np.float32)
    for xx in range(twp):
        xs = xi[x0 + xx]
        if nk:
            t_b[xx] = f_b[xs]
            for qy in range(ph):
                for kk in range(nk):
                    t_c[qy, kk, xx] = f_cx[qy, kk, xs]
        for qy in range(nw):
            t_wb[qy, xx] = w_x[qy, xs]
    return t_rows, t_base, t_cap, t_b, t_c, t_wb


@nb.njit(nogil=True, error_model="numpy")
def field_rule(dst, twp, g, f_one, sat):
    """A learned field's float32 gains ``g`` on a band row ``dst``, in place, with its
    clipping rule (:func:`l3cli.lens.field.correct_mosaic`): never above ``max(v, 1)`` when
    every field gain is at least 1 (``f_one``), else a pixel at or above ``sat`` not
    lowered."""
    one = np.float32(1.0)
    if f_one:
        for xx in range(twp):
            v = dst[xx]
            dst[xx] = min(v * g[xx], max(v, one))
    else:
        for xx in range(twp):
            v = dst[xx]
            dst[xx] = v * g[xx] if (v < sat or g[xx] >= one) else v


@nb.njit(nogil=True, error_model="numpy")
def row_gains(dst, twp, yy, qy, g_mode, g_iv, g_fv, f_a, f_one, t_rows, t_base, t_cap,
              t_b, t_c, t_wb, sat, r2, acc, gf, f_map, m_y0, m_col, inner, xi, x0):
    """The raw's gains on one copied band row ``dst`` (image row ``yy``, row phase ``qy``),
    in place, in this order and with these rules (:mod:`l3cli.lens.gainmaps`): each DNG map
    layer's gain (the band's two grid rows around row ``yy``, interpolated at the tile's
    columns by :func:`tile_gains`, weighted ``1 - fv`` and ``fv``), the product clipped
    at ``cap`` (1 where the layer has a map); the learned field's (its polynomial in
    ``r²`` in float64, the operations of :func:`l3cli.lens.field.gain_map`), or a field's
    gain map (``f_map``: row ``m_y0 + yy``, the band's columns from ``m_col`` when
    ``inner``, else ``xi[x0 + xx]`` offset by ``m_col``), with :func:`field_rule`;
    the white balance's, a pixel at or above ``sat`` not lowered. The products are float32, as the passes over the mosaic make them. One
    simple loop per step over contiguous values: each vectorises."""
    one = np.float32(1.0)
    for ly in range(t_rows.shape[0]):
        rr = g_iv[ly, yy] - t_base[ly, qy]
        f1 = g_fv[ly, yy]
        f0 = 1.0 - f1
        a0 = t_rows[ly, qy, rr]
        a1 = t_rows[ly, qy, rr + 1]
        tp = t_cap[ly, qy]
        for xx in range(twp):
            g = np.float32(f0 * a0[xx] + f1 * a1[xx])
            dst[xx] = min(dst[xx] * g, tp[xx])
    if g_mode & 2:
        a = f_a[yy]
        tc = t_c[qy]
        nk = tc.shape[0]
        for xx in range(twp):
            r2[xx] = a + t_b[xx]
            acc[xx] = tc[nk - 1, xx]
        for kk in range(nk - 2, -1, -1):
            for xx in range(twp):
                acc[xx] = acc[xx] * r2[xx] + tc[kk, xx]
        for xx in range(twp):
            gf[xx] = np.float32(acc[xx])
        field_rule(dst, twp, gf, f_one, sat)
    if g_mode & 8:
        mrow = f_map[m_y0 + yy]
        if inner:
            for xx in range(twp):
                gf[xx] = mrow[m_col + np.uint64(xx)]
        else:
            for xx in range(twp):
                gf[xx] = mrow[m_col + np.uint64(xi[x0 + xx])]
        field_rule(dst, twp, gf, f_one, sat)
    if g_mode & 4:
        tw = t_wb[qy]
        for xx in range(twp):
            v = dst[xx]
            g = tw[xx]
            dst[xx] = v * g if (g > one or (g < one and not v >= sat)) else v


# ---------------------------------------------------------------- the entry points
# One row of output per call, per entry point: what the tile loop hands each finished
# output row (its features, and its classes where the entry needs them). ``outs`` is
# the entry's own arguments, ``sc`` its per-tile scratch (``*_scratch``).
@nb.njit(nogil=True)
def _no_scratch(outs, tw):
    return ()


@nb.njit(nogil=True)
def _features_row(outs, sc, pb, i, y, x0, tw, W, S, lev, spr, satr, clsr):
    out_lev, out_con, out_sat = outs
    for x in range(tw):
        out_lev[y, x0 + x] = lev[x]
        out_con[y, x0 + x] = spr[x]
        out_sat[y, x0 + x] = satr[x]


@nb.njit(nogil=True)
def _classes_row(outs, sc, pb, i, y, x0, tw, W, S, lev, spr, satr, clsr):
    out_cls = outs[0]
    for x in range(tw):
        out_cls[y, x0 + x] = clsr[x]


@nb.njit(nogil=True)
def _render_row(outs, sc, pb, i, y, x0, tw, W, S, lev, spr, satr, clsr):
    K, n_out, outf, cv_base, cv_slope, cv_lo, cv_step = outs
    o = (y * W + x0) * n_out
    if n_out <= 4:
        render_row4(pb, i, tw, S, clsr, K, outf, o, n_out)
    else:
        render_row_any(pb, i, tw, S, clsr, K, outf, o, n_out)
    if cv_base.shape[1] > 1:  # a learned tone curve
        curve_row(outf, o, tw, n_out, cv_base, cv_slope, cv_lo, cv_step)


@nb.njit(nogil=True)
def _display_scratch(outs, tw):
    n_out = outs[1]
    return (np.empty(tw * n_out, dtype=np.float32), np.empty(tw * n_out, dtype=np.float32))


@nb.njit(nogil=True)
def _display_row(outs, sc, pb, i, y, x0, tw, W, S, lev, spr, satr, clsr):
    (K, n_out, out8, out16, cv_base, cv_slope, cv_lo, cv_step, use_matrix, matrix, thr,
     buckets, interp, shift, enc_bits, ct_first, ct_thr, ct_lo, ct_scale, ct_walk) = outs
    rowf, lin = sc
    o = (y * W + x0) * n_out
    # render the row, then encode it while in cache
    if n_out <= 4:
        render_row4(pb, i, tw, S, clsr, K, rowf, 0, n_out)
    else:
        render_row_any(pb, i, tw, S, clsr, K, rowf, 0, n_out)
    if ct_walk > 0:  # tone curve and encoding as one lookup (l3cli.tone.code)
        curve_encode_row(rowf, tw, n_out, ct_first, ct_thr, ct_lo, ct_scale, ct_walk, out8,
                         out16, enc_bits, o)
    elif ct_walk == 0:  # 16 bits: the composed codes interpolated
        curve_code16_row(rowf, tw, ct_thr, ct_lo, ct_scale, out16, o)
    else:
        if cv_base.shape[1] > 1:  # learned tone curve, then the encoding
            curve_row(rowf, 0, tw, n_out, cv_base, cv_slope, cv_lo, cv_step)
        encode_row(rowf, tw * n_out, use_matrix, matrix, thr, buckets, interp, shift, lin,
                   out8, out16, enc_bits, o)


#: The entry points: name -> (whether it classifies, its per-tile scratch, its row).
ENTRIES = {
    "features": (False, _no_scratch, _features_row),
    "classes": (True, _no_scratch, _classes_row),
    "render": (True, _no_scratch, _render_row),
    "display": (True, _display_scratch, _display_row),
}


@functools.cache
def tile_kernel(S: int, PW: int, entry: str):
    """The tile kernel's entry point ``entry`` (:data:`ENTRIES`) compiled for patch
    size ``S``: ``kernel(mosaic, yi, xi, y0, nrows, tc, tables, guide, gains, outs,
    t_lo, t_hi)``.

    Each entry point is a function of its own (its own machine code, stored apart by
    :mod:`l3cli.kernel_store`): the tile loop below, shared, with the entry's row
    function (and whether it classifies) as compile-time constants. ``tables`` is
    :class:`~l3cli.classify.layout.KernelTables` as a tuple, ``guide`` the
    :class:`~l3cli.classify.features.ContextGuide` (a tuple), ``gains``
    :meth:`l3cli.lens.gainmaps.MosaicGains.kernel_args` (or :data:`l3cli.lens.gainmaps.NO_GAINS`),
    ``outs`` the entry's outputs and parameters (:func:`l3cli.classify.kernel.run_tiles`).

    ``S`` (and the CFA period's width ``PW``, for the structure tensor's
    ``S - PW``-tap sums) are compile-time constants, so the tap loops unroll
    and the loops along a row vectorise. Runs tiles ``t_lo`` to ``t_hi``
    (row-major) of ``TILE_ROWS`` x ``TILE_COLS`` output pixels without the
    GIL, so threads share an image's tiles (:func:`l3cli.classify.kernel.run_tiles`);
    each tile copies its padded band from the
    mosaic (mirror indices at the image borders, the raw's gains applied), reduces every band row to
    horizontal S-tap sums of ``x`` and ``x²`` per channel present in the row
    (channel masks along the row) and an OR of saturated-channel bits, kept
    in a ring of S rows, and finishes each output row from its S ring rows:
    per channel mean and standard deviation, response level, relative
    contrast, saturation pattern, class. Every sum runs in a fixed order in
    float32 without fast-math, so a pixel's features and class depend on its
    patch only, never on the tiling or on vectorisation.
    """
    CLASSIFY, scratch, row_out = ENTRIES[entry]
    r = S // 2
    TR = TILE_ROWS
    PAD = max(tap_lanes(S) - S, 0)

    # no numba cache: the machine code is stored by l3cli.kernel_store, whose key covers
    # the callees' sources too (numba's cache would not need the object code kept)
    # error_model="numpy": no zero-division checks, whose branch per pixel kept the
    # contrast's division scalar (its divisor is at least eps > 0; the values are the same)
    @nb.njit(nogil=True, error_model="numpy")
    def kernel(mosaic, yi, xi, y0, nrows, tc, tables, guide, gains, outs, t_lo, t_hi):
        (idx_pattern, cnt_inv, wc, group, lut, lut_shift, lut_base, cuts, ccuts, sat_thr,
         eps, n_sat, n_or, ori_c, ori_s, coh2, ctx_mode, xcuts, ctx_eps, n_hl,
         hl_cnt) = tables
        ctx, ctx_r0, ctx_r1, ctx_wy, ctx_c0, ctx_c1, ctx_wx = guide
        (g_mode, g_idx, g_frac, g_cap, g_grid, g_gdiff, g_iv, g_fv, f_a, f_b, f_cx, f_one,
         w_x, f_map, m_y0, m_x0) = gains
        if not CLASSIFY:  # features only: no orientation, context or highlight sums
            n_or = 1
            n_hl = 1
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
        for t in range(max(t_lo, 0), min(t_hi, n_rt * n_ct)):
            i0 = (t // n_ct) * TR
            i1 = min(nrows, i0 + TR)
            x0 = (t % n_ct) * tc
            x1 = min(W, x0 + tc)
            tw = x1 - x0
            twp = tw + S - 1
            nbr = i1 - i0 + S - 1
            # padded band of the tile: row k is padded row y0 + i0 + k (image row - r)
            # (+ zeros past the last patch: the render's vector loads of a patch row,
            # render_rows.affine_taps, read tap_lanes(S) values)
            pb = np.empty((nbr, twp + PAD), dtype=np.float32)
            # the raw's gains (l3cli.lens.gainmaps): the tile's columns of their tables
            t_rows, t_base, t_cap, t_b, t_c, t_wb = tile_gains(
                x0, twp, xi, yi, y0 + i0, nbr, ph, g_mode, g_idx, g_frac, g_cap, g_grid,
                g_gdiff, g_iv, f_b, f_cx, w_x)
            g_r2 = np.empty(twp if g_mode & 2 else 0, dtype=np.float64)
            g_acc = np.empty(twp if g_mode & 2 else 0, dtype=np.float64)
            g_f = np.empty(twp if g_mode & 10 else 0, dtype=np.float32)
            inner = x0 - r >= 0 and x0 - r + twp <= W
            c0 = np.uint64(x0 - r) if inner else np.uint64(0)
            m_col = np.uint64(m_x0) + c0  # the gain map's first column of the band
            for k in range(nbr):
                src = mosaic[yi[y0 + i0 + k]]
                dst = pb[k]
                if inner:  # unsigned offsets: a vector copy (signed ones are checked per value)
                    for xx in range(twp):
                        dst[xx] = src[c0 + np.uint64(xx)]
                else:
                    for xx in range(twp):
                        dst[xx] = src[xi[x0 + xx]]
                if g_mode != 0:  # the raw's gains (l3cli.lens.gainmaps), on the band's copy
                    yy = yi[y0 + i0 + k]
                    row_gains(dst, twp, yy, yy % ph, g_mode, g_iv, g_fv, f_a, f_one,
                              t_rows, t_base, t_cap, t_b, t_c, t_wb, sat_thr, g_r2, g_acc,
                              g_f, f_map, m_y0, m_col, inner, xi, x0)
                for xx in range(twp, twp + PAD):
                    dst[xx] = np.float32(0.0)
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
            sc = scratch(outs, tw)  # the entry's own (a display row's floats)
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
                if not CLASSIFY:
                    row_out(outs, sc, pb, i, i0 + i, x0, tw, W, S, lev, spr, satr, clsr)
                    continue
                # level bin: a lookup on the float's leading bits, then at most two
                # comparisons with the cut points of the bucket (see levels.level_lookup);
                # the table reads cannot vectorise (gathers), the rest does
                for x in range(tw):
                    kb = (levi[x] >> lut_shift) - lut_base
                    kbr[x] = min(max(kb, 0), nlut - 1)
                for x in range(tw):
                    kb = np.uint64(kbr[x])  # clamped above: unsigned, no wrap-around code
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
                row_out(outs, sc, pb, i, i0 + i, x0, tw, W, S, lev, spr, satr, clsr)

    return kernel
