"""Display encoding: float images → 8/16-bit display sRGB integers, fast and exact.

TIFF, PNG and JPEG hold display sRGB. The reference recipe (what
:func:`l3cli.colourspace.convert` followed by quantisation computes) is, per
value: linear sRGB in float32 (``xyz @ M.T`` in float64, then cast), clipped to
[0, 1]; the IEC 61966-2-1 transfer function in float64, cast to float32;
``round(v * (2**bits - 1))`` in float32 (half to even). This module gives the
same integers without colour-science and without float64 image temporaries:

* the quantised transfer function ``Q(v)`` is monotonic in ``v``, so it is
  fully described by the smallest float32 ``v`` reaching each code (a
  threshold table, found once per bit depth by bisection over float32 bit
  patterns with the reference recipe itself);
* a numba kernel (``nogil``: it runs beside the renderer in the file pipeline)
  does the 3x3 matrix per pixel and looks the code up: a table indexed by the
  top bits of ``v`` gives the code of its bucket's first value, a short
  branch-free walk over the thresholds (as many steps as a bucket spans codes:
  1 for 8 bits, 3-4 for 16) finishes it.

Only the matrix product can differ from numpy's (BLAS may fuse multiply-adds):
by one float64 ulp, which changes a float32 value about once in 2**29.
"""

from __future__ import annotations

import functools

import numpy as np

from l3cli.colourspace import XYZ_TO_LINEAR_SRGB, check_space

__all__ = ["display_encode", "quantise_reference", "srgb_thresholds"]

#: Bits of a float32 dropped to index the bucket table (2**(30 - 10) buckets over [0, 1]).
_BUCKET_SHIFT = 10
_ONE_BITS = int(np.float32(1.0).view(np.int32))


def _srgb_oetf64(lin32: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 encoding in float64 as colour-science computes it (``eotf_inverse_sRGB``)."""
    lin = np.asarray(lin32, dtype=np.float64)
    return np.where(lin <= 0.0031308, lin * 12.92, 1.055 * np.sign(lin) * np.abs(lin) ** (1 / 2.4)
                    - 0.055)


def quantise_reference(lin: np.ndarray, bits: int, *, encode: bool = True) -> np.ndarray:
    """The reference recipe on float32 values: clip, (encode,) quantise. Slow; for tables and tests.

    Parameters
    ----------
    lin
        float32 values (linear sRGB when ``encode``, display values otherwise).
    bits
        8 or 16.
    encode
        Apply the sRGB transfer function (False: values already display-encoded).
    """
    v = np.clip(np.asarray(lin, dtype=np.float32), np.float32(0), np.float32(1))
    if encode:
        v = _srgb_oetf64(v).astype(np.float32)
    maxv = (1 << bits) - 1
    q = np.round(np.clip(v, np.float32(0), np.float32(1)) * maxv)
    return q.astype(np.uint16 if bits == 16 else np.uint8)


@functools.cache
def srgb_thresholds(bits: int, encode: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Threshold and bucket tables of the quantised transfer function.

    Returns
    -------
    thresholds
        float32 (2**bits + 1,): ``thresholds[k]`` is the smallest float32 in
        [0, 1] whose code is >= k (``thresholds[0] = 0``, the last entry is
        +inf as a sentinel).
    buckets
        uint16: the code of the first float32 of each bucket of ``2**10``
        consecutive bit patterns in [0, 1].
    """
    n = 1 << bits
    maxv = n - 1
    codes = np.arange(1, n, dtype=np.int64)

    def q_of(pattern: np.ndarray) -> np.ndarray:
        return quantise_reference(pattern.astype(np.int32).view(np.float32), bits,
                                  encode=encode).astype(np.int64)

    # bracket each threshold near the analytic inverse, then bisect over bit patterns
    mid_code = (codes - 0.5) / maxv
    guess = mid_code if not encode else np.where(
        mid_code <= 0.04045, mid_code / 12.92, ((mid_code + 0.055) / 1.055) ** 2.4)
    g = guess.astype(np.float32).view(np.int32).astype(np.int64)
    lo = np.maximum(g - 64, 0)  # bit patterns: Q(lo) < k
    hi = np.minimum(g + 64, _ONE_BITS)  # Q(hi) >= k (Q(1.0) = n - 1)
    bad = (q_of(lo) >= codes) & (lo > 0)
    lo[bad] = 0
    bad = q_of(hi) < codes
    hi[bad] = _ONE_BITS
    while np.any(hi - lo > 1):
        mid = (lo + hi) // 2
        ge = q_of(mid) >= codes
        hi = np.where(ge, mid, hi)
        lo = np.where(ge, lo, mid)
    thr = np.empty(n + 1, dtype=np.float32)
    thr[0] = 0.0
    thr[1:n] = hi.astype(np.int32).view(np.float32)
    thr[n] = np.inf
    starts = (np.arange((_ONE_BITS >> _BUCKET_SHIFT) + 1, dtype=np.int64) << _BUCKET_SHIFT)
    first = starts.astype(np.int32).view(np.float32)
    buckets = (np.searchsorted(thr[: n], first, side="right") - 1).astype(np.uint16)
    return thr, buckets


@functools.cache
def _walk(bits: int, encode: bool) -> int:
    """Most codes a bucket spans (the steps of the kernel's walk): 1 for 8 bits, ~3 for 16."""
    return max(1, int(np.diff(srgb_thresholds(bits, encode)[1].astype(np.int64)).max()))


@functools.cache
def _kernel():
    """The numba kernel (compiled, or loaded from numba's on-disk cache, on first use)."""
    import numba as nb

    @nb.njit(cache=True, nogil=True)
    def encode_rows(img, matrix, use_matrix, thr, buckets, shift, steps, out):
        h, w, c = img.shape
        flat = out.reshape(h, w * c)
        lin = np.empty(w * c, dtype=np.float32)
        bits = lin.view(np.int32)
        m = matrix
        for y in range(h):
            if use_matrix:
                for x in range(w):
                    a = np.float64(img[y, x, 0])
                    b = np.float64(img[y, x, 1])
                    d = np.float64(img[y, x, 2])
                    lin[3 * x] = np.float32(m[0, 0] * a + m[0, 1] * b + m[0, 2] * d)
                    lin[3 * x + 1] = np.float32(m[1, 0] * a + m[1, 1] * b + m[1, 2] * d)
                    lin[3 * x + 2] = np.float32(m[2, 0] * a + m[2, 1] * b + m[2, 2] * d)
            else:
                for x in range(w):
                    for k in range(c):
                        lin[c * x + k] = img[y, x, k]
            for i in range(w * c):  # clip to [0, 1]; NaN gives 0
                v = lin[i]
                lin[i] = v if v > 0.0 else np.float32(0.0)
                if v > 1.0:
                    lin[i] = np.float32(1.0)
            for i in range(w * c):  # the bucket's first code, then a fixed, branch-free walk
                v = lin[i]
                q = np.int64(buckets[bits[i] >> shift])
                for _ in range(steps):
                    q += v >= thr[q + 1]
                flat[y, i] = q

    return encode_rows


def display_encode(image: np.ndarray, space: str, bits: int) -> np.ndarray:
    """Display-encoded integers of an image, as l3 writes TIFF, PNG and JPEG.

    Parameters
    ----------
    image
        float (H, W, C). Three channels in ``xyz``, ``linear-srgb`` or
        ``srgb`` are converted to display sRGB; any other channel count, or
        ``space="data"``, is clipped to [0, 1] and quantised as is.
    space
        The image's colour space (:data:`l3cli.colourspace.SPACES`) or ``"data"``.
    bits
        8 or 16.

    Returns
    -------
    numpy.ndarray
        uint8 or uint16 (H, W, C): ``round(clip(display value) * (2**bits - 1))``,
        the same integers as :func:`l3cli.colourspace.convert` followed by
        :func:`quantise_reference` (``lab`` images take that slower path).
    """
    if bits not in (8, 16):
        raise ValueError(f"bits must be 8 or 16, got {bits}")
    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.ndim != 3:
        raise ValueError(f"image must be (H, W, C), got {img.shape}")
    c = img.shape[2]
    space = space if space == "data" else check_space(space)
    if c == 3 and space == "lab":
        from l3cli.colourspace import convert

        img = convert(img, space, "linear-srgb")
        space = "linear-srgb"
    encode = c == 3 and space in ("xyz", "linear-srgb")
    thr, buckets = srgb_thresholds(bits, encode)
    out = np.empty(img.shape, dtype=np.uint16 if bits == 16 else np.uint8)
    matrix = XYZ_TO_LINEAR_SRGB if (encode and space == "xyz") else np.eye(3)
    _kernel()(img, matrix, bool(encode and space == "xyz"), thr, buckets, _BUCKET_SHIFT,
              _walk(bits, encode), out)
    return out
