"""Raw reading and writing against real files and rawpy/LibRaw."""

from __future__ import annotations

import os

import numpy as np
import pytest
import rawpy

from l3cli.cfa import CFA
from l3cli.errors import ConfigError, InputError, OutputError
from l3cli.io.raw import read_raw, sidecar_path, write_raw


def test_headerless_rose_crop(data_dir):
    path = data_dir / "DSC_1339_768x512_rggb_14bit.raw"
    raw = read_raw(path)
    assert raw.shape == (512, 768)
    assert raw.cfa == CFA.from_spec("RGGB")
    dn = np.fromfile(path, dtype="<u2").reshape(512, 768).astype(np.float64)
    np.testing.assert_allclose(raw.mosaic, (dn - 600) / (15520 - 600), rtol=1e-6, atol=1e-7)
    assert raw.mosaic.dtype == np.float32


def test_png_mosaic_with_sidecar(data_dir):
    raw = read_raw(data_dir / "halide_bayer_small.png")
    assert raw.shape == (344, 256)
    assert raw.cfa.spec == "GR/BG"
    assert raw.black_level.tolist() == [25.0] * 4
    # independent decode with Pillow
    from PIL import Image

    dn = np.asarray(Image.open(data_dir / "halide_bayer_small.png"), dtype=np.float64)
    np.testing.assert_allclose(raw.mosaic, (dn - 25) / (1023 - 25), rtol=1e-6, atol=1e-7)


def test_blackmagic_dng(shared_data):
    path = shared_data / "raw/misc/blackmagic_pocket4k_rggb.dng"
    raw = read_raw(path)
    assert raw.cfa.spec == "RG/GB"
    assert raw.shape == (2176, 4128)
    assert raw.black_level.tolist() == [512.0] * 4
    with rawpy.imread(str(path)) as rp:
        vis = rp.raw_image_visible.astype(np.float64)
        white = rp.white_level
    np.testing.assert_allclose(raw.mosaic[:64, :64], (vis[:64, :64] - 512) / (white - 512),
                               rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("spec", ["RGGB", "GRBG", "BGGR", "GBRG"])
def test_dng_round_trip(tmp_path, spec):
    rng = np.random.default_rng(1)
    dn = rng.integers(64, 4095, size=(48, 64)).astype(np.uint16)
    out = write_raw(tmp_path / "a.dng", dn, spec, black_level=64, white_level=4095,
                    make="l3", model="test")
    assert out.suffix == ".dng"
    raw = read_raw(out)
    assert raw.cfa == CFA.from_spec(spec)
    assert raw.black_level.tolist() == [64.0] * 4 and raw.white_level == 4095
    np.testing.assert_allclose(raw.mosaic, (dn - 64.0) / (4095 - 64), rtol=1e-6)
    with rawpy.imread(str(out)) as rp:
        np.testing.assert_array_equal(rp.raw_image_visible, dn)
        letters = rp.color_desc.decode()
        got = "".join(letters[c] for c in rp.raw_pattern.ravel()).replace("G", "G")
        assert got.replace("G", "G") == spec.replace("G", "G")[: len(got)] or got == spec
        assert list(rp.black_level_per_channel) == [64] * 4
        assert rp.white_level == 4095
        rgb = rp.postprocess()
    assert rgb.shape == (48, 64, 3) and rgb.dtype == np.uint8


def test_non_dng_cfa_writes_tiff_with_sidecar(tmp_path):
    dn = np.arange(16 * 24, dtype=np.uint16).reshape(16, 24) * 10
    out = write_raw(tmp_path / "n.dng", dn, "R G/NIR B", black_level=[1, 2, 3, 4],
                    white_level=60000)
    assert out.suffix == ".tif" and sidecar_path(out).exists()
    raw = read_raw(out)
    assert raw.cfa.channels == ("R", "G", "NIR", "B")
    assert raw.black_level.tolist() == [1, 2, 3, 4]
    expect = (dn - np.tile([[1, 2], [3, 4]], (8, 12))) / (60000 - 4)
    np.testing.assert_allclose(raw.mosaic, expect, rtol=1e-6, atol=1e-8)


# ------------------------------------------------------------------ bad input
def test_truncated_headerless(tmp_path, data_dir):
    src = data_dir / "DSC_1339_768x512_rggb_14bit.raw"
    dst = tmp_path / "cut.raw"
    dst.write_bytes(src.read_bytes()[:-100])
    sidecar_path(dst).write_text(sidecar_path(src).read_text())
    with pytest.raises(InputError, match=r"cut.raw: file is 786332 bytes .* 768x512 uint16"):
        read_raw(dst)


def test_missing_sidecar(tmp_path):
    p = tmp_path / "x.raw"
    p.write_bytes(b"\0" * 100)
    with pytest.raises(InputError, match=r"x.raw: sidecar x.raw.toml is missing"):
        read_raw(p)


def test_sidecar_syntax_error_names_file_and_line(tmp_path):
    p = tmp_path / "x.raw"
    p.write_bytes(b"\0" * 4)
    sidecar_path(p).write_text('width = 2\nheight = = 2\n')
    with pytest.raises(ConfigError, match=r"x.raw.toml: TOML syntax error.*line 2"):
        read_raw(p)


def test_sidecar_unknown_key_and_bad_cfa(tmp_path):
    p = tmp_path / "x.raw"
    p.write_bytes(b"\0" * 4)
    base = 'width = 2\nheight = 2\ndtype = "uint8"\nblack_level = 0\nwhite_level = 255\n'
    sidecar_path(p).write_text(base + 'cfa = "RGGB"\nwidht = 3\n')
    with pytest.raises(ConfigError, match="unknown key 'widht'"):
        read_raw(p)
    sidecar_path(p).write_text(base + 'cfa = "RGXB"\n')
    with pytest.raises(ConfigError, match="unknown channel 'X'"):
        read_raw(p)
    sidecar_path(p).write_text(base.replace('"uint8"', '"float32"') + 'cfa = "RGGB"\n')
    with pytest.raises(ConfigError, match="dtype 'float32' is not allowed"):
        read_raw(p)


@pytest.mark.parametrize("content", [b"", b"this is not a raw file" * 50, b"II*\0" + b"\0" * 64])
def test_non_raw_file(tmp_path, content):
    p = tmp_path / "fake.dng"
    p.write_bytes(content)
    with pytest.raises(InputError, match="fake.dng"):
        read_raw(p)


def test_truncated_dng(tmp_path, shared_data):
    src = shared_data / "raw/misc/blackmagic_pocket4k_rggb.dng"
    p = tmp_path / "cut.dng"
    p.write_bytes(src.read_bytes()[:4096])
    with pytest.raises(InputError, match="cut.dng"):
        read_raw(p)


def test_image_is_not_raw(tmp_path):
    p = tmp_path / "photo.jpg"
    p.write_bytes(b"\xff\xd8\xff")
    with pytest.raises(InputError, match="not a raw file"):
        read_raw(p)


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_unwritable_folder(tmp_path):  # pragma: no cover - CI runs as root
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o500)
    with pytest.raises(OutputError, match="not writable"):
        write_raw(d / "a.dng", np.zeros((4, 4), np.uint16), "RGGB")


def test_missing_output_folder_leaves_nothing(tmp_path):
    with pytest.raises(OutputError, match="does not exist"):
        write_raw(tmp_path / "nope" / "a.dng", np.zeros((4, 4), np.uint16), "RGGB")
    assert not (tmp_path / "nope").exists()


def test_unwritable_folder_via_access(tmp_path, monkeypatch):
    """As root chmod cannot deny writes, so deny through os.access as a non-root user would see."""
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, m: False if str(p) == str(tmp_path) else
                        real_access(p, m))
    with pytest.raises(OutputError, match="not writable"):
        write_raw(tmp_path / "a.dng", np.zeros((4, 4), np.uint16), "RGGB")
    assert list(tmp_path.iterdir()) == []


def test_output_parent_is_a_file(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(OutputError, match="not a folder"):
        write_raw(f / "a.dng", np.zeros((4, 4), np.uint16), "RGGB")
