"""Lossless-JPEG DNG tiles (compression 7, SOF3) decoded by imagecodecs, placed as LibRaw
places them.

Lossless JPEG (ITU-T T.81 annex H) is the commonest DNG compression (Adobe's
converter, most phones and cameras that write DNG). LibRaw decodes it with
dcraw's ``ljpeg_row``: a Huffman reader refilled a byte per call, one core.
The codes are exact by definition (a lossless stream has one decoding), so any
conforming decoder gives LibRaw's samples; what is LibRaw's own is where they
go (``lossless_dng_load_raw``, branch ``0xc3``): each tile's decoded samples,
``high x wide x components`` in stream order, are laid row after row of
``min(tile width, raw width)`` columns from the tile's corner, anything past
the raw's right or bottom edge dropped; then LibRaw's linearisation curve
(:mod:`l3cli.io.dng_direct` applies it).

The tiles are decoded by imagecodecs (libjpeg-turbo 3's lossless decoder,
``jpeg8_decode``, 1.6x faster here than its ``ljpeg_decode``, which is used
where the former is missing), several at a
time on a thread pool (the codec releases the GIL). imagecodecs is optional:
without it (:func:`available` is False) LibRaw decodes these files as before.
A layout LibRaw treats specially (several strips, Fuji's two-sample raws,
LibRaw's ``jh.clrs * jwide == raw_width`` case) returns None and goes to LibRaw;
a stream a decoder rejects raises :class:`~l3cli.errors.InputError` with the file's
name, as does a file cut short.
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from l3cli import buffers
from l3cli.errors import InputError

__all__ = ["available", "decode", "is_lossless"]

log = logging.getLogger(__name__)

_SOF3 = 0xC3


def _codec():
    """imagecodecs' lossless-JPEG decoder, or None."""
    try:
        import imagecodecs
    except ImportError:
        return None
    for name in ("jpeg8_decode", "ljpeg_decode"):  # libjpeg-turbo 3: 1.6x faster here
        fn = getattr(imagecodecs, name, None)
        codec = getattr(imagecodecs, name.split("_")[0].upper(), None)
        if fn is not None and getattr(codec, "available", False):
            return fn
    return None


def available() -> bool:
    """Whether imagecodecs (with a lossless-JPEG decoder) is installed."""
    return _codec() is not None


def _frame(data: bytes | memoryview, start: int, count: int) -> tuple[int, int, int] | None:
    """The (lines, samples per line, components) of a lossless (SOF3) JPEG stream at
    ``start``, or None for another kind of JPEG (or none)."""
    end = min(start + count, len(data))
    if end - start < 4 or data[start] != 0xFF or data[start + 1] != 0xD8:
        return None
    pos = start + 2
    while pos + 4 <= end:
        if data[pos] != 0xFF:
            return None
        tag = data[pos + 1]
        if tag == 0xFF:  # fill byte
            pos += 1
            continue
        seg = data[pos + 2] << 8 | data[pos + 3]
        if tag == _SOF3:
            if pos + 10 > end:
                return None
            return (data[pos + 5] << 8 | data[pos + 6], data[pos + 7] << 8 | data[pos + 8],
                    data[pos + 9])
        if 0xC0 <= tag <= 0xCF and tag not in (0xC4, 0xC8, 0xCC) or tag == 0xDA:
            return None  # another coding process, or a scan before any frame header
        pos += 2 + seg
    return None


def is_lossless(data: memoryview, layout: Any, base: int = 0) -> bool:
    """Whether the first tile (or strip) is a lossless-JPEG stream (``data``: the file's
    bytes from byte ``base``)."""
    return _frame(data, layout.offsets[0] - base, layout.counts[0]) is not None


def _workers() -> int:
    from l3cli.parallel import cpu_count

    return max(1, min(4, cpu_count()))


def decode(path, region: np.ndarray, base: int, layout: Any
           ) -> tuple[np.ndarray, np.ndarray] | None:
    """LibRaw's raw image (uint16 ``raw_height x raw_width``, before its curve) from
    ``region`` (uint8, the file from byte ``base``), twice (the array, and the same array
    as the one from :func:`l3cli.buffers.empty` to release), or None where LibRaw's layout
    is one this module leaves to it."""
    fn = _codec()
    if fn is None:
        return None
    h, w = layout.raw_height, layout.raw_width
    if layout.tile_height:
        th, tw = layout.tile_height, layout.tile_width
        n = -(-w // tw) * -(-h // th)
        if len(layout.offsets) < n:
            log.debug("%s: fewer tiles than the image needs: read by LibRaw", path)
            return None
    elif len(layout.offsets) != 1:
        log.debug("%s: lossless JPEG in several strips: read by LibRaw", path)
        return None
    else:
        th, tw, n = h, w, 1
    size = base + region.size
    spans = [(o - base, c) for o, c in zip(layout.offsets[:n], layout.counts[:n], strict=True)]
    for offset, count in spans:
        if offset < 0 or base + offset + count > size:
            raise InputError(f"{path}: cannot unpack raw data (Unexpected end of file: a "
                             f"JPEG tile ends at byte {base + offset + count}, the file has "
                             f"{size})")
    view = memoryview(region)
    frames = [_frame(view, o, c) for o, c in spans]
    if any(f is None for f in frames):
        log.debug("%s: a tile is not a lossless JPEG stream: read by LibRaw", path)
        return None
    for _lines, samples, comps in frames:  # type: ignore[misc]
        if comps > 1 and comps * samples * comps == w:
            log.debug("%s: LibRaw's jh.clrs * jwide == raw_width case: read by LibRaw", path)
            return None
    across = -(-w // tw)
    wrap = min(tw, w)
    # each stream fills exactly its tile (the usual case): tiles decode in parallel, each
    # into its own part; otherwise one after another, a later tile overwriting an earlier
    # one's overflow as in LibRaw, over zeros
    exact = tw <= w and all(f[0] * f[1] * f[2] == th * tw for f in frames)  # type: ignore
    out = buffers.empty((h, w), np.uint16)
    if not exact:
        out.fill(0)

    def one(i: int) -> None:
        offset, count = spans[i]
        try:
            tile = np.asarray(fn(view[offset:offset + count]))
        except Exception as exc:  # noqa: BLE001 - any decoder failure is a damaged file
            raise InputError(f"{path}: cannot unpack raw data (a lossless-JPEG tile: {exc})"
                             ) from None
        flat = tile.reshape(-1)
        if flat.dtype != np.uint16:
            flat = flat.astype(np.uint16)
        y0, x0 = i // across * th, i % across * tw
        rows, rest = divmod(flat.size, wrap)
        cols = min(wrap, w - x0)
        keep = min(rows, h - y0)
        if keep > 0:
            out[y0:y0 + keep, x0:x0 + cols] = flat[:keep * wrap].reshape(keep, wrap)[:, :cols]
        if rest and rows < h - y0:  # a last, partial row
            part = min(rest, cols)
            out[y0 + rows, x0:x0 + part] = flat[rows * wrap:rows * wrap + part]

    workers = min(_workers(), n) if exact else 1
    if workers > 1:
        with ThreadPoolExecutor(workers, thread_name_prefix="l3-ljpeg") as pool:
            list(pool.map(one, range(n)))
    else:
        for i in range(n):
            one(i)
    return out, out
