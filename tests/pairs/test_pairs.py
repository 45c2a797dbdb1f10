"""Pairs directories (l3cli.pairs): scanning, alignment, clipping and margin masks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from l3cli.colourspace import srgb_decode, srgb_encode
from l3cli.errors import InputError
from l3cli.io.image import write_image
from l3cli.io.raw import write_raw
from l3cli.pairs import (
    CLIP_HIGH,
    CLIP_LOW,
    find_pairs,
    is_pairs_dir,
    iter_pairs,
    weight_mask,
)
from tests.builders import H, W, mosaic_dn, scene


def test_find_pairs(pairs_dir: Path):
    pairs = find_pairs([pairs_dir])
    assert [(p.name, p.raw.name, p.target.name) for p in pairs] == [
        ("a", "a.raw", "a.png"), ("b", "b.dng", "b.tif")]
    assert is_pairs_dir(pairs_dir)


def test_iter_pairs_aligns_and_masks(pairs_dir: Path):
    got = {p.name: p for p in iter_pairs([pairs_dir], margin=4)}
    a, b = got["a"], got["b"]
    assert (a.alignment.dy, a.alignment.dx, a.alignment.flip) == (0, 0, "none")
    assert (b.alignment.dy, b.alignment.dx) == (4, 4)
    assert b.raw.shape == (H - 8, W - 8) and b.target.shape == (H - 8, W - 8, 3)
    assert b.raw.cfa.spec == "RG/GB"  # (4, 4) is even: phase unchanged
    assert a.space == "srgb" and a.target.dtype == np.float32
    for p in (a, b):
        m = p.weight_mask
        assert m.shape == p.raw.shape
        assert not m[:4].any() and not m[-4:].any() and not m[:, :4].any()
        assert not m[:, -4:].any()
        assert m[4:-4, 4:-4].mean() > 0.9


def test_target_space_conversion(pairs_dir: Path):
    (lin_pair,) = [p for p in iter_pairs([pairs_dir / "a.raw"], target_space="linear-srgb")]
    (enc_pair,) = [p for p in iter_pairs([pairs_dir / "a.raw"])]
    assert lin_pair.space == "linear-srgb"
    np.testing.assert_allclose(lin_pair.target, srgb_decode(enc_pair.target), atol=1e-6)


def test_weight_mask_clipping_and_margin():
    img = np.full((10, 12, 3), 0.5, dtype=np.float32)
    img[5, 6, 1] = 255 / 255  # clipped white in one channel
    img[6, 6, 2] = 0.0  # clipped black in one channel
    img[5, 7] = 254 / 255  # the largest unclipped 8-bit code
    img[6, 7] = 1 / 255  # the smallest unclipped code
    m = weight_mask(img, margin=2)
    assert not m[5, 6] and not m[6, 6] and m[5, 7] and m[6, 7]
    assert not m[:2].any() and not m[-2:].any() and not m[:, :2].any() and not m[:, -2:].any()
    assert m[2:-2, 2:-2].sum() == 6 * 8 - 2
    assert CLIP_LOW * 255 == pytest.approx(0.5) and CLIP_HIGH * 255 == pytest.approx(254.5)
    assert weight_mask(img, margin=0, clip_low=None, clip_high=None).all()
    with pytest.raises(InputError, match="margin -1"):
        weight_mask(img, margin=-1)


def test_raw_without_render(pairs_dir: Path):
    (pairs_dir / "a.png").unlink()
    with pytest.raises(InputError, match=r"a\.raw: no rendered image with the same stem"):
        find_pairs([pairs_dir])


def test_empty_folder(tmp_path: Path):
    with pytest.raises(InputError, match="no raw files in this folder"):
        find_pairs([tmp_path])
    assert not is_pairs_dir(tmp_path)


def test_missing_path(tmp_path: Path):
    with pytest.raises(InputError, match="no such file or folder"):
        find_pairs([tmp_path / "nope"])


def test_two_renders_ambiguous(pairs_dir: Path):
    write_image(pairs_dir / "a.jpg", np.zeros((H, W, 3), np.float32), space="srgb")
    with pytest.raises(InputError, match=r"several rendered images.*a\.jpg, a\.png"):
        find_pairs([pairs_dir])


def test_misaligned_pair_refused_naming_both(pairs_dir: Path):
    other = srgb_encode(scene(H, W, seed=99))
    write_image(pairs_dir / "a.png", other, space="srgb")
    with pytest.raises(InputError, match=r"a\.png does not align with .*a\.raw"):
        list(iter_pairs([pairs_dir]))


def test_simulation_dir_is_not_pairs_dir(pairs_dir: Path):
    (pairs_dir / "manifest.json").write_text("{}")
    assert not is_pairs_dir(pairs_dir)


def test_odd_crop_keeps_the_raw_cfa_phase(pairs_dir: Path):
    lin = scene(H, W, seed=21)
    write_raw(pairs_dir / "c.dng", mosaic_dn(lin, "RGGB", 4095), "RGGB", white_level=4095)
    write_image(pairs_dir / "c.png", srgb_encode(lin)[3:-4, 5:-2][:, ::-1], space="srgb")
    (c,) = [p for p in iter_pairs([pairs_dir / "c.dng"], margin=0)]
    assert (c.alignment.dy, c.alignment.dx, c.alignment.flip) == (3, 5, "horizontal")
    assert c.raw.cfa.spec == "RG/GB"
    assert c.raw.shape == (H - 8, W - 8) and c.target.shape == (H - 8, W - 8, 3)
    assert c.raw.metadata["crop"] == [4, 6, H - 8, W - 8]
    expect = np.round(srgb_encode(lin)[4:-4, 6:-2] * 255) / 255
    np.testing.assert_allclose(c.target, expect, atol=1e-6)


@pytest.fixture
def dng_pairs(tmp_path: Path) -> Path:
    """Two RGGB DNG pairs: a full-frame PNG render and a 4-pixel crop as JPEG."""
    d = tmp_path / "dng_pairs"
    d.mkdir()
    for stem, seed, crop, suffix in (("x", 31, 0, ".png"), ("y", 32, 4, ".jpg")):
        lin = scene(H, W, seed=seed)
        write_raw(d / f"{stem}.dng", mosaic_dn(lin, "RGGB", 4095), "RGGB", white_level=4095)
        enc = srgb_encode(lin)
        write_image(d / f"{stem}{suffix}", enc[crop:H - crop, crop:W - crop], space="srgb")
    return d


def test_cli_train_on_pairs_folder(dng_pairs: Path, tmp_path: Path, runner):
    from l3cli.cli.main import cli
    from l3cli.table import load_table

    out = tmp_path / "cam.npz"
    res = runner.invoke(cli, ["-v", "train", str(dng_pairs), "-o", str(out), "--levels", "3", "--no-tune",
                              "--patch", "3"])
    assert res.exit_code == 0, res.output
    assert "offset (dy=4, dx=4)" in res.output  # -v reports the alignment of y
    # the linear version of the renders' space by default (l3 render writes display sRGB)
    assert load_table(out).output_space == "linear-srgb"
    res = runner.invoke(cli, ["train", str(dng_pairs), "-o", str(out), "--levels", "3", "--no-tune",
                              "--patch", "3", "--target", "linear-srgb"])
    assert res.exit_code == 0, res.output
    assert load_table(out).output_space == "linear-srgb"


def test_cli_train_refuses_misaligned_pair(dng_pairs: Path, tmp_path: Path, runner):
    from l3cli.cli.main import cli

    write_image(dng_pairs / "x.png", srgb_encode(scene(H, W, seed=5)), space="srgb")
    res = runner.invoke(cli, ["train", str(dng_pairs), "-o", str(tmp_path / "z.npz"),
                              "--levels", "3", "--patch", "3", "--no-tune"])
    assert res.exit_code == 1
    assert "x.png does not align with" in res.output
    assert not (tmp_path / "z.npz").exists()


def test_resized_render_needs_scaled_renders(dng_pairs: Path, tmp_path: Path, runner):
    """A render resized by 0.9 is refused (with a pointer to the option) unless asked;
    with --scaled-renders it trains at its reduced resolution."""
    from scipy.ndimage import zoom

    from l3cli.align import ScaledAlignment
    from l3cli.cli.main import cli
    from l3cli.pairs import load_pair
    from l3cli.table import load_table

    enc = srgb_encode(scene(H, W, seed=31))  # x.dng's scene
    (dng_pairs / "x.png").unlink()
    write_image(dng_pairs / "x.png", np.clip(zoom(enc, (0.9, 0.9, 1), order=1), 0, 1), space="srgb")
    out = tmp_path / "cam.npz"
    args = ["-v", "train", str(dng_pairs), "-o", str(out), "--levels", "3", "--patch", "3", "--no-tune"]
    res = runner.invoke(cli, args)
    assert res.exit_code == 1 and not out.exists()
    assert "x.png does not align with" in res.output and "--scaled-renders" in res.output

    res = runner.invoke(cli, args + ["--scaled-renders"])
    assert res.exit_code == 0, res.output
    import re

    m = re.search(r"x: resized render: scale ([\d.]+) x ([\d.]+) of the raw", res.output)
    assert m and "reduced resolution" in res.output
    # zoom maps first and last pixel centres: 115x144 render pixels span 127x159 raw steps
    assert float(m.group(1)) == pytest.approx(114 / 127, abs=0.003)
    assert float(m.group(2)) == pytest.approx(143 / 159, abs=0.003)
    assert "offset (dy=4, dx=4)" in res.output  # y.jpg still aligns pixel for pixel
    assert load_table(out).counts.sum() > 0

    (files,) = [f for f in find_pairs([dng_pairs]) if f.name == "x"]
    p = load_pair(files, scaled=True, margin=4)
    assert isinstance(p.alignment, ScaledAlignment)
    assert p.raw.shape == p.target.shape[:2] == p.weight_mask.shape
    assert p.raw.cfa.spec == "RG/GB"
    mask = p.weight_mask
    assert not mask[:4].any() and not mask[-4:].any()
    assert not mask[:, :4].any() and not mask[:, -4:].any()
    assert mask[4:-4, 4:-4].mean() > 0.9


def test_render_to_jpeg_and_evaluate_against_the_camera_jpeg(dng_pairs: Path, tmp_path: Path,
                                                             runner):
    """The workflow of docs/real-camera.md: train on pairs, `l3 render TABLE RAW -o out.jpg`,
    `l3 evaluate out.jpg --reference camera.jpg` (--align for a camera JPEG that is a crop)."""
    import json

    from l3cli.cli.main import cli
    from l3cli.io.image import read_image

    table = tmp_path / "cam.npz"
    res = runner.invoke(cli, ["train", str(dng_pairs), "-o", str(table), "--levels", "3", "--no-tune",
                              "--patch", "3", "--target", "linear-srgb"])
    assert res.exit_code == 0, res.output
    # a new raw, not trained on, whose camera JPEG is cropped by 4 pixels and mirrored
    lin = scene(H, W, seed=33)
    new_raw = write_raw(tmp_path / "z.dng", mosaic_dn(lin, "RGGB", 4095), "RGGB",
                        white_level=4095)
    camera = tmp_path / "camera.jpg"
    write_image(camera, srgb_encode(lin)[4:-4, 4:-4, :][:, ::-1], space="srgb", quality=95)
    out = tmp_path / "out.jpg"
    res = runner.invoke(cli, ["render", str(table), str(new_raw), "-o", str(out)])
    assert res.exit_code == 0, res.output
    img, space = read_image(out)
    assert img.shape == (H, W, 3) and space == "srgb"  # the raw's full area
    rep = tmp_path / "r.json"
    args = ["evaluate", str(out), "--reference", str(camera), "--exclude-border", "4",
            "--json", str(rep)]
    res = runner.invoke(cli, args)
    assert res.exit_code == 1 and "use --align" in res.output
    res = runner.invoke(cli, args + ["--align"])
    assert res.exit_code == 0, res.output
    got = json.loads(rep.read_text())["images"][0]
    assert got["scielab_mean"] < 1.0 and got["psnr_db"] > 28  # measured 0.28 and 33.4 dB


def test_one_input_layer_for_simulate_and_pairs_folders(pairs_dir: Path):
    """find_pairs lists simulation captures and rendered pairs alike, as one Pair type;
    simulation captures carry their manifest's per-capture facts."""
    import json

    import l3cli.train
    from tests.builders import DATA

    sim = DATA / "golden" / "train"
    pairs = find_pairs([sim, pairs_dir])
    assert l3cli.train.Pair is type(pairs[0]) is type(pairs[-1])
    caps = json.loads((sim / "manifest.json").read_text())["captures"]
    assert [p.name for p in pairs] == [c["stem"] for c in caps] + ["a", "b"]
    assert [p.align for p in pairs] == [False] * len(caps) + [True, True]
    for p, c in zip(pairs[: len(caps)], caps, strict=True):
        assert p.raw == sim / c["raw"] and p.target == sim / c["target"]
        assert p.metadata == {k: c[k] for k in ("scene", "illuminant", "lux", "exposure_s")}
    assert pairs[-1].metadata == {}
