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
from typing import NamedTuple

import numpy as np

from l3cli.colourspace import XYZ_TO_LINEAR_SRGB, check_space

__all__ = ["DisplayParams", "display_encode", "display_params", "encode_into",
           "interpolation_table",
           "quantise_reference", "srgb_thresholds"]

#: Bits of a float32 dropped to number its bucket: 2**(30 - 16) buckets over [0, 1]
#: (128 per octave), tables of 32 kB (8 bits) and 128 kB (16 bits) that stay in cache.
_BUCKET_SHIFT = 16
_ONE_BITS = int(np.float32(1.0).view(np.int32))
_NO_U8 = np.zeros(1, dtype=np.uint8)
_NO_U16 = np.zeros(1, dtype=np.uint16)


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
        uint16: the code of the first float32 of each bucket of ``2**16``
        consecutive bit patterns in [0, 1].
    """
    n = 1 << bits
    maxv = n - 1
    codes = np.arange(1, n, dtype=np.int64)

    def q_of(pattern: np.ndarray) -> np.ndarray:
        return quantise_reference(pattern.astype(np.int32).view(np.float32), bits,
                                  encode=encode).astype(np.int64)

    # bracket each threshold near the analytic inverse (a few bit patterns off it;
    # wider where that fails), then bisect over bit patterns, the open brackets only
    mid_code = (codes - 0.5) / maxv
    guess = mid_code if not encode else np.where(
        mid_code <= 0.04045, mid_code / 12.92, ((mid_code + 0.055) / 1.055) ** 2.4)
    g = guess.astype(np.float32).view(np.int32).astype(np.int64)
    lo = np.maximum(g - 4, 0)  # bit patterns: Q(lo) < k
    hi = np.minimum(g + 4, _ONE_BITS)  # Q(hi) >= k (Q(1.0) = n - 1)
    bad = np.flatnonzero((q_of(lo) >= codes) & (lo > 0))
    for step in (64, None):  # then the whole range
        lo[bad] = np.maximum(g[bad] - step, 0) if step else 0
        bad = bad[(q_of(lo[bad]) >= codes[bad]) & (lo[bad] > 0)]
    bad = np.flatnonzero(q_of(hi) < codes)
    for step in (64, None):
        hi[bad] = np.minimum(g[bad] + step, _ONE_BITS) if step else _ONE_BITS
        bad = bad[q_of(hi[bad]) < codes[bad]]
    todo = np.flatnonzero(hi - lo > 1)
    while todo.size:
        mid = (lo[todo] + hi[todo]) // 2
        ge = q_of(mid) >= codes[todo]
        hi[todo] = np.where(ge, mid, hi[todo])
        lo[todo] = np.where(ge, lo[todo], mid)
        todo = todo[hi[todo] - lo[todo] > 1]
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
    """Most codes a bucket spans: 1 for 8 bits (one comparison after the lookup)."""
    return max(1, int(np.diff(srgb_thresholds(bits, encode)[1].astype(np.int64)).max()))


@functools.cache
def interpolation_table(bits: int, encode: bool = True) -> np.ndarray:
    """Per bucket, the code as a linear function of a value's low 16 bits (for 16-bit output).

    Within a bucket (``2**16`` consecutive float32 bit patterns, one
    exponent) a value is linear in its low bits ``f``, and the unrounded code
    ``oetf(v) * (2**bits - 1)`` is smooth, so ``base + slope * f`` stays
    within a tenth of a code of it (the transfer curve's bend over 1/128 of
    an octave; most at the kink between its linear and power segments).
    Its floor is therefore the exact code or the one below, which the
    encoder settles with one comparison against the next threshold (a test
    checks every float32 in [0, 1]).

    Returns
    -------
    numpy.ndarray
        float32 (n_buckets, 2): ``base`` (the unrounded code of the bucket's
        first value) and ``slope`` (codes per unit of the low bits).
    """
    maxv = (1 << bits) - 1
    n_b = (_ONE_BITS >> _BUCKET_SHIFT) + 1
    pats = np.arange(n_b + 1, dtype=np.int64) << _BUCKET_SHIFT
    v = pats.astype(np.int32).view(np.float32).astype(np.float64)
    code = (_srgb_oetf64(v) if encode else v) * maxv
    table = np.zeros((n_b, 2), dtype=np.float32)
    table[:, 0] = code[:-1]
    table[:-1, 1] = (code[1:-1] - code[:-2]) / (1 << _BUCKET_SHIFT)  # the last: 1.0 only
    return table


class DisplayParams(NamedTuple):
    """What the display encoder (:func:`l3cli.io.encode_rows.encode_row`) needs, in its order."""

    #: Apply ``matrix`` (XYZ to linear sRGB) to each pixel of 3 values first.
    use_matrix: bool
    #: float64 (3, 3).
    matrix: np.ndarray
    #: float32 thresholds (:func:`srgb_thresholds`).
    thr: np.ndarray
    #: uint16 bucket codes (:func:`srgb_thresholds`) for 8 bits; unused for 16.
    buckets: np.ndarray
    #: float32 (2 n_buckets,): :func:`interpolation_table` flattened, for 16 bits; unused for 8.
    interp: np.ndarray
    #: Right shift of a value's float32 bits that numbers its bucket.
    shift: int


_NO_BUCKETS = np.zeros(1, dtype=np.uint16)
_NO_INTERP = np.zeros((1, 2), dtype=np.float32)  # flattened when passed


def display_params(space: str, n_channels: int, bits: int) -> DisplayParams | None:
    """The encoder's parameters for images of ``n_channels`` in ``space``; None for ``lab``.

    Three channels in ``xyz``, ``linear-srgb`` or ``srgb`` become display
    sRGB; any other channel count, or ``space="data"``, is clipped and
    quantised as is. Three ``lab`` channels need colour-science's conversion
    first (None: the caller converts).
    """
    if bits not in (8, 16):
        raise ValueError(f"bits must be 8 or 16, got {bits}")
    space = space if space == "data" else check_space(space)
    if n_channels == 3 and space == "lab":
        return None
    encode = n_channels == 3 and space in ("xyz", "linear-srgb")
    use_matrix = bool(encode and space == "xyz")
    thr, buckets = srgb_thresholds(bits, encode)
    if bits == 16:
        buckets, interp = _NO_BUCKETS, interpolation_table(bits, encode)
    else:
        if _walk(bits, encode) != 1:  # the 8-bit lookup makes one comparison
            raise RuntimeError("an 8-bit bucket spans more than 2 codes")
        interp = _NO_INTERP
    return DisplayParams(use_matrix, XYZ_TO_LINEAR_SRGB if use_matrix else np.eye(3), thr,
                         buckets, interp.reshape(-1), _BUCKET_SHIFT)


@functools.cache
def _kernel():
    """The numba kernel (compiled, or loaded from numba's on-disk cache, on first use).

    It lives in :mod:`l3cli.io.encode_rows` (imported here, on first use, so that
    importing this module does not import numba) as a module-level function:
    a kernel defined in here as a closure over ``encode_row`` would miss
    numba's cache in every new process (the closure's pickled dispatcher
    differs), costing a compile (~0.4 s) per ``l3 render`` to TIFF.
    """
    from l3cli.io.encode_rows import encode_rows

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
    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.ndim != 3:
        raise ValueError(f"image must be (H, W, C), got {img.shape}")
    params = display_params(space, img.shape[2], bits)
    if params is None:  # lab: colour-science's conversion to linear sRGB first
        from l3cli.colourspace import convert

        img = np.ascontiguousarray(convert(img, "lab", "linear-srgb"), dtype=np.float32)
        params = display_params("linear-srgb", 3, bits)
    out = np.empty(img.shape, dtype=np.uint16 if bits == 16 else np.uint8)
    return encode_into(img, params, bits, out)


def encode_into(img: np.ndarray, params: DisplayParams, bits: int, out: np.ndarray) -> np.ndarray:
    """Display-encode float32 C-contiguous ``img`` (H, W, C) into ``out`` (same shape, uint8
    for 8 bits, uint16 for 16, C-contiguous) with :func:`display_params`' ``params``."""
    flat = out.reshape(-1)
    _kernel()(img, *params, flat if bits == 8 else _NO_U8, flat if bits == 16 else _NO_U16,
              bits)
    return out
