"""Raw mosaic output: :func:`write_raw` (DNG, or a 16-bit TIFF + sidecar) and the
sidecar naming rule (:func:`sidecar_path`) that the reader shares.

Split from :mod:`l3cli.io.raw` (the reader), which re-exports both names.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.cfa import CFA
from l3cli.errors import ConfigError, InputError
from l3cli.io.atomic import atomic_path
from l3cli.io.metadata import dng_shot_tags

__all__ = ["write_raw", "sidecar_path", "per_position"]


def sidecar_path(path: str | os.PathLike) -> Path:
    """The sidecar of a raw file: ``NAME.raw`` → ``NAME.raw.toml``."""
    path = Path(path)
    return path.with_name(path.name + ".toml")


def _number(value: Any, key: str, where: str) -> float:
    """A finite real number from a sidecar (bools and strings are refused)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ConfigError(f"{where}: {key} must be a number, got {value!r}")
    v = float(value)
    if not np.isfinite(v):
        raise ConfigError(f"{where}: {key} must be finite, got {value!r}")
    return v


def per_position(value: Any, cfa: CFA, where: str) -> np.ndarray:
    """A sidecar's ``black_level`` (one number, or one per CFA position) per position."""
    if isinstance(value, np.ndarray):
        value = value.ravel().tolist()
    items = list(value) if isinstance(value, list | tuple) else [value]
    arr = np.array([_number(v, "black_level", where) for v in items], dtype=np.float64)
    if arr.size == 0:
        raise ConfigError(f"{where}: black_level is an empty list")
    if arr.size == 1:
        return np.full(cfa.n_positions, arr[0])
    if arr.size != cfa.n_positions:
        raise ConfigError(
            f"{where}: black_level has {arr.size} values; give one, or one per CFA position "
            f"({cfa.n_positions} for {cfa.spec})"
        )
    return arr


def _rational(values: np.ndarray, denominator: int = 10000) -> list[int]:
    out: list[int] = []
    for v in np.asarray(values, dtype=np.float64).ravel():
        out += [int(round(v * denominator)), denominator]
    return out


#: XYZ (D65) → linear sRGB; a sensible ColorMatrix1 for a camera whose raw
#: channels are close to linear sRGB.
_XYZ_TO_SRGB = np.array(
    [[3.2404542, -1.5371385, -0.4985314],
     [-0.9692660, 1.8760108, 0.0415560],
     [0.0556434, -0.2040259, 1.0572252]]
)


def write_raw(
    path: str | os.PathLike,
    mosaic: np.ndarray,
    cfa: CFA | str,
    *,
    black_level: float | np.ndarray = 0,
    white_level: float = 65535,
    color_matrix: np.ndarray | None = None,
    as_shot_neutral: np.ndarray | None = None,
    make: str = "l3",
    model: str = "simulated camera",
    description: str = "",
    shot: dict[str, Any] | None = None,
) -> Path:
    """Write an integer CFA mosaic as DNG, or as a 16-bit TIFF + sidecar.

    Parameters
    ----------
    path
        Output path. A ``.dng`` path whose CFA has no DNG colour codes (W, NIR,
        ...) is written as ``.tif`` with a ``.tif.toml`` sidecar instead.
    mosaic
        (H, W) integer digital numbers (cast to uint16).
    cfa
        The CFA, phase at ``mosaic[0, 0]``.
    black_level, white_level
        Levels in DN (black: scalar or one per CFA position).
    color_matrix
        ColorMatrix1 (XYZ → camera, 3x3, D65) for 3-colour CFAs; defaults to
        the XYZ → linear sRGB matrix.
    as_shot_neutral
        Camera neutral (white balance) per colour, defaults to ones.
    make, model, description
        Identification tags.
    shot
        DNG only: shot metadata with keys of :data:`l3cli.io.metadata.SHOT_KEYS`
        (``orientation`` 1-8, ``datetime_original``, ``iso``, ``exposure_time``,
        ``f_number``, ``lens``, ``as_shot_white_xy``), written as the TIFF/EXIF/DNG
        tags of IFD0.

    Returns
    -------
    Path
        The path written (may differ in suffix from ``path``).
    """
    import tifffile

    cfa = CFA.from_spec(cfa)
    path = Path(path)
    mosaic = np.asarray(mosaic)
    if mosaic.ndim != 2:
        raise InputError(f"{path}: mosaic must be 2-D, got shape {mosaic.shape}")
    if mosaic.dtype.kind == "f":
        raise InputError(f"{path}: write_raw needs integer DN, got {mosaic.dtype}")
    dn = np.clip(mosaic, 0, 65535).astype(np.uint16)
    black = per_position(black_level, cfa, str(path))
    codes = cfa.dng_codes()
    colours = sorted(set(codes)) if codes else []
    if codes is None or path.suffix.lower() not in (".dng",) or len(colours) != 3:
        out = path if path.suffix.lower() in (".tif", ".tiff") else path.with_suffix(".tif")
        with atomic_path(out) as tmp:
            tifffile.imwrite(tmp, dn, photometric="minisblack", compression=None,
                             description=description or None, metadata=None)
        side = {
            "cfa": cfa.to_list() if any(len(c) > 1 for c in cfa.channels) else cfa.spec,
            "black_level": black.tolist() if np.ptp(black) else float(black[0]),
            "white_level": float(white_level),
            "bit_depth": 16,
            "description": description or f"{make} {model}",
        }
        sc = sidecar_path(out)
        with atomic_path(sc) as tmp:
            tmp.write_text(_toml_dumps(side))
        return out

    # TIFF ASCII tags hold 7-bit text only: a camera named "Kamera Ä" is written "Kamera ?"
    make, model, description = (t.encode("ascii", "replace").decode("ascii")
                                for t in (make, model, description))
    ph, pw = cfa.period
    cmat = _XYZ_TO_SRGB if color_matrix is None else np.asarray(color_matrix, dtype=np.float64)
    neutral = np.ones(3) if as_shot_neutral is None else np.asarray(as_shot_neutral, float)
    plane_colour = tuple(colours)
    # CFAPattern codes index the CFAPlaneColor order; keep R, G, B = 0, 1, 2.
    extratags = [
        (271, "s", 0, make, True),
        (272, "s", 0, model, True),
        (33421, "H", 2, (ph, pw), True),  # CFARepeatPatternDim
        (33422, "B", ph * pw, tuple(codes), True),  # CFAPattern
        (50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),  # DNGBackwardVersion
        (50708, "s", 0, f"{make} {model}", True),  # UniqueCameraModel
        (50710, "B", 3, plane_colour, True),  # CFAPlaneColor
        (50711, "H", 1, 1, True),  # CFALayout: rectangular
        (50713, "H", 2, (ph, pw), True),  # BlackLevelRepeatDim
        (50714, "I", ph * pw, tuple(int(round(b)) for b in black), True),  # BlackLevel
        (50717, "I", 1, int(white_level), True),  # WhiteLevel
        (50721, "2i", 9, tuple(_rational(cmat)), True),  # ColorMatrix1 (SRATIONAL)
        (50728, "2I", 3, tuple(_rational(neutral)), True),  # AsShotNeutral
        (50778, "H", 1, 21, True),  # CalibrationIlluminant1: D65
    ]
    if description:
        extratags.append((270, "s", 0, description, True))
    extratags += dng_shot_tags(shot or {})
    with atomic_path(path) as tmp:
        tifffile.imwrite(
            tmp,
            dn,
            photometric=32803,  # CFA
            planarconfig=1,
            compression=None,
            subfiletype=0,
            extratags=extratags,
            metadata=None,
        )
    return path


def _toml_dumps(d: dict[str, Any]) -> str:
    """Minimal TOML writer for flat sidecars (strings, numbers, lists)."""

    def val(v: Any) -> str:
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, list | tuple):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)

    return "".join(f"{k} = {val(v)}\n" for k, v in d.items())
