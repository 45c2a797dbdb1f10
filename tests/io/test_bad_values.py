"""Silently wrong values the fault campaign found: each is now right or a one-line error."""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.errors import ConfigError, InputError, L3Error
from l3cli.io.image import read_image
from l3cli.io.raw import read_raw


def _headerless(tmp_path, sidecar: str, nbytes: int = 8 * 6 * 2):
    raw = tmp_path / "a.raw"
    raw.write_bytes(np.arange(nbytes, dtype=np.uint8).tobytes())
    (tmp_path / "a.raw.toml").write_text(sidecar)
    return raw


_BASE = 'width = 8\nheight = 6\ndtype = "uint16"\ncfa = "RGGB"\n'


@pytest.mark.parametrize("levels, key", [
    ("black_level = 0\nwhite_level = inf", "white_level must be finite"),
    ("black_level = 0\nwhite_level = nan", "white_level must be finite"),
    ("black_level = -4\nwhite_level = 1000", "black_level must be >= 0"),
    ("black_level = [0, 0, -inf, 0]\nwhite_level = 1000", "black_level must be finite"),
    ("black_level = true\nwhite_level = 1000", "black_level must be a number"),
    ('black_level = "12"\nwhite_level = 1000', "black_level must be a number"),
    ("black_level = [[1, 2]]\nwhite_level = 1000", "black_level must be a number"),
    ("black_level = 0\nwhite_level = 70000", "exceeds the data's range"),
])
def test_sidecar_levels(tmp_path, levels, key):
    with pytest.raises(ConfigError, match=key):
        read_raw(_headerless(tmp_path, _BASE + levels))


@pytest.mark.parametrize("text, key", [
    ('width = "8"\nheight = 6\ndtype = "uint16"\ncfa = "RGGB"\nblack_level = 0\nwhite_level = 9',
     "width has the wrong type"),
    ('width = 8\nheight = 6\ndtype = 16\ncfa = "RGGB"\nblack_level = 0\nwhite_level = 9',
     "dtype has the wrong type"),
    ('width = 8\nheight = 6\ndtype = "uint16"\ncfa = 3\nblack_level = 0\nwhite_level = 9',
     "cfa has the wrong type"),
    ('width = 8\nheight = 6\ndtype = "uint16"\ncfa = [[1, 2]]\nblack_level = 0\nwhite_level = 9',
     "cfa"),
])
def test_sidecar_types(tmp_path, text, key):
    with pytest.raises(L3Error, match=key):
        read_raw(_headerless(tmp_path, text))


def test_sidecar_not_utf8(tmp_path):
    raw = _headerless(tmp_path, "")
    (tmp_path / "a.raw.toml").write_bytes(b"width = 8\n\xff\xfe = 1\n")
    with pytest.raises(ConfigError, match="not UTF-8|TOML"):
        read_raw(raw)


def test_one_pixel_raw_is_refused(tmp_path):
    raw = _headerless(tmp_path, 'width = 1\nheight = 1\ndtype = "uint8"\ncfa = "RGGB"\n'
                                "black_level = 0\nwhite_level = 255", nbytes=1)
    with pytest.raises(InputError, match="too small"):
        read_raw(raw)


def test_rgba_png_is_not_multiplied_by_alpha(tmp_path):
    from PIL import Image

    a = np.zeros((4, 4, 4), np.uint8)
    a[..., :3] = 200
    a[..., 3] = 64
    Image.fromarray(a, "RGBA").save(tmp_path / "x.png")
    img, _ = read_image(tmp_path / "x.png")
    np.testing.assert_allclose(img[..., :3], 200 / 255, rtol=1e-6)
    np.testing.assert_allclose(img[..., 3], 64 / 255, rtol=1e-6)


def test_non_ascii_camera_name_writes_a_dng(tmp_path):
    from l3cli.io.raw import write_raw

    p = write_raw(tmp_path / "k.dng", np.full((32, 48), 100, np.uint16), "RGGB",
                  white_level=4095, model="simulated Kämera ☃", description="Ä")
    assert read_raw(p).shape == (32, 48)
