"""The multi-scale stage's loops (:mod:`l3cli.multiscale`), in numba.

* :func:`blend_rows`: ``out[y, x, c] = coarse[y, x, c] + sum_r stack[y, x, r] *
  blend[cls[y, x], r, c]``, a gather of a small per-pixel matrix, which numpy
  could only do with a (H, W, R, C) temporary; here rows run in parallel and
  nothing is allocated.
* :func:`gauss_rows` and :func:`gauss_cols`: the two passes of
  ``scipy.ndimage.gaussian_filter(img, (s, s, 0), mode="reflect")`` on a float32
  (H, W, C) image, with scipy's own arithmetic (``correlate1d`` of a symmetric
  kernel: per output ``w[0] * x[0]``, then ``(x[-j] + x[j]) * w[j]`` added from
  the outermost tap in, in float64; float32 between the passes), so the result
  is scipy's bit for bit (a test checks it), vectorised along rows and in
  parallel over them: scipy's generic line loop took 0.5-1.5 s per low-pass of a
  9-MP image.
* :func:`transfer_rows`: the stage's sRGB coding and its inverse, one pass with
  numpy's float32 arithmetic (the same ``powf``), in parallel over rows.
* :func:`level_rows` and :func:`class_rows`: the coarse level and the coarse
  classes, parallel over rows (numpy's mean over the short channel axis and its
  per-pixel gathers of the cuts took 0.1 s per band).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from l3cli.startup import lean_cache

__all__ = ["blend_rows", "class_rows", "gauss_cols", "gauss_rows", "level_rows",
           "transfer_rows"]


@lean_cache
@nb.njit(cache=True, parallel=True)
def blend_rows(stack: np.ndarray, coarse: np.ndarray, cls: np.ndarray, blend: np.ndarray,
               out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Fill ``out`` (H, W, C) with ``coarse + stack @ blend[cls]`` pixel by pixel."""
    h, w, r = stack.shape
    c = coarse.shape[2]
    for y in nb.prange(h):
        for x in range(w):
            a = blend[cls[y, x]]
            for j in range(c):
                acc = coarse[y, x, j]
                for i in range(r):
                    acc += stack[y, x, i] * a[i, j]
                out[y, x, j] = acc


@nb.njit(inline="always")
def _reflect(i: int, n: int) -> int:  # pragma: no cover - compiled
    """scipy's ``"reflect"`` index (d c b a | a b c d | d c b a), any distance out."""
    p = 2 * n
    i = i % p
    if i < 0:
        i += p
    return i if i < n else p - 1 - i


#: Values of a row accumulated at a time (float64 sums that stay in the L1 cache).
_CHUNK = 512


@lean_cache
@nb.njit(cache=True, parallel=True)
def gauss_rows(src: np.ndarray, w: np.ndarray, dst: np.ndarray) -> None:  # pragma: no cover
    """The low-pass along axis 0 of ``src`` (H, L) float32 into ``dst`` (H, L) float32.

    ``w`` float64 (r + 1,): the kernel's centre tap and its taps at distance 1..r.
    """
    h, n = src.shape
    r = w.shape[0] - 1
    for y in nb.prange(h):
        acc = np.empty(_CHUNK, dtype=np.float64)
        s0 = src[y]
        d = dst[y]
        w0 = w[0]
        for k0 in range(0, n, _CHUNK):
            m = min(_CHUNK, n - k0)
            for k in range(m):
                acc[k] = np.float64(s0[k0 + k]) * w0
            for j in range(r, 0, -1):
                a = src[_reflect(y - j, h)]
                b = src[_reflect(y + j, h)]
                wj = w[j]
                for k in range(m):
                    acc[k] += (np.float64(a[k0 + k]) + np.float64(b[k0 + k])) * wj
            for k in range(m):
                d[k0 + k] = np.float32(acc[k])


@lean_cache
@nb.njit(cache=True, parallel=True)
def gauss_cols(src: np.ndarray, w: np.ndarray, dst: np.ndarray) -> None:  # pragma: no cover
    """The low-pass along axis 1 of ``src`` (H, W, C) float32 into ``dst`` (H, W, C)."""
    h, wd, c = src.shape
    r = w.shape[0] - 1
    n = wd * c
    for y in nb.prange(h):
        pad = np.empty((wd + 2 * r) * c, dtype=np.float64)  # the row, reflected at both ends
        row = src[y].reshape(n)
        rc = np.uint64(r * c)
        for k in range(n):  # the inside: a plain copy (no index arithmetic per value)
            pad[rc + np.uint64(k)] = np.float64(row[k])
        for x in range(1, r + 1):  # the reflected ends
            sl = _reflect(-x, wd)
            sr = _reflect(wd - 1 + x, wd)
            for ch in range(c):
                pad[(r - x) * c + ch] = np.float64(src[y, sl, ch])
                pad[(r + wd - 1 + x) * c + ch] = np.float64(src[y, sr, ch])
        acc = np.empty(_CHUNK, dtype=np.float64)
        d = dst[y].reshape(n)
        w0 = w[0]
        for k0 in range(0, n, _CHUNK):
            m = min(_CHUNK, n - k0)
            o = np.uint64(r * c + k0)  # unsigned offsets: no per-value wrap-around code
            for k in range(m):
                acc[k] = pad[o + np.uint64(k)] * w0
            for j in range(r, 0, -1):
                lo = o - np.uint64(j * c)
                hi = o + np.uint64(j * c)
                wj = w[j]
                for k in range(m):
                    acc[k] += (pad[lo + np.uint64(k)] + pad[hi + np.uint64(k)]) * wj
            for k in range(m):
                d[k0 + k] = np.float32(acc[k])


@lean_cache
@nb.njit(cache=True, parallel=True)
def transfer_rows(src: np.ndarray, dst: np.ndarray, inverse: bool) -> None:  # pragma: no cover
    """The stage's sRGB coding (``inverse``: its inverse) of ``src`` (H, L) float32 into
    ``dst``: :func:`l3cli.multiscale.encode` / ``decode``'s float32 steps, per value."""
    h, n = src.shape
    for y in nb.prange(h):
        s = src[y]
        d = dst[y]
        for k in range(n):
            v = s[k]
            a = abs(v)
            if inverse:
                if a <= np.float32(0.04045):
                    o = a / np.float32(12.92)
                else:
                    o = ((a + np.float32(0.055)) / np.float32(1.055)) ** np.float32(2.4)
            else:
                if a <= np.float32(0.0031308):
                    o = np.float32(12.92) * a
                else:
                    o = np.float32(1.055) * a ** np.float32(1 / 2.4) - np.float32(0.055)
            d[k] = np.float32(np.copysign(o, v))


@lean_cache
@nb.njit(cache=True, parallel=True)
def level_rows(coarse: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """The channel mean of ``coarse`` (H, W, C) into ``out`` (H, W), float32
    ``((c0 + c1) + c2 ...) / C`` as numpy's mean over a short last axis."""
    h, w, c = coarse.shape
    cf = np.float32(c)
    for y in nb.prange(h):
        for x in range(w):
            s = coarse[y, x, 0]
            for ch in range(1, c):
                s += coarse[y, x, ch]
            out[y, x] = s / cf


@lean_cache
@nb.njit(cache=True, parallel=True)
def class_rows(lev: np.ndarray, en: np.ndarray, level_cuts: np.ndarray,
               energy_cuts: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """The coarse class of every pixel into ``out`` (H, W) int32: the bin of ``lev``
    among ``level_cuts`` times the energy bins, plus the bin of ``en`` among its
    level's ``energy_cuts`` (float32; a value equal to a cut falls in the bin above
    it: :func:`l3cli.multiscale.classes`)."""
    h, w = lev.shape
    nl = level_cuts.shape[0]
    ne = energy_cuts.shape[1]
    for y in nb.prange(h):
        for x in range(w):
            v = lev[y, x]
            lb = 0
            while lb < nl and level_cuts[lb] <= v:
                lb += 1
            e = en[y, x]
            eb = 0
            for j in range(ne):
                eb += np.int32(e >= energy_cuts[lb, j])
            out[y, x] = lb * (ne + 1) + eb
