"""Image input and output through OpenImageIO.

* EXR: float32 (or half) linear values as stored; l3 records the colour space
  in the ``l3:space`` attribute (``xyz``, ``linear-srgb``, ...).
* TIFF (16-bit), PNG (8/16-bit), JPEG (8-bit): display-encoded sRGB. Read into
  float32 in [0, 1] (still encoded); written from any l3 space by converting to
  display sRGB first (:func:`l3cli.io.encode.display_encode`, the same integers
  as :func:`l3cli.colourspace.convert` then rounding, without colour-science).

Compression (:data:`COMPRESSIONS`, defaults :data:`DEFAULT_COMPRESSION`):
TIFF is written uncompressed by default, as dcraw/LibRaw, RawTherapee and most
raw converters do: deflate costs seconds per 16-bit image on one core and
saves little on camera noise (``lzw``/``zip`` on request). float32 EXR is
written uncompressed by default: the low mantissa bits of float renders and
targets are noise to a lossless coder, so ``zips``/``zip`` saved 0-2 % of the
file (a 9-MP render: 105 vs 107 MB; a simulated target: 905 vs 926 kB) for
5x the write time (1.6 vs 0.3 s of CPU). Half-float EXR (``--half``) keeps
``zips`` (deflate over single scanlines, read by every EXR reader): there it
halves the file (29 vs 53 MB for a 9-MP render), and ``piz`` was smaller on
one render and larger on another (``docs/performance.md``).

Images are float32 (H, W, C), channels last.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.colourspace import check_space
from l3cli.errors import InputError, OutputError
from l3cli.io import fd2
from l3cli.io.atomic import atomic_path, check_free_space

__all__ = ["read_image", "write_image", "IMAGE_FORMATS", "display_bits", "format_of", "COMPRESSIONS",
           "DEFAULT_COMPRESSION"]

#: Output formats by name → file suffix.
IMAGE_FORMATS: dict[str, str] = {"exr": ".exr", "tiff": ".tif", "png": ".png", "jpg": ".jpg"}
#: Lossless compressions l3 writes, by format (OpenImageIO's names).
COMPRESSIONS: dict[str, tuple[str, ...]] = {
    "tiff": ("none", "lzw", "zip"),
    "exr": ("none", "rle", "zips", "zip", "piz"),
}
#: The compression used when none is asked for (see the module notes for why);
#: ``exr-half``: half-float EXR.
DEFAULT_COMPRESSION: dict[str, str] = {"tiff": "none", "exr": "none", "exr-half": "zips"}
_SUFFIX_FORMAT = {".exr": "exr", ".tif": "tiff", ".tiff": "tiff", ".png": "png", ".jpg": "jpg",
                  ".jpeg": "jpg"}


#: Display bits each output format holds (None: float32).
_FORMAT_BITS = {"exr": None, "tiff": 16, "png": 8, "jpg": 8}


def format_of(path: str | os.PathLike) -> str:
    """The image format name of a path by its suffix (``exr``, ``tiff``, ``png``, ``jpg``)."""
    suffix = Path(path).suffix.lower()
    if suffix not in _SUFFIX_FORMAT:
        raise InputError(
            f"{path}: unknown image format {suffix!r}; use one of "
            f"{', '.join(sorted(_SUFFIX_FORMAT))}"
        )
    return _SUFFIX_FORMAT[suffix]


def display_bits(fmt: str) -> int | None:
    """The bits of a render for an output format (:func:`format_of`): None (float32)
    for EXR, 16 for TIFF, 8 for PNG and JPEG."""
    return _FORMAT_BITS[fmt]


def read_image(path: str | os.PathLike) -> tuple[np.ndarray, str]:
    """Read an image as float32 (H, W, C).

    Returns
    -------
    image, space
        ``space`` is the colour space: for EXR the ``l3:space`` attribute
        (default ``linear-srgb`` when absent), for other formats ``srgb``
        (display-encoded values in [0, 1]).

    Raises
    ------
    InputError
        Missing, unreadable or truncated image.
    """
    import OpenImageIO as oiio

    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    fmt = format_of(path)
    config = oiio.ImageSpec()
    # keep colour values as stored: PNG/TIFF alpha is not multiplied into them
    config.attribute("oiio:UnassociatedAlpha", 1)
    # libpng and libjpeg also print their errors on fd 2 ("libpng error: ..."); the
    # same text comes back through geterror(): keep the terminal to l3's one line
    quiet_c = fd2.captured(str(path)) if fmt != "exr" else contextlib.nullcontext()
    with quiet_c:
        inp = oiio.ImageInput.open(str(path), config)
        if inp is None:
            raise InputError(f"{path}: cannot read image "
                             f"({oiio.geterror().strip() or 'unknown'})")
        try:
            spec = inp.spec()
            data = inp.read_image(0, 0, 0, spec.nchannels, "float")
            err = inp.geterror()
            space_attr = spec.getattribute("l3:space")
        finally:
            inp.close()
    if data is None or (err and "error" in err.lower()):
        raise InputError(f"{path}: damaged or truncated image ({(err or 'no data').strip()})")
    arr = np.asarray(data, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if fmt == "exr":
        space = space_attr if isinstance(space_attr, str) and space_attr else "linear-srgb"
    else:
        space = "srgb"
    return np.ascontiguousarray(arr), space


def write_image(
    path: str | os.PathLike,
    image: np.ndarray,
    *,
    space: str = "srgb",
    half: bool = False,
    quality: int = 95,
    bits: int | None = None,
    attributes: dict[str, str] | None = None,
    compression: str | None = None,
    metadata: dict[str, Any] | None = None,
    allow_nonfinite: bool = False,
    source: str | os.PathLike | None = None,
) -> Path:
    """Write an image atomically; the format follows the suffix.

    Parameters
    ----------
    path
        ``.exr``, ``.tif``/``.tiff``, ``.png``, ``.jpg``/``.jpeg``.
    image
        float (H, W) or (H, W, C) in colour space ``space``; or, for
        TIFF/PNG/JPEG, uint8/uint16 integers already display-encoded (as
        :func:`l3cli.io.encode.display_encode` gives them), written as they
        are: uint16 for TIFF (and PNG with ``bits=16``), uint8 for JPEG/PNG.
    space
        Colour space of ``image`` (:data:`l3cli.colourspace.SPACES`), or
        ``"data"`` for non-colour data (written as is; EXR only for floats).
        EXR keeps the values and records the space; TIFF/PNG/JPEG receive
        display sRGB (3-channel images are converted, then quantised).
    half
        EXR as half floats.
    quality
        JPEG quality (1-100).
    bits
        8 or 16 for PNG (TIFF is 16, JPEG 8).
    attributes
        Extra string metadata. No ``DateTime`` is written unless given here, so
        the same image always gives the same bytes.
    compression
        TIFF or EXR compression (:data:`COMPRESSIONS`; default
        :data:`DEFAULT_COMPRESSION`). PNG and JPEG take none.
    metadata
        Typed attributes, e.g. the shot's EXIF of
        :func:`l3cli.io.metadata.exif_attributes` (``Orientation``, ``Make``,
        ...): EXIF in JPEG/PNG/TIFF, header attributes in EXR.
    allow_nonfinite
        Write the values to an EXR as they are, NaN and infinity included (a
        test's deliberately bad input). By default NaN, ±inf and (with
        ``half``) values beyond half-float range are an :class:`OutputError`;
        float pixels bound for TIFF/PNG/JPEG are checked alike before they are
        encoded (a NaN would become some integer: never an image).
    source
        The input the image was made from (a raw), named in the message when
        the image holds NaN or infinity.
    """
    path = Path(path)
    fmt = format_of(path)
    if fmt != "exr" and np.asarray(image).dtype in (np.uint8, np.uint16):
        return _write_encoded(path, fmt, np.asarray(image), space=space, quality=quality,
                              bits=bits, attributes=attributes, compression=compression,
                              metadata=metadata)
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3:
        raise OutputError(f"{path}: image must be (H, W) or (H, W, C), got {img.shape}")
    if space != "data":
        space = check_space(space)
    _check_compression(path, fmt, compression)
    if fmt == "exr":
        _check_finite(path, img, half, allow_nonfinite, source)
        data = img
        typedesc = "half" if half else "float"
    else:
        from l3cli.io.encode import display_encode

        _check_finite(path, img, False, False, source)  # the last line of defence

        data = display_encode(img, space, _bits_of(fmt, bits))
        typedesc = "uint16" if data.dtype == np.uint16 else "uint8"
    return _write(path, fmt, data, typedesc, space=space, quality=quality,
                  attributes=attributes, compression=compression, metadata=metadata)


#: Values at or beyond this magnitude become infinite as half floats (65504 is the
#: largest finite one; up to here they round to it).
HALF_LIMIT = 65520.0


def _check_finite(path: Path, img: np.ndarray, half: bool, allow_nonfinite: bool = False,
                  source: str | os.PathLike | None = None) -> None:
    """Refuse float pixels that would be stored or encoded from NaN or infinity (two
    reductions, no copy): NaN or ±inf, and with ``half`` values beyond half-float range."""
    if img.size == 0 or allow_nonfinite:
        return
    lo, hi = float(img.min()), float(img.max())
    if not (np.isfinite(lo) and np.isfinite(hi)):
        made = f" (rendered from {source})" if source is not None else ""
        raise OutputError(f"{path}: the image{made} holds NaN or infinite values; "
                          "nothing written")
    if half and max(-lo, hi) >= HALF_LIMIT:
        raise OutputError(f"{path}: values up to {max(-lo, hi):.6g} overflow half floats "
                          "(largest 65504) and would be written as infinity; write full "
                          "floats (without --half)")


def _bits_of(fmt: str, bits: int | None) -> int:
    return {"tiff": 16, "jpg": 8}.get(fmt, bits or 8)


def _check_compression(path: Path, fmt: str, compression: str | None) -> None:
    if compression is not None and compression not in COMPRESSIONS.get(fmt, ()):
        allowed = ", ".join(COMPRESSIONS.get(fmt, ())) or "none (the format has no choice)"
        raise OutputError(f"{path}: compression {compression!r} is not one for {fmt}; "
                          f"use {allowed}")


def _write_encoded(path: Path, fmt: str, data: np.ndarray, *, space: str, quality: int,
                   bits: int | None, attributes: dict[str, str] | None,
                   compression: str | None, metadata: dict[str, Any] | None = None) -> Path:
    """Write display-encoded integers (TIFF/PNG/JPEG) as they are."""
    if data.ndim == 2:
        data = data[:, :, None]
    if data.ndim != 3:
        raise OutputError(f"{path}: image must be (H, W) or (H, W, C), got {data.shape}")
    want = np.uint16 if _bits_of(fmt, bits) == 16 else np.uint8
    if data.dtype != want:
        raise OutputError(f"{path}: {fmt} takes {np.dtype(want).name} display values, got "
                          f"{data.dtype.name}")
    if space != "data":
        space = check_space(space)
    _check_compression(path, fmt, compression)
    return _write(path, fmt, data, "uint16" if want == np.uint16 else "uint8", space=space,
                  quality=quality, attributes=attributes, compression=compression,
                  metadata=metadata)


def _write(path: Path, fmt: str, data: np.ndarray, typedesc: str, *, space: str, quality: int,
           attributes: dict[str, str] | None, compression: str | None,
           metadata: dict[str, Any] | None = None) -> Path:
    """Write pixels of OpenImageIO type ``typedesc`` atomically with l3's attributes."""
    import OpenImageIO as oiio

    h, w, c = data.shape
    spec = oiio.ImageSpec(w, h, c, typedesc)
    if fmt in COMPRESSIONS:
        default = DEFAULT_COMPRESSION["exr-half" if typedesc == "half" else fmt]
        spec.attribute("compression", compression or default)
    if fmt == "exr":
        spec.attribute("l3:space", space)
    elif fmt == "jpg":
        spec.attribute("Compression", f"jpeg:{int(quality)}")
        spec.attribute("jpeg:subsampling", "4:4:4")
    if fmt != "exr" and space != "data":
        spec.attribute("oiio:ColorSpace", "sRGB")
    # OpenImageIO stamps EXR/TIFF files with the current DateTime unless one is given;
    # an empty one leaves it out, so equal pixels give byte-identical files (--seed).
    spec.attribute("DateTime", "")
    for k, v in (attributes or {}).items():
        spec.attribute(str(k), str(v))
    if metadata:
        from l3cli.io.metadata import set_spec_metadata

        set_spec_metadata(spec, metadata)
    if fmt == "jpg":  # libjpeg ends the process on a failed write: check the room first
        check_free_space(path, 2 * data.nbytes + (1 << 16))
    with atomic_path(path) as tmp:
        _encode(oiio, path, tmp, spec, data)
    return path


def _encode(oiio, path: Path, tmp: Path, spec, data: np.ndarray) -> None:
    """Write ``data`` into ``tmp`` with OpenImageIO; any error it reports is an OutputError.

    OpenImageIO's writers may return success and only record a short write in
    ``geterror()`` (PNG), or report it on close: all three are checked.
    """
    out = oiio.ImageOutput.create(str(tmp))
    if out is None:
        raise OutputError(f"{path}: cannot create writer ({oiio.geterror().strip()})")
    closed = False
    try:
        if not out.open(str(tmp), spec):
            raise OutputError(f"{path}: cannot open for writing ({out.geterror().strip()})")
        ok = out.write_image(np.ascontiguousarray(data))
        err = out.geterror().strip()
        closed = True
        ok = out.close() and ok
        err = (err + " " + out.geterror().strip()).strip()
        if err and _BENIGN_TIFF in err and err.replace(_BENIGN_TIFF, "").strip() == "":
            # OpenImageIO's TIFF writer says this of files without a colour space
            # although the file is whole: accept it when the file reads back.
            err = "" if _reads_back(oiio, tmp, spec) else err
        if not ok or err:
            raise OutputError(f"{path}: cannot write: {err or 'the encoder failed'}")
        if format_of(tmp) in ("png", "jpg") and not (_ends_whole(tmp)
                                                     and _reads_back(oiio, tmp, spec)):
            # libpng/libjpeg write through stdio and may lose a failed final write
            raise OutputError(f"{path}: cannot write: the file is truncated (disk full?)")
    finally:
        if not closed:
            out.close()


_BENIGN_TIFF = "failed TIFFWriteCustomDirectory() of the Exif data"


#: format -> (how a whole file starts, how it ends): JPEG's SOI/EOI markers, PNG's
#: signature and its IEND chunk (length 0, type, CRC).
_FRAMING = {
    "jpg": (b"\xff\xd8", b"\xff\xd9"),
    "png": (b"\x89PNG\r\n\x1a\n", b"\x00\x00\x00\x00IEND\xaeB`\x82"),
}


def _ends_whole(tmp: Path) -> bool:
    """True when the JPEG/PNG file ``tmp`` starts and ends with its format's markers.

    The encoders write the end marker last: a write lost on a full disk (stdio
    buffers flushed on close) leaves a file without it. Two reads of a few
    bytes instead of decoding the whole image again.
    """
    head, tail = _FRAMING[format_of(tmp)]
    try:
        with open(tmp, "rb") as f:
            start = f.read(len(head))
            size = f.seek(0, os.SEEK_END)
            if size < len(head) + len(tail):
                return False
            f.seek(size - len(tail))
            end = f.read(len(tail))
    except OSError:
        return False
    return start == head and end == tail


def _reads_back(oiio, tmp: Path, spec) -> bool:
    """True when ``tmp`` opens (its header) as an image of ``spec``'s size."""
    inp = oiio.ImageInput.open(str(tmp))
    if inp is None:
        oiio.geterror()
        return False
    try:
        got = inp.spec()
        return (got.width, got.height, got.nchannels) == (spec.width, spec.height,
                                                            spec.nchannels)
    finally:
        inp.close()
