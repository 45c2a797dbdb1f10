"""Image I/O through OpenImageIO and the colour-space conversions."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from l3cli.colourspace import convert, srgb_decode, srgb_encode
from l3cli.errors import ConfigError, InputError
from l3cli.io.image import read_image, write_image


@pytest.fixture
def img():
    return np.random.default_rng(3).random((17, 23, 3)).astype(np.float32)


def test_exr_round_trip_is_exact_and_keeps_space(tmp_path, img):
    p = write_image(tmp_path / "a.exr", img, space="xyz")
    back, space = read_image(p)
    assert space == "xyz"
    np.testing.assert_array_equal(back, img)


def test_exr_half(tmp_path, img):
    back, _ = read_image(write_image(tmp_path / "h.exr", img, space="linear-srgb", half=True))
    np.testing.assert_allclose(back, img, atol=1e-3)


@pytest.mark.parametrize("suffix, bits, tol", [(".png", 16, 1e-4), (".png", 8, 2.1e-3),
                                               (".tif", None, 1e-4)])
def test_encoded_round_trip(tmp_path, img, suffix, bits, tol):
    back, space = read_image(write_image(tmp_path / f"a{suffix}", img, space="srgb", bits=bits))
    assert space == "srgb"
    np.testing.assert_allclose(back, img, atol=tol)


def test_jpeg_smooth_image(tmp_path):
    y, x = np.mgrid[0:32, 0:48] / 64.0
    img = np.stack([x, y, 0.5 * (x + y)], -1).astype(np.float32)
    back, _ = read_image(write_image(tmp_path / "a.jpg", img, space="srgb", quality=98))
    assert np.abs(back - img).mean() < 0.01


def test_linear_written_to_png_is_display_encoded(tmp_path):
    grey = np.full((4, 4, 3), 0.18, np.float32)
    back, _ = read_image(write_image(tmp_path / "g.png", grey, space="linear-srgb", bits=16))
    # sRGB encoding of 18 % grey is about 0.461 (IEC 61966-2-1)
    np.testing.assert_allclose(back, 1.055 * 0.18 ** (1 / 2.4) - 0.055, atol=1e-4)


def test_srgb_transfer_matches_standard():
    x = np.linspace(0, 1, 101, dtype=np.float32)
    ref = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(srgb_encode(x), ref, atol=1e-6)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)), x, atol=1e-6)


def test_xyz_white_maps_to_srgb_white():
    d65 = colour.xy_to_XYZ(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])
    np.testing.assert_allclose(convert(d65[None], "xyz", "linear-srgb"), [[1, 1, 1]], atol=2e-3)
    lab = convert(d65[None], "xyz", "lab")
    np.testing.assert_allclose(lab, [[100, 0, 0]], atol=0.3)


@pytest.mark.parametrize("dst", ["xyz", "linear-srgb", "srgb", "lab"])
def test_conversions_invert(img, dst):
    lin = img * 0.8 + 0.1
    back = convert(convert(lin, "linear-srgb", dst), dst, "linear-srgb")
    np.testing.assert_allclose(back, lin, atol=1e-4)


def test_unknown_space_lists_allowed(img):
    with pytest.raises(ConfigError, match="xyz, linear-srgb, srgb, lab"):
        convert(img, "prophoto", "xyz")


def test_unreadable_images(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_image(tmp_path / "none.png")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
    with pytest.raises(InputError, match="bad.png"):
        read_image(bad)
    other = tmp_path / "x.bmpx"
    other.write_bytes(b"BM")
    with pytest.raises(InputError, match="unknown image format '.bmpx'"):
        read_image(other)


def test_failed_write_leaves_nothing(tmp_path, img):
    with pytest.raises(Exception):  # noqa: B017 - any failure must leave no file behind
        write_image(tmp_path / "a.png", img[:, :, :0], space="data")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name, kwargs, fmt, oiio_type, channels", [
    ("a.exr", {"space": "xyz"}, "openexr", "float", 3),
    ("h.exr", {"space": "xyz", "half": True}, "openexr", "half", 3),
    ("a.tif", {"space": "srgb"}, "tiff", "uint16", 3),
    ("a.png", {"space": "srgb", "bits": 16}, "png", "uint16", 3),
    ("b.png", {"space": "srgb"}, "png", "uint8", 3),
    ("a.jpg", {"space": "srgb"}, "jpeg", "uint8", 3),
])
def test_written_file_types(tmp_path, img, name, kwargs, fmt, oiio_type, channels):
    """What lands on disk: EXR float32/half, TIFF 16-bit, PNG 8/16-bit, JPEG 8-bit."""
    import OpenImageIO as oiio

    p = write_image(tmp_path / name, img, **kwargs)
    inp = oiio.ImageInput.open(str(p))
    try:
        spec = inp.spec()
        assert inp.format_name() == fmt
        assert str(spec.format) == oiio_type and spec.nchannels == channels
        assert (spec.width, spec.height) == (23, 17)
    finally:
        inp.close()


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_short_file_is_told_from_a_whole_one(tmp_path, img, suffix):
    """The cheap after-write check: a file missing its last bytes is not whole."""
    from l3cli.io.image import _ends_whole

    path = write_image(tmp_path / f"a{suffix}", img, space="srgb")
    assert _ends_whole(path)
    data = path.read_bytes()
    for cut in (1, len(data) // 2, len(data) - 2):
        short = tmp_path / f"short{suffix}"
        short.write_bytes(data[: len(data) - cut])
        assert not _ends_whole(short), cut
