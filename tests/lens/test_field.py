"""Lens shading (l3cli.lens.field): the gain field, its table keys, its application
before classification in every render path, and its learning from pairs."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from l3cli.cfa import CFA
from l3cli.errors import TableError
from l3cli.io.raw import write_raw
from l3cli.lens.field import GainField, corrected, gain_map, normalised_coords
from l3cli.lens.fit import BlockSamples, fit_field
from l3cli.table import SHADING_VERSION, TABLE_VERSION, load_table, save_table
from tests.builders import (
    MINIMAL,
    make_table,
    mosaic_raw,
    phone_gain_maps,
    shaded_examples_script,
    uniform_scene,
    write_dng_with_opcodes,
)


def _field(n_pos=4, size=(24, 32)):
    coeffs = np.zeros((n_pos, 3))
    coeffs[:, 0] = [0.6, 0.65, 0.7, 0.6][:n_pos]
    coeffs[:, 1] = [0.3, 0.25, 0.2, 0.3][:n_pos]
    coeffs[:, 2] = 0.05
    return GainField(np.array([0.05, -0.1]), coeffs, size)


def test_gain_map_is_the_polynomial_per_position():
    f = _field()
    g = gain_map(f, (24, 32), (2, 2))
    v, u = normalised_coords(24, 32)
    assert abs(v[0] + v[-1]) < 1e-12 and np.hypot(v[-1] + 0.5 / 20, u[-1] + 0.5 / 20) == \
        pytest.approx(1.0)  # the half-diagonal is 1 (24x32: 20 pixels)
    for y, x in [(0, 0), (3, 5), (10, 31), (23, 0)]:
        r2 = (v[y] - 0.05) ** 2 + (u[x] + 0.1) ** 2
        c = f.coeffs[(y % 2) * 2 + x % 2]
        assert g[y, x] == pytest.approx(c[0] + c[1] * r2 + c[2] * r2 ** 2, rel=1e-6)


def test_table_round_trip_and_version(tmp_path):
    t = make_table()
    p = save_table(tmp_path / "plain.npz", t)
    with np.load(p, allow_pickle=False) as z:
        assert int(z["version"]) == TABLE_VERSION and "shading_rule" not in z.files
    t.shading = _field()
    p = save_table(tmp_path / "shaded.npz", t)
    with np.load(p, allow_pickle=False) as z:
        arrs = {k: z[k] for k in z.files}
    assert int(arrs["version"]) == SHADING_VERSION
    back = load_table(p)
    from l3cli.inspect import format_summary, table_summary

    summary = table_summary(back)
    assert summary["version"] == SHADING_VERSION and back.file_version == SHADING_VERSION
    assert f" v{SHADING_VERSION}, " in format_summary(summary)  # the header names the file's version
    want = t.shading.gains(np.array([1.0]))[:, 0] / t.shading.gains(np.array([0.0]))[:, 0]
    np.testing.assert_allclose(summary["shading"]["gain_at_r1"], want, atol=1e-4)
    assert "lens shading corrected first (gain field learned on 32x24 raws" in \
        format_summary(summary)
    np.testing.assert_array_equal(back.shading.coeffs, t.shading.coeffs)
    np.testing.assert_array_equal(back.shading.centre, t.shading.centre)
    assert back.shading.size == (24, 32)

    def damaged(name, **change):
        a = dict(arrs)
        for k, v in change.items():
            if v is None:
                del a[k]
            else:
                a[k] = v
        q = tmp_path / f"{name}.npz"
        np.savez(q, **a)
        with pytest.raises(TableError) as err:
            load_table(q)
        assert str(q) in str(err.value)
        return str(err.value)

    bad = arrs["shading_coeffs"].copy()
    bad[1, 0] = -1.0
    assert "not positive" in damaged("negative", shading_coeffs=bad)
    bad = arrs["shading_coeffs"].copy()
    bad[0, 1] = np.nan
    assert "NaN" in damaged("nan", shading_coeffs=bad)
    assert "missing keys shading_size" in damaged("missing", shading_size=None)
    assert "(4, k)" in damaged("shape", shading_coeffs=arrs["shading_coeffs"][:2])
    assert "holds no shading" in damaged("v1", version=np.array(1))
    assert "not supported" in damaged("rule", shading_rule=np.array("grid-v9"))
    assert "not supported" in damaged("v9", version=np.array(9))


def test_corrected_keeps_clipping_and_is_applied_once():
    f = _field()
    t = make_table()
    t.shading = f
    rng = np.random.default_rng(1)
    m = rng.uniform(0, 1.2, (24, 32)).astype(np.float32)
    raw = mosaic_raw(m)
    out = corrected(t, raw)
    thr = t.definition.saturation_threshold
    g = gain_map(f, (24, 32), (2, 2))
    assert g.min() < 1 < g.max()  # gains below one leave clipped pixels as they are
    expect = np.where((m < thr) | (g >= 1), m * g, m)
    np.testing.assert_array_equal(out.mosaic, expect.astype(np.float32))
    up = _field()
    up.coeffs[:, 0] = 1.0  # gains >= 1 (a learned field): every pixel is multiplied
    t.shading = up
    g_up = gain_map(up, (24, 32), (2, 2))
    np.testing.assert_array_equal(corrected(t, raw).mosaic,
                                  np.minimum(m * g_up, np.maximum(m, 1)))  # white clips
    np.testing.assert_array_equal(corrected(t, mosaic_raw(m.copy()), inplace=True).mosaic,
                                  np.minimum(m * g_up, np.maximum(m, 1)))  # in place too
    t.shading = f
    np.testing.assert_array_equal(raw.mosaic, m)  # not in place: the input is kept
    assert corrected(t, out) is out  # a corrected raw is not corrected again
    inplace = corrected(t, mosaic_raw(m.copy()), inplace=True)
    np.testing.assert_array_equal(inplace.mosaic, out.mosaic)
    # a crop is corrected where it lies on its full raw
    crop = corrected(t, raw.crop(4, 6, 12, 20))
    np.testing.assert_array_equal(crop.mosaic, out.mosaic[4:16, 6:26])


def test_other_raw_size_warns(caplog):
    t = make_table()
    t.shading = _field()
    with caplog.at_level(logging.WARNING, logger="l3cli.lens.field"):
        corrected(t, mosaic_raw(np.full((20, 30), 0.3), path="x.dng"))
    assert "x.dng: the raw is 30x20" in caplog.text and "32x24" in caplog.text


def test_render_applies_the_field_before_classification(tmp_path):
    """Every render path (render_raw, l3 render's pipeline to EXR and to PNG) renders a
    raw of a table with a field as the plain table renders the corrected mosaic."""
    from l3cli.io.image import read_image
    from l3cli.render import render_file, render_mosaic, render_raw

    t = make_table(patch=3)
    t.kernels[:] = np.abs(t.kernels) * 0.05
    t.tone_lut = None
    size = (24, 32)
    dn = np.random.default_rng(2).integers(100, 60000, size)
    path = write_raw(tmp_path / "r.dng", dn, "RGGB")
    from l3cli.io.raw import read_raw

    raw = read_raw(path)
    plain = render_mosaic(t, corrected(_with(t, _field(size=size)), raw).mosaic)
    t.shading = _field(size=size)
    np.testing.assert_array_equal(render_raw(t, raw), plain)
    np.testing.assert_array_equal(raw.mosaic, read_raw(path).mosaic)  # input kept
    out = render_file(t, path, tmp_path / "o.exr")
    np.testing.assert_allclose(read_image(out)[0], plain, rtol=1e-6, atol=1e-6)
    t.shading = None
    ref = render_file(t, path, tmp_path / "ref.exr")
    assert not np.allclose(read_image(ref)[0], plain, atol=1e-3)


def _with(table, field):
    import copy

    t = copy.copy(table)
    t.shading = field
    return t


def _synthetic_samples(field_coeffs, centre, n_images=3, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_images):
        v = rng.uniform(-0.6, 0.6, 900)
        u = rng.uniform(-0.8, 0.8, 900)
        m = rng.uniform(0.05, 0.6, (900, 3))
        r2 = (v - centre[0]) ** 2 + (u - centre[1]) ** 2
        g = 1 + np.stack([r2, r2 ** 2, r2 ** 3], 1) @ field_coeffs.T
        mat = np.eye(3) + rng.normal(0, 0.2, (3, 3))
        out.append(BlockSamples(v, u, m, (m * g) @ mat.T))
    return out


def test_fit_recovers_an_exact_field():
    """Noise-free blocks made by the model itself: the fit recovers the field."""
    a = np.array([[0.5, 0.1, 0.0], [0.3, 0.05, 0.0], [0.7, -0.1, 0.05]])
    centre = np.array([0.07, -0.04])
    field, rec = fit_field(_synthetic_samples(a, centre), CFA.from_spec("GRBG"), (600, 800))
    assert field is not None, rec
    np.testing.assert_allclose(field.centre, centre, atol=1e-4)
    chans = CFA.from_spec("GRBG")
    r2 = np.linspace(0, 1, 11)
    got = field.gains(r2)
    for p in range(4):
        c = chans.channels.index(chans.channel_at(p // 2, p % 2))  # block columns: this order
        want = 1 + a[c, 0] * r2 + a[c, 1] * r2 ** 2 + a[c, 2] * r2 ** 3
        np.testing.assert_allclose(got[p] / got[p][0], want, rtol=1e-4)
    assert got.min() >= 1 - 1e-9  # scaled: the least gain over the sensor is one


def test_fit_rejects_a_flat_field():
    """Blocks without shading (and a little noise): no field is kept."""
    s = _synthetic_samples(np.zeros((3, 3)), np.zeros(2), seed=3)
    rng = np.random.default_rng(4)
    for b in s:
        b.target *= 1 + rng.normal(0, 0.01, b.target.shape)
    field, rec = fit_field(s, CFA.from_spec("RGGB"), (600, 800))
    assert field is None and "no better" in rec["reason"]




@pytest.mark.slow
def test_learned_field_recovers_known_shading(tmp_path):
    """The bundled frames with a known per-channel shading on the raws (targets
    unchanged): the learned field undoes it to within 2 % rms per channel (up to each
    channel's scale, which the kernels absorb)."""
    from l3cli.lens.train import learn_shading
    from l3cli.pairs import find_pairs
    from l3cli.train.options import TrainOptions

    mod = shaded_examples_script()
    mod.main(tmp_path)
    opts = TrainOptions(target_space="linear-srgb", tone_curve=True, shading=True)
    field, rec = learn_shading(find_pairs([tmp_path / "frames"]), opts)
    assert field is not None, rec
    cfa = CFA.from_spec("GRBG")
    g = gain_map(field, field.size, cfa.period).astype(np.float64)
    s = mod.shading_map(*field.size, cfa)
    chan = cfa.channel_map(*field.size)
    for c in range(cfa.n_channels):
        q = (g * s)[chan == c]
        rms = np.sqrt(np.mean((q / q.mean() - 1) ** 2))
        assert rms < 0.02, (cfa.channels[c], rms)


# ------------------------------------------------------------------ DNG GainMap




def test_gain_map_opcodes_round_trip_and_errors():
    from l3cli.errors import InputError
    from l3cli.io.dng_opcodes import encode_gain_maps, parse_opcode_list

    maps = phone_gain_maps(40, 60)
    back = parse_opcode_list(encode_gain_maps(maps))
    assert len(back) == 4
    for a, b in zip(maps, back, strict=True):
        assert (a.top, a.left, a.row_pitch, a.points_h, a.spacing_h) == \
            (b.top, b.left, b.row_pitch, b.points_h, b.spacing_h)
        np.testing.assert_array_equal(a.gains, b.gains)
    data = encode_gain_maps(maps)
    with pytest.raises(InputError, match="ends inside opcode|claims"):
        parse_opcode_list(data[:-10], "x.dng: OpcodeList2")
    bad = bytearray(data)
    bad[20 + 32:24 + 32] = (0).to_bytes(4, "big")  # MapPointsV = 0
    with pytest.raises(InputError, match="x.dng: OpcodeList2, opcode 1: GainMap"):
        parse_opcode_list(bytes(bad), "x.dng: OpcodeList2")


def test_dng_gain_map_is_applied_as_by_hand(tmp_path):
    """A DNG with GainMap opcodes renders as its mosaic with the maps applied by hand
    (bilinear interpolation at pixel centres, clamped, clipped at white), to 1e-6."""
    from scipy.interpolate import RegularGridInterpolator

    from l3cli.io.dng_opcodes import encode_gain_maps
    from l3cli.io.raw import read_raw
    from l3cli.lens.gainmaps import apply_dng_gains
    from l3cli.render import render_file, render_mosaic, render_raw

    h, w = 40, 60
    dn = np.random.default_rng(3).integers(64, 4096, (h, w))
    maps = phone_gain_maps(h, w)
    plain = read_raw(write_dng_with_opcodes(tmp_path / "plain.dng", dn, None))
    shaded = read_raw(write_dng_with_opcodes(tmp_path / "gm.dng", dn, encode_gain_maps(maps)))
    assert shaded.gain_maps is not None  # parsed by the file layer, applied by the model
    apply_dng_gains(shaded)
    assert shaded.metadata["gain_maps"] == {"OpcodeList2": 4, "OpcodeList3": 0}
    by_hand = plain.mosaic.astype(np.float64)
    for m in maps:
        f = RegularGridInterpolator((m.origin_v + m.spacing_v * np.arange(m.points_v),
                                     m.origin_h + m.spacing_h * np.arange(m.points_h)),
                                    m.gains[:, :, 0].astype(np.float64))
        ys, xs = np.arange(m.top, h, 2), np.arange(m.left, w, 2)
        pv = np.clip((ys + 0.5) / h, 0, m.origin_v + m.spacing_v * (m.points_v - 1))
        ph = np.clip((xs + 0.5) / w, 0, m.origin_h + m.spacing_h * (m.points_h - 1))
        g = f(np.stack(np.meshgrid(pv, ph, indexing="ij"), axis=-1))
        by_hand[np.ix_(ys, xs)] = np.minimum(by_hand[np.ix_(ys, xs)] * g, 1.0)
    assert np.abs(by_hand - plain.mosaic).max() > 0.05  # the maps do something
    np.testing.assert_allclose(shaded.mosaic, by_hand, atol=1e-6, rtol=0)
    t = make_table(patch=3)
    t.kernels[:] = np.abs(t.kernels) * 0.05
    expect = render_mosaic(t, by_hand.astype(np.float32))
    np.testing.assert_allclose(render_raw(t, shaded), expect, atol=1e-6, rtol=0)
    from l3cli.io.image import read_image

    out = render_file(t, tmp_path / "gm.dng", tmp_path / "gm.exr")
    np.testing.assert_allclose(read_image(out)[0], expect, atol=1e-6, rtol=0)


# ------------------------------------------------- l3 simulate: relative illumination
def _rgb_camera(**optics):
    import dataclasses
    import tomllib

    from l3cli.camera import camera_from_dict

    data = tomllib.loads(MINIMAL)
    data["optics"] = optics
    cam = camera_from_dict(data, file="cam.toml")
    return cam, dataclasses


RI = {"radius": [0.0, 0.5, 1.0], "R": [1.0, 0.9, 0.6], "B": [1.0, 0.8, 0.5]}


@pytest.mark.parametrize(("ri", "msg"), [
    ({"radius": [0.1, 1.0], "R": [1, 0.5]}, "must increase from 0"),
    ({"radius": [0.0, 1.0], "R": [1, 0.5, 0.2]}, "R has 3 values, radius 2"),
    ({"radius": [0.0, 1.0], "NIR": [1, 0.5]}, "unknown key 'NIR'"),
    ({"radius": [0.0, 1.0], "G": [1, 0.0]}, "must lie in (0, 1.5]"),
    ({"radius": [0.0, 1.0]}, "gives no channel"),
    ("cos4", "must be a table"),
])
def test_relative_illumination_is_validated(ri, msg):
    from l3cli.errors import ConfigError

    with pytest.raises(ConfigError) as err:
        _rgb_camera(relative_illumination=ri)
    assert "cam.toml: optics.relative_illumination" in str(err.value)
    assert msg in str(err.value)


def test_simulated_raw_carries_the_relative_illumination_and_the_target_not():
    """The measured per-channel fall-off (and cos^4 of a camera that corrects its
    shading) multiply the raw's signal only: raw ratio = the table interpolated at each
    pixel's normalised radius; the target is the unshaded camera's."""
    from l3cli.simulate import prepare_camera, simulate_capture
    from l3cli.simulate.optics import cos4_falloff

    plain, dc = _rgb_camera()
    shaded, _ = _rgb_camera(relative_illumination=RI, cos4=True, shading_corrected=True,
                            focal_length_mm=0.3)
    h, w = 40, 60
    caps = []
    for cam in (plain, shaded):
        model = prepare_camera(cam)
        caps.append(simulate_capture(model, uniform_scene(h, w, model.wavelengths),
                                     illuminant="D65", lux=100, seed=0, noise=False,
                                     blur=False, exposure_s=0.001))
    np.testing.assert_array_equal(caps[0].target, caps[1].target)  # the target is unshaded
    ratio = caps[1].noise_free / caps[0].noise_free
    v, u = normalised_coords(h, w)
    r = np.hypot(v[:, None], u[None, :])
    cos4 = cos4_falloff(h, w, plain.pixel.pitch_um * 1e-3, 0.3)
    cfa = plain.cfa.cfa
    chan = np.asarray(cfa.channel_map(h, w))
    for i, name in enumerate(cfa.channels):
        want = np.interp(r, RI["radius"], RI[name]) if name in RI else np.ones_like(r)
        sel = chan == i
        np.testing.assert_allclose(ratio[sel], (want * cos4)[sel], rtol=1e-5)
    assert ratio.min() < 0.5
