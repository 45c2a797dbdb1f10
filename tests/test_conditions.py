"""Condition-indexed tables (issue 15, part 2): per-ISO kernels against one pooled table.

Simulated captures whose noise grows strongly with ISO, rendered by a
reference pipeline that denoises harder at higher ISO (a Gaussian blur
whose width grows with log2 ISO, after a bilinear demosaic); trained on four
ISOs and scored on three ISOs between them.
"""

from __future__ import annotations

import json

import numpy as np
from scipy.ndimage import convolve, gaussian_filter

from l3cli.cli.main import cli
from l3cli.io.image import write_image
from l3cli.io.raw import read_raw, write_raw
from l3cli.render import render_raw
from l3cli.table import load_table, save_table

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
    write_raw(folder / f"{stem}.dng", dn, "RGGB", white_level=4000, shot={"iso": iso})
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


def test_iso_bins_beat_one_table_on_held_out_isos(runner, tmp_path):
    train = _folder(tmp_path / "train", TRAIN_ISO, (0, 1), seed=1)
    test = _folder(tmp_path / "test", TEST_ISO, (2,), seed=2)
    common = ["--target", "linear-srgb", "--levels", "6", "--seed", "1"]
    for name, extra in (("single", []), ("binned", ["--by", "iso"])):
        res = runner.invoke(cli, ["-q", "train", str(train), "-o", str(tmp_path / f"{name}.npz"),
                                  *common, *extra])
        assert res.exit_code == 0, res.output
    single = _rmse(load_table(tmp_path / "single.npz"), test)
    binned_table = load_table(tmp_path / "binned.npz")
    binned = _rmse(binned_table, test)
    assert binned_table.conditions.values.tolist() == list(TRAIN_ISO)
    print(f"held-out ISOs RMSE: single table {single:.5f}, ISO bins {binned:.5f}")
    assert binned < 0.8 * single
    res = runner.invoke(cli, ["inspect", str(tmp_path / "binned.npz")])
    assert res.exit_code == 0 and "iso 1600:" in res.output


def test_kernels_interpolate_in_log_iso_and_round_trip(tmp_path):
    from l3cli.conditions import Conditioned, kernels_for
    from tests.test_table import make_table

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
