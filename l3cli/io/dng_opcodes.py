"""DNG opcode lists: the ``GainMap`` opcodes a camera writes for its lens shading.

DNG 1.3 added opcode lists, processing steps a reader applies to the raw
data: ``OpcodeList1`` (tag 51008) to the stored values, ``OpcodeList2``
(51009) after linearisation (black level subtracted, scaled to 0..1: l3's
normalised mosaic), ``OpcodeList3`` (51022) after demosaicing. Phones write
their lens-shading correction as ``GainMap`` opcodes (ID 9) in OpcodeList2,
one per CFA position (``Top``/``Left`` 0 or 1, pitch 2).

The binary layout (DNG specification 1.4, chapter 7; big-endian):

* list: ``uint32 count``, then ``count`` opcodes;
* opcode: ``uint32 id``, ``uint8[4] dng_version``, ``uint32 flags`` (bit 0:
  optional, bit 1: preview only), ``uint32 n_bytes``, then ``n_bytes`` of
  parameters;
* GainMap parameters: ``uint32 Top, Left, Bottom, Right, Plane, Planes,
  RowPitch, ColPitch, MapPointsV, MapPointsH``, ``float64 MapSpacingV,
  MapSpacingH, MapOriginV, MapOriginH``, ``uint32 MapPlanes``, then
  ``float32 MapGain[MapPointsV][MapPointsH][MapPlanes]``.

:func:`read_gain_maps` reads them from the raw IFD of a DNG (tifffile reads
the tags), and :func:`dng_gain_maps` is what :func:`l3cli.io.raw.read_raw`
calls on every DNG: the parsed maps ride on the :class:`~l3cli.io.raw.RawImage`
(``gain_maps``), not yet applied. This layer parses; the model applies them
as the DNG SDK does (:mod:`l3cli.lens.gainmaps`: to the mosaic, or folded into the
render's tile kernel). OpcodeList3's maps act on colour planes after
demosaicing; l3 applies them to the mosaic's pixels of each plane's colour
(the maps are smooth, so this is what the camera does up to the demosaic's
blur of the gain). Other opcodes are left out (logged).

A map is checked against the image it acts on before any pixel is touched
(:func:`check_gain_map`): its planes among the image's planes, its area
inside the image, its pitches within its area, its grid no finer than the
pixels, its gains finite and within the DNG SDK's range for gains
(:data:`GAIN_RANGE`); a list holds at most :data:`MAX_GAIN_MAPS` maps. So the
work of applying them is bounded by the image, never by a field of the file.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.errors import InputError
from l3cli.startup import stop_if_interrupted

__all__ = ["GAIN_MAP", "GAIN_RANGE", "MAX_GAIN_MAPS", "OPCODE_LIST2", "OPCODE_LIST3", "GainMap",
           "parse_opcode_list", "check_gain_map", "encode_gain_maps", "read_gain_maps",
           "DngGainMaps", "dng_gain_maps"]

log = logging.getLogger(__name__)

#: The gains a lens-shading correction may give anywhere on a sensor, a DNG ``GainMap``'s
#: and a table's stored field alike (:mod:`l3cli.lens.field` takes it from here): the DNG
#: SDK's range for gain-map entries (``kProfileGainTableMap_MinGainValue``/``MaxGainValue``
#: in ``dng_sdk_limits.h``, 1/4096 .. 4096). A lens darkens its corners by a few stops at
#: most (cameras' maps hold gains of about 1 to 8); beyond this range a gain only
#: amplifies noise, or, applied twice, overflows float32.
GAIN_RANGE = (1.0 / 4096.0, 4096.0)

#: Opcode ID of GainMap.
GAIN_MAP = 9
#: TIFF tags of the opcode lists applied after linearisation and after demosaicing.
OPCODE_LIST2, OPCODE_LIST3 = 51009, 51022
_CFA = 32803
_HEAD = struct.Struct(">10I4dI")  # the GainMap parameters before the gains
#: GainMaps per opcode list at most: a camera writes one per CFA position or colour
#: plane (4 for a Bayer phone's OpcodeList2); each map's work is the whole image's.
MAX_GAIN_MAPS = 64


@dataclass(eq=False)
class GainMap:
    """One ``GainMap`` opcode (field names as the DNG specification's, snake case).

    ``gains`` is float32 (points_v, points_h, map_planes).
    """

    top: int
    left: int
    bottom: int
    right: int
    plane: int
    planes: int
    row_pitch: int
    col_pitch: int
    points_v: int
    points_h: int
    spacing_v: float
    spacing_h: float
    origin_v: float
    origin_h: float
    gains: np.ndarray
    #: Where the map was read (``FILE: OpcodeListN, opcode K``), for messages.
    where: str = field(default="GainMap opcode", repr=False)

    @property
    def map_planes(self) -> int:
        return int(self.gains.shape[2])


def _gain_map(data: bytes, where: str) -> GainMap:
    if len(data) < _HEAD.size:
        raise InputError(f"{where}: GainMap opcode of {len(data)} bytes is shorter than its "
                         f"{_HEAD.size}-byte header")
    (top, left, bottom, right, plane, planes, row_pitch, col_pitch, pv, ph,
     sv, sh, ov, oh, n_planes) = _HEAD.unpack_from(data)
    if pv == 1:  # as the DNG SDK: one point on an axis is constant along it
        sv, ov = 1.0, 0.0
    if ph == 1:
        sh, oh = 1.0, 0.0
    n = pv * ph * n_planes
    if (pv < 1 or ph < 1 or n_planes < 1 or not (sv > 0 and sh > 0)
            or not all(np.isfinite([sv, sh, ov, oh])) or row_pitch < 1 or col_pitch < 1
            or planes < 1 or bottom <= top or right <= left):
        raise InputError(f"{where}: GainMap opcode has bad parameters (points {pv}x{ph}, "
                         f"spacing {sv:g}x{sh:g}, planes {n_planes}, pitch {row_pitch}x"
                         f"{col_pitch}, area {top},{left},{bottom},{right})")
    if len(data) != _HEAD.size + 4 * n:
        raise InputError(f"{where}: GainMap opcode holds {len(data)} bytes, its {pv}x{ph}x"
                         f"{n_planes} gains need {_HEAD.size + 4 * n}")
    gains = np.frombuffer(data, dtype=">f4", count=n, offset=_HEAD.size)
    gains = gains.astype(np.float32).reshape(pv, ph, n_planes)
    if not np.all(np.isfinite(gains)):
        raise InputError(f"{where}: GainMap opcode holds NaN or Inf gains")
    lo, hi = GAIN_RANGE
    if not (float(gains.min()) >= lo and float(gains.max()) <= hi):
        raise InputError(f"{where}: GainMap opcode holds gains from {float(gains.min()):g} to "
                         f"{float(gains.max()):g}, outside the {lo:g} .. {hi:g} a gain map "
                         "may hold")
    return GainMap(top, left, bottom, right, plane, planes, row_pitch, col_pitch, pv, ph,
                   sv, sh, ov, oh, gains, where)


def parse_opcode_list(data: bytes, where: str = "opcode list") -> list[GainMap]:
    """The GainMap opcodes of an opcode list's bytes (other opcodes are skipped).

    Raises
    ------
    InputError
        The list is cut short or a GainMap is malformed (names ``where``).
    """
    data = bytes(data)
    if len(data) < 4:
        raise InputError(f"{where}: opcode list of {len(data)} bytes has no count")
    (count,), pos, maps = struct.unpack_from(">I", data), 4, []
    if count > (len(data) - 4) // 16:  # every opcode has a 16-byte header
        raise InputError(f"{where}: opcode list claims {count} opcodes, its {len(data)} bytes "
                         f"hold at most {(len(data) - 4) // 16}")
    for i in range(count):
        if i % 4096 == 4095:  # a list of millions of tiny opcodes: a signal still ends it
            stop_if_interrupted()
        if pos + 16 > len(data):
            raise InputError(f"{where}: opcode list ends inside opcode {i + 1} of {count}")
        op, version, flags, n = struct.unpack_from(">I4sII", data, pos)
        pos += 16
        if pos + n > len(data):
            raise InputError(f"{where}: opcode {i + 1} of {count} (ID {op}) claims {n} bytes, "
                             f"{len(data) - pos} remain")
        if op == GAIN_MAP:
            if len(maps) == MAX_GAIN_MAPS:
                raise InputError(f"{where}: more than {MAX_GAIN_MAPS} GainMap opcodes (a "
                                 "camera writes one per CFA position or colour plane)")
            maps.append(_gain_map(data[pos:pos + n], f"{where}, opcode {i + 1}"))
        else:
            log.info("%s: opcode %d (ID %d, flags %d) is not applied by l3", where, i + 1, op,
                     flags)
        pos += n
    return maps


def check_gain_map(gm: GainMap, shape: tuple[int, int], n_planes: int) -> None:
    """Refuse a map that does not fit the image it acts on (``shape``: the normalised
    mosaic's (H, W); ``n_planes``: 1 for OpcodeList2's one-plane image, the colours for
    OpcodeList3's).

    Raises
    ------
    InputError
        Naming the file, the opcode and the field: planes beyond the image's, an area
        outside the image, a pitch beyond the area, more map points than pixels along an
        axis, more map planes than the image has.
    """
    h, w = int(shape[0]), int(shape[1])
    where = gm.where
    if gm.plane >= n_planes or gm.planes > n_planes - gm.plane:
        raise InputError(f"{where}: GainMap acts on planes {gm.plane} .. "
                         f"{gm.plane + gm.planes - 1}, the image has {n_planes} "
                         f"plane{'s' if n_planes > 1 else ''} (0 .. {n_planes - 1})")
    if gm.bottom > h or gm.right > w:
        raise InputError(f"{where}: GainMap area (top {gm.top}, left {gm.left}, bottom "
                         f"{gm.bottom}, right {gm.right}) lies outside the {w}x{h} image")
    if gm.row_pitch > gm.bottom - gm.top or gm.col_pitch > gm.right - gm.left:
        raise InputError(f"{where}: GainMap pitch {gm.row_pitch}x{gm.col_pitch} is larger "
                         f"than its {gm.bottom - gm.top}x{gm.right - gm.left} area")
    if gm.points_v > max(h, 2) or gm.points_h > max(w, 2):
        raise InputError(f"{where}: GainMap of {gm.points_v}x{gm.points_h} points is finer "
                         f"than the {w}x{h} image's pixels")
    if gm.map_planes > n_planes:
        raise InputError(f"{where}: GainMap holds {gm.map_planes} map planes, the image has "
                         f"{n_planes}")


def encode_gain_maps(maps: list[GainMap]) -> bytes:
    """An opcode list (bytes, big-endian) holding ``maps``: the inverse of
    :func:`parse_opcode_list`, for writing DNGs (flags 0, DNG version 1.3)."""
    out = [struct.pack(">I", len(maps))]
    for m in maps:
        body = _HEAD.pack(m.top, m.left, m.bottom, m.right, m.plane, m.planes, m.row_pitch,
                          m.col_pitch, m.points_v, m.points_h, m.spacing_v, m.spacing_h,
                          m.origin_v, m.origin_h, m.map_planes)
        body += np.ascontiguousarray(m.gains, dtype=">f4").tobytes()
        out.append(struct.pack(">I4sII", GAIN_MAP, bytes((1, 3, 0, 0)), 0, len(body)) + body)
    return b"".join(out)


def read_gain_maps(path: str | Path) -> tuple[list[GainMap], list[GainMap]]:
    """The GainMaps of a DNG's raw IFD: ``(OpcodeList2's, OpcodeList3's)``.

    Raises
    ------
    InputError
        A malformed opcode list (a file tifffile cannot read has none: LibRaw
        judges it).
    """
    import tifffile

    try:
        with tifffile.TiffFile(path) as tf:
            pages = list(tf.pages) + [s for p in tf.pages for s in (p.pages or [])]
            raws = [p for p in pages if p.photometric == _CFA and not (p.subfiletype & 1)]
            if not raws:
                return [], []
            tags = raws[0].tags
            lists = [tags.valueof(code) for code in (OPCODE_LIST2, OPCODE_LIST3)]
    except Exception as exc:  # noqa: BLE001 - not ours to judge: LibRaw reads the file
        log.debug("%s: DNG tags not read (%s)", path, exc)
        return [], []
    return tuple(  # type: ignore[return-value]
        [] if data is None else parse_opcode_list(bytes(data), f"{path}: OpcodeList{n}")
        for data, n in zip(lists, (2, 3), strict=True))


@dataclass(eq=False)
class DngGainMaps:
    """A DNG's GainMap opcodes, parsed, not yet applied to its mosaic.

    ``list2`` (OpcodeList2's maps) act on the mosaic as on the DNG's one-plane
    stage-2 image; ``list3`` (OpcodeList3's) on the pixels of each map plane's
    colour (planes in the CFA's R, G, B order). ``shape`` is the (height, width)
    of the image the maps' positions are relative to (the mosaic as read).
    """

    list2: list[GainMap]
    list3: list[GainMap]
    shape: tuple[int, int]

    def counts(self) -> dict[str, int]:
        """``{"OpcodeList2": n, "OpcodeList3": n}`` (``RawImage.metadata["gain_maps"]``)."""
        return {"OpcodeList2": len(self.list2), "OpcodeList3": len(self.list3)}


def dng_gain_maps(raw: Any) -> DngGainMaps | None:
    """The GainMap opcodes of the DNG ``raw`` was read from (None: it has none).

    The file layer parses; the maps are applied by the model
    (:mod:`l3cli.lens.gainmaps`): to the mosaic for callers that want it corrected
    (training, ``l3 info``), inside the tile kernel's band copy for renders.
    """
    if raw.path is None:
        return None
    list2, list3 = read_gain_maps(raw.path)
    if not (list2 or list3):
        return None
    chans = [c for c in ("R", "G", "B") if c in raw.cfa.channels]
    for maps, n_planes in ((list2, 1), (list3, len(chans))):
        for gm in maps:  # checked against the image before any pixel is touched
            check_gain_map(gm, raw.mosaic.shape, n_planes)
    return DngGainMaps(list2, list3, (int(raw.mosaic.shape[0]), int(raw.mosaic.shape[1])))
