"""Display render (render + display encoding fused in the tile kernel) and the fast encoder.

The fused path must give exactly the integers of the two-step path it replaces:
the float render (:func:`l3cli.render.render_mosaic`) followed by
:func:`l3cli.io.encode.display_encode`, itself checked against colour-science
in ``test_encode.py``; the encoder's lookup tables are checked against the
thresholds on every float32 in [0, 1].
"""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest

from l3cli.io.encode import _ONE_BITS, display_encode, display_params
from l3cli.render import render_display, render_mosaic
from l3cli.render_rows import encode_row
from tests.builders import make_table


def _table(spec, patch, n_out, space, seed):
    t = make_table(spec, patch=patch, n_out=n_out, seed=seed, space=space)
    # outputs spread over [-0.3, 1.3]: clipping at both ends, the whole curve between
    t.kernels *= np.float32(0.15)
    t.kernels[:, -1, :] += np.float32(0.4)
    return t


def _mosaic(h, w, seed):
    rng = np.random.default_rng(seed)
    m = (rng.random((h, w)) ** 2).astype(np.float32)
    m[min(3, h - 1), min(5, w - 1)] = 1.0  # a saturated pixel: another class
    return m


CASES = [  # (CFA, patch, n_out, space)
    ("RGGB", 5, 3, "xyz"),  # the simulate default's patch; the matrix path
    ("RGGB", 7, 3, "linear-srgb"),  # the pairs default
    ("RGGB", 3, 3, "srgb"),  # display values: clip and quantise only
    ("RGGB", 5, 4, "xyz"),  # 4 outputs: no colour conversion, the 4-lane store
    ("RGGB", 5, 1, "linear-srgb"),  # 1 output
    ("RGGB", 3, 5, "xyz"),  # > 4 outputs: the general render loop
    ("RGBW/GWRB/BRWG/WBGR", 5, 3, "xyz"),  # a 4x4 CFA
    ("RGGB", 5, 3, "lab"),  # not fused: colour-science's path, same result
]


@pytest.mark.parametrize("spec, patch, n_out, space", CASES)
@pytest.mark.parametrize("bits", [8, 16])
def test_fused_display_render_equals_render_then_encode(spec, patch, n_out, space, bits):
    t = _table(spec, patch, n_out, space, seed=patch + n_out)
    # wider than one tile (512 columns) and not a multiple of it; odd height
    m = _mosaic(45, 1100, seed=bits)
    got = render_display(t, m, bits)
    assert got.dtype == (np.uint16 if bits == 16 else np.uint8)
    assert got.shape == (45, 1100, n_out)
    want = display_encode(render_mosaic(t, m), space, bits)
    np.testing.assert_array_equal(got, want)
    maxv = (1 << bits) - 1
    if space != "lab":  # the test reaches both clipping ends
        assert (got == 0).any() and (got == maxv).any()


@pytest.mark.parametrize("bits", [8, 16])
def test_display_row_bands_and_edges_equal_the_whole(bits):
    t = _table("RGGB", 5, 3, "xyz", seed=1)
    m = _mosaic(37, 530, seed=3)
    whole = render_display(t, m, bits)
    # bands that start and stop at the image's edges, inside the mirror zone, one row
    for y0, y1 in [(0, 1), (0, 2), (1, 9), (9, 30), (30, 37), (36, 37)]:
        out = np.empty((y1 - y0, 530, 3), dtype=whole.dtype)
        assert render_display(t, m, bits, out=out, rows=(y0, y1)) is out
        np.testing.assert_array_equal(out, whole[y0:y1])
    # the smallest mosaic a 5x5 patch fits
    tiny = _mosaic(3, 3, seed=4)
    np.testing.assert_array_equal(render_display(t, tiny, bits),
                                  display_encode(render_mosaic(t, tiny), "xyz", bits))


def test_display_render_checks_its_output_array():
    t = _table("RGGB", 3, 3, "xyz", seed=2)
    m = _mosaic(8, 8, seed=5)
    with pytest.raises(ValueError, match="uint8"):
        render_display(t, m, 8, out=np.empty((8, 8, 3), np.uint16))
    with pytest.raises(ValueError, match="shape"):
        render_display(t, m, 16, out=np.empty((8, 7, 3), np.uint16))


@nb.njit(cache=False)
def _sweep(matrix, thr, buckets, interp, shift, bits, one, chunk):
    """Encode every float32 bit pattern in [0, one]; count codes that differ from the
    thresholds' (a monotonic walk: the code of ``v`` is the number of thresholds <= v)."""
    src = np.empty(chunk, np.float32)
    si = src.view(np.int32)
    lin = np.empty(chunk, np.float32)
    o8 = np.empty(chunk, np.uint8)
    o16 = np.empty(chunk, np.uint16)
    k = 0
    bad = 0
    for s in range(0, one + 1, chunk):
        n = min(chunk, one + 1 - s)
        for j in range(n):
            si[j] = s + j
        encode_row(src, n, False, matrix, thr, buckets, interp, shift, lin, o8, o16, bits, 0)
        for j in range(n):
            v = src[j]
            while v >= thr[k + 1]:
                k += 1
            got = o8[j] if bits == 8 else o16[j]
            bad += got != k
    return bad, k


@pytest.mark.slow
@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("space", ["linear-srgb", "data"])
def test_encoder_lookup_is_exact_for_every_float32_in_0_1(bits, space):
    """The bucket tables (8 bits) and the floor of the interpolated estimate settled by one
    threshold (16 bits) give the thresholds' code for all 1,065,353,217 float32 values in [0, 1]
    (values outside are clipped first; the thresholds are checked against the reference
    recipe in test_encode.py)."""
    p = display_params(space, 3, bits)
    bad, last = _sweep(p.matrix, p.thr, p.buckets, p.interp, p.shift, bits, _ONE_BITS, 1 << 20)
    assert last == (1 << bits) - 1
    assert bad == 0


def test_16_bit_fused_path_and_the_banded_lab_path(monkeypatch):
    """16 bits are encoded inside the kernel (whole image and a row range); ``lab`` tables
    take the banded two-step path (float bands, then colour-science's conversion). Both
    give render-then-encode's integers."""
    from l3cli import kernelset

    t = _table("RGGB", 5, 3, "xyz", seed=6)
    m = _mosaic(41, 600, seed=7)
    want = display_encode(render_mosaic(t, m), "xyz", 16)
    np.testing.assert_array_equal(render_display(t, m, 16), want)
    np.testing.assert_array_equal(render_display(t, m, 16, rows=(5, 38)), want[5:38])
    lab = _table("RGGB", 5, 3, "lab", seed=6)
    want = display_encode(render_mosaic(lab, m), "lab", 16)
    monkeypatch.setattr(kernelset, "DISPLAY_BAND_PIXELS", 600 * 4)  # 4-row bands, a ragged last
    np.testing.assert_array_equal(render_display(lab, m, 16), want)
    np.testing.assert_array_equal(render_display(lab, m, 16, rows=(5, 38)), want[5:38])


def test_encoder_kernel_loads_from_numba_cache_in_a_new_process(tmp_path):
    """The display encoder's kernel is compiled once, then loaded from numba's on-disk cache
    by every later process (a kernel that closes over another dispatcher misses the cache
    in every process and recompiles: ~0.4 s per ``l3 render`` to TIFF)."""
    import os
    import subprocess
    import sys

    from tests.builders import REPO

    code = ("import numpy as np\nfrom l3cli.io.encode import display_encode\n"
            "display_encode(np.zeros((2, 2, 3), np.float32), 'xyz', 16)\n")
    env = {**os.environ, "NUMBA_DEBUG_CACHE": "1", "NUMBA_CACHE_DIR": str(tmp_path)}
    runs = [subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True,
                           text=True, check=True).stdout for _ in range(2)]
    assert "data saved" in runs[0]  # compiled into the empty cache
    assert "data loaded" in runs[1] and "data saved" not in runs[1], runs[1]


@pytest.mark.parametrize("bits", [8, 16])
def test_display_render_applies_a_learned_tone_curve(bits):
    """A table with a tone curve (l3cli.tone.curve): the curve runs in the kernel before
    the encoding, so the display render equals the float render (curve applied) encoded
    (16 bits: the composed lookup is interpolated, within one code)."""
    from l3cli.tone.curve import ToneCurve

    t = _table("RGGB", 7, 3, "linear-srgb", seed=5)
    e = np.linspace(0.0, 1.0, 17)
    s_curve = 0.5 - 0.5 * np.cos(np.pi * e)  # increasing, f(0) = 0, f(1) = 1
    t.tone_lut = ToneCurve(np.stack([s_curve, e, e ** 2], axis=1)).lut("linear-srgb")
    m = _mosaic(45, 1100, seed=7)
    got = render_display(t, m, bits)
    want = display_encode(render_mosaic(t, m), "linear-srgb", bits)
    if bits == 8:
        np.testing.assert_array_equal(got, want)
    else:
        d = got.astype(np.int64) - want
        assert np.abs(d).max() <= 1 and np.mean(d != 0) < 0.01
    t_plain = _table("RGGB", 7, 3, "linear-srgb", seed=5)
    assert (render_display(t_plain, m, bits) != got).mean() > 0.1  # the curve changed it
