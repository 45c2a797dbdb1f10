"""Condition-indexed tables (issue 15, part 2): per-bin kernels against one pooled table.

Simulated captures whose noise grows strongly with ISO (or, at a fixed
scene brightness, as the exposure time shortens), rendered by a reference
pipeline that denoises harder at higher ISO (a Gaussian blur whose width
grows with log2 ISO, after a bilinear demosaic); trained on four ISOs and
scored on three ISOs between them. White balance: one shot per white, a
reference converter that white-balances by the as-shot gains and applies a
fixed colour matrix; scored on whites between the trained ones.
"""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from scipy.ndimage import convolve, gaussian_filter

from l3cli.cli.main import cli
from l3cli.io.image import write_image
from l3cli.io.raw import read_raw, write_raw
from l3cli.render import render_raw
from l3cli.table import load_table, save_table
from tests.builders import make_table

TRAIN_ISO = (100, 400, 1600, 6400)
TEST_ISO = (200, 800, 3200)


def _scene(seed, h=128, w=128):
    rng = np.random.default_rng(seed)
    s = np.stack([gaussian_filter(rng.random((h, w)), 2.5) for _ in range(3)], axis=2)
    s = (s - s.min()) / (s.max() - s.min())
    return (0.1 + 0.6 * s).astype(np.float32)


def _mosaic(scene):
    m = np.empty(scene.shape[:2], np.float32)
    m[0::2, 0::2] = scene[0::2, 0::2, 0]
    m[0::2, 1::2] = scene[0::2, 1::2, 1]
    m[1::2, 0::2] = scene[1::2, 0::2, 1]
    m[1::2, 1::2] = scene[1::2, 1::2, 2]
    return m


def reference(mosaic, iso):
    """Bilinear demosaic (RGGB), then a denoising blur that widens with ISO."""
    h, w = mosaic.shape
    masks = np.zeros((3, h, w), np.float32)
    masks[0, 0::2, 0::2] = 1
    masks[1, 0::2, 1::2] = masks[1, 1::2, 0::2] = 1
    masks[2, 1::2, 1::2] = 1
    k = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]], np.float32)
    rgb = np.stack([convolve(mosaic * masks[c], k, mode="mirror")
                    / convolve(masks[c], k, mode="mirror") for c in range(3)], axis=2)
    sigma = 0.3 * np.log2(iso / 100)
    return np.stack([gaussian_filter(rgb[..., c], sigma, mode="mirror") if sigma > 0
                     else rgb[..., c] for c in range(3)], axis=2).astype(np.float32)


def _capture(folder, stem, scene, iso, seed):
    rng = np.random.default_rng(seed)
    sigma = 0.003 * np.sqrt(iso / 100)  # 0.003 at ISO 100, 0.024 at ISO 6400
    m = np.clip(_mosaic(scene) + rng.normal(scale=sigma, size=scene.shape[:2]), 0, 1)
    dn = np.round(m * 4000).astype(np.uint16)
    write_raw(folder / f"{stem}.dng", dn, "RGGB", white_level=4000,
              shot={"iso": iso, "exposure_time": 0.01 * 100 / iso})
    norm = dn.astype(np.float32) / 4000
    write_image(folder / f"{stem}.exr", reference(norm, iso), space="linear-srgb")
    return {"stem": stem, "raw": f"{stem}.dng", "target": f"{stem}.exr"}


def _folder(path, isos, scenes, seed):
    path.mkdir()
    caps = [_capture(path, f"s{s}_iso{iso}", _scene(s), iso, seed + 31 * s + iso)
            for iso in isos for s in scenes]
    (path / "manifest.json").write_text(json.dumps(
        {"format": "l3-simulation", "version": 1, "target": {"space": "linear-srgb"}, "captures": caps}))
    return path


def _rmse(table, folder):
    errs = []
    for raw_path in sorted(folder.glob("*.dng")):
        from l3cli.io.image import read_image

        raw = read_raw(raw_path)
        ref, _ = read_image(raw_path.with_suffix(".exr"))
        errs.append(np.mean((render_raw(table, raw) - ref)[6:-6, 6:-6] ** 2))
    return float(np.sqrt(np.mean(errs)))


@pytest.mark.parametrize("by", ["iso", pytest.param("exposure", marks=pytest.mark.slow)])
def test_iso_bins_beat_one_table_on_held_out_isos(runner, tmp_path, by):
    train = _folder(tmp_path / "train", TRAIN_ISO, (0, 1), seed=1)
    test = _folder(tmp_path / "test", TEST_ISO, (2,), seed=2)
    common = ["--target", "linear-srgb", "--levels", "6", "--seed", "1"]
    for name, extra in (("single", []), ("binned", ["--by", by])):
        res = runner.invoke(cli, ["-q", "train", str(train), "-o", str(tmp_path / f"{name}.npz"),
                                  *common, *extra])
        assert res.exit_code == 0, res.output
    single = _rmse(load_table(tmp_path / "single.npz"), test)
    binned_table = load_table(tmp_path / "binned.npz")
    binned = _rmse(binned_table, test)
    values = {"iso": list(TRAIN_ISO), "exposure": sorted(0.01 * 100 / i for i in TRAIN_ISO)}[by]
    np.testing.assert_allclose(binned_table.conditions.values, values, rtol=5e-3)  # DNG rationals
    print(f"held-out {by} RMSE: single table {single:.5f}, {by} bins {binned:.5f}")
    assert binned < 0.8 * single
    res = runner.invoke(cli, ["inspect", str(tmp_path / "binned.npz")])
    assert res.exit_code == 0 and f"{by} {values[2]:g}: " in res.output


def test_kernels_interpolate_in_log_iso_and_round_trip(tmp_path):
    from l3cli.conditions import Conditioned, kernels_for

    t = make_table()
    k = np.stack([np.full_like(t.kernels, 1.0), np.full_like(t.kernels, 3.0)])
    counts = np.ones((2, t.kernels.shape[0]), np.int64)
    counts[1, 0] = 0  # class 0 untrained at ISO 400: the pooled kernel stands in
    t.conditions = Conditioned("iso", [100.0, 400.0], k, counts)
    np.testing.assert_allclose(kernels_for(t, 200.0)[1], 2.0)  # halfway in log2
    np.testing.assert_allclose(kernels_for(t, 50.0)[1], 1.0)  # clamped
    np.testing.assert_allclose(kernels_for(t, 400.0)[0], t.kernels[0])
    assert kernels_for(t, None) is t.kernels
    u = load_table(save_table(tmp_path / "c.npz", t))
    np.testing.assert_array_equal(u.conditions.kernels, t.conditions.kernels)
    np.testing.assert_array_equal(u.conditions.counts, counts)


WB_TRAIN = (0.35, 0.6, 1.0, 1.7)  # the white's camera b/r, one shot each
WB_TEST = (0.45, 0.8, 1.3)
CAMERA_TO_SRGB = np.array([[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [0.0, -0.5, 1.5]], np.float32)


def _wb_folder(path, whites, seed):
    """Shots of a scene under whites ``(r, 1, b)`` with b/r in ``whites``; converter targets."""
    path.mkdir()
    caps = []
    for i, br in enumerate(whites):
        white = np.array([1 / np.sqrt(br), 1.0, np.sqrt(br)]) * 0.8
        scene = _scene(seed + i, 96, 96) * white.astype(np.float32)
        dn = np.round(np.clip(_mosaic(scene), 0, 1) * 4000).astype(np.uint16)
        stem = f"w{i}"
        write_raw(path / f"{stem}.dng", dn, "RGGB", white_level=4000,
                  as_shot_neutral=white / white[1])
        rgb = reference(dn.astype(np.float32) / 4000, 100) / (white / white[1]).astype(np.float32)
        write_image(path / f"{stem}.exr", rgb @ CAMERA_TO_SRGB.T, space="linear-srgb")
        caps.append({"stem": stem, "raw": f"{stem}.dng", "target": f"{stem}.exr"})
    (path / "manifest.json").write_text(json.dumps(
        {"format": "l3-simulation", "version": 1, "target": {"space": "linear-srgb"}, "captures": caps}))
    return path


def test_white_balance_bins_beat_one_table_on_held_out_whites(runner, tmp_path):
    train = _wb_folder(tmp_path / "train", WB_TRAIN, seed=10)
    test = _wb_folder(tmp_path / "test", WB_TEST, seed=20)
    common = ["--target", "linear-srgb", "--levels", "4", "--seed", "1"]
    for name, extra in (("single", []), ("binned", ["--by", "white-balance"])):
        res = runner.invoke(cli, ["-q", "train", str(train), "-o", str(tmp_path / f"{name}.npz"),
                                  *common, *extra])
        assert res.exit_code == 0, res.output
    binned_table = load_table(tmp_path / "binned.npz")
    np.testing.assert_allclose(binned_table.conditions.values, WB_TRAIN, rtol=1e-3)
    single = _rmse(load_table(tmp_path / "single.npz"), test)
    binned = _rmse(binned_table, test)
    print(f"held-out whites RMSE: single table {single:.5f}, white-balance bins {binned:.5f}")
    assert binned < 0.5 * single
    res = runner.invoke(cli, ["inspect", str(tmp_path / "binned.npz")])
    assert res.exit_code == 0 and "white-balance 0.6: " in res.output


def _conditioned(by="iso"):
    from l3cli.conditions import Conditioned

    t = make_table()
    t.kernels[:] = 10.0  # the pooled kernels
    k = np.stack([np.full_like(t.kernels, v) for v in (1.0, 5.0, 3.0)])
    counts = np.full((3, t.kernels.shape[0]), 400, np.int64)
    counts[1, 0] = 0  # class 0 has no samples in the middle bin
    counts[2, 2] = 0  # class 2 none in the last bin
    t.conditions = Conditioned(by, [100.0, 400.0, 1600.0], k, counts)
    return t


def test_smooth_fills_a_sparse_bin_from_its_neighbours_not_the_pooled_kernel(runner, tmp_path):
    from l3cli.conditions import kernels_for
    from l3cli.smooth import smooth_table

    t = _conditioned()
    assert np.allclose(kernels_for(t, 400.0)[0], 10.0)  # before: the pooled kernel
    s = smooth_table(t, symmetry=False, uniformity=False)
    # equally spaced in ln value: the spline through the two trained neighbours (1 and 3,
    # a straight line) gives their mean in the middle
    np.testing.assert_allclose(kernels_for(s, 400.0)[0], 2.0, rtol=1e-5)
    assert s.conditions.filled[1, 0] and s.conditions.filled.sum() == 1
    # beyond a class's last trained bin the pooled kernel stands in (not copied outwards)
    np.testing.assert_allclose(kernels_for(s, 1600.0)[2], 10.0)
    assert not s.conditions.filled[2, 2]
    # plentiful trained bins stay close to their data under the default strength
    np.testing.assert_allclose(kernels_for(s, 400.0)[1], 5.0, atol=0.05)
    path = save_table(tmp_path / "s.npz", s)
    np.testing.assert_array_equal(load_table(path).conditions.filled, s.conditions.filled)
    res = runner.invoke(cli, ["inspect", str(path)])
    assert res.exit_code == 0 and "iso 400: " in res.output and "1 filled" in res.output


@pytest.mark.parametrize("by", ["iso", "exposure", "white-balance"])
def test_inspect_lists_the_bins_with_their_samples(by):
    from l3cli.inspect import format_summary, table_summary

    t = _conditioned(by)
    text = format_summary(table_summary(t), provenance=False)
    n = t.kernels.shape[0]
    assert f"--by {by}" in text
    assert f"  {by} 100: {400 * n} samples, {n} classes trained" in text
    assert f"  {by} 400: {400 * (n - 1)} samples, {n - 1} classes trained" in text
    assert f"  {by} 1600: {400 * (n - 1)} samples" in text


def test_raw_without_the_condition_renders_with_pooled_kernels(caplog):
    from l3cli.io.raw import RawImage
    from l3cli.render import render_mosaic

    t = _conditioned("exposure")
    rng = np.random.default_rng(0)
    raw = RawImage(mosaic=rng.random((24, 24)).astype(np.float32), cfa=t.definition.cfa,
                   black_level=np.zeros(4), white_level=1.0, metadata={"shot": {"iso": 100}})
    with caplog.at_level(logging.WARNING):
        out = render_raw(t, raw)
    assert "no exposure time (s) in the metadata" in caplog.text
    np.testing.assert_array_equal(out, render_mosaic(t, raw.mosaic))


def test_training_raw_without_the_condition_is_a_one_line_error(runner, tmp_path):
    train = _folder(tmp_path / "train", (100,), (0,), seed=1)
    dng = next(train.glob("*.dng"))
    raw = read_raw(dng)
    write_raw(dng, np.round(raw.mosaic * 4000).astype(np.uint16), "RGGB", white_level=4000)
    res = runner.invoke(cli, ["train", str(train), "-o", str(tmp_path / "t.npz"), "--by",
                              "exposure"])
    assert res.exit_code == 1
    assert f"{dng}: the metadata give no exposure time (s); --by exposure needs it" \
        in res.output and "Traceback" not in res.output


def test_train_offers_every_condition():
    """The CLI spells the choices out (its help must not import numpy); they match the library's."""
    from l3cli.cli.train import train
    from l3cli.conditions import CONDITIONS

    opt = next(p for p in train.params if p.name == "by")
    assert tuple(opt.type.choices) == CONDITIONS
