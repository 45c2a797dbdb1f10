"""The multi-scale stage (l3cli.multiscale.stage): fit, apply, table keys, l3 train --multiscale."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from l3cli import defaults
from l3cli.errors import TableError
from l3cli.multiscale.fit import MultiscaleStats, accumulate, place_cuts, solve
from l3cli.multiscale.stage import TRUNCATE, Multiscale, apply_stage, factor, feature_maps

ROOT = Path(__file__).resolve().parents[2]


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

    from l3cli.multiscale.stage import decode, encode

    # the coding is a table, linear between the curve's values 512 times per octave: the
    # chord of x ** (1 / 2.4) over a step of h = x / 512 is off by at most
    # p (1 - p) / 8 (h / x)² x = 1.2e-7 x, plus float32 rounding (6e-8)
    v = np.linspace(0, 1, 100_001, dtype=np.float32)
    np.testing.assert_allclose(encode(v, "srgb"), colour.cctf_encoding(v.astype(np.float64),
                                                                        function="sRGB"),
                               atol=3e-7)
    # the inverse: p (p - 1) / 8 (1 / 512)² = 1.6e-6 relative, plus rounding
    np.testing.assert_allclose(decode(v, "srgb"), colour.cctf_decoding(v.astype(np.float64),
                                                                        function="sRGB"),
                               rtol=2e-6, atol=1e-9)
    w = np.linspace(-3, 3, 2001, dtype=np.float32)
    np.testing.assert_allclose(encode(-w, "srgb"), -encode(w, "srgb"), atol=0)
    np.testing.assert_allclose(decode(encode(w, "srgb"), "srgb"), w, rtol=1e-5, atol=1e-7)
    assert encode(w, "none") is not None and np.array_equal(encode(w, "none"), w)


def test_zero_blend_returns_the_coarsest_lowpass():
    # A = 0: out = lp_n, a Gaussian of the image; on a delta far from the borders
    # that is the 2-D Gaussian's own taps (sigma < 3: at full resolution)
    sigma = 2.5
    stage = Multiscale.identity(1, (1.0, sigma))
    stage.blend[:] = 0
    y = np.zeros((41, 41, 1), np.float32)
    y[20, 20, 0] = 1.0
    out = apply_stage(stage, y)[..., 0]
    g = _gauss_taps(sigma)
    r = g.size // 2
    np.testing.assert_allclose(out[20 - r:21 + r, 20 - r:21 + r], np.outer(g, g), atol=1e-6)


@pytest.mark.parametrize("sigma", [3.0, 9.0, 6.0])
def test_reduced_resolution_lowpass_has_the_gaussians_variance(sigma):
    """A coarse low-pass (block means, a Gaussian on them, bilinear upsampling) of a
    delta keeps its mass, and its second moment about the delta, averaged over the
    delta's place among the blocks, is the sum of its parts' variances (the block
    centre's offset from the delta, (f² - 1) / 12; the taps', scaled by f²; the
    interpolation's, f² / 6): sigma² less what the 3-sigma truncation of the Gaussian
    takes away."""
    from l3cli.multiscale.stage import factor, low_sigma

    f = factor(sigma)
    assert f == {3.0: 2, 6.0: 4, 9.0: 4}[sigma]
    stage = Multiscale.identity(1, (1.0, sigma))
    stage.blend[:] = 0
    n = 8 * int(sigma) + 40
    variances = []
    for phase in range(f):
        y = np.zeros((n, n, 1), np.float32)
        c = n // 2 + phase
        y[c, c, 0] = 1.0
        out = apply_stage(stage, y)[..., 0].astype(np.float64)
        assert abs(out.sum() - 1.0) < 1e-5
        rows = out.sum(axis=1)
        pos = np.arange(n) - c
        # centred on the delta's block: at most (f - 1) / 2 off the delta
        assert abs((rows * pos).sum()) <= (f - 1) / 2 + 1e-4
        variances.append((rows * pos ** 2).sum())
    taps = _gauss_taps(low_sigma(sigma, f))
    x = np.arange(taps.size) - taps.size // 2
    want = (f * f - 1) / 12 + f * f * (taps * x ** 2).sum() + f * f / 6
    assert want < sigma ** 2 and want > 0.95 * sigma ** 2
    np.testing.assert_allclose(np.mean(variances), want, rtol=0.02)


def test_fit_recovers_a_known_blend():
    # target = lp_n + sum_j A_true[k, j] b_j exactly: the per-class solve gives A_true back
    rng = np.random.default_rng(1)
    y = rng.random((96, 128, 3), dtype=np.float32)
    _, _, lev, en = feature_maps(y, (1.0, 3.0))
    lc, ec = place_cuts(lev, en, 2, 2)
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
    # a table of the previous rule (full-resolution low-passes) still loads, the same stage
    old = dict(arrs, multiscale_rule=np.array("gauss-bands-v1"))
    np.savez(tmp_path / "old.npz", **old)
    kept = load_table(tmp_path / "old.npz").multiscale
    np.testing.assert_array_equal(kept.blend, stage.blend)
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
    for suffix in (".exr", ".tif", ".png"):
        out = tmp_path / f"r{suffix}"
        res = runner.invoke(cli, ["-q", "render", str(tmp_path / "ms.npz"), str(raw_path),
                                  "-o", str(out)])
        assert res.exit_code == 0, res.output
        img = read_image(out)[0]
        if suffix == ".exr":
            np.testing.assert_allclose(img, expected, atol=1e-6)
        elif suffix == ".png":  # 8 bits, encoded as each row is blended: the same codes
            from l3cli.io.encode import display_encode

            codes = display_encode(expected, table.output_space, 8).astype(np.int64)
            np.testing.assert_array_equal(np.round(img * 255).astype(np.int64), codes)
        else:  # display sRGB of the staged float render, within one 16-bit code
            from l3cli.io.encode import display_encode

            codes = display_encode(expected, table.output_space, 16).astype(np.int64)
            assert np.abs(np.round(img * 65535).astype(np.int64) - codes).max() <= 1
    assert json.loads(json.dumps(table.provenance["multiscale"]))["levels"] == defaults.MULTISCALE_LEVELS


def test_bands_of_rows_give_the_whole_image_bit_for_bit(monkeypatch):
    import l3cli.multiscale.stage as ms

    rng = np.random.default_rng(4)
    y = rng.random((157, 64, 3), dtype=np.float32) * 1.1
    stage = Multiscale(np.array([1.0, 3.0, 9.0]), np.array([0.4, 0.6]),
                       np.array([[0.05, 0.1], [0.05, 0.1], [0.05, 0.2]]),
                       rng.normal(size=(9, 9, 3)), np.ones(9, np.int64), "srgb")
    monkeypatch.setattr(ms, "BAND_ROWS", 10_000)
    whole = apply_stage(stage, y)
    for rows in (1, 17, 64, 156):
        monkeypatch.setattr(ms, "BAND_ROWS", rows)
        np.testing.assert_array_equal(apply_stage(stage, y), whole)
    assert not np.allclose(whole, y, atol=1e-3)  # the blend did change the image


@pytest.mark.parametrize("shape", [(157, 64, 3), (5, 7, 3), (40, 33, 1), (1, 90, 2)])
@pytest.mark.parametrize("sigma", [1.0, 3.0, 9.0, 2.5])
def test_lowpass_is_scipys_gaussian_filter(shape, sigma):
    """The numba low-pass against ``scipy.ndimage.gaussian_filter``, including images
    smaller than the kernel (reflected more than once): the same taps and order in
    float32 instead of float64 sums, so within a few float32 roundings of the values'
    size (|values| < 3: 1e-6)."""
    from scipy.ndimage import gaussian_filter

    from l3cli.multiscale.stage import lowpass

    img = np.random.default_rng(11).normal(0.3, 0.4, shape).astype(np.float32)
    want = gaussian_filter(img, sigma=(sigma, sigma, 0.0), mode="reflect", truncate=TRUNCATE)
    got = lowpass(img, sigma)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-6, rtol=0)
    # the taps are the Gaussian written out here
    from l3cli.multiscale.stage import gauss_taps

    taps = _gauss_taps(sigma)
    np.testing.assert_allclose(gauss_taps(sigma), taps[taps.size // 2:], rtol=1e-12)


def test_srgb_coding_is_odd_exact_on_its_linear_segment_and_the_formula_beyond_its_table():
    from l3cli.multiscale.coding import CODE_TOP
    from l3cli.multiscale.stage import decode, encode

    rng = np.random.default_rng(12)
    v = rng.normal(0, 2, 99_999).astype(np.float32)
    np.testing.assert_array_equal(encode(-v, "srgb"), -encode(v, "srgb"))
    np.testing.assert_array_equal(decode(-v, "srgb"), -decode(v, "srgb"))
    lin = np.float32([0.0, 1e-30, 0.001, 0.0031308])
    np.testing.assert_array_equal(encode(lin, "srgb"), np.float32(12.92) * lin)
    cod = np.float32([0.0, 0.01, 0.04045])
    np.testing.assert_array_equal(decode(cod, "srgb"), cod / np.float32(12.92))
    big = np.float32([2 * CODE_TOP, 1e6])
    np.testing.assert_allclose(encode(big, "srgb"), 1.055 * big.astype(np.float64) ** (1 / 2.4)
                               - 0.055, rtol=1e-6)
    assert encode(np.float32(0.5), "srgb").shape == ()


def test_direct_display_codes_are_the_encoders_codes_of_the_decoded_blend():
    """The 8-bit look-up on the coded blend (no decoding) gives the display encoder's
    code of the decoded value: around every threshold (its neighbours to 2000 float32
    steps), and on values of all kinds."""
    from l3cli.io.encode import display_encode
    from l3cli.multiscale.stage import decode, direct_table

    cell_code, uthr = direct_table()

    def direct(v):
        v = np.asarray(v, np.float32)
        pos = np.where(v > 0, v, 0).astype(np.float32)
        cell = (np.minimum(pos, np.float32(1.0)) * np.float32(cell_code.size - 1)).astype(int)
        q = cell_code[cell].astype(int)
        q += (v >= uthr[q + 1]) & (q < 255)
        return np.where(v > 0, q, 0)

    bits = uthr[1:256].view(np.int32).astype(np.int64)
    near = (bits[:, None] + np.arange(-2000, 2001)[None, :]).ravel()
    v = np.concatenate([near.astype(np.int32).view(np.float32),
                        np.random.default_rng(5).uniform(-0.5, 1.5, 200_000).astype(np.float32),
                        np.float32([np.nan, np.inf, -np.inf, 0, 1, 2])])
    want = display_encode(decode(v, "srgb").reshape(-1, 1, 1).repeat(3, 2), "linear-srgb", 8)
    np.testing.assert_array_equal(direct(v), want[:, 0, 0])


@pytest.mark.parametrize("transfer", ["none", "srgb"])
@pytest.mark.parametrize("space,bits", [("linear-srgb", 8), ("linear-srgb", 16), ("xyz", 8),
                                        ("srgb", 8)])
def test_fused_display_output_is_the_encoded_float_output(transfer, space, bits):
    """apply_display (the blend display-encoded row by row, or looked up straight from the
    coding) gives display_encode of apply_stage's float output, code for code."""
    from l3cli.io.encode import display_encode
    from l3cli.multiscale.stage import apply_display

    rng = np.random.default_rng(6)
    y = (rng.random((70, 45, 3), dtype=np.float32) * 1.3 - 0.1)
    y[3, 4] = np.nan
    stage = Multiscale(np.array([1.0, 3.0, 6.0]), np.array([0.4, 0.6]),
                       np.array([[0.05, 0.1], [0.05, 0.1], [0.05, 0.2]]),
                       rng.normal(size=(9, 9, 3)) * 0.5, np.ones(9, np.int64), transfer)
    got = apply_display(stage, y, space, bits)
    assert got.dtype == (np.uint8 if bits == 8 else np.uint16)
    np.testing.assert_array_equal(got, display_encode(apply_stage(stage, y), space, bits))


def _numpy_classes(lev, en, level_cuts, energy_cuts):
    """The coarse class rule in numpy: searchsorted on the level cuts, then one
    comparison per energy cut of the pixel's level (float32)."""
    lb = np.searchsorted(np.asarray(level_cuts, dtype=np.float32), lev, side="right")
    cuts = np.asarray(energy_cuts, dtype=np.float32)
    eb = np.zeros(lev.shape, dtype=np.int32)
    for j in range(cuts.shape[1]):
        eb += en >= cuts[lb, j]
    return (lb.astype(np.int32) * (cuts.shape[1] + 1) + eb).astype(np.int32)


def test_stage_classes_and_blend_are_the_numpy_rule():
    """The features' level (numpy's channel mean of the coarse low-pass), the classes (the
    rule in numpy), the finest low-pass (scipy's Gaussian, within float32 rounding), and
    the output (coarse + the class's blend of the bands, in numpy, float64)."""
    from scipy.ndimage import gaussian_filter

    from l3cli.multiscale.stage import classes

    rng = np.random.default_rng(13)
    ramp = np.linspace(0.05, 1.0, 80, dtype=np.float32)[None, :, None]  # levels vary
    noise = rng.normal(0, 1, (60, 80, 3)).astype(np.float32)
    y = ramp + noise * np.linspace(0.0, 0.1, 60, dtype=np.float32)[:, None, None]  # energy
    y = np.ascontiguousarray(y, dtype=np.float32)
    stage = Multiscale(np.array([1.0, 3.0]), np.array([0.3, 0.5, 0.7]),
                       np.array([[0.01, 0.05], [0.02, 0.06], [0.03, 0.07], [0.04, 0.08]]),
                       rng.normal(size=(12, 6, 3)), np.ones(12, np.int64), "none")
    stack, coarse, lev, en = feature_maps(y, stage.sigmas)
    np.testing.assert_array_equal(lev.view(np.uint32),
                                  coarse.mean(axis=2, dtype=np.float32).view(np.uint32))
    cls = classes(lev, en, stage.level_cuts, stage.energy_cuts)
    np.testing.assert_array_equal(cls, _numpy_classes(lev, en, stage.level_cuts,
                                                      stage.energy_cuts))
    assert len(np.unique(cls)) > 4
    _, fine, _, _ = feature_maps(y, stage.sigmas[:1])  # one scale: lp_1 is the coarsest
    want = gaussian_filter(y, sigma=(1.0, 1.0, 0.0), mode="reflect", truncate=TRUNCATE)
    np.testing.assert_allclose(fine, want, atol=1e-6, rtol=0)
    # the energy: sqrt of the low-passed channel mean of (y - lp_n)², in float64
    e = ((y.astype(np.float64) - coarse) ** 2).mean(axis=2)
    np.testing.assert_allclose(en, np.sqrt(gaussian_filter(e, 1.0, mode="reflect",
                                                           truncate=TRUNCATE)), atol=1e-6)
    out = coarse + np.einsum("hwr,hwrc->hwc", stack.astype(np.float64), stage.blend[cls])
    np.testing.assert_allclose(apply_stage(stage, y), out, atol=1e-5)
    np.testing.assert_array_equal(stage.features(y)[2], cls)


@pytest.mark.parametrize("sigmas", [(1.0, 4.0, 9.0), (0.8, 2.0)])
def test_srgb_stage_is_the_plain_stage_on_the_coded_render(sigmas):
    """A stage that blends in the sRGB coding codes the render in the pass that makes its
    pyramid's first level (or, with no pyramid, in a pass of its own): its output is the
    same stage's with no coding applied to the coded render, then decoded; ``y`` is left
    as it was unless ``inplace``."""
    from l3cli.multiscale.stage import decode, encode

    rng = np.random.default_rng(5)
    y = rng.random((37, 51, 3), dtype=np.float32) * 1.3 - 0.1  # odd sizes: cut blocks
    y[3, 4] = 80.0  # beyond the coding's table
    blend = rng.normal(0, 0.5, (6, 3 * len(sigmas), 3)).astype(np.float32)  # 2 x 3 classes
    coded = Multiscale(np.array(sigmas), [0.4], np.array([[0.01, 0.05]] * 2), blend,
                       np.ones(6, np.int64), "srgb")
    plain = Multiscale(coded.sigmas, coded.level_cuts, coded.energy_cuts, coded.blend,
                       coded.counts, "none")
    want = decode(apply_stage(plain, encode(y, "srgb")), "srgb")
    kept = y.copy()
    np.testing.assert_allclose(apply_stage(coded, y), want, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(y, kept)
    np.testing.assert_allclose(apply_stage(coded, y.copy(), inplace=True), want, rtol=1e-6,
                               atol=1e-7)


def test_scales_of_one_block_size_each_lowpass_the_block_means():
    """Two scales at the same reduced resolution (sigma 3 and 4.5: 2 x 2 blocks) each
    low-pass the block means, not one the other's result: the coarsest low-pass is the
    one the 4.5 scale alone gives."""
    rng = np.random.default_rng(8)
    y = rng.random((48, 40, 3), dtype=np.float32)
    assert factor(3.0) == factor(4.5) == 2
    _, both, _, _ = feature_maps(y, (1.0, 3.0, 4.5))
    _, alone, _, _ = feature_maps(y, (1.0, 4.5))
    np.testing.assert_allclose(both, alone, atol=1e-6, rtol=0)
