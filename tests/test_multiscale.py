"""The multi-scale stage (l3cli.multiscale): fit, apply, table keys, l3 train --multiscale."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from l3cli import defaults
from l3cli.errors import TableError
from l3cli.multiscale import (
    TRUNCATE,
    Multiscale,
    MultiscaleStats,
    accumulate,
    apply_stage,
    place_cuts,
    solve,
)

ROOT = Path(__file__).resolve().parents[1]


def _gauss_taps(sigma: float) -> np.ndarray:
    """The 1-D Gaussian of a sampled standard deviation, written out (not scipy's)."""
    r = int(TRUNCATE * sigma + 0.5)
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    return g / g.sum()


@pytest.mark.parametrize("transfer", ["none", "srgb"])
def test_identity_blend_returns_the_render(transfer):
    rng = np.random.default_rng(0)
    y = rng.random((40, 56, 3), dtype=np.float32) * 1.2 - 0.05  # below 0 and above 1 too
    stage = Multiscale.identity(3, (1.5, 4.0), [0.3, 0.6], np.array([[0.01, 0.1]] * 3),
                                transfer=transfer)
    out = apply_stage(stage, y)
    assert out.shape == y.shape and out.dtype == np.float32
    np.testing.assert_allclose(out, y, atol=1e-5)


def test_srgb_coding_is_the_iec_curve_and_inverts():
    import colour

    from l3cli.multiscale import decode, encode

    v = np.linspace(0, 1, 1001, dtype=np.float32)
    np.testing.assert_allclose(encode(v, "srgb"), colour.cctf_encoding(v.astype(np.float64),
                                                                        function="sRGB"),
                               atol=2e-6)
    w = np.linspace(-3, 3, 2001, dtype=np.float32)
    np.testing.assert_allclose(encode(-w, "srgb"), -encode(w, "srgb"), atol=0)
    np.testing.assert_allclose(decode(encode(w, "srgb"), "srgb"), w, rtol=1e-5, atol=1e-7)
    assert encode(w, "none") is not None and np.array_equal(encode(w, "none"), w)


def test_zero_blend_returns_the_coarsest_lowpass():
    # A = 0: out = lp_n, a Gaussian of the image; on a delta far from the borders
    # that is the 2-D Gaussian's own taps
    sigma = 3.0
    stage = Multiscale.identity(1, (1.0, sigma))
    stage.blend[:] = 0
    y = np.zeros((41, 41, 1), np.float32)
    y[20, 20, 0] = 1.0
    out = apply_stage(stage, y)[..., 0]
    g = _gauss_taps(sigma)
    r = g.size // 2
    np.testing.assert_allclose(out[20 - r:21 + r, 20 - r:21 + r], np.outer(g, g), atol=1e-6)


def test_fit_recovers_a_known_blend():
    # target = lp_n + sum_j A_true[k, j] b_j exactly: the per-class solve gives A_true back
    rng = np.random.default_rng(1)
    y = rng.random((96, 128, 3), dtype=np.float32)
    probe = Multiscale.identity(3, (1.0, 3.0))
    stack, coarse, _ = probe.features(y)
    from l3cli.multiscale import energy, level

    lc, ec = place_cuts(level(coarse), energy(y, coarse, 1.0), 2, 2)
    shape = Multiscale.identity(3, (1.0, 3.0), lc, ec)
    stack, coarse, cls = shape.features(y)
    assert set(np.unique(cls)) == {0, 1, 2, 3}
    a_true = rng.normal(size=(4, 6, 3)).astype(np.float32)
    target = coarse + np.einsum("hwr,hwrc->hwc", stack, a_true[cls])
    stats = accumulate(MultiscaleStats.zeros(4, 2, 3), stack, coarse, cls, target)
    assert stats.n.sum() == y.shape[0] * y.shape[1]
    a = solve(stats, 1e-9, 3)
    np.testing.assert_allclose(a, a_true, atol=1e-4)
    fitted = Multiscale(np.array([1.0, 3.0]), lc, ec, a, stats.n)
    np.testing.assert_allclose(apply_stage(fitted, y), target, atol=1e-4)


def test_fit_of_a_flat_noisy_image_is_the_wiener_blend():
    # y = s + n (s constant, n white, independent per channel), one scale, one class:
    # the least-squares A of (s - lp) on (y - lp) is, with the 2-D kernel's centre tap
    # g0 and energy e = sum g^2, A = (e - g0) / (1 - 2 g0 + e) on the diagonal, 0 off it
    sigma = 2.0
    rng = np.random.default_rng(2)
    y = (0.4 + 0.05 * rng.standard_normal((600, 600, 3))).astype(np.float32)
    stage = Multiscale.identity(3, (sigma,))
    stack, coarse, cls = stage.features(y)
    r = 3 * int(TRUNCATE * sigma + 0.5)
    mask = np.zeros(y.shape[:2], bool)
    mask[r:-r, r:-r] = True  # away from the mirrored borders
    stats = accumulate(MultiscaleStats.zeros(1, 1, 3), stack, coarse, cls,
                       np.full_like(y, 0.4), mask)
    a = solve(stats, 0.0, 3)[0]
    g = _gauss_taps(sigma)
    g0, e = g[g.size // 2] ** 2, (g ** 2).sum() ** 2
    wiener = (e - g0) / (1 - 2 * g0 + e)
    np.testing.assert_allclose(np.diag(a), wiener, atol=0.01)
    assert np.abs(a - np.diag(np.diag(a))).max() < 0.01
    # the blended output is smoother than the render
    out = apply_stage(Multiscale(stage.sigmas, [], np.zeros((1, 0)), a[None], stats.n), y)
    assert out[mask].std(axis=0).max() < 0.3 * y[mask].std(axis=0).min()


def test_empty_class_keeps_the_identity():
    stats = MultiscaleStats.zeros(2, 2, 3)
    a = solve(stats, 1e-3, 3)
    np.testing.assert_allclose(a, np.tile(np.eye(3), (2, 1))[None].repeat(2, 0), atol=1e-12)


def test_table_round_trip_and_refusals(tmp_path):
    from l3cli.classify import ClassDefinition
    from l3cli.table import MULTISCALE_VERSION, TransformTable, load_table, save_table

    d = ClassDefinition.build("RGGB", patch=3, level_cuts=[0.1])
    n = d.n_classes
    rng = np.random.default_rng(3)
    stage = Multiscale(np.array([2.0, 6.0]), np.array([0.1, 0.3]),
                       np.array([[0.01, 0.02], [0.01, 0.03], [0.02, 0.05]]),
                       rng.normal(size=(9, 6, 3)), np.arange(9), "srgb")
    t = TransformTable(d, np.zeros((n, d.n_coeffs, 3)), np.full(n, 100), np.zeros((n, 3)),
                       np.zeros(n, bool), np.arange(n), multiscale=stage)
    path = save_table(tmp_path / "t.npz", t)
    back = load_table(path)
    assert back.multiscale.transfer == "srgb"
    for name in ("sigmas", "level_cuts", "energy_cuts", "blend", "counts"):
        np.testing.assert_array_equal(getattr(back.multiscale, name), getattr(stage, name))
    with np.load(path, allow_pickle=False) as z:
        arrs = {k: z[k] for k in z.files}
    assert int(arrs["version"]) == MULTISCALE_VERSION
    plain = TransformTable(d, t.kernels, t.counts, t.lambdas, t.empty, t.source_class)
    assert load_table(save_table(tmp_path / "p.npz", plain)).multiscale is None

    def refused(change, match):
        a = dict(arrs)
        change(a)
        p = tmp_path / "bad.npz"
        np.savez(p, **a)
        with pytest.raises(TableError, match=match):
            load_table(p)

    refused(lambda a: a.update(multiscale_blend=np.full((9, 6, 3), np.nan, np.float32)),
            "NaN or Inf")
    refused(lambda a: a.pop("multiscale_counts"), "missing keys multiscale_counts")
    refused(lambda a: a.update(version=np.array(1)), "holds multiscale_")
    refused(lambda a: a.update(multiscale_rule=np.array("gauss-bands-v9")), "not supported")
    refused(lambda a: a.update(multiscale_sigmas=np.array([6.0, 2.0])), "increasing")
    refused(lambda a: a.update(multiscale_transfer=np.array("gamma")), "transfer 'gamma'")
    refused(lambda a: [a.pop(k) for k in list(a) if k.startswith("multiscale_")],
            "needs the multiscale_")
    with pytest.raises(TableError, match="takes 1 channels"):
        TransformTable(d, t.kernels, t.counts, t.lambdas, t.empty, t.source_class,
                       multiscale=Multiscale.identity(1))


def test_train_multiscale_flag_and_render(runner, tmp_path):
    from l3cli.cli.main import cli
    from l3cli.io.image import read_image
    from l3cli.io.raw import read_raw
    from l3cli.kernelset import prepare_kernels, render_mosaic
    from l3cli.table import load_table

    sim = tmp_path / "sim"
    res = runner.invoke(cli, ["-q", "simulate", str(ROOT / "sample_configs" / "bayer.toml"),
                              "-o", str(sim), "--scene", "macbeth", "--lux", "30",
                              "--size", "96x64"])
    assert res.exit_code == 0, res.output
    for flag, name in (("--multiscale", "ms.npz"), ("--no-multiscale", "plain.npz")):
        res = runner.invoke(cli, ["-q", "train", str(sim), flag, "-o", str(tmp_path / name)])
        assert res.exit_code == 0, res.output
    table = load_table(tmp_path / "ms.npz")
    assert load_table(tmp_path / "plain.npz").multiscale is None
    assert table.multiscale is not None and table.multiscale.counts.sum() == 96 * 64
    assert table.provenance["multiscale"]["sigmas"] == list(defaults.MULTISCALE_SIGMAS)
    assert table.multiscale.transfer == "srgb"  # an xyz table blends in the sRGB coding
    res = runner.invoke(cli, ["inspect", str(tmp_path / "ms.npz")])
    assert res.exit_code == 0 and "multiscale stage (--multiscale): bands of Gaussian " \
        "low-passes sigma 1, 3, 9 px blended per 96 coarse classes" in res.output, res.output
    res = runner.invoke(cli, ["inspect", str(tmp_path / "plain.npz")])
    assert res.exit_code == 0 and "multiscale stage" not in res.output
    raw_path = next(sim.glob("*.dng"))
    raw = read_raw(raw_path)
    ks = prepare_kernels(table, raw)
    expected = apply_stage(table.multiscale, render_mosaic(ks, ks.prepare_mosaic(raw.mosaic)))
    for suffix in (".exr", ".tif"):
        out = tmp_path / f"r{suffix}"
        res = runner.invoke(cli, ["-q", "render", str(tmp_path / "ms.npz"), str(raw_path),
                                  "-o", str(out)])
        assert res.exit_code == 0, res.output
        img = read_image(out)[0]
        if suffix == ".exr":
            np.testing.assert_allclose(img, expected, atol=1e-6)
        else:  # display sRGB of the staged float render, within one 16-bit code
            from l3cli.io.encode import display_encode

            codes = display_encode(expected, table.output_space, 16).astype(np.int64)
            assert np.abs(np.round(img * 65535).astype(np.int64) - codes).max() <= 1
    assert json.loads(json.dumps(table.provenance["multiscale"]))["levels"] == defaults.MULTISCALE_LEVELS


def test_bands_of_rows_give_the_whole_image_bit_for_bit():
    rng = np.random.default_rng(4)
    y = rng.random((157, 64, 3), dtype=np.float32) * 1.1
    stage = Multiscale(np.array([1.0, 3.0, 9.0]), np.array([0.4, 0.6]),
                       np.array([[0.05, 0.1], [0.05, 0.1], [0.05, 0.2]]),
                       rng.normal(size=(9, 9, 3)), np.ones(9, np.int64), "srgb")
    whole = apply_stage(stage, y, band_rows=10_000)
    for rows in (1, 17, 64, 156):
        np.testing.assert_array_equal(apply_stage(stage, y, band_rows=rows), whole)
    assert not np.allclose(whole, y, atol=1e-3)  # the blend did change the image


@pytest.mark.parametrize("shape", [(157, 64, 3), (5, 7, 3), (40, 33, 1), (1, 90, 2)])
@pytest.mark.parametrize("sigma", [1.0, 3.0, 9.0, 2.5])
def test_lowpass_is_scipys_gaussian_filter_bit_for_bit(shape, sigma):
    """The numba low-pass against ``scipy.ndimage.gaussian_filter`` (what the stage was
    defined and trained with), including images smaller than the kernel (reflected
    more than once)."""
    from scipy.ndimage import gaussian_filter

    from l3cli.multiscale import lowpass

    img = np.random.default_rng(11).normal(0.3, 0.4, shape).astype(np.float32)
    want = gaussian_filter(img, sigma=(sigma, sigma, 0.0), mode="reflect", truncate=TRUNCATE)
    got = lowpass(img, sigma)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, want)
    # the taps are the Gaussian written out here
    from l3cli.multiscale import gauss_taps

    taps = _gauss_taps(sigma)
    np.testing.assert_allclose(gauss_taps(sigma), taps[taps.size // 2:], rtol=1e-12)


def test_srgb_coding_is_the_float32_expression_within_the_powers_ulps():
    """encode/decode (one numba pass) against numpy's float32 steps and the float64
    curve, on values of both signs, at the segment joins, tiny and large.

    The linear segments are one IEEE operation (a product or quotient, correctly
    rounded by both): equal bit for bit, as is the sign. The power segments use two
    libraries' float32 ``pow`` (numpy's, which dispatches to SIMD code such as its
    AVX-512 path on some CPUs, and numba's libm call), each documented within 4 ulp
    of the exact power: so the two differ by at most 8 ulp of the power, scaled by the
    factor after it (1.055, or 1 for the decode), plus one rounding of the sum.
    """
    from l3cli.multiscale import decode, encode

    rng = np.random.default_rng(12)
    v = np.concatenate([rng.normal(0, 2, 99_999), [0.0, -0.0, 0.0031308, -0.0031308,
                                                    0.04045, 1e-38, -1e-30, 1e6, 1.0]])
    v = v.astype(np.float32).reshape(-1, 9)
    a = np.abs(v)
    f32 = np.float32
    with np.errstate(all="ignore"):
        p_enc = np.power(a, f32(1 / 2.4))
        p_dec = np.power((a + f32(0.055)) / f32(1.055), f32(2.4))
    lin_enc, lin_dec = a <= f32(0.0031308), a <= f32(0.04045)
    enc = np.copysign(np.where(lin_enc, f32(12.92) * a, f32(1.055) * p_enc - f32(0.055)), v)
    dec = np.copysign(np.where(lin_dec, a / f32(12.92), p_dec), v)
    # the float64 curve (IEC 61966-2-1), an independent reference for both
    a64 = a.astype(np.float64)
    enc64 = np.copysign(np.where(lin_enc, 12.92 * a64, 1.055 * a64 ** (1 / 2.4) - 0.055), v)
    dec64 = np.copysign(np.where(lin_dec, a64 / 12.92,
                                 ((a64 + 0.055) / 1.055) ** 2.4), v)
    for got, want, ref, lin, power, scale in (
            (encode(v, "srgb"), enc, enc64, lin_enc, p_enc, 1.055),
            (decode(v, "srgb"), dec, dec64, lin_dec, p_dec, 1.0)):
        assert got.dtype == np.float32
        np.testing.assert_array_equal(np.signbit(got), np.signbit(v))
        np.testing.assert_array_equal(got[lin].view(np.uint32), want[lin].view(np.uint32))
        bound = 8 * np.spacing(f32(scale) * power) + np.spacing(np.abs(want))
        assert np.all(np.abs(got - want)[~lin] <= bound[~lin])
        # within a few float32 roundings of the float64 curve: the bound above plus
        # the float32 steps' own roundings (the decode's argument rounded twice, then
        # raised to 2.4: about 5 ulp of the result), so 4 x the bound
        assert np.all(np.abs(got - ref)[~lin] <= 4 * bound[~lin])
    assert encode(np.float32(0.5), "srgb").shape == ()


def _numpy_classes(lev, en, level_cuts, energy_cuts):
    """The coarse class rule in numpy: searchsorted on the level cuts, then one
    comparison per energy cut of the pixel's level (float32)."""
    lb = np.searchsorted(np.asarray(level_cuts, dtype=np.float32), lev, side="right")
    cuts = np.asarray(energy_cuts, dtype=np.float32)
    eb = np.zeros(lev.shape, dtype=np.int32)
    for j in range(cuts.shape[1]):
        eb += en >= cuts[lb, j]
    return (lb.astype(np.int32) * (cuts.shape[1] + 1) + eb).astype(np.int32)


def test_stage_classes_are_the_numpy_rule():
    """The parallel level and class passes (features) against numpy's mean and the class
    rule in numpy."""
    from l3cli.multiscale import bands, energy, level

    rng = np.random.default_rng(13)
    ramp = np.linspace(0.05, 1.0, 80, dtype=np.float32)[None, :, None]  # levels vary
    noise = rng.normal(0, 1, (60, 80, 3)).astype(np.float32)
    y = ramp + noise * np.linspace(0.0, 0.1, 60, dtype=np.float32)[:, None, None]  # energy
    stage = Multiscale(np.array([1.0, 3.0]), np.array([0.3, 0.5, 0.7]),
                       np.array([[0.01, 0.05], [0.02, 0.06], [0.03, 0.07], [0.04, 0.08]]),
                       rng.normal(size=(12, 6, 3)), np.ones(12, np.int64), "none")
    stack, coarse, cls = stage.features(y)
    s2, c2 = bands(y, stage.sigmas)
    lev = c2.mean(axis=2, dtype=np.float32)
    np.testing.assert_array_equal(level(c2).view(np.uint32), lev.view(np.uint32))
    want = _numpy_classes(lev, energy(y, c2, stage.sigmas[0]), stage.level_cuts,
                          stage.energy_cuts)
    np.testing.assert_array_equal(stack, s2)
    np.testing.assert_array_equal(cls, want)
    assert len(np.unique(cls)) > 4
    work = np.empty(stage.work_size(y.shape), np.float32)  # the preallocated path
    s3, c3, k3 = stage.features(y, work=work)
    np.testing.assert_array_equal(s3, s2)
    np.testing.assert_array_equal(c3, c2)
    np.testing.assert_array_equal(k3, want)
