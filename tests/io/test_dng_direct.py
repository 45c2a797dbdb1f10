"""l3's own reader of uncompressed and lossless-JPEG DNGs (l3cli.io.dng_direct, dng_ljpeg)
against LibRaw: the same mosaic, bit for bit, and the same metadata, on every layout."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np
import pytest
import rawpy

from l3cli.errors import InputError
from l3cli.io import dng_direct
from l3cli.io.raw import read_raw, write_raw
from tests.dngmake import make_dng, pack_bits


def _meta(rp):
    return (list(rp.black_level_per_channel), rp.white_level, list(rp.camera_whitebalance),
            rp.raw_pattern.tolist(), rp.color_desc, tuple(rp.sizes),
            np.asarray(rp.rgb_xyz_matrix).tolist(), rp.raw_type, list(rp.tone_curve))


def _libraw(path):
    with rawpy.imread(str(path)) as rp:
        return rp.raw_image_visible.copy(), _meta(rp)


def _ours(path):
    got = dng_direct.read(path)
    assert got is not None, "l3's reader declined the file"
    rp, vis, _ = got
    with rp:
        return np.array(vis), _meta(rp)


def _same_as_libraw(path, dn=None):
    ref, ref_meta = _libraw(path)
    ours, meta = _ours(path)
    assert ours.dtype == np.uint16 and ours.shape == ref.shape
    assert np.array_equal(ours, ref)
    assert meta == ref_meta
    if dn is not None:  # LibRaw reads what was written (the file is what it claims)
        assert np.array_equal(ref, dn)


UNCOMPRESSED = {
    "16-bit strip": {},
    "16-bit big-endian": {"byteorder": ">"},
    "16-bit strips of 7 rows": {"rowsperstrip": 7},
    "16-bit tiles, partial": {"tile": (32, 48)},
    "16-bit tiles, big-endian": {"tile": (16, 16), "byteorder": ">"},
    "8-bit": {"bits": 8},
    "8-bit tiles": {"bits": 8, "tile": (16, 32)},
    "10-bit packed": {"bits": 10},
    "12-bit packed": {"bits": 12},
    "12-bit packed, big-endian": {"bits": 12, "byteorder": ">"},
    "14-bit packed": {"bits": 14},
}


@pytest.mark.parametrize("width", [133, 134])
@pytest.mark.parametrize("name", list(UNCOMPRESSED))
def test_uncompressed_layouts(tmp_path, name, width):
    """Strips and tiles, both byte orders, 8/10/12/14/16 bits, odd and even widths."""
    kw = UNCOMPRESSED[name]
    rng = np.random.default_rng(len(name) + width)
    dn = rng.integers(0, 1 << kw.get("bits", 16), (101, width)).astype(np.uint16)
    path = make_dng(tmp_path / "a.dng", dn, **kw)
    _same_as_libraw(path, dn)


def test_active_area_and_linearisation(tmp_path):
    """LibRaw's crop (ActiveArea) and linearisation curve are applied as LibRaw applies them."""
    rng = np.random.default_rng(3)
    dn = rng.integers(0, 4096, (101, 134)).astype(np.uint16)
    lin = (np.arange(4096) * 3 // 2 + 5).astype(np.uint16)
    for kw in ({"active_area": (2, 4, 95, 127)}, {"bits": 12, "linearization": lin},
               {"linearization": (np.arange(65536) // 2).astype(np.uint16)},
               {"bits": 8, "linearization": lin[:256] * 7}):
        path = make_dng(tmp_path / "a.dng", dn >> (4 if kw.get("bits") == 8 else 0), **kw)
        _same_as_libraw(path)
    ours, _ = _ours(path)
    assert ours.max() > 255  # the 8-bit file went through its curve


def test_libraw_decodes_nothing_for_the_metadata(tmp_path):
    """The copy LibRaw reads the metadata from costs it no decode: its raw is not the file's."""
    dn = np.random.default_rng(0).integers(1, 4096, (64, 96)).astype(np.uint16)
    path = make_dng(tmp_path / "a.dng", dn, black=0)
    layout = dng_direct.probe(path)
    assert layout is not None and layout.at_end
    with dng_direct.libraw_metadata(path.read_bytes(), layout) as rp:
        assert not np.array_equal(rp.raw_image_visible, dn)


def test_data_not_at_the_end(tmp_path):
    """Bytes after the raw data (a thumbnail, say): LibRaw is given the whole file."""
    dn = np.random.default_rng(1).integers(0, 65536, (50, 70)).astype(np.uint16)
    path = make_dng(tmp_path / "a.dng", dn, tile=(16, 16))
    with open(path, "ab") as fh:
        fh.write(b"\xff\xd8" + bytes(1000))
    assert not dng_direct.probe(path).at_end
    _same_as_libraw(path, dn)


def test_simulate_and_bench_dngs(tmp_path):
    """The DNGs ``l3 simulate`` writes (write_raw): per-position black, as-shot white."""
    dn = np.random.default_rng(2).integers(0, 4096, (120, 160)).astype(np.uint16)
    path = write_raw(tmp_path / "sim.dng", dn, "GRBG", black_level=[60, 64, 62, 66],
                     white_level=4095, as_shot_neutral=np.array([0.5, 1, 0.7]),
                     shot={"iso": 200, "orientation": 6})
    _same_as_libraw(path, dn)


@pytest.mark.slow
def test_bench_synthetic_dng(tmp_path):
    """The benchmark's synthetic 9-MP DNG (``bench_product.synthetic_dng``)."""
    sys.path.insert(0, str(Path(__file__).parents[2] / "benchmarks"))
    from bench_product import synthetic_dng

    _same_as_libraw(synthetic_dng(tmp_path / "syn.dng"))


def test_read_raw_same_either_way(tmp_path, caplog):
    """read_raw: l3's reader and LibRaw's give the same RawImage (mosaic, levels, metadata)."""
    dn = np.random.default_rng(4).integers(0, 4096, (64, 96)).astype(np.uint16)
    path = write_raw(tmp_path / "sim.dng", dn, "RGGB", black_level=64, white_level=4095,
                     as_shot_neutral=np.array([0.6, 1, 0.8]), shot={"iso": 400})
    with caplog.at_level(logging.DEBUG, logger="l3cli.io.dng_direct"):
        fast = read_raw(path)
    assert "read by l3cli.io.dng_direct" in caplog.text
    slow = read_raw(path, libraw=True)
    assert np.array_equal(fast.mosaic, slow.mosaic)
    assert fast.cfa == slow.cfa and fast.white_level == slow.white_level
    assert np.array_equal(fast.black_level, slow.black_level)
    assert fast.metadata == slow.metadata


def test_truncated_file_is_one_line_error(tmp_path):
    """A DNG cut short in its raw data: InputError naming the file (not a numpy error)."""
    dn = np.zeros((64, 96), np.uint16)
    for kw in ({}, {"tile": (16, 16)}, {"bits": 12}):
        path = make_dng(tmp_path / "a.dng", dn, **kw)
        data = path.read_bytes()
        cut = tmp_path / "cut.dng"
        cut.write_bytes(data[:len(data) - 1000])
        with pytest.raises(InputError, match=r"cut\.dng: cannot unpack raw data \(Unexpected "
                           r"end of file: the raw data needs \d+ bytes, the file has \d+\)"):
            read_raw(cut)


def test_declined_layouts_go_to_libraw(tmp_path, caplog):
    """Strips with gaps and masked areas: l3 declines (and says why); LibRaw reads them."""
    dn = np.random.default_rng(5).integers(0, 65536, (40, 60)).astype(np.uint16)
    path = make_dng(tmp_path / "gaps.dng", dn, rowsperstrip=10)
    data = bytearray(path.read_bytes())
    layout = dng_direct.probe(path)
    # move the last strip 16 bytes on: a gap LibRaw does not know about
    last, count = layout.offsets[-1], layout.counts[-1]
    data += bytes(16)
    data[last + 16:last + 16 + count] = data[last:last + count]
    import tifffile

    with tifffile.TiffFile(path) as tf:
        tag = tf.pages[0].tags[273]
        at = tag.valueoffset + 4 * (len(layout.offsets) - 1)
    data[at:at + 4] = np.array([last + 16], "<u4").tobytes()
    path.write_bytes(bytes(data))
    with caplog.at_level(logging.DEBUG, logger="l3cli.io.dng_direct"):
        assert dng_direct.read(path) is None
    assert "strips with gaps" in caplog.text
    assert read_raw(path).mosaic.shape == (40, 60)


def test_pack_bits_is_msb_first():
    """The test writer's packing against the TIFF order written out by hand."""
    packed = pack_bits(np.array([[0xABC, 0x123]], np.uint16), 12)
    assert packed.tobytes() == bytes([0xAB, 0xC1, 0x23])


# ---------------------------------------------------------------- lossless JPEG
LJPEG = {
    "12-bit tiles": {"bits": 12, "tile": (64, 64)},
    "14-bit partial tiles": {"bits": 14, "tile": (32, 48)},
    "16-bit tiles": {"bits": 16, "tile": (16, 16)},
    "12-bit strip": {"bits": 12},
    "one tile wider than the image": {"bits": 12, "tile": (32, 256)},  # LibRaw wraps at 134
    "predictor 6": {"bits": 12, "tile": (32, 32), "predictor": 6},
    "predictor 7, strip": {"bits": 14, "predictor": 7},
    "2 components, tiles": {"bits": 12, "tile": (32, 64), "components": 2},
    "2 components, strip": {"bits": 14, "components": 2},
    "active area": {"bits": 12, "tile": (32, 32), "active_area": (2, 4, 95, 127)},
    "linearisation": {"bits": 12, "tile": (32, 32),
                      "linearization": (np.arange(4096) * 3 // 2 + 5).astype(np.uint16)},
}


@pytest.mark.parametrize("name", list(LJPEG))
def test_lossless_jpeg_layouts(tmp_path, name):
    """Compression 7 (SOF3): one and two components per row, tiles and strips, predictors."""
    pytest.importorskip("imagecodecs")
    kw = LJPEG[name]
    dn = np.random.default_rng(len(name)).integers(0, 1 << kw["bits"], (101, 134))
    path = make_dng(tmp_path / "a.dng", dn.astype(np.uint16), lossless_jpeg=True, **kw)
    _same_as_libraw(path, None if {"linearization", "active_area"} & set(kw)
                    or "wider" in name else dn)


def test_lossless_jpeg_damaged(tmp_path):
    """A cut or damaged lossless-JPEG DNG is a one-line InputError naming the file."""
    pytest.importorskip("imagecodecs")
    dn = np.random.default_rng(6).integers(0, 4096, (64, 64)).astype(np.uint16)
    path = make_dng(tmp_path / "a.dng", dn, lossless_jpeg=True, bits=12, tile=(32, 32))
    data = path.read_bytes()
    cut = tmp_path / "cut.dng"
    cut.write_bytes(data[:len(data) - 100])
    with pytest.raises(InputError, match=r"cut\.dng: "):
        read_raw(cut)


def test_without_imagecodecs_libraw_reads_it(tmp_path, monkeypatch):
    """imagecodecs is optional: without it LibRaw decodes lossless-JPEG DNGs as before."""
    pytest.importorskip("imagecodecs")
    from l3cli.io import dng_ljpeg

    dn = np.random.default_rng(7).integers(0, 4096, (40, 64)).astype(np.uint16)
    path = make_dng(tmp_path / "a.dng", dn, lossless_jpeg=True, bits=12, tile=(16, 32))
    monkeypatch.setattr(dng_ljpeg, "_codec", lambda: None)
    assert dng_direct.read(path) is None
    ref, _ = _libraw(path)
    raw = read_raw(path)
    assert np.allclose(raw.mosaic, (ref - 64.0) / (4095 - 64), atol=1e-6)
