"""The tone curve and the display encoding as one lookup (l3cli.tone.code): exact
thresholds for 8 bits, interpolated codes for 16."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from l3cli.classify import ClassDefinition
from l3cli.io.encode import display_encode, display_params, quantise_reference
from l3cli.kernelset import KernelSet, render_display, render_mosaic
from l3cli.render_rows import curve_code16_row, curve_encode_row
from l3cli.table import TransformTable
from l3cli.tone.code import _curve_codes_np, code_table, curve_codes, interpolated_codes
from l3cli.tone.curve import ToneCurve


def _lut(space="linear-srgb"):
    x = np.linspace(0, 1, 33)[:, None]
    knots = np.hstack([x ** 2.0, x ** 2.2, x ** 1.9])  # f(e): encoded -> curve space
    knots[0] = [-0.002, -0.004, -0.008]  # a curve that starts below 0, as trained ones do
    return ToneCurve(knots, space="srgb").lut(space)


def _interp_reference(v, lut, lo_hi):
    """The table's curve as plain numpy: np.interp on its uniform grid, per channel."""
    out = np.empty(v.shape, np.float64)
    for c in range(v.shape[-1]):
        grid = np.linspace(lo_hi[0, c], lo_hi[1, c], lut.shape[0])
        out[..., c] = np.interp(v[..., c], grid, lut[:, c])
    return out.astype(np.float32)


def _values(n=200_000, seed=0):
    rng = np.random.default_rng(seed)
    v = rng.uniform(-0.05, 1.05, size=(n, 3)).astype(np.float32)
    v[: n // 4] = rng.uniform(-0.01, 0.02, size=(n // 4, 3))  # the steep shadows
    return v


def _composed(v, ct, bits=8):
    flat = np.ascontiguousarray(v, np.float32).reshape(-1)
    out8 = np.empty(flat.size, np.uint8)
    out16 = np.empty(flat.size if bits == 16 else 1, np.uint16)
    curve_encode_row(flat, flat.size // 3, 3, *ct, out8, out16, bits, 0)
    return (out8 if bits == 8 else out16).reshape(v.shape).astype(np.int64)


def test_composed_codes_are_curve_then_encode_and_near_np_interp():
    lut, lo_hi = _lut()
    cv = tone_curve_arrays_of(lut, lo_hi)
    thr = display_params("linear-srgb", 3, 8).thr
    ct = code_table(cv, thr, 8)
    assert ct is not None and ct.walk == 1
    v = _values()
    got = _composed(v, ct)
    # exactly the codes of the curve followed by the encoder (what the kernel did before)
    want = np.stack([curve_codes(v[:, c], c, cv, thr) for c in range(3)], axis=1)
    np.testing.assert_array_equal(got, want)
    # and within one code of plain numpy: np.interp of the table's curve, then the
    # reference sRGB quantisation
    ref = quantise_reference(_interp_reference(v, lut, lo_hi), 8).astype(np.int64)
    assert np.abs(got - ref).max() <= 1
    assert np.mean(got != ref) < 1e-3


def test_every_threshold_is_the_first_value_of_its_code():
    lut, lo_hi = _lut()
    cv = tone_curve_arrays_of(lut, lo_hi)
    thr = display_params("linear-srgb", 3, 8).thr
    ct = code_table(cv, thr, 8)
    for c in range(3):
        t = ct.thr[c, 1:256]
        t = t[np.isfinite(t)]
        below = np.nextafter(t, np.float32(-np.inf))
        at = _composed(np.repeat(t[:, None], 3, axis=1), ct)[:, c]
        under = _composed(np.repeat(below[:, None], 3, axis=1), ct)[:, c]
        # the table's definition: the curve's multiply-add rounded once (a product of two
        # float32 is exact in float64), the same on every CPU
        np.testing.assert_array_equal(at, _curve_codes_np(t, c, cv, thr))
        np.testing.assert_array_equal(under, _curve_codes_np(below, c, cv, thr))
        assert np.all(at == under + 1)  # one code per threshold: none skipped or doubled
        # the compiled curve fuses that multiply-add where the CPU has FMA and rounds twice
        # where it has not (NUMBA_CPU_NAME=generic): at a threshold, one code at most
        for v, codes in ((t, at), (below, under)):
            assert np.abs(curve_codes(v, c, cv, thr) - codes).max() <= 1


def test_out_of_range_values_take_the_end_codes_and_nan_does_not_crash():
    lut, lo_hi = _lut()
    cv = tone_curve_arrays_of(lut, lo_hi)
    thr = display_params("linear-srgb", 3, 8).thr
    ct = code_table(cv, thr, 8)
    v = np.array([[-1e30] * 3, [-5.0] * 3, [5.0] * 3, [1e30] * 3, [np.inf] * 3,
                  [-np.inf] * 3], np.float32)
    got = _composed(v, ct)
    want = np.stack([curve_codes(v[:, c], c, cv, thr) for c in range(3)], axis=1)
    np.testing.assert_array_equal(got[:4], want[:4])
    assert np.all(got[2:5] == 255) and np.all(got[[0, 1, 5]] == got[0])
    nan = _composed(np.full((4, 3), np.nan, np.float32), ct)
    assert nan.min() >= 0 and nan.max() <= 255


def test_a_grid_too_coarse_for_the_codes_is_refused():
    lut, lo_hi = _lut()
    cv = tone_curve_arrays_of(lut, lo_hi)
    thr16 = display_params("linear-srgb", 3, 16).thr
    assert code_table(cv, thr16, 16, cells=1024) is None  # 16 bits: many codes per cell
    ct = code_table(cv, thr16, 16, cells=1024, max_walk=4096)  # the general loop
    v = _values(20_000)
    got = _composed(v, ct, bits=16)
    want = np.stack([curve_codes(v[:, c], c, cv, thr16) for c in range(3)], axis=1)
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("patch", [5, 7])
def test_display_render_with_a_curve_uses_it_and_matches_the_float_render(patch, monkeypatch):
    d = ClassDefinition.build("RGGB", patch=patch, level_cuts=[0.02, 0.08, 0.3],
                              contrast_cuts=0.2)
    rng = np.random.default_rng(3)
    nc, q = d.n_classes, d.n_coeffs
    k = rng.normal(scale=0.05, size=(nc, q, 3)).astype(np.float32)
    k[:, : q - 1, :] += np.float32(1.0 / (q - 1))
    t = TransformTable(definition=d, kernels=k, counts=np.full(nc, 500),
                       lambdas=np.full((nc, 3), 1e-3), empty=np.zeros(nc, bool),
                       source_class=np.arange(nc), output_space="linear-srgb",
                       tone_lut=_lut())
    yy, xx = np.mgrid[:96, :700]
    m = np.clip(0.2 + 0.18 * np.sin(xx / 9.0) * np.cos(yy / 7.0)
                + rng.normal(scale=0.03, size=yy.shape), 0, 1).astype(np.float32)
    ks = KernelSet.plain(t)
    import l3cli.tone.code as tc

    used = []
    real = tc.code_table_for
    monkeypatch.setattr(tc, "code_table_for", lambda *a: used.append(a[2]) or real(*a))
    got = render_display(ks, m, 8).astype(np.int64)
    assert used == [8]  # the composed lookup ran
    f = render_mosaic(ks, m)
    np.testing.assert_array_equal(got, display_encode(f, "linear-srgb", 8))
    # against plain numpy's curve on the kernels' own output (the curve space)
    raw_out = render_mosaic(KernelSet.plain(dataclasses.replace(t, tone_lut=None)), m)
    ref = quantise_reference(_interp_reference(raw_out, *t.tone_lut), 8).astype(np.int64)
    assert np.abs(got - ref).max() <= 1
    # 16 bits: the interpolated lookup, within one code of curve-then-encode
    used.clear()
    got16 = render_display(ks, m, 16).astype(np.int64)
    assert used == [16]
    d = got16 - display_encode(f, "linear-srgb", 16)
    assert np.abs(d).max() <= 1 and np.mean(d != 0) < 0.01


def tone_curve_arrays_of(lut, lo_hi):
    """The curve arrays the tile kernel reads, from a (lut, range) pair."""
    from l3cli.tone.curve import curve_arrays

    return curve_arrays(lut, lo_hi)



def _interpolated(v, ct):
    flat = np.ascontiguousarray(v, np.float32).reshape(-1)
    out16 = np.empty(flat.size, np.uint16)
    curve_code16_row(flat, flat.size // 3, ct.thr, ct.lo, ct.scale, out16, 0)
    return out16.reshape(v.shape).astype(np.int64)


def _sweep(lo_hi, n=400_000):
    """Every channel's curve range, densely, plus values beyond both ends."""
    v = np.linspace(lo_hi[0] - 0.05, lo_hi[1] + 0.05, n).astype(np.float32)
    return np.concatenate([v, _values(100_000, seed=4)])


@pytest.mark.parametrize("space", ["linear-srgb", "srgb"])
def test_16_bit_interpolated_codes_are_within_one_code_of_curve_then_encode(space):
    """Against the curve then the encoder's thresholds (the sRGB transfer curve, or none
    for an ``srgb`` table), over the whole range and the steep shadows."""
    lut, lo_hi = _lut(space)
    cv = tone_curve_arrays_of(lut, lo_hi)
    thr = display_params(space, 3, 16).thr
    ct = interpolated_codes(cv, thr)
    assert ct is not None and ct.walk == 0
    v = _sweep(lo_hi)
    got = _interpolated(v, ct)
    want = np.stack([curve_codes(v[:, c], c, cv, thr) for c in range(3)], axis=1)
    d = got - want
    assert np.abs(d).max() <= 1
    assert np.mean(d != 0) < 0.01
    assert got.min() == 0 and got.max() == 65535  # both ends reached


def test_16_bit_interpolated_codes_refine_a_steep_curve_and_refuse_an_impossible_bound():
    """A steeper curve needs more sub-cells for the same error; a bound no grid can meet
    gives None (the render keeps curve-then-encode)."""
    lut, lo_hi = _lut()
    cv = tone_curve_arrays_of(lut, lo_hi)
    thr = display_params("linear-srgb", 3, 16).thr
    gentle = interpolated_codes(cv, thr)
    steep_lut = (np.clip(lut, 0, None) ** 0.8).astype(np.float32)  # steeper near black
    steep = interpolated_codes(tone_curve_arrays_of(steep_lut, lo_hi), thr)
    assert steep is not None and steep.thr.shape[1] > gentle.thr.shape[1]
    v = _sweep(lo_hi)
    cv_s = tone_curve_arrays_of(steep_lut, lo_hi)
    want = np.stack([curve_codes(v[:, c], c, cv_s, thr) for c in range(3)], axis=1)
    assert np.abs(_interpolated(v, steep) - want).max() <= 1
    assert interpolated_codes(cv, thr, max_error=1e-6) is None


def test_16_bit_interpolated_codes_out_of_range_and_nan():
    lut, lo_hi = _lut()
    cv = tone_curve_arrays_of(lut, lo_hi)
    thr = display_params("linear-srgb", 3, 16).thr
    ct = interpolated_codes(cv, thr)
    v = np.array([[-1e30] * 3, [-5.0] * 3, [5.0] * 3, [1e30] * 3, [np.inf] * 3,
                  [-np.inf] * 3], np.float32)
    got = _interpolated(v, ct)
    want = np.stack([curve_codes(v[:, c], c, cv, thr) for c in range(3)], axis=1)
    np.testing.assert_array_equal(got, want)  # the ends are nodes: exact
    nan = _interpolated(np.full((4, 3), np.nan, np.float32), ct)
    assert nan.min() >= 0 and nan.max() <= 65535
