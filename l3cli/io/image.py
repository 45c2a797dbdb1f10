"""Image input and output through OpenImageIO.

* EXR: float32 (or half) linear values as stored; l3 records the colour space
  in the ``l3:space`` attribute (``xyz``, ``linear-srgb``, ...).
* TIFF (16-bit), PNG (8/16-bit), JPEG (8-bit): display-encoded sRGB. Read into
  float32 in [0, 1] (still encoded); written from any l3 space by converting to
  display sRGB first (:func:`l3cli.colourspace.convert`).

Images are float32 (H, W, C), channels last.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.colourspace import check_space, convert
from l3cli.errors import InputError, OutputError
from l3cli.io.atomic import atomic_path

__all__ = ["read_image", "write_image", "IMAGE_FORMATS", "format_of"]

#: Output formats by name → file suffix.
IMAGE_FORMATS: dict[str, str] = {"exr": ".exr", "tiff": ".tif", "png": ".png", "jpg": ".jpg"}
_SUFFIX_FORMAT = {".exr": "exr", ".tif": "tiff", ".tiff": "tiff", ".png": "png", ".jpg": "jpg",
                  ".jpeg": "jpg"}


def format_of(path: str | os.PathLike) -> str:
    """The image format name of a path by its suffix (``exr``, ``tiff``, ``png``, ``jpg``)."""
    suffix = Path(path).suffix.lower()
    if suffix not in _SUFFIX_FORMAT:
        raise InputError(
            f"{path}: unknown image format {suffix!r}; use one of "
            f"{', '.join(sorted(_SUFFIX_FORMAT))}"
        )
    return _SUFFIX_FORMAT[suffix]


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
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"{path}: cannot read image ({oiio.geterror().strip() or 'unknown'})")
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
    metadata: dict[str, Any] | None = None,
) -> Path:
    """Write an image atomically; the format follows the suffix.

    Parameters
    ----------
    path
        ``.exr``, ``.tif``/``.tiff``, ``.png``, ``.jpg``/``.jpeg``.
    image
        float (H, W) or (H, W, C) in colour space ``space``.
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
    metadata
        Typed attributes, e.g. the shot's EXIF of
        :func:`l3cli.io.metadata.exif_attributes` (``Orientation``, ``Make``,
        ...): EXIF in JPEG/PNG/TIFF, header attributes in EXR.
    """
    import OpenImageIO as oiio

    path = Path(path)
    fmt = format_of(path)
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3:
        raise OutputError(f"{path}: image must be (H, W) or (H, W, C), got {img.shape}")
    if space != "data":
        space = check_space(space)
    h, w, c = img.shape
    if fmt == "exr":
        data = img
        typedesc = "half" if half else "float"
    else:
        if space not in ("data", "srgb") and c == 3:
            img = convert(img, space, "srgb")
        elif space == "srgb" or c != 3:
            img = np.clip(img, 0.0, 1.0)
        nbits = {"tiff": 16, "jpg": 8}.get(fmt, bits or 8)
        maxv = (1 << nbits) - 1
        data = np.round(np.clip(img, 0.0, 1.0) * maxv).astype(np.uint16 if nbits == 16 else np.uint8)
        typedesc = "uint16" if nbits == 16 else "uint8"
    spec = oiio.ImageSpec(w, h, c, typedesc)
    if fmt == "exr":
        spec.attribute("l3:space", space)
        spec.attribute("compression", "zip")
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
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise OutputError(f"{path}: cannot create writer ({oiio.geterror().strip()})")
        try:
            if not out.open(str(tmp), spec):
                raise OutputError(f"{path}: cannot open for writing ({out.geterror().strip()})")
            if not out.write_image(np.ascontiguousarray(data)):
                raise OutputError(f"{path}: write failed ({out.geterror().strip()})")
        finally:
            out.close()
    return path
