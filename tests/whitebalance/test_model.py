"""White balance as an input (issue 15, part 1): reading, normalising, adapting, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import rawpy

from l3cli.cfa import CFA
from l3cli.cli.main import cli
from l3cli.errors import ConfigError, InputError
from l3cli.io.raw import RawImage, read_raw, write_raw
from l3cli.render import render_raw
from l3cli.table import load_table, save_table
from l3cli.whitebalance.model import (
    WhiteBalanceModel,
    apply_gains,
    fit_adaptation_model,
    parse_gains,
    raw_gains,
    white_features,
)
from tests.builders import make_table


def _dng(tmp_path, name="a.dng", neutral=(0.5, 1.0, 0.8), shape=(24, 32), **shot):
    m = (np.random.default_rng(0).random(shape) * 3000 + 200).astype(np.uint16)
    return write_raw(tmp_path / name, m, "RGGB", as_shot_neutral=np.array(neutral),
                     shot=shot or None)


def test_dng_as_shot_neutral_gives_libraw_gains(tmp_path):
    p = _dng(tmp_path, neutral=(0.5, 1.0, 0.8))
    g = raw_gains(read_raw(p))
    np.testing.assert_allclose(g, [2.0, 1.0, 1.25], rtol=1e-3)
    with rawpy.imread(str(p)) as rp:  # LibRaw's own reading of the tag
        cam = np.array(rp.camera_whitebalance[:3])
    np.testing.assert_allclose(g, cam / cam[1], rtol=1e-3)


def test_sidecar_white_balance_read_and_validated(tmp_path):
    np.full((8, 8), 100, np.uint8).tofile(tmp_path / "h.raw")
    base = 'width = 8\nheight = 8\ndtype = "uint8"\ncfa = "GRBG"\nblack_level = 0\n' \
           "white_level = 255\n"
    (tmp_path / "h.raw.toml").write_text(base + "white_balance = [2.0, 1.0, 1.5]\n")
    np.testing.assert_allclose(raw_gains(read_raw(tmp_path / "h.raw")), [2.0, 1.0, 1.5])
    (tmp_path / "h.raw.toml").write_text(base)
    assert raw_gains(read_raw(tmp_path / "h.raw")) is None
    for bad in ("[2.0, 1.0]", "[2.0, 0.0, 1.0]", '[2.0, "x", 1.0]', "[2.0, nan, 1.0]", "2.0"):
        (tmp_path / "h.raw.toml").write_text(base + f"white_balance = {bad}\n")
        with pytest.raises(ConfigError, match=r"h\.raw\.toml: white_balance: must be 3 finite"):
            read_raw(tmp_path / "h.raw")


def test_parse_gains():
    np.testing.assert_allclose(parse_gains("2, 2, 3"), [1.0, 1.0, 1.5])
    for bad in ("1,2", "a,b,c", "1,-1,1", "1,inf,1"):
        with pytest.raises(InputError, match="--white-balance"):
            parse_gains(bad)


def test_apply_gains_per_channel_and_keeps_clipping():
    cfa = CFA.from_spec("GRBG")
    m = np.full((4, 4), 0.4, np.float32)
    m[0, 0] = 0.97  # a clipped green
    m[1, 0] = 0.97  # a clipped blue (gain < 1 below)
    out = apply_gains(m, cfa, np.array([2.0, 1.0, 0.5]), 0.95)
    assert out[0, 1] == pytest.approx(0.8) and out[1, 2] == pytest.approx(0.2)  # R, B
    assert out[0, 2] == pytest.approx(0.4) and out[1, 1] == pytest.approx(0.4)  # G
    assert out[1, 0] >= 0.95 and out[0, 0] == pytest.approx(0.97)
    with pytest.raises(InputError, match="R, G, B CFA"):
        apply_gains(m, CFA.from_spec("RGBW/GWRB/BRWG/WBGR"), np.ones(3), 0.95)


def test_white_features_are_log_gain_ratios():
    # log(b / r) and the tint log(g^2 / (r b)), written out for two whites
    np.testing.assert_allclose(white_features(np.array([2.0, 1.0, 1.25]), 2),
                               [np.log(0.625), -np.log(2.5)], rtol=1e-15)
    np.testing.assert_allclose(white_features(np.array([1.0, 2.0, 4.0]), 1), [np.log(4.0)],
                               rtol=1e-15)
    # scale-free: the same white at any overall gain
    np.testing.assert_allclose(white_features(np.array([4.0, 2.0, 2.5]), 2),
                               [np.log(0.625), -np.log(2.5)], rtol=1e-12)
    assert white_features(np.ones(3), 2).tolist() == [0.0, 0.0]


def test_adaptation_model_recovers_a_linear_law():
    rng = np.random.default_rng(3)
    whites = np.exp(rng.normal(scale=0.4, size=(6, 3)))
    whites /= whites[:, 1:2]
    c0, c1, c2 = (rng.normal(size=9) for _ in range(3))
    mats = np.array([c0 + white_features(w, 2) @ np.array([c1, c2]) for w in whites])
    model = fit_adaptation_model(whites, mats, "linear-srgb")
    probe = np.array([1.3, 1.0, 0.7])
    np.testing.assert_allclose(model.matrix(probe).ravel(),
                               c0 + white_features(probe, 2) @ np.array([c1, c2]), atol=1e-9)
    again = WhiteBalanceModel.from_dict(model.as_dict())
    np.testing.assert_allclose(again.matrix(probe), model.matrix(probe))
    # two distinct whites: one feature; all alike: a constant
    assert fit_adaptation_model(whites[:2], mats[:2], "xyz").center.size == 1
    assert fit_adaptation_model(whites[:1].repeat(3, 0), mats[:3], "xyz").center.size == 0


def _wb_table(space="linear-srgb"):
    t = make_table("RGGB", patch=5, space=space)
    t.kernels[:] = 0
    t.kernels[:, 12, :] = 1.0  # every output = the centre pixel
    m = WhiteBalanceModel(space, [0.0], [np.eye(3).ravel(), np.diag([0.1, 0, -0.1]).ravel()],
                          [[1, 1, 1]])
    t.white_balance = m.as_dict()
    return t


def test_render_normalises_and_adapts(tmp_path):
    t = _wb_table()
    p = _dng(tmp_path, neutral=(0.5, 1.0, 0.8))
    raw = read_raw(p)
    out = render_raw(t, raw)
    g = np.array([2.0, 1.0, 1.25])
    f = np.log(1.25 / 2.0)  # the white's feature: log(b / r) of its gains, written out
    a = np.diag([1 + 0.1 * f, 1.0, 1 - 0.1 * f])
    expect = (apply_gains(raw.mosaic, raw.cfa, g, 0.95)[:, :, None]
              * np.diag(a)[None, None, :])
    np.testing.assert_allclose(out, expect, rtol=2e-3, atol=1e-6)
    # an override replaces the raw's own white balance
    out2 = render_raw(t, raw, white_balance=np.array([1.0, 1.0, 1.0]))
    np.testing.assert_allclose(out2[:, :, 1], raw.mosaic, rtol=1e-6)
    # a table without the record renders as before, and refuses an override
    plain = make_table("RGGB", patch=5, space="linear-srgb")
    plain.kernels[:] = t.kernels
    np.testing.assert_array_equal(render_raw(plain, raw)[:, :, 0], raw.mosaic)
    with pytest.raises(InputError, match="trained without white balance"):
        render_raw(plain, raw, white_balance=np.ones(3))


def test_table_round_trip_keeps_the_record(tmp_path):
    t = _wb_table()
    u = load_table(save_table(tmp_path / "t.npz", t))
    assert u.white_balance == t.white_balance
    assert load_table(save_table(tmp_path / "p.npz", make_table())).white_balance is None


def test_cli_raw_without_white_balance_is_one_line_and_writes_nothing(runner, tmp_path):
    save_table(tmp_path / "t.npz", _wb_table())
    np.full((16, 16), 100, np.uint8).tofile(tmp_path / "h.raw")
    (tmp_path / "h.raw.toml").write_text(
        'width = 16\nheight = 16\ndtype = "uint8"\ncfa = "RGGB"\nblack_level = 0\n'
        "white_level = 255\n")
    ok = _dng(tmp_path, "b.dng")
    out = tmp_path / "out"
    res = runner.invoke(cli, ["render", str(tmp_path / "t.npz"), str(ok), str(tmp_path / "h.raw"),
                              "-o", str(out)])
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and "h.raw" in lines[0] and "--white-balance" in lines[0]
    assert not out.exists()
    # with --white-balance it renders
    res = runner.invoke(cli, ["render", str(tmp_path / "t.npz"), str(tmp_path / "h.raw"),
                              "-o", str(tmp_path / "h.exr"), "--white-balance", "2,1,1.5"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(cli, ["render", str(tmp_path / "t.npz"), str(tmp_path / "h.raw"),
                              "-o", str(tmp_path / "x.exr"), "--white-balance", "2,1"])
    assert res.exit_code == 2 and "--white-balance" in res.output


def test_contradictory_white_balance_is_named(runner, tmp_path):
    # AsShotNeutral (0.5, 1, 0.8) and an AsShotWhiteXY of D65 through the default
    # ColorMatrix1 (XYZ -> sRGB: D65 is neutral 1, 1, 1) disagree.
    p = _dng(tmp_path, "c.dng", neutral=(0.5, 1.0, 0.8), as_shot_white_xy=(0.3127, 0.3290))
    with pytest.raises(InputError, match="contradictory white balance: .*AsShotWhiteXY"):
        raw_gains(read_raw(p))
    save_table(tmp_path / "t.npz", _wb_table())
    res = runner.invoke(cli, ["render", str(tmp_path / "t.npz"), str(p), "-o",
                              str(tmp_path / "c.exr")])
    assert res.exit_code == 1 and "contradictory" in res.output
    assert not (tmp_path / "c.exr").exists()
    # agreeing tags are fine: D65 white, neutral ones
    q = _dng(tmp_path, "d.dng", neutral=(1.0, 1.0, 1.0), as_shot_white_xy=(0.3127, 0.3290))
    np.testing.assert_allclose(raw_gains(read_raw(q)), [1, 1, 1], atol=0.01)


def test_raw_without_metadata_has_no_gains():
    raw = RawImage(mosaic=np.zeros((4, 4), np.float32), cfa=CFA.from_spec("RGGB"),
                   black_level=np.zeros(4), white_level=1.0)
    assert raw_gains(raw) is None
