"""Uncompressed and lossless-JPEG DNGs read by l3, with LibRaw's metadata and values.

LibRaw gives no metadata (levels, white balance, matrices, CFA) before it has
unpacked the whole raw: for an uncompressed 12-MP DNG that is 0.13-0.16 s of
a file's read, where the pixels themselves are a copy of the file's bytes
(3 ms from the page cache). This module reads the pixels itself and still
takes every property from LibRaw:

* :func:`probe` finds the raw IFD with tifffile (the tags only) and says how
  its data is laid out: uncompressed (8 or 16 bits, or 10/12/14 bits packed
  most significant bit first), strips or tiles, either byte order; or
  lossless-JPEG (compression 7, SOF3) tiles or strips.
* :func:`libraw_metadata` opens, with LibRaw, a copy of the file in which the
  raw IFD says *JPEG* (compression 7) and the first two bytes of each strip
  or tile are blanked: LibRaw's lossless-JPEG loader finds no start-of-image
  marker at the first one and stops (``lossless_dng_load_raw``), so ``unpack``
  returns at once, while every tag LibRaw parsed (levels, white balance,
  matrices, sizes, the linearisation curve) is what it reports for the
  real file (tested against LibRaw on every layout).
* :func:`decode_uncompressed` reads the samples as LibRaw's
  ``packed_dng_load_raw`` does: from the first strip offset, rows one after
  another (strips must be contiguous, as LibRaw reads them), or tile by tile
  clipped to the raw; then LibRaw's linearisation curve.
  :mod:`l3cli.io.dng_ljpeg` decodes the lossless-JPEG tiles.

Anything else (another compression, several samples per pixel, floating-point
samples, masked areas, where LibRaw measures black in pixels it is not given
here, strips with gaps) returns None and the caller lets LibRaw read the file;
the reason goes to the debug log. A file too short for the data its tags
describe raises :class:`~l3cli.errors.InputError` naming the file.

Reference: Adobe, *Digital Negative (DNG) Specification* 1.4; LibRaw 0.22
``src/decoders/dng.cpp`` (``packed_dng_load_raw``, ``packed_tiled_dng_load_raw``,
``adobe_copy_pixel``), whose values this module reproduces.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from l3cli import buffers
from l3cli.errors import InputError
from l3cli.io import fd2

__all__ = ["Layout", "decode_uncompressed", "libraw_metadata", "probe", "quiet_probe", "read"]

log = logging.getLogger(__name__)

_CFA = 32803
_COMPRESSION_NONE = 1
_COMPRESSION_JPEG = 7
_MASKED_AREAS = 50830
_PACKED_BITS = (10, 12, 14)
_MAX_PIXELS = 1 << 29


@dataclass(frozen=True)
class Layout:
    """Where a DNG's raw samples are and how they are stored."""

    compression: int  # 1 or 7
    bits: int  # BitsPerSample
    big_endian: bool
    raw_height: int
    raw_width: int
    tile_height: int  # 0 for strips
    tile_width: int
    offsets: tuple[int, ...]
    counts: tuple[int, ...]
    compression_at: int  # file offset of the raw IFD's Compression value (a SHORT)
    file_size: int

    @property
    def at_end(self) -> bool:
        """Whether the raw data is one run of bytes that ends the file (or runs past its
        end): then everything LibRaw parses lies before it."""
        start = min(self.offsets)
        end = max(o + c for o, c in zip(self.offsets, self.counts, strict=True))
        return end >= self.file_size and sum(self.counts) == end - start


def probe(path: str | os.PathLike) -> Layout | None:
    """The raw layout of a DNG this module reads, or None (the reason in the debug log)."""
    import tifffile

    try:
        with quiet_probe(), tifffile.TiffFile(path) as tf:
            if not tf.is_dng:
                return None
            pages = list(tf.pages) + [s for p in tf.pages for s in (p.pages or [])]
            raws = [p for p in pages if p.photometric == _CFA and not (p.subfiletype & 1)]
            if len(raws) != 1:
                return _no(path, f"{len(raws)} CFA images")
            p = raws[0]
            why = _unsupported(p)
            if why:
                return _no(path, why)
            tag = p.tags[259]
            if tag.dtype != 3 or tag.count != 1:  # a SHORT: the value sits in the entry
                return _no(path, "Compression is not one SHORT")
            return Layout(int(p.compression), int(p.bitspersample), tf.byteorder == ">",
                          int(p.imagelength), int(p.imagewidth),
                          int(p.tilelength) if p.is_tiled else 0,
                          int(p.tilewidth) if p.is_tiled else 0,
                          tuple(int(o) for o in p.dataoffsets),
                          tuple(int(c) for c in p.databytecounts), int(tag.valueoffset),
                          int(tf.filehandle.size))
    except Exception as exc:  # noqa: BLE001 - not ours to judge: LibRaw reads it
        return _no(path, f"tags: {exc}")


_probing = threading.local()


@contextlib.contextmanager
def quiet_probe():
    """tifffile's log records to l3's debug log while this thread probes a DNG's tags.

    A probe only asks whether one of l3's decoders applies (here, or
    :mod:`l3cli.io.dng_lossy`); a damaged or foreign file goes on to LibRaw,
    whose one-line error is the user's message. Without this, tifffile's
    warning on such a file reached stderr only when the render's job decoded
    the file itself (not the prefetch, which reads with LibRaw alone): an
    extra line that depended on thread timing.
    """
    depth = getattr(_probing, "depth", 0)
    _probing.depth = depth + 1
    try:
        yield
    finally:
        _probing.depth = depth


class _QuietProbe(logging.Filter):
    """Drops tifffile's records in a thread inside :func:`quiet_probe` (to the debug log)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if getattr(_probing, "depth", 0):
            log.debug("DNG probe, tifffile: %s", record.getMessage())
            return False
        return True


logging.getLogger("tifffile").addFilter(_QuietProbe())


def _unsupported(p) -> str | None:
    """Why this module leaves the raw page ``p`` to LibRaw (None if it takes it)."""
    if p.compression not in (_COMPRESSION_NONE, _COMPRESSION_JPEG):
        return f"compression {int(p.compression)}"
    if p.samplesperpixel != 1 or p.imagedepth != 1 or p.sampleformat != 1:
        return "not one unsigned integer sample per pixel"
    if not 0 < p.imagelength * p.imagewidth <= _MAX_PIXELS:
        return "size"
    if _MASKED_AREAS in p.tags:
        return "masked areas (LibRaw measures black in them)"
    if not p.dataoffsets:
        return "no data offsets"
    if p.compression == _COMPRESSION_NONE and p.bitspersample not in (8, 16, *_PACKED_BITS):
        return f"{p.bitspersample}-bit samples"
    return None


def _no(path, why: str) -> None:
    log.debug("%s: read by LibRaw (%s)", path, why)
    return None


class _Bytes:
    """What ``rawpy.RawPy.open_buffer`` reads: ``read()`` returns these bytes (no copy)."""

    def __init__(self, data: bytes) -> None:
        self.data = data

    def read(self) -> bytes:
        return self.data


def libraw_metadata(data: bytes | memoryview | np.ndarray, layout: Layout):
    """A :class:`rawpy.RawPy` of the file with LibRaw's metadata and no pixels decoded.

    ``data`` is the file's bytes from its start: all of them, or (where the raw
    data ends the file, :attr:`Layout.at_end`) those before the raw data. The
    copy handed to LibRaw says compression 7 (lossless JPEG) and has the first
    two bytes of every strip or tile zeroed (or zeros in their place): LibRaw's
    loader stops at the first, which has no JPEG start marker (see the module
    docstring).
    """
    import rawpy

    view = memoryview(data).cast("B")
    order = "big" if layout.big_endian else "little"
    patches = [(layout.compression_at, _COMPRESSION_JPEG.to_bytes(2, order))]
    patches += [(o, b"\0\0") for o in sorted(set(layout.offsets)) if o + 2 <= len(view)]
    pieces, at = [], 0
    for where, value in sorted(patches):
        if where < at:
            continue
        pieces += [view[at:where], value]
        at = where + len(value)
    pieces.append(view[at:])
    if len(view) < layout.offsets[0] + 16:  # zeros where LibRaw looks for the first marker
        pieces.append(bytes(layout.offsets[0] + 16 - len(view)))
    rp = rawpy.RawPy()
    try:
        rp.open_buffer(_Bytes(b"".join(pieces)))
        rp.unpack()
    except BaseException:
        rp.close()
        raise
    return rp


def _cut_short(path, need: int, size: int) -> InputError:
    """LibRaw's words for it, and the sizes."""
    return InputError(f"{path}: cannot unpack raw data (Unexpected end of file: the raw data "
                      f"needs {need} bytes, the file has {size})")


def _unpack_bits(raw: np.ndarray, rows: int, width: int, bits: int) -> np.ndarray:
    """``rows`` rows of ``width`` samples of ``bits`` bits, most significant bit first, each
    row starting on a byte (LibRaw's ``getbits``), from the bytes ``raw`` (uint16 result)."""
    row_bytes = -(-width * bits // 8)
    if bits == 12 and width % 2 == 0:  # 2 samples in 3 bytes: 16-bit arithmetic suffices
        b = raw[:rows * row_bytes].reshape(rows, width // 2, 3)
        out = np.empty((rows, width // 2, 2), np.uint16)
        np.left_shift(b[:, :, 0], 4, out=out[:, :, 0], dtype=np.uint16)
        out[:, :, 0] |= b[:, :, 1] >> 4
        np.bitwise_and(b[:, :, 1], 15, out=out[:, :, 1], dtype=np.uint16)
        out[:, :, 1] <<= 8
        out[:, :, 1] |= b[:, :, 2]
        return out.reshape(rows, width)
    group = bits // 2  # 4 samples in bits / 2 bytes (bits even)
    groups = -(-width // 4)
    src = raw[:rows * row_bytes].reshape(rows, row_bytes)
    if groups * group != row_bytes:
        padded = np.zeros((rows, groups * group), np.uint8)
        padded[:, :row_bytes] = src
        src = padded
    src = src.reshape(rows, groups, group)
    word = np.zeros((rows, groups), np.uint64)
    for k in range(group):
        word <<= np.uint64(8)
        word |= src[:, :, k]
    out = np.empty((rows, groups, 4), np.uint16)
    mask = np.uint64((1 << bits) - 1)
    for j in range(4):
        out[:, :, j] = (word >> np.uint64(bits * (3 - j))) & mask
    return out.reshape(rows, groups * 4)[:, :width]


def _samples(path, region: np.ndarray, base: int, offset: int, rows: int, width: int,
             layout: Layout) -> np.ndarray:
    """``rows`` x ``width`` samples stored from file byte ``offset`` (``region`` holds the
    file from byte ``base``): a view of ``region`` for 8 bits and native 16 bits."""
    bits = layout.bits
    start = offset - base
    need = start + -(-width * bits // 8) * rows
    if need > region.size:
        raise _cut_short(path, base + need, base + region.size)
    if bits == 16:
        dt = np.dtype(">u2" if layout.big_endian else "<u2")
        out = region[start:need].view(dt).reshape(rows, width)
        return out if dt.isnative else out.byteswap().view(np.uint16)
    if bits == 8:
        return region[start:need].reshape(rows, width)
    return _unpack_bits(region[start:need], rows, width, bits)


def decode_uncompressed(path, region: np.ndarray, base: int, layout: Layout
                        ) -> tuple[np.ndarray, np.ndarray | None] | None:
    """LibRaw's raw image of an uncompressed DNG (before its curve), from ``region`` (uint8,
    the file from byte ``base``): (the image, which may be a view of ``region``; the array
    from :func:`l3cli.buffers.empty` that holds it, if not ``region``, else None).

    None where LibRaw would not read the strips as one run of rows.
    """
    h, w = layout.raw_height, layout.raw_width
    if not layout.tile_height:
        offsets, counts = layout.offsets, layout.counts
        if any(o + c != n for o, c, n in zip(offsets, counts, offsets[1:], strict=False)):
            return _no(path, "strips with gaps (LibRaw reads one run of rows)")
        return _samples(path, region, base, offsets[0], h, w, layout), None
    th, tw = layout.tile_height, layout.tile_width
    across, n = -(-w // tw), -(-w // tw) * -(-h // th)
    if len(layout.offsets) < n:
        return _no(path, "fewer tiles than the image needs")
    out = buffers.empty((h, w), np.uint8 if layout.bits == 8 else np.uint16)
    for i, offset in enumerate(layout.offsets[:n]):
        y, x = i // across * th, i % across * tw
        rows, cols = min(th, h - y), min(tw, w - x)
        out[y:y + rows, x:x + cols] = _samples(path, region, base, offset, rows, tw,
                                               layout)[:, :cols]
    return out, out


def read(path: str | os.PathLike) -> tuple[Any, np.ndarray, np.ndarray | None] | None:
    """An uncompressed or lossless-JPEG DNG read here, with LibRaw's metadata; None for any
    other file (LibRaw then reads it, and reports any damage).

    Returns (LibRaw's handle, for the metadata; the visible mosaic; the array from
    :func:`l3cli.buffers.empty` it is a view of, for the caller to release).

    The raw data is read once into a buffer from :func:`l3cli.buffers.empty`
    (in a folder render, a recycled one: no fresh pages to fault in per file),
    and 16-bit samples in the machine's byte order are used where they lie.
    Where the raw data ends the file (most writers), LibRaw is given only the
    bytes before it.

    Raises
    ------
    InputError
        The file is shorter than the data its tags describe.
    """
    path = Path(path)
    layout = probe(path)
    if layout is None:
        return None
    if layout.compression == _COMPRESSION_JPEG:
        from l3cli.io import dng_ljpeg

        if not dng_ljpeg.available():
            return _no(path, "lossless JPEG: imagecodecs is not installed")
    base = min(layout.offsets) if layout.at_end else 0
    try:
        with open(path, "rb") as fh:
            if layout.compression == _COMPRESSION_JPEG:  # lossy JPEG (dng_lossy's) reads on
                fh.seek(layout.offsets[0])
                if not dng_ljpeg.is_lossless(memoryview(fh.read(1 << 16)), layout,
                                             layout.offsets[0]):
                    return _no(path, "JPEG tiles that are not lossless (SOF3)")
                fh.seek(0)
            head = fh.read(base) if base else None
            region = buffers.empty((max(0, layout.file_size - base),), np.uint8)
            fh.seek(base)
            got = fh.readinto(region)
    except OSError:
        return None  # LibRaw's own read reports it
    region = region[:got] if got < region.size else region
    tags = head if head is not None else region
    try:
        with fd2.captured(str(path)) as said:
            rp = libraw_metadata(tags, layout)
    except Exception as exc:  # noqa: BLE001 - LibRaw's own path reports it
        return _no(path, f"metadata: {exc}")
    for line in said:
        log.debug("LibRaw: %s", line)
    try:
        return _decode(path, region, base, layout, rp)
    except InputError:
        rp.close()
        raise
    except Exception as exc:  # noqa: BLE001 - anything unexpected: LibRaw reads the file
        rp.close()
        return _no(path, f"decode: {type(exc).__name__}: {exc}")


def _decode(path: Path, region: np.ndarray, base: int, layout: Layout, rp) -> tuple | None:
    sz = rp.sizes
    curve = np.asarray(rp.tone_curve, dtype=np.uint16)
    if (sz.raw_height, sz.raw_width) != (layout.raw_height, layout.raw_width):
        rp.close()
        return _no(path, "LibRaw's raw size is not the tags'")
    if curve.shape != (65536,):
        rp.close()
        return _no(path, "no linearisation curve from LibRaw")
    if layout.compression == _COMPRESSION_JPEG:
        from l3cli.io import dng_ljpeg

        got = dng_ljpeg.decode(path, region, base, layout)
    else:
        got = decode_uncompressed(path, region, base, layout)
    if got is None:
        rp.close()
        return None
    raw, owner = got
    if owner is None:
        owner = region  # raw is a view of it
    else:
        buffers.release(region)
    if raw.dtype != np.uint16 or not np.array_equal(curve, np.arange(65536, dtype=np.uint16)):
        mapped = buffers.empty(raw.shape, np.uint16)
        np.take(curve, raw, out=mapped)
        del raw
        buffers.release(owner)
        raw = owner = mapped
    log.debug("%s: raw data read by l3cli.io.dng_direct (compression %d, %d bits)",
              path, layout.compression, layout.bits)
    return rp, raw[sz.top_margin:sz.top_margin + sz.height,
                   sz.left_margin:sz.left_margin + sz.width], owner
