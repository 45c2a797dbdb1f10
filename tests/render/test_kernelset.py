"""The per-raw kernel set (issue 26): every table feature renders as the whole-image path did.

The reference is the path l3 took before the kernel set, written out here
with the library's own building blocks: the condition bins interpolated
(:func:`l3cli.conditions.kernels_for`), the mosaic multiplied by the gains
(:func:`l3cli.whitebalance.model.apply_gains`), the plain float render, the 3x3
adaptation of the whole float image (:func:`l3cli.whitebalance.model.adapt_image`)
and then the display encoding (:func:`l3cli.io.encode.display_encode`).
The kernel set folds the adaptation into the kernels or into the encoder's
matrix, so its pixels may differ by float32 rounding: float renders within
a few ulps, display integers by at most one code.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from l3cli.classify import ClassDefinition
from l3cli.conditions import kernels_for, raw_condition
from l3cli.errors import InputError
from l3cli.io.encode import display_encode
from l3cli.io.raw import RawImage, read_raw, write_raw
from l3cli.kernelset import KernelSet, linear_adaptation, prepare_kernels
from l3cli.render import render_display, render_file, render_mosaic, render_raw
from l3cli.table import TransformTable
from l3cli.tone.curve import ToneCurve
from l3cli.whitebalance.model import WhiteBalanceModel, adapt_image, apply_gains, gains_or_error


def _old_float(table: TransformTable, raw: RawImage, white_balance=None) -> np.ndarray:
    """The whole-image render of l3 before the kernel set."""
    plain = table
    if table.conditions is not None:
        k = kernels_for(table, raw_condition(raw, table.conditions.by))
        plain = dataclasses.replace(table, kernels=k, conditions=None)
    if table.white_balance is None:
        return render_mosaic(plain, raw.mosaic)
    gains = gains_or_error(raw, white_balance)
    mosaic = apply_gains(raw.mosaic, raw.cfa, gains, table.definition.saturation_threshold)
    model = WhiteBalanceModel.from_dict(table.white_balance)
    img = render_mosaic(plain, mosaic)
    return adapt_image(img, model.matrix(gains), table.output_space, model.space)


def _definition(patch=5, **features):
    return ClassDefinition.build("RGGB", patch=patch, level_cuts=[0.02, 0.08, 0.3],
                                 contrast_cuts=0.2, **features)


def _table(d, space="linear-srgb", *, seed=0, wb=True, curve=False, n_out=3):
    rng = np.random.default_rng(seed)
    nc, q = d.n_classes, d.n_coeffs
    # smooth-ish kernels: a weighted mean of the patch per output, plus noise
    k = rng.normal(scale=0.05, size=(nc, q, n_out)).astype(np.float32)
    k[:, : q - 1, :] += np.float32(1.0 / (q - 1))
    k[:, -1, :] = rng.normal(scale=0.02, size=(nc, n_out))
    lam = np.full((nc, n_out), 1e-3)
    t = TransformTable(definition=d, kernels=k, counts=np.full(nc, 500),
                       lambdas=lam, empty=np.zeros(nc, bool), source_class=np.arange(nc),
                       output_space=space)
    if wb:
        # an adaptation that depends on the white (one feature), as training fits it
        c0 = np.array([[1.05, 0.04, -0.02], [0.03, 0.97, 0.01], [-0.01, 0.05, 1.1]])
        c1 = np.array([[0.1, 0.0, 0.02], [0.0, 0.0, 0.0], [0.01, 0.0, -0.12]])
        space_a = {"xyz": "xyz", "lab": "xyz"}.get(space, "linear-srgb")
        t.white_balance = WhiteBalanceModel(space_a, [0.2], [c0.ravel(), c1.ravel()],
                                            [[2.0, 1.0, 1.5], [1.6, 1.0, 2.1]]).as_dict()
    if curve:
        x = np.linspace(0, 1, 33)[:, None]
        knots = np.hstack([x ** 2.0, x ** 2.2, x ** 1.9])  # f(e): encoded -> curve space
        t.tone_lut = ToneCurve(knots, space="srgb").lut(space)
    return t


def _raw(tmp_path, *, shape=(64, 600), neutral=(0.45, 1.0, 0.7), iso=None, seed=1):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    base = 0.25 + 0.2 * np.sin(xx / 9.0) * np.cos(yy / 7.0)
    m = np.clip(base + rng.normal(scale=0.05, size=shape), 0.001, 1.0)
    m[10:14, 100:160] = 1.0  # clipped highlights: the saturation classes and a gain < 1
    dn = (m * 3800 + 200).astype(np.uint16)
    shot = {"iso": iso} if iso is not None else None
    p = write_raw(tmp_path / f"r{seed}.dng", dn, "RGGB", black_level=200, white_level=4000,
                  as_shot_neutral=np.array(neutral), shot=shot)
    return p, read_raw(p)


def _check(table, raw, white_balance=None):
    want = _old_float(table, raw, white_balance)
    ks = prepare_kernels(table, raw, white_balance=white_balance)
    mosaic = ks.prepare_mosaic(raw.mosaic)
    got = render_mosaic(ks, mosaic)
    scale = max(1.0, float(np.abs(want).max()))
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-5 * scale)
    np.testing.assert_allclose(render_raw(table, raw, white_balance=white_balance), got,
                               rtol=0, atol=0)
    for bits in (8, 16):
        old = display_encode(want, table.output_space, bits).astype(np.int64)
        new = render_display(ks, mosaic, bits).astype(np.int64)
        assert np.abs(new - old).max() <= 1, (bits, np.abs(new - old).max())
        assert np.mean(new != old) < (1e-3 if bits == 8 else 1e-2)  # float32 rounding only
    return ks


FEATURES = {  # name: (definition features, table keywords)
    "wb": ({}, {}),
    "wb+curve": ({}, {"curve": True}),
    "wb+curve, patch 7": ({"patch": 7}, {"curve": True}),
    "wb+curve, patch 9": ({"patch": 9}, {"curve": True}),
    "wb, xyz": ({}, {"space": "xyz"}),
    "wb, srgb (adaptation not linear)": ({}, {"space": "srgb"}),
    "wb, lab": ({}, {"space": "lab"}),
    "wb+curve, orientation": ({"orientation_bins": 4}, {"curve": True}),
    "wb+curve, context": ({"context_block": 16, "context_cuts": np.array([0.1, 0.3])},
                          {"curve": True}),
    "wb+curve, highlights": ({"highlight_bins": 2}, {"curve": True}),
    "curve, no wb": ({}, {"curve": True, "wb": False}),
    "plain": ({}, {"wb": False}),
}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if "patch 9" in n
                                  else n for n in FEATURES])  # patch 9: a kernel compile
def test_kernel_set_renders_as_the_whole_image_path(tmp_path, name):
    features, kw = FEATURES[name]
    patch = features.pop("patch", 5) if "patch" in features else 5
    d = _definition(patch, **dict(features))
    t = _table(d, **kw)
    _, raw = _raw(tmp_path)
    ks = _check(t, raw)
    if t.white_balance is not None:
        assert ks.mosaic_gains is not None
        np.testing.assert_allclose(ks.mosaic_gains[0, 0], 1 / 0.45, rtol=1e-4)  # R of RGGB
        # linear spaces: fused (folded, or the encoder's matrix with a curve)
        assert ks.fused == (t.output_space in ("xyz", "linear-srgb"))
        assert (ks.post is not None) == (kw.get("curve", False) and ks.fused)
    else:
        assert ks.mosaic_gains is None and ks.post is None and ks.fused
    # an override replaces the raw's own white
    if t.white_balance is not None:
        _check(t, raw, white_balance=np.array([1.7, 1.0, 1.3]))


def test_condition_bins_are_interpolated_once_per_raw(tmp_path, monkeypatch):
    from l3cli.conditions import Conditioned

    d = _definition()
    t = _table(d, curve=True)
    rng = np.random.default_rng(5)
    kb = np.stack([t.kernels, t.kernels * np.float32(1.3)
                   + rng.normal(scale=0.01, size=t.kernels.shape).astype(np.float32)])
    nc = d.n_classes
    t.conditions = Conditioned(by="iso", values=np.array([100.0, 1600.0]), kernels=kb,
                               counts=np.full((2, nc), 500))
    import l3cli.conditions as conditions
    from l3cli.render import render_file

    calls = []
    real = conditions.kernels_for
    monkeypatch.setattr(conditions, "kernels_for",
                        lambda table, value: calls.append(value) or real(table, value))
    for iso in (100, 400, 3200):
        path, raw = _raw(tmp_path, iso=iso, seed=iso)
        _check(t, raw)
        calls.clear()  # one render of the file, to a display format: one interpolation
        render_file(t, path, tmp_path / f"r{iso}.png")
        assert calls == [iso], calls
        calls.clear()
        render_raw(t, raw)
        assert calls == [iso], calls


def test_no_tone_curve_folds_the_adaptation_into_the_kernels(tmp_path):
    t = _table(_definition(), space="xyz")
    _, raw = _raw(tmp_path)
    ks = prepare_kernels(t, raw)
    assert ks.post is None and ks.adapt is None and ks.curve is None
    plain = KernelSet.plain(t)
    assert not np.array_equal(ks.kernels, plain.kernels)  # the adaptation is in there


def test_linear_adaptation_is_adapt_image():
    rng = np.random.default_rng(0)
    img = rng.random((4, 5, 3)).astype(np.float32)
    a = np.eye(3) + rng.normal(scale=0.1, size=(3, 3))
    for out_space in ("xyz", "linear-srgb"):
        for space in ("xyz", "linear-srgb"):
            m = linear_adaptation(a, out_space, space)
            np.testing.assert_allclose(img @ m.T, adapt_image(img, a, out_space, space),
                                       rtol=1e-5, atol=1e-6)
    assert linear_adaptation(a, "srgb", "linear-srgb") is None
    assert linear_adaptation(a, "lab", "xyz") is None


def test_gains_are_apply_gains_folded_or_as_a_pass(tmp_path):
    """The white balance is folded into the tile kernel (``prepare_mosaic`` hands the mosaic
    on untouched); ``corrected_mosaic``, and ``prepare_mosaic`` where the kernel cannot fold
    (a context guide reads the corrected mosaic), are exactly ``apply_gains``, on a copy
    unless told."""
    _, raw = _raw(tmp_path, neutral=(1.4, 1.0, 0.6))  # gains below and above one
    want = apply_gains(raw.mosaic, raw.cfa, 1 / np.array([1.4, 1.0, 0.6]), 0.95)
    before = raw.mosaic.copy()
    ks = prepare_kernels(_table(_definition()), raw)
    assert ks.folded
    assert ks.prepare_mosaic(raw.mosaic) is raw.mosaic
    np.testing.assert_array_equal(ks.corrected_mosaic(raw.mosaic), want)
    np.testing.assert_array_equal(raw.mosaic, before)  # not changed
    ctx = _table(_definition(context_block=16, context_cuts=np.array([0.1, 0.3])))
    ks = prepare_kernels(ctx, raw)
    assert not ks.folded
    got = ks.prepare_mosaic(raw.mosaic)
    np.testing.assert_array_equal(raw.mosaic, before)  # not changed
    np.testing.assert_array_equal(got, want)
    same = ks.prepare_mosaic(raw.mosaic, inplace=True)
    assert same is raw.mosaic
    np.testing.assert_array_equal(same, want)


def test_errors_are_the_old_ones(tmp_path):
    plain = _table(_definition(), wb=False)
    wb = _table(_definition())
    _, raw = _raw(tmp_path)
    with pytest.raises(InputError, match="trained without white balance"):
        prepare_kernels(plain, raw, white_balance=np.ones(3))
    bare = RawImage(raw.mosaic, raw.cfa, raw.black_level, raw.white_level, raw.path, {})
    with pytest.raises(InputError, match="no white balance"):
        prepare_kernels(wb, bare)


@pytest.mark.parametrize("suffix", [".tif", ".exr"])
def test_file_render_of_a_white_balancing_curve_table(tmp_path, suffix):
    """The file path (pipeline.render_one) takes the kernel set too: its outputs are the
    reference's, written as l3 writes images."""
    from l3cli.io.image import read_image

    t = _table(_definition(7), curve=True)
    p, raw = _raw(tmp_path)
    want = _old_float(t, raw)
    got, space = read_image(render_file(t, p, tmp_path / f"o{suffix}"))
    if suffix == ".exr":
        assert space == t.output_space
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-5)
    else:
        old = display_encode(want, t.output_space, 16).astype(np.int64)
        new = np.round(got.astype(np.float64) * 65535).astype(np.int64)
        assert np.abs(new - old).max() <= 1


def test_one_training_white_means_no_adaptation_step(tmp_path):
    """A table trained on one white holds the identity adaptation: the kernel set keeps the
    gains and drops the matrix (the old path multiplied by exactly the identity)."""
    t = _table(_definition(), curve=True)
    model = WhiteBalanceModel("linear-srgb", [], [np.eye(3).ravel()], [[2.0, 1.0, 1.5]])
    t.white_balance = model.as_dict()
    _, raw = _raw(tmp_path)
    ks = _check(t, raw)
    assert ks.post is None and ks.adapt is None and ks.mosaic_gains is not None


def test_white_balance_precheck_reads_dng_tags_without_decoding(tmp_path, monkeypatch):
    """The check before any output takes a DNG's white from its tags: asking LibRaw (rawpy
    unpacks the whole raw for it) decoded every file twice. A DNG without the tags still
    goes to LibRaw, and contradictory tags are still named before any output."""
    import l3cli.whitebalance.model as wb
    from l3cli.render import check_white_balance

    t = _table(_definition())
    p, _ = _raw(tmp_path)
    asked = []
    monkeypatch.setattr(wb, "file_gains", lambda path: asked.append(path) or None)
    check_white_balance(t, [p], None)  # no LibRaw call
    assert asked == []
    bare = tmp_path / "h.raw"  # not a DNG: LibRaw's (or the sidecar's) word is asked
    np.full((16, 16), 100, np.uint8).tofile(bare)
    (tmp_path / "h.raw.toml").write_text(
        'width = 16\nheight = 16\ndtype = "uint8"\ncfa = "RGGB"\nblack_level = 0\n'
        "white_level = 255\n")
    with pytest.raises(InputError, match="no white balance"):
        check_white_balance(t, [p, bare], None)
    assert [str(a) for a in asked] == [str(bare)]
    bad = write_raw(tmp_path / "bad.dng", np.full((16, 16), 900, np.uint16), "RGGB",
                    white_level=4000, as_shot_neutral=np.array([0.5, 1.0, 0.8]),
                    shot={"as_shot_white_xy": (0.3127, 0.3290)})
    with pytest.raises(InputError, match="contradictory"):
        check_white_balance(t, [bad], None)
