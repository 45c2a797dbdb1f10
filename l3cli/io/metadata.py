"""Shot metadata of raw files: orientation, camera, exposure, and writing it into renders.

:func:`read_shot_metadata` collects what a raw file says about the shot, in
one flat dict with the keys of :data:`SHOT_KEYS` (absent keys are left out):

``orientation``
    EXIF orientation 1-8 (1 = stored upright). From LibRaw's ``sizes.flip``
    for anything rawpy reads (DNG, NEF, CR2, ...), mapped as LibRaw maps the
    TIFF Orientation tag (:data:`LIBRAW_FLIP_TO_EXIF`).
``make``, ``model``, ``datetime_original``, ``iso``, ``exposure_time``, ``f_number``, ``lens``
    From the file's TIFF/EXIF tags (tifffile) where the raw is TIFF-based
    (DNG, NEF, CR2, ARW, PEF, ...), else from what LibRaw reports through
    rawpy (``other``, ``lens``: ISO, shutter, aperture, timestamp, lens).
``as_shot_neutral``, ``as_shot_white_xy``, ``color_matrix1``
    A DNG's AsShotNeutral (camera neutral), AsShotWhiteXY and ColorMatrix1
    (XYZ -> camera), where present; :mod:`l3cli.whitebalance.model` cross-checks
    them with LibRaw's camera white balance.

:func:`exif_attributes` turns such a dict into OpenImageIO attributes, which
:func:`l3cli.io.image.write_image` writes: EXIF in JPEG, PNG (``eXIf``) and
TIFF, plain header attributes in EXR. Renders keep the raw's pixel grid (the
contract: full size, pixel-aligned with the raw) and carry the orientation
as the EXIF ``Orientation`` tag, so viewers show them upright while
``l3 evaluate`` and training alignment keep working on the stored pixels.
"""

from __future__ import annotations

import datetime as _dt
import logging
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["SHOT_KEYS", "LIBRAW_FLIP_TO_EXIF", "read_shot_metadata", "exif_attributes",
           "set_spec_metadata", "dng_shot_tags", "sidecar_white_balance", "check_gains"]

log = logging.getLogger(__name__)

#: Keys :func:`read_shot_metadata` may return.
SHOT_KEYS = ("orientation", "make", "model", "datetime_original", "iso", "exposure_time",
             "f_number", "lens")

#: LibRaw's ``flip`` code -> EXIF Orientation. LibRaw sets ``flip`` from the TIFF
#: Orientation tag as ``"50132467"[tag & 7]`` (bit 0: mirror left-right, bit 1:
#: mirror top-bottom, bit 2: transpose); this is its inverse.
LIBRAW_FLIP_TO_EXIF = {0: 1, 1: 2, 3: 3, 2: 4, 4: 5, 6: 6, 7: 7, 5: 8}

_TIFF_BASED = {".dng", ".nef", ".nrw", ".cr2", ".arw", ".srf", ".sr2", ".pef", ".orf", ".rw2",
               ".3fr", ".iiq", ".mos", ".mef", ".erf", ".kdc", ".dcr", ".srw", ".tif", ".tiff"}

#: OpenImageIO attribute names of each key (EXIF names; EXR stores them as given).
_OIIO_NAMES = {
    "orientation": "Orientation",
    "make": "Make",
    "model": "Model",
    "datetime_original": "Exif:DateTimeOriginal",
    "iso": "Exif:PhotographicSensitivity",
    "exposure_time": "ExposureTime",
    "f_number": "FNumber",
    "lens": "Exif:LensModel",
}


def _num(value: Any) -> float | None:
    """A TIFF number or rational ``(num, den)`` as float, None when unusable."""
    try:
        if isinstance(value, tuple | list):
            if len(value) == 2 and value[1]:
                value = value[0] / value[1]
            elif len(value) >= 1:
                value = value[0]
        v = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def _text(value: Any) -> str | None:
    if isinstance(value, bytes):
        value = value.decode("latin-1", "replace")
    if not isinstance(value, str):
        return None
    value = value.strip("\x00 ").strip()
    return value or None


def _from_tiff(path: Path) -> dict[str, Any]:
    """Camera and exposure tags of a TIFF-based raw (IFD0 and its EXIF IFD)."""
    import tifffile

    out: dict[str, Any] = {}
    try:
        with tifffile.TiffFile(path) as tf:
            tags = tf.pages[0].tags
            flat = {t.name: t.value for t in tags}
            exif = flat.get("ExifTag")
            if isinstance(exif, dict):
                flat = {**exif, **flat}
    except Exception as exc:  # noqa: BLE001 - metadata is optional; the raw reader judges the file
        log.debug("%s: no TIFF tags (%s)", path, exc)
        return out
    for key, names in (("make", ("Make",)), ("model", ("Model",)),
                       ("datetime_original", ("DateTimeOriginal",)),
                       ("lens", ("LensModel", "Lens"))):
        for name in names:
            v = _text(flat.get(name))
            if v:
                out[key] = v
                break
    for key, tag, n in (("as_shot_neutral", "AsShotNeutral", 3),
                        ("as_shot_white_xy", "AsShotWhiteXY", 2),
                        ("color_matrix1", "ColorMatrix1", 9)):
        v = flat.get(tag)
        if isinstance(v, tuple | list) and len(v) == 2 * n:  # n (signed) rationals
            vals = [v[i] / v[i + 1] if v[i + 1] else None for i in range(0, 2 * n, 2)]
            if all(x is not None and math.isfinite(x) for x in vals):
                out[key] = [float(x) for x in vals]
    for key, names in (("iso", ("ISOSpeedRatings", "PhotographicSensitivity",
                                "RecommendedExposureIndex")),
                       ("exposure_time", ("ExposureTime",)), ("f_number", ("FNumber",))):
        for name in names:
            v = _num(flat.get(name))
            if v is not None:
                out[key] = v
                break
    return out


def _from_libraw(rp: Any) -> dict[str, Any]:
    """What LibRaw reports through rawpy: orientation, ISO, shutter, aperture, time, lens."""
    out: dict[str, Any] = {}
    flip = int(getattr(rp.sizes, "flip", 0))
    out["orientation"] = LIBRAW_FLIP_TO_EXIF.get(flip, 1)
    other = getattr(rp, "other", None)
    if other is not None:
        for key, attr in (("iso", "iso_speed"), ("exposure_time", "shutter_speed"),
                          ("f_number", "aperture")):
            v = _num(getattr(other, attr, None))
            if v is not None:
                out[key] = v
        ts = getattr(other, "timestamp", None)
        if isinstance(ts, _dt.datetime) and ts.year > 1970:
            out["datetime_original"] = ts.strftime("%Y:%m:%d %H:%M:%S")
    lens = getattr(rp, "lens", None)
    model = _text(getattr(lens, "model", None)) if lens is not None else None
    if model:
        out["lens"] = model
    return out


def read_shot_metadata(path: str | os.PathLike, rp: Any = None) -> dict[str, Any]:
    """The shot metadata of a raw file (see the module docstring).

    Parameters
    ----------
    path
        The raw file.
    rp
        An open ``rawpy.RawPy`` of it, when the caller has one (gives the
        orientation and LibRaw's exposure fields).

    Returns
    -------
    dict
        A subset of :data:`SHOT_KEYS`; TIFF tags win over LibRaw's values
        except for the orientation, which LibRaw resolves for every format.
    """
    path = Path(path)
    out: dict[str, Any] = {}
    if rp is not None:
        out.update(_from_libraw(rp))
    if path.suffix.lower() in _TIFF_BASED:
        orientation = out.get("orientation")
        out.update(_from_tiff(path))
        if orientation is not None:
            out["orientation"] = orientation
    return out


def exif_attributes(shot: dict[str, Any]) -> dict[str, Any]:
    """OpenImageIO attributes (EXIF names) for the keys of ``shot`` that are set.

    Numbers stay numbers (``Orientation`` and ISO as int, exposure time and
    f-number as float), text stays text.
    """
    attrs: dict[str, Any] = {}
    for key, name in _OIIO_NAMES.items():
        v = shot.get(key)
        if v is None:
            continue
        if key in ("orientation", "iso"):
            v = int(round(float(v)))
            if key == "orientation" and not 1 <= v <= 8:
                continue
        elif key in ("exposure_time", "f_number"):
            v = float(v)
        else:
            v = str(v)
        attrs[name] = v
    return attrs


def set_spec_metadata(spec: Any, metadata: dict[str, Any]) -> None:
    """Set typed attributes (int, float or str) on an OpenImageIO ``ImageSpec``."""
    for name, v in metadata.items():
        if isinstance(v, bool):
            v = int(v)
        if isinstance(v, int | float | str):
            spec.attribute(str(name), v)
        else:
            spec.attribute(str(name), str(v))


def _rationals(values: Any, denominator: int = 1000000) -> tuple[int, ...]:
    out: list[int] = []
    for v in np.asarray(values, dtype=np.float64).ravel():
        out += [int(round(v * denominator)), denominator]
    return tuple(out)


def dng_shot_tags(shot: dict[str, Any]) -> list[tuple]:
    """TIFF/EXIF/DNG tags (in IFD0, as DNG allows) for ``write_raw(..., shot=...)``."""
    tags: list[tuple] = []
    if "orientation" in shot:
        tags.append((274, "H", 1, int(shot["orientation"]), True))
    for code, key in ((33434, "exposure_time"), (33437, "f_number")):
        if key in shot:
            tags.append((code, "2I", 1, _rationals([float(shot[key])]), True))
    if "iso" in shot:
        tags.append((34855, "H", 1, int(shot["iso"]), True))
    if "datetime_original" in shot:
        tags.append((36867, "s", 0, str(shot["datetime_original"]), True))
    if "lens" in shot:
        tags.append((42036, "s", 0, str(shot["lens"]), True))
    if "as_shot_white_xy" in shot:  # AsShotWhiteXY (DNG writers give it or AsShotNeutral)
        tags.append((50729, "2I", 2, _rationals(shot["as_shot_white_xy"]), True))
    return tags


def sidecar_white_balance(meta: dict[str, Any], sc: Path) -> list[float] | None:
    """A raw sidecar's ``white_balance`` (validated: 3 finite numbers > 0), or None.

    Raises
    ------
    l3cli.errors.ConfigError
        A bad value; the message names the sidecar and the key.
    """
    from l3cli.errors import ConfigError, InputError

    if "white_balance" not in meta:
        return None
    v = meta["white_balance"]
    if not isinstance(v, list) or any(isinstance(x, bool | str) for x in v):
        raise ConfigError(f"{sc}: white_balance: must be 3 finite positive numbers [r, g, b], "
                          f"got {v!r}")
    try:
        return [float(x) for x in check_gains(v, f"{sc}: white_balance")]
    except InputError as exc:
        raise ConfigError(str(exc)) from None


def check_gains(values: Any, where: str) -> np.ndarray:
    """Validate white-balance multipliers ``[r, g, b]``; return them normalised to green = 1.

    The one check of a white balance's value, wherever it comes from (a
    sidecar, a raw's tags, ``--white-balance``); :mod:`l3cli.whitebalance.model`
    uses it too.

    Raises
    ------
    l3cli.errors.InputError
        Not 3 finite positive numbers (the message starts with ``where``).

    Examples
    --------
    >>> check_gains([2.0, 1.0, 1.5], "wb").tolist()
    [2.0, 1.0, 1.5]
    >>> check_gains([4, 2, 3], "wb").tolist()
    [2.0, 1.0, 1.5]
    """
    from l3cli.errors import InputError

    try:
        g = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        g = np.array([])
    if g.shape != (3,) or not np.all(np.isfinite(g)) or not np.all(g > 0):
        raise InputError(f"{where}: must be 3 finite positive numbers [r, g, b], "
                         f"got {values!r}")
    return g / g[1]
