"""DNGs of chosen layouts for the raw readers' tests and benchmarks, written with tifffile.

:func:`make_dng` writes a CFA mosaic as a DNG: uncompressed (8 or 16 bits, or 10/12/14
bits packed most significant bit first), in strips or tiles, little- or big-endian, or
lossless-JPEG tiles (compression 7, SOF3, by imagecodecs' libjpeg-turbo), with an optional
active area, linearisation table and opcode lists (GainMaps). LibRaw (rawpy) is the judge of what they hold.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def phone_gain_maps(h: int, w: int, *, points: tuple[int, int] = (13, 17), strength: float = 1.2,
                    seed: int = 7) -> list:
    """Four GainMaps, one per Bayer position (``Top``/``Left`` 0 or 1, pitch 2, the whole
    image), as phones and action cameras write their lens shading: a radial lift of
    ``strength`` times r² toward the corners, a little different per position."""
    from l3cli.io.dng_opcodes import GainMap

    rng = np.random.default_rng(seed)
    pv, ph = points
    maps = []
    for top, left in [(0, 0), (0, 1), (1, 0), (1, 1)]:
        v = np.linspace(0, 1, pv)[:, None] - 0.5
        u = np.linspace(0, 1, ph)[None, :] - 0.5
        g = 1 + (strength + 0.3 * rng.random()) * (v ** 2 + u ** 2)
        maps.append(GainMap(top, left, h, w, 0, 1, 2, 2, pv, ph, 1 / (pv - 1), 1 / (ph - 1),
                            0.0, 0.0, g[:, :, None].astype(np.float32)))
    return maps


def pack_bits(dn: np.ndarray, bits: int) -> np.ndarray:
    """Rows of ``bits``-bit samples packed most significant bit first, each row padded
    to whole bytes (TIFF's and LibRaw's ``getbits`` order): uint8 (rows, row bytes)."""
    rows, width = dn.shape
    row_bytes = -(-width * bits // 8)
    bitarr = ((dn[:, :, None].astype(np.uint32) >> np.arange(bits - 1, -1, -1, dtype=np.uint32))
              & 1).astype(np.uint8).reshape(rows, width * bits)
    padded = np.zeros((rows, row_bytes * 8), np.uint8)
    padded[:, :width * bits] = bitarr
    return np.packbits(padded, axis=1)


def _patch_tag(path: Path, code: int, value: int) -> None:
    """Set a one-value SHORT/LONG tag of the first IFD in place."""
    import tifffile

    with tifffile.TiffFile(path) as tf:
        tag = tf.pages[0].tags[code]
        order, at, dtype = tf.byteorder, tag.valueoffset, tag.dtype
    fmt = {3: "u2", 4: "u4"}[int(dtype)]
    with open(path, "r+b") as fh:
        fh.seek(at)
        fh.write(np.array([value], dtype=order + fmt).tobytes())


def make_dng(path: str | Path, dn: np.ndarray, *, pattern=(0, 1, 1, 2), bits: int = 16,
             byteorder: str = "<", tile: tuple[int, int] | None = None,
             rowsperstrip: int | None = None, black: int = 64, white: int | None = None,
             active_area: tuple[int, int, int, int] | None = None,
             linearization: np.ndarray | None = None, lossless_jpeg: bool = False, predictor: int = 1,
             components: int = 1,
             neutral=(0.5, 1.0, 0.7), opcode_lists: dict[int, bytes] | None = None,
             lossy_jpeg: bool = False, opcode_list2: bytes | None = None,
             opcode_list3: bytes | None = None) -> Path:
    """Write ``dn`` (uint16, H x W, values < 2**bits) as a DNG of the layout asked for.

    ``opcode_lists``: ``{2: bytes, 3: bytes}``, the OpcodeList2/3 tags' values
    (``l3cli.io.dng_opcodes.encode_gain_maps``, or any bytes); ``opcode_list2`` /
    ``opcode_list3`` the same one tag at a time, written as the cameras do
    (UNDEFINED). ``lossy_jpeg``: tiles of 12-bit lossy JPEG (SOF1, by imagecodecs),
    each JPEG row two sensor rows as Blackmagic cameras write them (``tile`` required).
    """
    import tifffile

    path = Path(path)
    h, w = dn.shape
    white = (1 << bits) - 1 if white is None else white
    tags = [
        (271, "s", 0, "l3", True), (272, "s", 0, "test camera", True),
        (33421, "H", 2, (2, 2), True), (33422, "B", 4, tuple(pattern), True),
        (50706, "B", 4, (1, 4, 0, 0), True), (50707, "B", 4, (1, 1, 0, 0), True),
        (50708, "s", 0, "l3 test camera", True), (50710, "B", 3, (0, 1, 2), True),
        (50711, "H", 1, 1, True), (50713, "H", 2, (1, 1), True),
        (50714, "I", 1, black, True), (50717, "I", 1, white, True),
        (50721, "2i", 9, (32405, 10000, -15371, 10000, -4985, 10000, -9693, 10000, 18760,
                          10000, 416, 10000, 556, 10000, -2040, 10000, 10572, 10000), True),
        (50728, "2I", 3, tuple(v for x in neutral for v in (int(x * 10000), 10000)), True),
        (50778, "H", 1, 21, True),
    ]
    if active_area is not None:
        tags.append((50829, "I", 4, tuple(active_area), True))
    lists = dict(opcode_lists or {})
    for n, data in ((2, opcode_list2), (3, opcode_list3)):
        if data is not None:
            lists[n] = data
    for n, data in lists.items():
        tags.append(({1: 51008, 2: 51009, 3: 51022}[n], "B", len(data), bytes(data), True))
    if linearization is not None:
        lin = np.asarray(linearization, np.uint16)
        tags.append((50712, "H", lin.size, tuple(int(v) for v in lin), True))
    kw: dict = {"photometric": 32803, "planarconfig": 1, "subfiletype": 0, "extratags": tags,
                "metadata": None, "byteorder": byteorder}
    if tile is not None:
        kw["tile"] = tile
    if rowsperstrip is not None:
        kw["rowsperstrip"] = rowsperstrip
    if lossy_jpeg:
        import imagecodecs

        th, tw = tile
        padded = np.zeros((-(-h // th) * th, -(-w // tw) * tw), np.uint16)
        padded[:h, :w] = dn
        tiles = [imagecodecs.jpeg8_encode(
            np.ascontiguousarray(padded[y:y + th, x:x + tw]).reshape(th // 2, 2 * tw),
            bitspersample=12, level=95)
            for y in range(0, padded.shape[0], th) for x in range(0, padded.shape[1], tw)]
        with tifffile.TiffWriter(path, byteorder=byteorder) as tw_:
            kw.pop("byteorder")
            tw_.write(iter(tiles), shape=(h, w), dtype=np.uint16, compression=7,
                      bitspersample=12, **kw)
        return path
    if lossless_jpeg and components == 2:  # as cameras write: each row as 2 interleaved halves
        import imagecodecs

        th, tw = tile if tile is not None else (h, w)
        padded = np.zeros((-(-h // th) * th, -(-w // tw) * tw), np.uint16)
        padded[:h, :w] = dn
        tiles = [imagecodecs.jpeg8_encode(
            np.ascontiguousarray(padded[y:y + th, x:x + tw]).reshape(th, tw // 2, 2),
            lossless=True, bitspersample=bits, predictor=predictor)
            for y in range(0, padded.shape[0], th) for x in range(0, padded.shape[1], tw)]
        with tifffile.TiffWriter(path, byteorder=byteorder) as tw_:
            kw.pop("byteorder")
            tw_.write(iter(tiles), shape=(h, w), dtype=np.uint16, compression=7,
                      bitspersample=bits, **kw)
        return path
    if lossless_jpeg:
        kw["compression"] = "jpeg"
        kw["compressionargs"] = {"lossless": True, "bitspersample": bits, "predictor": predictor}
        tifffile.imwrite(path, dn.astype(np.uint16), bitspersample=bits, **kw)
        return path
    if bits in (8, 16):
        tifffile.imwrite(path, dn.astype(np.uint8 if bits == 8 else np.uint16), **kw)
        return path
    if tile is not None:
        raise ValueError("packed tiles are not made here")
    packed = pack_bits(dn, bits)  # written as bytes, then the tags say what they are
    tifffile.imwrite(path, packed, **kw)
    _patch_tag(path, 256, w)
    _patch_tag(path, 258, bits)
    return path
