"""Renders keep the raw's orientation (EXIF Orientation) and shot metadata (issue 15, part 3)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image, ImageOps

from l3cli.io.metadata import LIBRAW_FLIP_TO_EXIF, exif_attributes, read_shot_metadata
from l3cli.io.raw import read_raw, write_raw
from l3cli.render import render_file
from tests.builders import make_table

# The stored pixels S of an image that a viewer shows upright as U under EXIF
# orientation o satisfy exif_transpose(S, o) == U; PIL's exif_transpose is the
# independent reference of what a viewer does. These build S from U (inverses).
_INVERSE = {1: None, 2: Image.Transpose.FLIP_LEFT_RIGHT, 3: Image.Transpose.ROTATE_180,
            4: Image.Transpose.FLIP_TOP_BOTTOM, 5: Image.Transpose.TRANSPOSE,
            6: Image.Transpose.ROTATE_90, 7: Image.Transpose.TRANSVERSE,
            8: Image.Transpose.ROTATE_270}


def _identity_table():
    t = make_table("RGGB", patch=5, space="linear-srgb")
    t.kernels[:] = 0
    t.kernels[:, 12, :] = 1.0  # every output channel = the centre pixel
    return t


def _upright():
    """A 40x60 scene (portrait-incompatible: wider than tall) with a distinct quadrant layout."""
    u = np.full((40, 60), 40, np.uint8)
    u[:20, :30] = 220  # top-left bright
    u[:20, 30:] = 120  # top-right mid
    u[20:, :30] = 80
    return u


@pytest.mark.parametrize("orientation", range(1, 9))
def test_dng_of_each_orientation_renders_upright(tmp_path, orientation):
    up = Image.fromarray(_upright())
    inv = _INVERSE[orientation]
    stored = np.array(up if inv is None else up.transpose(inv))
    dng = write_raw(tmp_path / "a.dng", stored.astype(np.uint16) * 256, "RGGB",
                    white_level=65535, shot={"orientation": orientation})
    raw = read_raw(dng)
    assert raw.shape == stored.shape  # stored grid, not rotated
    assert raw.metadata["shot"]["orientation"] == orientation
    for fmt in ("jpg", "png", "tif"):
        out = render_file(_identity_table(), dng, tmp_path / f"a.{fmt}")
        if fmt == "tif":  # Pillow's libtiff path may orient TIFFs itself: read what is stored
            import tifffile

            with tifffile.TiffFile(out) as tf:
                pixels = tf.pages[0].asarray()
                tag = tf.pages[0].tags["Orientation"].value
            im = Image.fromarray(pixels[:, :, :3].astype(np.uint8) if pixels.dtype == np.uint8
                                 else (pixels[:, :, :3] >> 8).astype(np.uint8))
            im.getexif()[0x0112] = int(tag)
            im.info["exif"] = im.getexif().tobytes()
        else:
            im = Image.open(out)
        assert im.size == (stored.shape[1], stored.shape[0])  # pixels stay raw-aligned
        assert im.getexif().get(0x0112) == orientation
        shown = np.asarray(ImageOps.exif_transpose(im).convert("L"), dtype=float)
        assert shown.shape == (40, 60)
        q = [shown[:20, :30].mean(), shown[:20, 30:].mean(), shown[20:, :30].mean(),
             shown[20:, 30:].mean()]
        assert np.argsort(q).tolist() == [3, 2, 1, 0], (fmt, q)


def test_libraw_flip_codes_invert_the_tiff_orientation_map():
    # LibRaw: flip = "50132467"[orientation & 7]
    for o in range(1, 9):
        assert LIBRAW_FLIP_TO_EXIF[int("50132467"[o & 7])] == o


SHOT = {"make": "Acme", "model": "Cam 1", "datetime_original": "2024:05:06 07:08:09",
        "iso": 800, "exposure_time": 1 / 250, "f_number": 5.6, "lens": "Acme 35mm F2",
        "orientation": 6}


def test_shot_metadata_round_trip(tmp_path):
    m = (np.arange(24 * 32).reshape(24, 32) % 200 * 100).astype(np.uint16)
    dng = write_raw(tmp_path / "s.dng", m, "RGGB", make="Acme", model="Cam 1",
                    shot={k: v for k, v in SHOT.items() if k not in ("make", "model")})
    got = read_shot_metadata(dng)
    assert got["iso"] == 800 and got["lens"] == "Acme 35mm F2"
    assert got["exposure_time"] == pytest.approx(0.004) and got["f_number"] == pytest.approx(5.6)
    raw = read_raw(dng)
    assert {k: raw.metadata["shot"][k] for k in SHOT} == pytest.approx(SHOT)
    table = _identity_table()
    for fmt in ("jpg", "png", "tif"):
        out = render_file(table, dng, tmp_path / f"s.{fmt}")
        ex = Image.open(out).getexif()  # PIL reads EXIF independently of OpenImageIO
        sub = {**ex, **ex.get_ifd(0x8769)}
        assert sub[0x010F] == "Acme" and sub[0x0110] == "Cam 1"  # Make, Model
        assert sub[0x9003] == "2024:05:06 07:08:09"  # DateTimeOriginal
        assert float(sub[0x829A]) == pytest.approx(0.004)  # ExposureTime
        assert float(sub[0x829D]) == pytest.approx(5.6)  # FNumber
        assert sub[0xA434] == "Acme 35mm F2"  # LensModel
        if fmt != "tif":  # OpenImageIO's TIFF writer leaves ISO out
            assert sub[0x8827] == 800  # ISOSpeedRatings
    import OpenImageIO as oiio

    out = render_file(table, dng, tmp_path / "s.exr")
    spec = oiio.ImageInput.open(str(out)).spec()
    for name, v in exif_attributes(SHOT).items():
        got = spec.getattribute(name)
        assert got == pytest.approx(v) if isinstance(v, float) else got == v, name


def test_headerless_raw_has_no_orientation_and_renders_plain(tmp_path):
    m = np.full((16, 16), 100, np.uint8)
    m.tofile(tmp_path / "h.raw")
    (tmp_path / "h.raw.toml").write_text(
        'width = 16\nheight = 16\ndtype = "uint8"\ncfa = "RGGB"\nblack_level = 0\n'
        "white_level = 255\n")
    out = render_file(_identity_table(), tmp_path / "h.raw", tmp_path / "h.jpg")
    assert Image.open(out).getexif().get(0x0112) is None
