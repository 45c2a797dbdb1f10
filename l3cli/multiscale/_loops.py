"""The multi-scale stage's loops (:mod:`l3cli.multiscale.stage`), in numba.

* :func:`stage_rows`: the whole stage after its reduced-resolution low-passes,
  in bands of rows run in parallel: the full-resolution low-passes (the finest,
  sigma below 3 pixels), the bilinear upsampling of the coarser ones, the band
  energy and level, the coarse class, and then either the feature maps
  (training: :func:`l3cli.multiscale.stage.feature_maps`) or the blend
  ``coarse + sum_r stack_r blend[cls, r, c]``, decoded from the stage's
  coding and written as float or display-encoded
  (:func:`l3cli.io.encode_rows.encode_row`) while the row is in cache: one
  code path for training and rendering, so both see the same bands and classes.
* :func:`half_means`: the 2 x 2 block means of the pyramid the coarse low-passes
  start from (the first level's pass codes the render's rows as it reads them).
* :func:`gauss_rows`: the stage's Gaussian, ``scipy.ndimage.gaussian_filter(img,
  (s, s, 0), mode="reflect")``'s order of operations (``correlate1d`` of a
  symmetric kernel: per output ``w[0] * x[0]``, then ``(x[-j] + x[j]) * w[j]``
  added from the outermost tap in, axis 0 first) in float32, vectorised along
  rows; :func:`stage_rows` runs the same arithmetic per row for the
  full-resolution low-passes and the energy.
* :func:`code_rows`: the stage's coding (a table of the sRGB curve, linear in
  between) and its inverse.
* :func:`class_rows`: the coarse classes of level and energy maps.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from l3cli.io.encode_rows import encode_row
from l3cli.multiscale._layout import MODE_FEATURES, MODE_FLOAT

__all__ = ["class_rows", "code_rows", "gauss_rows", "half_means",
           "stage_rows", "upsample_cols"]

#: The loops below that the caller runs: compiled without numba's cache (the caller
#: stores their machine code, :mod:`l3cli.kernel_store`), without the GIL, each on a
#: range of rows (or bands) so that l3's threads share an image
#: (:func:`l3cli.threads.run_split`); ``error_model="numpy"``: no division
#: checks (no divisor here is zero).
_loop = nb.njit(nogil=True, error_model="numpy")


@nb.njit(inline="always")
def _reflect(i: int, n: int) -> int:  # pragma: no cover - compiled
    """scipy's ``"reflect"`` index (d c b a | a b c d | d c b a), any distance out."""
    p = 2 * n
    i = i % p
    if i < 0:
        i += p
    return i if i < n else p - 1 - i


@nb.njit(inline="always")
def _class_of(v, e, level_cuts, energy_cuts):  # pragma: no cover - compiled
    """The coarse class of a level ``v`` and energy ``e`` (float32): the level's bin times
    the energy bins plus the energy's bin among its level's cuts (a value equal to a cut
    falls in the bin above it)."""
    nl = level_cuts.shape[0]
    ne = energy_cuts.shape[1]
    lb = 0
    while lb < nl and level_cuts[lb] <= v:
        lb += 1
    eb = 0
    for j in range(ne):
        eb += np.int32(e >= energy_cuts[lb, j])
    return lb * (ne + 1) + eb


@nb.njit(inline="always")
def _code(v, base, slope, first, last, inverse):  # pragma: no cover - compiled
    """The stage's coding of one float32 value (``inverse``: its inverse): the sRGB
    curve's linear segment exactly, above it the table's line through the curve's values
    at the value's bucket ends (the value's float32 bits shifted right by
    :data:`l3cli.multiscale.stage.CODE_SHIFT`), the formula itself beyond the table."""
    a = abs(v)
    bits = np.uint32(np.float32(a).view(np.uint32))
    b = np.int64(bits >> np.uint32(14))
    if b > last:  # far above white (or NaN): the formula (rare)
        if inverse:
            o = ((a + np.float32(0.055)) / np.float32(1.055)) ** np.float32(2.4)
        else:
            o = np.float32(1.055) * a ** np.float32(1 / 2.4) - np.float32(0.055)
        return np.float32(np.copysign(o, v))
    # both the line and the linear segment, then a select (no branch on the value: see
    # _direct_code); below the table's first bucket the line is not used (index 0)
    start = np.uint32(bits & np.uint32(0xFFFFC000)).view(np.float32)
    k = max(b - first, 0)
    t = base[k] + slope[k] * (a - start)
    if inverse:
        o = a / np.float32(12.92) if a <= np.float32(0.04045) else t
    else:
        o = np.float32(12.92) * a if a <= np.float32(0.0031308) else t
    return np.float32(np.copysign(o, v))


@_loop
def code_rows(src, dst, base, slope, first, last, inverse, lo, hi):  # pragma: no cover
    """The stage's coding (:func:`_code`) of rows ``lo..hi`` of ``src`` (H, L) float32
    into ``dst``."""
    n = src.shape[1]
    for y in range(lo, hi):
        for k in range(n):
            dst[y, k] = _code(src[y, k], base, slope, first, last, inverse)


@_loop
def class_rows(lev, en, level_cuts, energy_cuts, out, lo, hi):  # pragma: no cover - compiled
    """The coarse class (:func:`_class_of`) of the pixels of rows ``lo..hi`` into ``out``
    (H, W) int32."""
    w = lev.shape[1]
    for y in range(lo, hi):
        for x in range(w):
            out[y, x] = _class_of(lev[y, x], en[y, x], level_cuts, energy_cuts)


@nb.njit(inline="always")
def _taps(d, s0, w0, a1, b1, w1, a2, b2, w2, a3, b3, w3, g, first, n):  # pragma: no cover
    """Up to three symmetric taps (``g``) of a low-pass added to ``d`` in one pass, the
    outermost first: ``((d + (a1 + b1) w1) + (a2 + b2) w2) + (a3 + b3) w3``, with ``d``
    starting at ``s0 w0`` when ``first`` (the order of :func:`_vertical`'s sums)."""
    if first:
        if g == 3:
            for k in range(n):
                d[k] = ((s0[k] * w0 + (a1[k] + b1[k]) * w1) + (a2[k] + b2[k]) * w2) + (
                    a3[k] + b3[k]) * w3
        elif g == 2:
            for k in range(n):
                d[k] = (s0[k] * w0 + (a1[k] + b1[k]) * w1) + (a2[k] + b2[k]) * w2
        elif g == 1:
            for k in range(n):
                d[k] = s0[k] * w0 + (a1[k] + b1[k]) * w1
        else:
            for k in range(n):
                d[k] = s0[k] * w0
    elif g == 3:
        for k in range(n):
            d[k] = ((d[k] + (a1[k] + b1[k]) * w1) + (a2[k] + b2[k]) * w2) + (
                a3[k] + b3[k]) * w3
    elif g == 2:
        for k in range(n):
            d[k] = (d[k] + (a1[k] + b1[k]) * w1) + (a2[k] + b2[k]) * w2
    else:
        for k in range(n):
            d[k] = d[k] + (a1[k] + b1[k]) * w1


@nb.njit(inline="always")
def _vertical(u, y, w, d):  # pragma: no cover - compiled
    """Row ``y`` of the low-pass along axis 0 of ``u`` (H, L) into ``d`` (L,), float32:
    ``w[0] x[y]``, then ``(x[y - j] + x[y + j]) w[j]`` added from the outermost tap in
    (rows reflected at the ends, scipy's ``"reflect"``), three taps a pass (:func:`_taps`)."""
    h, n = u.shape
    j = w.shape[0] - 1
    s0 = u[y]
    first = True
    while first or j > 0:
        g = min(j, 3)
        a1 = u[_reflect(y - j, h)]
        b1 = u[_reflect(y + j, h)]
        a2 = u[_reflect(y - max(j - 1, 0), h)]
        b2 = u[_reflect(y + max(j - 1, 0), h)]
        a3 = u[_reflect(y - max(j - 2, 0), h)]
        b3 = u[_reflect(y + max(j - 2, 0), h)]
        _taps(d, s0, w[0], a1, b1, w[j], a2, b2, w[max(j - 1, 0)], a3, b3, w[max(j - 2, 0)],
              g, first, n)
        first = False
        j -= g


@nb.njit(inline="always")
def _horizontal(row, wd, c, w, pad, d):  # pragma: no cover - compiled
    """The low-pass along a row ``row`` (wd * c,) of ``c`` channels into ``d``: the
    arithmetic of :func:`_vertical`, columns reflected at the ends (``pad``: float32
    scratch of at least (wd + 2 r) * c)."""
    r = w.shape[0] - 1
    n = wd * c
    rc = r * c
    for k in range(n):
        pad[rc + k] = row[k]
    for x in range(1, r + 1):  # the reflected ends
        sl = _reflect(-x, wd)
        sr = _reflect(wd - 1 + x, wd)
        for ch in range(c):
            pad[(r - x) * c + ch] = row[sl * c + ch]
            pad[(r + wd - 1 + x) * c + ch] = row[sr * c + ch]
    s0 = pad[rc:rc + n]
    j = r
    first = True
    while first or j > 0:
        g = min(j, 3)
        j2 = max(j - 1, 0)
        j3 = max(j - 2, 0)
        _taps(d, s0, w[0], pad[rc - j * c:rc - j * c + n], pad[rc + j * c:rc + j * c + n], w[j],
              pad[rc - j2 * c:rc - j2 * c + n], pad[rc + j2 * c:rc + j2 * c + n], w[j2],
              pad[rc - j3 * c:rc - j3 * c + n], pad[rc + j3 * c:rc + j3 * c + n], w[j3],
              g, first, n)
        first = False
        j -= g


@_loop
def gauss_rows(src, w, tmp, dst, horizontal, lo, hi):  # pragma: no cover - compiled
    """One pass of the separable Gaussian of each channel of ``src`` (H, W, C) float32,
    rows ``lo..hi``: along axis 0 (:func:`_vertical`) into ``tmp``, or (``horizontal``,
    once every row of ``tmp`` is done) along axis 1 (:func:`_horizontal`) from ``tmp``
    into ``dst``; ``w`` float32 (r + 1,): the centre tap and the taps at distance 1..r."""
    h, wd, c = src.shape
    n = wd * c
    t2 = tmp.reshape(h, n)
    if horizontal:
        d2 = dst.reshape(h, n)
        pad = np.empty((wd + 2 * w.shape[0]) * c, dtype=np.float32)
        for y in range(lo, hi):
            _horizontal(t2[y], wd, c, w, pad, d2[y])
    else:
        s2 = src.reshape(h, n)
        for y in range(lo, hi):
            _vertical(s2, y, w, t2[y])


@nb.njit(inline="always")
def _upsample_row(wide, f, y, d):  # pragma: no cover - compiled
    """Row ``y`` of the bilinear upsampling by ``f`` into ``d`` (L,) from ``wide``
    (h, L): the low-resolution rows already upsampled along their columns
    (:func:`upsample_cols`). The row at ``s = (2 y + 1 - f) / (2 f)``: the rows on
    either side with weights ``1 - t`` and ``t`` (clamped at the ends)."""
    hl = wide.shape[0]
    num = 2 * y + 1 - f
    i0 = num // (2 * f)
    t = np.float32(num - i0 * 2 * f) / np.float32(2 * f)
    i1 = min(max(i0 + 1, 0), hl - 1)
    i0 = min(max(i0, 0), hl - 1)
    t0 = np.float32(1.0) - t
    a = wide[i0]
    b = wide[i1]
    for k in range(d.shape[0]):
        d[k] = t0 * a[k] + t * b[k]


@_loop
def upsample_cols(low, cx0, cx1, ctx, out, lo, hi):  # pragma: no cover - compiled
    """The bilinear upsampling of rows ``lo..hi`` of ``low`` (h, w, C) along its columns
    into ``out`` (h, W, C): column ``x`` from the columns ``cx0[x]``, ``cx1[x]`` with
    weights ``1 - ctx[x]``, ``ctx[x]`` (float32)."""
    c = low.shape[2]
    wd = cx0.shape[0]
    for i in range(lo, hi):
        r = low[i]
        o = out[i]
        for x in range(wd):
            p = cx0[x]
            q = cx1[x]
            tx = ctx[x]
            tx0 = np.float32(1.0) - tx
            for ch in range(c):
                o[x, ch] = tx0 * r[p, ch] + tx * r[q, ch]


@nb.njit(inline="always")
def _scale_row(u2, wides, offs, hls, wd, c, fac, taps, rads, j, yy, pad, vrow,
               d):  # pragma: no cover - compiled
    """Row ``yy`` of scale ``j``'s low-pass into ``d`` (W * C,): the full-resolution
    Gaussian (:func:`gauss_rows`'s arithmetic) or the bilinear upsampling of its
    low-resolution low-pass (:func:`_upsample_row`)."""
    if fac[j] == 1:
        wj = taps[j, :rads[j] + 1]
        _vertical(u2, yy, wj, vrow)
        _horizontal(vrow, wd, c, wj, pad, d)
    else:
        _upsample_row(wides[offs[j]:offs[j + 1]].reshape(hls[j], wd * c), fac[j], yy, d)


@nb.njit(inline="always")
def _direct_code(v, cell_code, uthr):  # pragma: no cover - compiled
    """The 8-bit display code of a blended value ``v`` in the stage's coding: the code
    at the start of its cell of ``1 / (len(cell_code) - 1)`` (``cell_code``), one more
    where ``v`` reaches the next threshold (``uthr``: the smallest value of each code;
    no cell holds two). NaN and values below 0 give 0, values from 1 up the last cell's.
    Selects, no branches: compiled serially, the branches cost ~35 ns a value (random
    data), the selects ~4."""
    c = v if v > np.float32(0.0) else np.float32(0.0)  # NaN: 0 (and below uthr[1])
    c = c if c < np.float32(1.0) else np.float32(1.0)
    q = np.int64(cell_code[np.int64(c * np.float32(cell_code.shape[0] - 1))])
    nxt = q + 1 if q < 255 else 255
    q += np.int64(v >= uthr[nxt]) if q < 255 else 0
    return np.uint8(q)


@_loop
def stage_rows(u, wides, fac, taps, rads, e_taps, level_cuts, energy_cuts, blend,
               coded, base, slope, first, last, mode, stack, coarse, lev, en, outf,
               use_matrix, m, thr, buckets, interp, shift, out8, out16, bits,
               direct, cell_code, uthr, band_rows, b_lo, b_hi):  # pragma: no cover - compiled
    """The stage on ``u`` (H, W, C) float32, the render in the stage's coding.

    ``wides``: the coarse scales' low-passes at reduced resolution, upsampled along
    their columns (:func:`upsample_cols`), one flat float32 array of (h_j, W, C)
    blocks in scale order (scales with ``fac[j] > 1``);
    ``taps`` (n_scales, r_max + 1) float32 and ``rads`` (n_scales,): the
    full-resolution scales' kernels (``fac[j] == 1``: :func:`gauss_rows`'s taps,
    ``rads[j] + 1`` of them); ``e_taps``: the energy's low-pass;
    ``mode``: :data:`MODE_FEATURES` fills ``stack``
    (H, W, n_scales C), ``coarse`` (H, W, C), ``lev``, ``en`` (H, W);
    :data:`MODE_FLOAT` the decoded blend into ``outf`` (H, W, C);
    :data:`MODE_DISPLAY` its display integers into ``out8`` / ``out16`` (flat)
    through :func:`l3cli.io.encode_rows.encode_row` with the encoder's parameters.
    Bands ``b_lo..b_hi`` of ``band_rows`` rows (a call's temporaries serve its bands;
    calls on other bands may run at the same time).
    ``coded``: the stage works in the sRGB coding, whose inverse (:func:`_code` with the
    table ``base``, ``slope``, ``first``, ``last``) the blend is decoded by.
    ``direct``: 8-bit display codes straight from the blend (the decoding and the
    encoder in one look-up: ``cell_code``, ``uthr``, :func:`_direct_code`).
    """
    h, wd, c = u.shape
    ns = fac.shape[0]
    re = e_taps.shape[0] - 1
    n = wd * c
    u2 = u.reshape(h, n)
    offs = np.zeros(ns + 1, dtype=np.int64)
    hls = np.zeros(ns, dtype=np.int64)
    for j in range(ns):
        f = fac[j]
        if f > 1:
            hl = h
            g = 1
            while g < f:  # the pyramid's heights: halved, rounded up, level by level
                hl = (hl + 1) // 2
                g *= 2
            hls[j] = hl
        offs[j + 1] = offs[j] + hls[j] * n
    nl = level_cuts.shape[0]
    ne = energy_cuts.shape[1]
    cf = np.float32(c)
    cu = np.uint64(c)
    bf = blend.reshape(-1)  # class k, band value r, channel ch at (k * R + r) * C + ch
    ecf = energy_cuts.reshape(-1)
    span = band_rows + 2 * re
    cc = np.empty((span, n), dtype=np.float32)  # the coarsest low-pass, halo included
    lp = np.empty((ns, n), dtype=np.float32)  # the finer low-passes of one row
    st = np.empty((ns, n), dtype=np.float32)  # one row's bands, band by band
    e_rows = np.empty((span, wd), dtype=np.float32)
    vrow = np.empty(n, dtype=np.float32)
    pad = np.empty((wd + 2 * max(taps.shape[1], e_taps.shape[0])) * c, dtype=np.float32)
    e_col = np.empty(wd, dtype=np.float32)
    e_out = np.empty(wd, dtype=np.float32)
    orow = np.empty(n, dtype=np.float32)
    lin = np.empty(n, dtype=np.float32)
    lvr = np.empty(wd, dtype=np.float32)
    cls = np.empty(wd, dtype=np.int64)
    for bi in range(b_lo, b_hi):
        y0 = bi * band_rows
        y1 = min(h, y0 + band_rows)
        a0 = y0 - re
        for k in range(y1 - y0 + 2 * re):  # the coarsest low-pass and the energy
            yy = _reflect(a0 + k, h)
            ck_row = cc[k]
            _scale_row(u2, wides, offs, hls, wd, c, fac, taps, rads, ns - 1, yy, pad, vrow,
                       ck_row)
            ur = u2[yy]
            er = e_rows[k]
            if c == 3:  # the same sums, unrolled (the loop vectorises)
                for x in range(wd):
                    d0 = ur[3 * x] - ck_row[3 * x]
                    d1 = ur[3 * x + 1] - ck_row[3 * x + 1]
                    d2 = ur[3 * x + 2] - ck_row[3 * x + 2]
                    er[x] = ((d0 * d0 + d1 * d1) + d2 * d2) / cf
            else:
                for x in range(wd):  # unsigned indices: no wrap-around code per value
                    b0 = np.uint64(x) * cu
                    sq = np.float32(0.0)
                    for ch in range(c):
                        dv = ur[b0 + np.uint64(ch)] - ck_row[b0 + np.uint64(ch)]
                        sq += dv * dv
                    er[x] = sq / cf
        for y in range(y0, y1):
            k = y - a0
            w0 = e_taps[0]  # the energy: its low-pass along axis 0, then axis 1
            for x in range(wd):
                e_col[x] = e_rows[k, x] * w0
            for j in range(re, 0, -1):
                wj = e_taps[j]
                a = e_rows[k - j]
                b = e_rows[k + j]
                for x in range(wd):
                    e_col[x] += (a[x] + b[x]) * wj
            _horizontal(e_col, wd, 1, e_taps, pad, e_out)
            ur = u2[y]
            crow = cc[k]
            for j in range(ns - 1):
                _scale_row(u2, wides, offs, hls, wd, c, fac, taps, rads, j, y, pad, vrow,
                           lp[j])
            for j in range(ns):  # the bands: finer minus coarser low-pass
                fin = ur if j == 0 else lp[j - 1]
                crs = crow if j == ns - 1 else lp[j]
                sr = st[j]
                for q in range(n):
                    sr[q] = fin[q] - crs[q]
            if c == 3:  # the level: the same sums, unrolled
                for x in range(wd):
                    lvr[x] = ((crow[3 * x] + crow[3 * x + 1]) + crow[3 * x + 2]) / cf
            else:
                for x in range(wd):
                    b0 = np.uint64(x) * cu
                    sv = crow[b0]
                    for ch in range(1, c):
                        sv += crow[b0 + np.uint64(ch)]
                    lvr[x] = sv / cf
            for x in range(wd):  # the energy
                ev = e_out[x]
                e_out[x] = np.sqrt(ev if ev > np.float32(0.0) else np.float32(0.0))
            if mode == MODE_FEATURES:
                for x in range(wd):
                    b0 = np.uint64(x) * cu
                    lev[y, x] = lvr[x]
                    en[y, x] = e_out[x]
                    for j in range(ns):
                        for ch in range(c):
                            stack[y, x, j * c + ch] = st[j, b0 + np.uint64(ch)]
                    for ch in range(c):
                        coarse[y, x, ch] = crow[b0 + np.uint64(ch)]
                continue
            for x in range(wd):  # the class (_class_of, as counts: the cuts increase)
                cls[x] = 0
            for i in range(nl):
                cut = level_cuts[i]
                for x in range(wd):
                    cls[x] += np.int64(cut <= lvr[x])
            for x in range(wd):
                lb = np.uint64(cls[x])
                eb = lb * np.uint64(ne + 1)
                row = lb * np.uint64(ne)
                ev = e_out[x]
                for i in range(ne):
                    eb += np.uint64(ev >= ecf[row + np.uint64(i)])
                cls[x] = np.int64(eb)
            for x in range(wd):  # the blend of the pixel's class
                b0 = np.uint64(x) * cu
                ab = np.uint64(cls[x]) * np.uint64(ns * c * c)
                if c == 3:  # the same sums, the band values loaded once
                    i1 = b0 + np.uint64(1)
                    i2 = b0 + np.uint64(2)
                    s0 = crow[b0]
                    s1 = crow[i1]
                    s2 = crow[i2]
                    for j in range(ns):
                        sj = st[j]
                        for ch in range(3):
                            v = sj[b0 + np.uint64(ch)]
                            q = ab + np.uint64((j * 3 + ch) * 3)
                            s0 += v * bf[q]
                            s1 += v * bf[q + np.uint64(1)]
                            s2 += v * bf[q + np.uint64(2)]
                    orow[b0] = s0
                    orow[i1] = s1
                    orow[i2] = s2
                else:
                    for ch in range(c):
                        sv = crow[b0 + np.uint64(ch)]
                        for j in range(ns):
                            for i in range(c):
                                q = ab + np.uint64(((j * c + i) * c) + ch)
                                sv += st[j, b0 + np.uint64(i)] * bf[q]
                        orow[b0 + np.uint64(ch)] = sv
            if mode == MODE_FEATURES:
                continue
            if direct:
                o8 = np.uint64(y * n)
                for q in range(n):
                    out8[o8 + np.uint64(q)] = _direct_code(orow[q], cell_code, uthr)
                continue
            if coded:
                for q in range(n):
                    lin[q] = _code(orow[q], base, slope, first, last, True)
            else:
                for q in range(n):
                    lin[q] = orow[q]
            if mode == MODE_FLOAT:
                o = outf[y].reshape(n)
                for q in range(n):
                    o[q] = lin[q]
            else:
                encode_row(lin, n, use_matrix, m, thr, buckets, interp, shift, orow,
                           out8, out16, bits, y * n)


@_loop
def half_means(src, dst, coded, code, base, slope, first, last, lo, hi):  # pragma: no cover
    """The mean of each 2 x 2 block of block rows ``lo..hi`` of ``src`` (H, W, C) float32
    into ``dst`` (ceil(H / 2), ceil(W / 2), C): per block ``(a + b) + (c + d)`` over its rows' sums
    (``a + c``, ``b + d``, float32), divided by its pixel count (blocks at the far
    edges are cut short: 2 or 1 pixels). ``code``: the block rows' rows of ``src`` are
    first coded (:func:`_code` with the table ``base``, ``slope``, ``first``, ``last``)
    into ``coded`` (H, W, C; may be ``src`` itself) and the means are those of the coded
    values: the stage's coding and its first pyramid level in one pass."""
    h, w, c = src.shape
    wl = dst.shape[1]
    n = w * c
    rs = np.empty(n, dtype=np.float32)
    for by in range(lo, hi):
        y0 = 2 * by
        if code:
            for yy in range(y0, min(y0 + 2, h)):
                srow = src[yy].reshape(n)
                crow = coded[yy].reshape(n)
                for k in range(n):
                    crow[k] = _code(srow[k], base, slope, first, last, False)
            r0 = coded[y0].reshape(n)
        else:
            r0 = src[y0].reshape(n)
        if y0 + 1 < h:
            r1 = coded[y0 + 1].reshape(n) if code else src[y0 + 1].reshape(n)
            for k in range(n):
                rs[k] = r0[k] + r1[k]
        else:
            for k in range(n):
                rs[k] = r0[k]
        rows = np.float32(2.0 if y0 + 1 < h else 1.0)
        d = dst[by]
        for bx in range(w // 2):
            for ch in range(c):
                d[bx, ch] = (rs[2 * bx * c + ch] + rs[(2 * bx + 1) * c + ch]) / (
                    rows * np.float32(2.0))
        if w % 2:
            for ch in range(c):
                d[wl - 1, ch] = rs[(w - 1) * c + ch] / rows
