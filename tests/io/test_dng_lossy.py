"""The lossy-JPEG DNG decoder (l3cli.io.dng_lossy) against LibRaw and the JPEG standard."""

from __future__ import annotations

import io
import logging
import subprocess
import sys

import numba
import numpy as np
import pytest
import rawpy

from l3cli.errors import InputError
from l3cli.io import dng_lossy, dng_lossy_tables, dng_lossy_tile
from l3cli.io.raw import read_raw, write_raw


@pytest.fixture
def bmd(shared_data):
    """The Blackmagic Pocket 4K DNG (12-bit lossy JPEG tiles) and its bytes."""
    path = shared_data / "raw/misc/blackmagic_pocket4k_rggb.dng"
    return path, path.read_bytes()


def _libraw(path):
    with rawpy.imread(str(path)) as rp:
        return rp.raw_image.copy(), _meta(rp)


def _meta(rp):
    return (list(rp.black_level_per_channel), rp.white_level, list(rp.camera_whitebalance),
            rp.raw_pattern.tolist(), rp.color_desc, tuple(rp.sizes),
            np.asarray(rp.rgb_xyz_matrix).tolist(), rp.raw_type)


def test_decode_is_libraw_bit_for_bit(bmd):
    """Every 16-bit value of the 9-MP frame equals LibRaw's, and so does the metadata."""
    path, data = bmd
    tiles = dng_lossy.probe(data)
    assert tiles is not None and len(tiles.offsets) == 4
    ours = dng_lossy.decode(data, tiles)
    ref, ref_meta = _libraw(path)
    assert ours.dtype == np.uint16 and ours.shape == ref.shape == (2176, 4128)
    assert np.array_equal(ours, ref)
    rp = dng_lossy.libraw_metadata(data, tiles)
    with rp:
        assert _meta(rp) == ref_meta
        assert not np.array_equal(rp.raw_image, ref)  # LibRaw decoded nothing


def test_read_raw_same_either_way(bmd, caplog):
    """read_raw: the fast decoder and LibRaw's give the same mosaic and metadata."""
    path, _ = bmd
    with caplog.at_level(logging.DEBUG, logger="l3cli.io.dng_lossy"):
        fast = read_raw(path)
    assert "decoded by l3cli.io.dng_lossy" in caplog.text
    slow = read_raw(path, libraw_only=True)
    assert np.array_equal(fast.mosaic, slow.mosaic)
    assert fast.cfa.spec == slow.cfa.spec
    assert np.array_equal(fast.black_level, slow.black_level)
    assert fast.white_level == slow.white_level
    assert fast.metadata == slow.metadata


def test_stream_ending_early_falls_back_to_libraw(bmd, tmp_path):
    """A tile whose scan ends (a marker) before its last block is not decoded here:
    read_raw hands the file to LibRaw, whose own error (data corrupted) it reports,
    word for word as when LibRaw alone reads it."""
    path, data = bmd
    tiles = dng_lossy.probe(data)
    cut = bytearray(data)
    mid = tiles.offsets[1] + tiles.counts[1] // 2
    cut[mid:mid + 2] = b"\xff\xd9"  # an end-of-image marker halfway through tile 2
    assert dng_lossy.decode(bytes(cut), tiles) is None
    bad = tmp_path / "cut.dng"
    bad.write_bytes(bytes(cut))
    messages = []
    for libraw_only in (False, True):
        with pytest.raises(InputError, match="cannot unpack raw data") as err:
            read_raw(bad, libraw_only=libraw_only)
        messages.append(str(err.value))
    assert messages[0] == messages[1]


def test_no_numba_import_for_a_quick_look(bmd):
    """A process without numba (l3 info) reads the DNG without importing numba (LibRaw,
    or the decoder's stored machine code): the import would cost more than it saves."""
    path, _ = bmd
    code = ("import sys; from l3cli.io.raw import read_raw; r = read_raw(sys.argv[1]); "
            "print(r.shape, 'numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                         text=True, check=True).stdout.split()
    assert out[-1] == "False"


def test_other_layouts_are_not_taken(tmp_path):
    """Uncompressed DNGs and files that are not DNG are left to LibRaw."""
    dn = np.random.default_rng(0).integers(0, 4095, (32, 48)).astype(np.uint16)
    dng = write_raw(tmp_path / "a.dng", dn, "RGGB", black_level=64, white_level=4095)
    assert dng_lossy.probe(dng.read_bytes()) is None
    assert dng_lossy.probe(b"not a tiff at all") is None
    raw = read_raw(dng)
    assert np.allclose(raw.mosaic, (dn.astype(float) - 64) / (4095 - 64), atol=1e-6)


def test_huffman_table_standard_dc_codes():
    """ITU-T T.81 table K.3 (luminance DC): categories 0-5 have the codes 00, 010,
    011, 100, 101, 110; category 6 is 1110 and 11 is 111111110 (9 bits)."""
    counts = bytes([0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0])
    values = bytes(range(12))
    table = dng_lossy_tables.huffman_table(counts, values)
    assert table[0] == 9
    lut = table[1:]

    def look(code: str) -> tuple[int, int]:
        e = int(lut[int(code.ljust(9, "0"), 2)])
        return e >> 8, e & 0xFF

    assert look("00") == (2, 0)
    assert look("010") == (3, 1)
    assert look("110") == (3, 5)
    assert look("1110") == (4, 6)
    assert look("111111110") == (9, 11)
    assert look("111111111") == (0, 0)  # no code: dcraw's table holds zeros there


@pytest.mark.parametrize(("bits", "length", "value"),
                         [(0b000, 3, -7), (0b011, 3, -4), (0b100, 3, 4), (0b111, 3, 7),
                          (0b0, 1, -1), (0b1, 1, 1), (0, 0, 0), (0x7FF, 12, -2048)])
def test_sign_extension(bits, length, value):
    """T.81 F.2.2.1: a magnitude category's low half codes the negative values."""
    assert dng_lossy_tile._extend(bits, length) == value


@numba.njit
def _run_idct(w0, basis, out):
    dng_lossy_tile.idct(w0, basis, out)


def test_idct_is_dcraws_float32_loops():
    """The vectorised IDCT against dcraw's loops written out in float32 numpy scalars:
    the same sums in the same order, no fused multiply-add, so equal bit for bit."""
    rng = np.random.default_rng(3)
    basis = dng_lossy_tables.BASIS
    for trial in range(20):
        w0 = np.zeros(64, np.float32)
        nz = rng.choice(64, size=rng.integers(1, 64), replace=False)
        w0[nz] = (rng.integers(-2047, 2048, nz.size) * rng.integers(1, 40, nz.size)
                  ).astype(np.float32)
        out = np.empty(64, np.float32)
        _run_idct(w0, basis.ravel(), out)
        a = w0.reshape(8, 8)
        w1 = np.zeros((8, 8), np.float32)
        for i in range(8):
            for j in range(8):
                for c in range(8):
                    w1[i, j] = np.float32(w1[i, j] + np.float32(a[i, c] * basis[c, j]))
        w2 = np.zeros((8, 8), np.float32)
        for i in range(8):
            for j in range(8):
                for c in range(8):
                    w2[i, j] = np.float32(w2[i, j] + np.float32(w1[c, j] * basis[c, i]))
        assert np.array_equal(out.reshape(8, 8).view(np.uint32), w2.view(np.uint32)), trial


def test_basis_is_dcraws_cosines():
    """cs[(2x + 1) u] = cos(((2x + 1) u mod 32) pi / 16) / 2, rounded to float32."""
    for u in range(8):
        for x in range(8):
            k = (2 * x + 1) * u
            assert dng_lossy_tables.BASIS[u, x] == np.float32(np.cos((k % 32) * np.pi / 16) / 2)


@pytest.mark.parametrize("seed", range(12))
def test_corrupted_files_read_as_libraw_reads_them(bmd, tmp_path, seed):
    """Damaged copies (bytes changed in a tile's header or scan, a cut file): read_raw
    either gives exactly what LibRaw alone gives or the same one-line error; never a
    crash, never other values (where l3's decoder is unsure it hands over to LibRaw)."""
    path, data = bmd
    tiles = dng_lossy.probe(data)
    rng = np.random.default_rng(seed)
    bad = bytearray(data)
    kind = seed % 4
    t = int(rng.integers(len(tiles.offsets)))
    if kind == 0:  # a few bytes of one tile's entropy-coded data
        for _ in range(3):
            at = tiles.offsets[t] + 700 + int(rng.integers(tiles.counts[t] - 700))
            bad[at] = int(rng.integers(256))
    elif kind == 1:  # one byte of one tile's JPEG header (tables, frame, scan)
        bad[tiles.offsets[t] + int(rng.integers(2, 660))] ^= 1 << int(rng.integers(8))
    elif kind == 2:  # a 0xFF (a marker, or a stuffed byte) in the data
        bad[tiles.offsets[t] + 700 + int(rng.integers(tiles.counts[t] - 700))] = 0xFF
    else:  # the file cut inside its last tiles
        bad = bad[:tiles.offsets[-1] + int(rng.integers(tiles.counts[-1]))]
    p = tmp_path / "bad.dng"
    p.write_bytes(bytes(bad))
    results = []
    for libraw_only in (False, True):
        try:
            results.append(read_raw(p, libraw_only=libraw_only).mosaic)
        except InputError as exc:
            results.append(str(exc))
    if isinstance(results[1], str):
        assert results[0] == results[1]
    else:
        assert not isinstance(results[0], str)
        assert np.array_equal(results[0], results[1])


def test_dng_1_0_is_left_to_libraw(bmd):
    """In a DNG 1.0 file dcraw reads a 16-bit DC difference where later versions code
    -32768: not a stream this decoder takes."""
    import tifffile

    _, data = bmd
    with tifffile.TiffFile(io.BytesIO(data)) as tf:
        at = tf.pages[0].tags[50706].valueoffset
    old = bytearray(data)
    old[at:at + 4] = bytes([1, 0, 0, 0])
    assert dng_lossy.probe(data) is not None
    assert dng_lossy.probe(bytes(old)) is None
