"""Lossy (DCT) JPEG DNG tiles, decoded as LibRaw decodes them, in a third of its time.

Blackmagic cameras (and CinemaDNG recorders) write each frame as a DNG whose
CFA tiles are 12-bit *lossy* JPEG (extended sequential DCT, marker SOF1): a
folder of such frames is a video clip. LibRaw decodes them with dcraw's
reference code (``lossless_dng_load_raw``, ``case 0xc1``, and
``ljpeg_idct``): a Huffman reader refilled a byte per call and a direct 8x8 float32 IDCT
of 1024 multiply-adds per block, about 0.12 s per 9-MP frame on one core,
a third of ``l3 render``'s CPU per file.

This module decodes the same tiles to the same 16-bit values, bit for bit,
in a third of the time (0.042 s of CPU per 9-MP frame, measured):

* the Huffman codes are read through dcraw's lookup table from a 64-bit bit
  buffer refilled a byte at a time (the same byte unstuffing, the same
  hand-over to LibRaw where a code would need bits past the end), the sign
  extension without a branch;
* the IDCT (:func:`l3cli.io.dng_lossy_tile.idct`) performs exactly dcraw's float32 operations, in
  its order and with no fused multiply-add, 8 lanes at a time: each lane
  is one of dcraw's sums;
* the final rounding (``(int)(v + 0.5)`` in double, clipped to 0..65535)
  and the linearisation table are LibRaw's.

The metadata still comes from LibRaw: :func:`libraw_metadata` hands LibRaw a
copy of the file whose tiles' JPEG start markers are blanked, so its decoder
stops at the first tile at once, while everything it parsed from the tags
(levels, white balance, matrices, sizes) is as before.

Only the layout LibRaw's ``0xc1`` branch handles is taken here (one CFA
sample per pixel, each JPEG row holding two sensor rows, whole 8x8 blocks,
no restart intervals, one 16-bit quantisation table; no opcode lists or
masked areas, where LibRaw would use the pixels it is not given here);
anything else, and any stream that ends early, returns ``None`` and the
caller lets LibRaw decode the file as usual (:func:`l3cli.io.raw.read_raw`).

References
----------
- Adobe, *Digital Negative (DNG) Specification* 1.4, section "Compression"
  (value 7: JPEG; lossy DCT allowed from DNG 1.4).
- ITU-T T.81 (1992), *JPEG*, annex F (sequential DCT, Huffman coding).
- D. Coffin, *dcraw.c* (``ljpeg_idct``), and LibRaw 0.22
  ``src/decoders/dng.cpp``: the decoder whose output this one reproduces.
"""

from __future__ import annotations

import io
import logging
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from l3cli import buffers
from l3cli.errors import InputError
from l3cli.io import fd2
from l3cli.io.dng_direct import quiet_probe
from l3cli.io.dng_lossy_tables import BASIS, SQRT1_2, ZIGZAG, fast_ac, huffman_table
from l3cli.kernel_store import Stored

__all__ = ["LossyTiles", "check_whole", "decode", "libraw_metadata", "probe", "read"]

log = logging.getLogger(__name__)

# tags of the raw IFD
_COMPRESSION_JPEG = 7
_CFA = 32803
_LINEARIZATION_TABLE = 50712
_OPCODE_LISTS = (51008, 51009, 51022)
_MASKED_AREAS = 50830  # LibRaw measures black there, in the pixels it is not given here
_DNG_VERSION = 50706
_MAX_PIXELS = 1 << 29  # larger raws (or tags claiming so) are left to LibRaw's own limits

@dataclass(frozen=True)
class LossyTiles:
    """Where a DNG's lossy JPEG tiles are and how they map onto the raw."""

    raw_height: int
    raw_width: int
    tile_height: int
    tile_width: int
    offsets: tuple[int, ...]
    counts: tuple[int, ...]
    curve: np.ndarray  # uint16[65536]: LibRaw's linearisation curve


def probe(source: str | os.PathLike | bytes) -> LossyTiles | None:
    """The lossy tile layout of a DNG (a path, or the file's bytes), or None if it has
    another one (only the file's tags are read; tifffile's warnings go to the debug log)."""
    with quiet_probe():
        return _probe(source)


def _probe(source: str | os.PathLike | bytes) -> LossyTiles | None:
    import tifffile

    try:
        with tifffile.TiffFile(io.BytesIO(source) if isinstance(source, bytes) else source) as tf:
            if not tf.is_dng:
                return None
            version = tuple(tf.pages[0].tags.valueof(_DNG_VERSION, b"\0\0\0\0"))
            if version < (1, 1, 0, 0):
                return None  # DNG 1.0: dcraw reads a 16-bit DC difference, not -32768
            pages = [p for p in tf.pages] + [s for p in tf.pages for s in (p.pages or [])]
            raws = [p for p in pages
                    if p.photometric == _CFA and not (p.subfiletype & 1)]
            if len(raws) != 1:
                return None
            p = raws[0]
            if (p.compression != _COMPRESSION_JPEG or not p.is_tiled
                    or p.samplesperpixel != 1 or p.imagedepth != 1
                    or not 0 < p.imagelength * p.imagewidth <= _MAX_PIXELS
                    or any(code in p.tags for code in (*_OPCODE_LISTS, _MASKED_AREAS))):
                return None
            curve = np.arange(65536, dtype=np.uint16)
            lin = p.tags.get(_LINEARIZATION_TABLE)
            if lin is not None:
                table = np.asarray(lin.value, dtype=np.uint16).ravel()[:65536]
                if table.size == 0:
                    return None
                curve[:table.size] = table
                curve[table.size:] = table[-1]
            return LossyTiles(int(p.imagelength), int(p.imagewidth), int(p.tilelength),
                              int(p.tilewidth), tuple(int(o) for o in p.dataoffsets),
                              tuple(int(c) for c in p.databytecounts), curve)
    except Exception as exc:  # noqa: BLE001 - not ours to judge: LibRaw reads it
        log.debug("lossy DNG probe: %s", exc)
        return None


def _tile_header(data: bytes | memoryview, start: int, count: int
                 ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, int, int] | None:
    """Parse one tile's JPEG header: (scan start, quant, DC table, AC table, lines, samples)."""
    end = start + count
    if count < 4 or data[start] != 0xFF or data[start + 1] != 0xD8:
        return None
    pos = start + 2
    quant = dc = ac = None
    sof = None
    while pos + 4 <= end:
        if data[pos] != 0xFF:
            return None
        tag = data[pos + 1]
        seg = (data[pos + 2] << 8 | data[pos + 3]) - 2
        body = bytes(data[pos + 4:pos + 4 + seg])
        if seg < 0 or len(body) != seg:
            return None
        pos += 4 + seg
        if tag == 0xDB:  # DQT: one table of 16-bit entries (dcraw keeps the last)
            if seg != 129 or body[0] >> 4 != 1:
                return None
            quant = np.frombuffer(body[1:], dtype=">u2").astype(np.int64)
        elif tag == 0xC4:  # DHT
            k = 0
            while k < seg:
                cls_id = body[k]
                if cls_id not in (0x00, 0x10):
                    return None
                counts = body[k + 1:k + 17]
                n = sum(counts)
                table = huffman_table(counts, body[k + 17:k + 17 + n])
                if cls_id == 0x00:
                    dc = table
                else:
                    ac = table
                k += 17 + n
        elif tag == 0xC1:  # SOF1: extended sequential DCT, Huffman
            if seg < 6 or body[5] != 1:
                return None
            sof = (body[1] << 8 | body[2], body[3] << 8 | body[4], body[0])
        elif tag == 0xDA:  # SOS: the entropy-coded data follows
            if quant is None or dc is None or ac is None or sof is None:
                return None
            n = 1 + 2 * body[0] + 3 if seg else 0
            # LibRaw's ljpeg_start gives up unless 1 <= precision - point transform <= 16
            if seg < n or not 1 <= sof[2] - (body[n - 1] & 15) <= 16 or not sof[0] or not sof[1]:
                return None
            return pos, quant, dc, ac, sof[0], sof[1]
        elif tag in (0x00, 0xDD, 0xC0, 0xC2, 0xC3) or 0xC5 <= tag <= 0xCF:
            return None  # restart intervals or another coding process: LibRaw's own path
    return None


#: The tile decoder (:mod:`l3cli.io.dng_lossy_tile`): stored machine code when there is
#: some for this machine, else numba's (:mod:`l3cli.kernel_store`).
_decode_tile = Stored("dng-lossy-tile", [str(Path(__file__).with_name(f)) for f in (
    "dng_lossy_tile.py", "dng_lossy_tables.py")], lambda: _numba_decode_tile())


def _numba_decode_tile() -> Any:
    from l3cli.io.dng_lossy_tile import decode_tile

    return decode_tile


def decode(data: bytes | memoryview, tiles: LossyTiles) -> np.ndarray | None:
    """The raw image (uint16, ``raw_height x raw_width``) LibRaw would decode, or None.

    None when a tile's header is one this decoder does not take or its data
    ends early: the caller then lets LibRaw decode the file.
    """
    buf = np.frombuffer(data, dtype=np.uint8)
    # every pixel is written: the tiles cover the raw and the blocks their tiles (checked)
    out = buffers.empty((tiles.raw_height, tiles.raw_width), np.uint16)
    trow = tcol = 0
    run = None  # the decoder, resolved on the first tile (the tiles' argument types agree)
    for offset, count in zip(tiles.offsets, tiles.counts, strict=True):
        if trow >= tiles.raw_height:
            break
        if offset + count > buf.size:
            return None
        try:
            head = _tile_header(data, offset, count)
        except (IndexError, ValueError):  # a segment cut short
            head = None
        if head is None:
            return None
        scan, quant, dc, ac, lines, samples = head
        # LibRaw's 0xc1 branch puts JPEG row r's halves on sensor rows 2r and 2r + 1
        if samples != 2 * tiles.tile_width or 2 * lines != tiles.tile_height:
            return None
        if lines % 8 or tiles.tile_width % 8:  # whole blocks in each half row
            return None
        args = (buf, scan, offset + count, quant, dc, ac, fast_ac(ac), lines, samples,
                tiles.tile_width, trow, tcol, tiles.curve, out, ZIGZAG, BASIS.ravel(), SQRT1_2)
        run = run or _decode_tile.function(*args)
        if run(*args) != 0:
            return None
        tcol += tiles.tile_width
        if tcol >= tiles.raw_width:
            trow += tiles.tile_height
            tcol = 0
    if trow < tiles.raw_height:
        return None
    return out


def libraw_metadata(data: bytes | memoryview, tiles: LossyTiles):
    """A :class:`rawpy.RawPy` of the file with its metadata but no pixels decoded.

    LibRaw parses the tags when it opens the file and decodes the tiles when
    it unpacks; each tile must begin with a JPEG start marker, and at the first
    that does not its decoder stops. The tiles' markers are blanked in a copy
    of the file, so ``unpack`` returns at once and every property is LibRaw's.
    """
    import rawpy

    blank = bytearray(data)
    for offset in tiles.offsets:
        blank[offset:offset + 2] = b"\0\0"
    rp = rawpy.RawPy()
    try:
        rp.open_buffer(io.BytesIO(bytes(blank)))
        rp.unpack()
    except BaseException:
        rp.close()
        raise
    return rp


def check_whole(path: str | os.PathLike, tiles: LossyTiles | None = None) -> None:
    """Refuse a lossy-JPEG DNG whose tiles lie past the end of the file (a file cut
    short, even right after its tags): LibRaw decodes what is there and leaves the rest
    black, so the file's size is the judge. Any other file passes (``tiles``: its
    :func:`probe`, made here when not given).

    Raises
    ------
    InputError
        "Unexpected end of file" (LibRaw's words), with the bytes needed and present.
    """
    tiles = probe(path) if tiles is None else tiles
    if tiles is None or not tiles.offsets:
        return
    need = max(o + c for o, c in zip(tiles.offsets, tiles.counts, strict=False))
    try:
        size = os.stat(path).st_size
    except OSError:
        return  # the reader's own open reports it
    if need > size:
        raise InputError(f"{path}: cannot unpack raw data (Unexpected end of file: the lossy "
                         f"JPEG tiles need {need} bytes, the file has {size})")


def _matches_this_libraw() -> bool:
    """Whether this decoder's values are the installed LibRaw's (checked by the tests).

    LibRaw 0.22 scales by ``float(M_SQRT1_2)``; dcraw and older LibRaw by the
    double constant (650 of the test frame's 9 M values differ), and LibRaw
    built for arm64 may fuse multiply-adds. Elsewhere LibRaw decodes.
    """
    import platform

    import rawpy

    return (platform.machine().lower() in ("x86_64", "amd64")
            and tuple(rawpy.libraw_version) >= (0, 22))


def read(path: str | os.PathLike, *, compile: bool = True
         ) -> tuple[Any, np.ndarray, np.ndarray] | None:
    """A lossy-JPEG DNG decoded here, with LibRaw's metadata; None for any other file.

    Returns (LibRaw's handle, for the metadata; the visible mosaic, a view;
    the whole decoded array, from :func:`l3cli.buffers.empty`, for the
    caller to release). None when the file is not of the layout this
    decoder takes, or anything in it is unexpected: LibRaw then reads the
    file as usual (:func:`l3cli.io.raw.read_raw`), and reports any damage.
    With ``compile`` False, also None unless the decoder's machine code is
    stored (:mod:`l3cli.kernel_store`): no numba import.
    """
    path = Path(path)
    tiles = probe(path)  # the tags only: most DNGs are not lossy
    if tiles is None:
        return None
    check_whole(path, tiles)  # a damaged file, whoever would decode it
    if not _matches_this_libraw() or not (compile or _decode_tile.stored()):
        return None
    try:
        data = path.read_bytes()
    except OSError:
        return None  # LibRaw's own read reports it
    try:
        with fd2.captured(str(path)) as said:
            rp = libraw_metadata(data, tiles)
    except Exception as exc:  # noqa: BLE001 - LibRaw's own path reports it
        log.debug("%s: lossy DNG metadata: %s", path, exc)
        return None
    for line in said:
        log.debug("LibRaw: %s", line)
    try:
        curve = np.asarray(rp.tone_curve, dtype=np.uint16)  # LibRaw's own linearisation
        sz = rp.sizes
        mosaic = None
        if curve.shape == (65536,) and (sz.raw_height, sz.raw_width) == (
                tiles.raw_height, tiles.raw_width):
            mosaic = decode(data, replace(tiles, curve=curve))
    except Exception as exc:  # noqa: BLE001 - anything unexpected: LibRaw decodes it
        log.debug("%s: lossy DNG decode: %s", path, exc)
        mosaic = None
    if mosaic is None:
        rp.close()
        log.debug("%s: lossy JPEG tiles this decoder does not take: LibRaw decodes them", path)
        return None
    log.debug("%s: lossy JPEG tiles decoded by l3cli.io.dng_lossy", path)
    return rp, mosaic[sz.top_margin:sz.top_margin + sz.height,
                      sz.left_margin:sz.left_margin + sz.width], mosaic
