"""Training from raws alone with their embedded previews (issue 15, part 4)."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
from scipy.ndimage import gaussian_filter

from l3cli.cli.main import cli
from l3cli.colourspace import srgb_encode
from l3cli.errors import InputError
from l3cli.io.raw import read_raw, write_raw
from l3cli.preview import extract_preview
from l3cli.render import render_raw
from l3cli.table import load_table


def _scene(h, w, seed):
    rng = np.random.default_rng(seed)
    s = np.stack([gaussian_filter(rng.random((h, w)), 3) for _ in range(3)], axis=2)
    s = (s - s.min()) / (s.max() - s.min())
    return (0.05 + 0.8 * s).astype(np.float32)


def _dng_with_preview(path, scene, preview):
    """A DNG: the preview in IFD0 (NewSubfileType 1), the RGGB raw of ``scene`` in a SubIFD."""
    h, w, _ = scene.shape
    raw = np.empty((h, w), np.float32)
    raw[0::2, 0::2] = scene[0::2, 0::2, 0]
    raw[0::2, 1::2] = scene[0::2, 1::2, 1]
    raw[1::2, 0::2] = scene[1::2, 0::2, 1]
    raw[1::2, 1::2] = scene[1::2, 1::2, 2]
    dn = np.round(raw * 4000).astype(np.uint16)
    ifd0 = [(50706, "B", 4, (1, 4, 0, 0), True), (271, "s", 0, "l3", True),
            (272, "s", 0, "test", True), (50708, "s", 0, "l3 test", True),
            (50721, "2i", 9, (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1), True),
            (50728, "2I", 3, (1, 1, 1, 1, 1, 1), True)]
    cfa = [(33421, "H", 2, (2, 2), True), (33422, "B", 4, (0, 1, 1, 2), True),
           (50714, "I", 1, (0,), True), (50717, "I", 1, (4095,), True), (50711, "H", 1, 1, True)]
    with tifffile.TiffWriter(path) as tw:
        tw.write(preview, photometric="rgb", subfiletype=1, subifds=1, extratags=ifd0,
                 metadata=None)
        tw.write(dn, photometric=32803, subfiletype=0, extratags=cfa, metadata=None)
    return path


def _encoded(scene):
    return np.round(srgb_encode(scene) * 255).astype(np.uint8)


@pytest.mark.parametrize("reduce", [1, 2])
def test_train_from_embedded_previews(runner, tmp_path, reduce):
    folder = tmp_path / "raws"
    folder.mkdir()
    for i in range(2):
        scene = _scene(192, 256, i)
        prev = _encoded(scene)
        if reduce > 1:  # a reduced preview: the mean of reduce x reduce blocks (in display values)
            prev = _encoded(scene).reshape(96, 2, 128, 2, 3).mean(axis=(1, 3)).round().astype(np.uint8)
        _dng_with_preview(folder / f"s{i}.dng", scene, prev)
    assert read_raw(folder / "s0.dng").shape == (192, 256)
    out = tmp_path / "t.npz"
    res = runner.invoke(cli, ["train", str(folder), "-o", str(out), "--embedded-preview",
                              "--target", "linear-srgb", "--levels", "4", "--seed", "1"])
    assert res.exit_code == 0, res.output
    assert not list(tmp_path.glob(".l3-tmp-previews-*"))  # working folder removed
    table = load_table(out)
    scene = _scene(192, 256, 0)
    img = render_raw(table, read_raw(folder / "s0.dng"))[8:-8, 8:-8]
    err = np.sqrt(np.mean((img - scene[8:-8, 8:-8]) ** 2))
    assert err < (0.02 if reduce == 1 else 0.05), err  # the preview's look is learned


def test_raw_without_preview_is_refused(tmp_path):
    p = write_raw(tmp_path / "n.dng", np.full((32, 32), 1000, np.uint16), "RGGB")
    with pytest.raises(InputError, match="no embedded preview"):
        extract_preview(p, tmp_path / "n_prev")


def test_tiny_preview_is_refused(tmp_path):
    scene = _scene(192, 256, 3)
    p = _dng_with_preview(tmp_path / "t.dng", scene, _encoded(scene)[::8, ::8])
    with pytest.raises(InputError, match="too small to train"):
        extract_preview(p, tmp_path / "t_prev")
