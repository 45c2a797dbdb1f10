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


@pytest.mark.parametrize("black", [64, [60, 62, 64, 66]], ids=["black64", "black-per-position"])
@pytest.mark.parametrize("spec", ["RGGB", "GRBG", "BGGR", "GBRG"])
def test_dng_round_trip(tmp_path, spec, black):
    """write -> read with rawpy and with l3: same mosaic, CFA and levels; postprocess() works."""
    rng = np.random.default_rng(1)
    dn = rng.integers(64, 4095, size=(48, 64)).astype(np.uint16)
    out = write_raw(tmp_path / "a.dng", dn, spec, black_level=black, white_level=4095,
                    make="l3", model="test")
    assert out.suffix == ".dng"
    black_pos = np.broadcast_to(np.asarray(black, float), (4,))
    black_map = np.tile(black_pos.reshape(2, 2), (24, 32))
    raw = read_raw(out)
    assert raw.cfa == CFA.from_spec(spec)
    assert raw.black_level.tolist() == black_pos.tolist() and raw.white_level == 4095
    np.testing.assert_allclose(raw.mosaic, (dn - black_map) / (4095 - black_map), rtol=1e-6)
    with rawpy.imread(str(out)) as rp:
        np.testing.assert_array_equal(rp.raw_image_visible, dn)
        # LibRaw's own view of the CFA and the levels, position by position
        letters = rp.color_desc.decode()
        colors = rp.raw_colors_visible
        assert "".join(letters[colors[y, x]] for y in range(2) for x in range(2)) == spec
        per_colour = rp.black_level_per_channel
        assert [per_colour[colors[y, x]] for y in range(2) for x in range(2)] == black_pos.tolist()
        assert rp.white_level == 4095
        rgb = rp.postprocess()
    assert rgb.shape == (48, 64, 3) and rgb.dtype == np.uint8 and rgb.max() > 0


def test_dng_tags(tmp_path):
    """The DNG tags raw converters need are present (read back with tifffile)."""
    import tifffile

    out = write_raw(tmp_path / "t.dng", np.full((8, 8), 100, np.uint16), "GRBG", black_level=16,
                    white_level=1023, make="l3", model="unit", as_shot_neutral=[0.5, 1.0, 0.8])
    with tifffile.TiffFile(out) as tf:
        tags = {t.name: t.value for t in tf.pages[0].tags}
    assert tags["Make"] == "l3" and tags["Model"] == "unit"
    assert tags["UniqueCameraModel"] == "l3 unit"
    assert tuple(tags["DNGVersion"]) == (1, 4, 0, 0)
    assert tuple(tags["CFARepeatPatternDim"]) == (2, 2)
    assert tuple(tags["CFAPattern"]) == (1, 0, 2, 1)
    assert tuple(tags["BlackLevel"]) == (16, 16, 16, 16) and tags["WhiteLevel"] == 1023
    assert len(tags["ColorMatrix1"]) == 18  # 9 signed rationals
    neutral = np.array(tags["AsShotNeutral"], float).reshape(3, 2)
    np.testing.assert_allclose(neutral[:, 0] / neutral[:, 1], [0.5, 1.0, 0.8])


def test_raw_image_visible_excludes_masked_margins(tmp_path):
    """A DNG with an ActiveArea: l3 reads LibRaw's visible area, with the CFA phase there."""
    import tifffile

    h, w, top, left = 52, 70, 2, 4
    dn = np.random.default_rng(2).integers(100, 4000, (h, w)).astype(np.uint16)
    dn[:top] = 7
    dn[:, :left] = 7  # masked (optical black) margins
    one, zero = (10000, 10000), (0, 10000)
    identity = one + zero + zero + zero + one + zero + zero + zero + one  # 3x3 SRATIONAL
    tags = [(271, "s", 0, "l3", True), (272, "s", 0, "margins", True),
            (33421, "H", 2, (2, 2), True), (33422, "B", 4, (0, 1, 1, 2), True),
            (50706, "B", 4, (1, 4, 0, 0), True), (50708, "s", 0, "l3 margins", True),
            (50710, "B", 3, (0, 1, 2), True), (50711, "H", 1, 1, True),
            (50714, "I", 1, 64, True), (50717, "I", 1, 4095, True),
            (50721, "2i", 9, identity, True),  # ColorMatrix1
            (50829, "I", 4, (top, left, h, w), True)]  # ActiveArea
    path = tmp_path / "m.dng"
    tifffile.imwrite(path, dn, photometric=32803, planarconfig=1, compression=None,
                     subfiletype=0, extratags=tags, metadata=None)
    with rawpy.imread(str(path)) as rp:
        assert rp.raw_image.shape == (h, w)
        vis = rp.raw_image_visible.astype(np.float64)
        letters = rp.color_desc.decode()
        phase = [letters[c] for c in rp.raw_colors_visible[:2, :2].ravel()]
    raw = read_raw(path)
    assert raw.shape == vis.shape and raw.shape[0] < h and raw.shape[1] < w
    np.testing.assert_allclose(raw.mosaic, (vis - 64) / (4095 - 64), rtol=1e-6, atol=1e-7)
    assert [raw.cfa.channel_at(y, x) for y in range(2) for x in range(2)] == phase
    assert raw.mosaic.min() > (7.5 - 64) / (4095 - 64)  # no masked pixel got in


def test_non_dng_cfa_writes_tiff_with_sidecar(tmp_path):
    dn = np.arange(16 * 24, dtype=np.uint16).reshape(16, 24) * 10
    out = write_raw(tmp_path / "n.dng", dn, "R G/NIR B", black_level=[1, 2, 3, 4],
                    white_level=60000)
    assert out.suffix == ".tif" and sidecar_path(out).exists()
    raw = read_raw(out)
    assert raw.cfa.channels == ("R", "G", "NIR", "B")
    assert raw.black_level.tolist() == [1, 2, 3, 4]
    black = np.tile([[1, 2], [3, 4]], (8, 12))
    expect = (dn - black) / (60000 - black)  # each position: its black -> 0, white -> 1
    np.testing.assert_allclose(raw.mosaic, expect, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("spec", ["RGGB", "RGB/GBR/BRG", "R"])
@pytest.mark.parametrize("h", [3, 5, 64, 67, 131])
def test_normalise_in_blocks_equals_the_elementwise_formula(spec, h):
    """Blocks of whole CFA periods, then the rows of a partial period: every pixel is the
    float32 (DN - black_p) * (1 / (white - black_p)) of its own position, bit for bit."""
    from l3cli.cfa import CFA
    from l3cli.io.raw import _normalise

    cfa = CFA.from_spec(spec)
    ph, pw = cfa.period
    rng = np.random.default_rng(h)
    dn = rng.integers(0, 4096, (h, 37)).astype(np.uint16)
    black = rng.random((ph, pw)) * 100
    black_px = np.tile(black, (-(-h // ph), -(-37 // pw)))[:h, :37]
    want = ((dn.astype(np.float32) - black_px.astype(np.float32))
            * (1.0 / (4095.0 - black_px)).astype(np.float32))
    got = _normalise(dn, black.ravel(), 4095.0, cfa)
    np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))


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


@pytest.mark.parametrize("dtype, name", [("<u1", "uint8"), ("<u2", "uint16"), (">u2", "uint16be")])
def test_headerless_dtypes_as_in_the_contract(tmp_path, dtype, name):
    """The CONTRACT's sidecar (width, height, dtype, cfa, black_level, white_level)."""
    white = 255 if name == "uint8" else 4095
    dn = np.random.default_rng(4).integers(12, white + 1, (6, 10)).astype(dtype)
    p = tmp_path / "dump.raw"
    dn.tofile(p)
    sidecar_path(p).write_text(f'width = 10\nheight = 6\ndtype = "{name}"\ncfa = "GRBG"\n'
                               f"black_level = 12\nwhite_level = {white}\n")
    raw = read_raw(p)
    assert raw.cfa.spec == "GR/BG" and raw.shape == (6, 10)
    np.testing.assert_allclose(raw.mosaic, (dn.astype(float) - 12) / (white - 12), rtol=1e-6)


@pytest.mark.parametrize("top,left", [(1, 3), (3, 0), (0, 1)])
def test_visible_pattern_is_rawpys_tiling(top, left):
    """rawpy's raw_colors_visible: the pattern np.pad-wrapped from the raw's origin, cut."""
    from l3cli.io.raw import _visible_pattern

    pattern = np.array([[0, 1, 2], [1, 2, 0], [3, 0, 1]], np.uint8)[:, :2]  # 3x2, asymmetric
    full = np.pad(pattern, ((0, 20 - 3), (0, 20 - 2)), mode="wrap")  # as rawpy builds it
    np.testing.assert_array_equal(_visible_pattern(pattern, top, left),
                                  full[top:top + 3, left:left + 2])


@pytest.mark.parametrize("top,left", [(1, 3), (3, 0), (0, 1)])
def test_cfa_phase_with_margins_is_libraws(tmp_path, top, left):
    """The CFA and levels read with margins equal rawpy's raw_colors_visible (LibRaw keeps
    the margins even, moving its pattern instead)."""
    import tifffile

    h, w = 41, 57
    dn = np.random.default_rng(3).integers(100, 4000, (h, w)).astype(np.uint16)
    one, zero = (10000, 10000), (0, 10000)
    identity = one + zero + zero + zero + one + zero + zero + zero + one
    tags = [(271, "s", 0, "l3", True), (272, "s", 0, "margins", True),
            (33421, "H", 2, (2, 2), True), (33422, "B", 4, (1, 0, 2, 1), True),
            (50706, "B", 4, (1, 4, 0, 0), True), (50708, "s", 0, "l3 margins", True),
            (50710, "B", 3, (0, 1, 2), True), (50711, "H", 1, 1, True),
            (50713, "H", 2, (2, 2), True), (50714, "I", 4, (60, 61, 62, 63), True),
            (50717, "I", 1, 4095, True), (50721, "2i", 9, identity, True),
            (50829, "I", 4, (top, left, h, w), True)]  # ActiveArea
    path = tmp_path / "odd.dng"
    tifffile.imwrite(path, dn, photometric=32803, planarconfig=1, compression=None,
                     subfiletype=0, extratags=tags, metadata=None)
    with rawpy.imread(str(path)) as rp:
        letters = rp.color_desc.decode()
        colors = np.array(rp.raw_colors_visible)
        per_colour = list(rp.black_level_per_channel)
        vis = rp.raw_image_visible.astype(np.float64)
    raw = read_raw(path)
    assert [raw.cfa.channel_at(y, x) for y in range(2) for x in range(2)] == [
        letters[colors[y, x]] for y in range(2) for x in range(2)]
    black_map = np.array([[per_colour[c] for c in row] for row in colors])
    np.testing.assert_allclose(raw.mosaic, (vis - black_map) / (4095 - black_map), rtol=1e-6)


@pytest.mark.parametrize("shape,spec,black,white,dtype", [
    ((64, 96), "RGGB", [512] * 4, 65535, np.uint16),
    ((37, 51), "GRBG", [60, 61, 62, 63], 4095, np.uint16),
    ((36, 50), "BGGR", [60.5, 61, 62, 63], 1023, ">u2"),
    ((31, 29), [["R", "G", "B"], ["G", "B", "R"], ["B", "R", "G"]], list(range(10, 19)), 255,
     np.uint8),
    ((20, 22), "RGGB", [4, 5, 6, 7], 70000, np.uint32),
])
def test_normalise_is_the_float32_formula_pixel_by_pixel(shape, spec, black, white, dtype):
    """Each pixel: float32(DN) - float32(black_p), times float32(1 / (white - black_p))."""
    from l3cli.io.raw import _normalise

    cfa = CFA.from_spec(spec)
    ph, pw = cfa.period
    dn = np.random.default_rng(4).integers(0, white + 1, shape).astype(dtype)
    b = np.asarray(black, np.float64).reshape(ph, pw)
    got = _normalise(dn, np.asarray(black, np.float64), float(white), cfa)
    want = np.empty(shape, np.float32)
    for y in range(shape[0]):
        for x in range(shape[1]):
            bp = b[y % ph, x % pw]
            want[y, x] = ((np.float32(dn[y, x]) - np.float32(bp))
                          * np.float32(1.0 / (white - bp)))
    assert got.dtype == np.float32 and got.shape == shape
    np.testing.assert_array_equal(got.view(np.int32), want.view(np.int32))


def _libraw_reference(path):
    """l3's normalisation recomputed from rawpy's own arrays, in plain float32 numpy."""
    with rawpy.imread(str(path)) as rp:
        dn = np.array(rp.raw_image_visible)
        colors = np.array(rp.raw_colors_visible)
        black = np.asarray(rp.black_level_per_channel, np.float64)[colors]
        white = float(rp.white_level)
    scale = (1.0 / (white - black)).astype(np.float32)
    return (dn.astype(np.float32) - black.astype(np.float32)) * scale


def test_mosaic_is_libraws_data_bit_for_bit(shared_data):
    """Normalised straight from LibRaw's buffer: the whole mosaic equals the reference
    computed from a copy of it (the real 9-MP DNG, lossy-JPEG tiles, linearisation table)."""
    path = shared_data / "raw/misc/blackmagic_pocket4k_rggb.dng"
    got = read_raw(path).mosaic
    np.testing.assert_array_equal(got.view(np.int32), _libraw_reference(path).view(np.int32))


@pytest.mark.parametrize("shape", [(48, 64), (37, 51)])
def test_fixture_mosaic_is_libraws_data_bit_for_bit(tmp_path, shape):
    dn = np.random.default_rng(5).integers(0, 4096, shape).astype(np.uint16)
    path = write_raw(tmp_path / "f.dng", dn, "GBRG", black_level=[60, 61, 62, 63],
                     white_level=4095)
    got = read_raw(path).mosaic
    np.testing.assert_array_equal(got.view(np.int32), _libraw_reference(path).view(np.int32))
