"""Raw mosaic input and output.

:func:`read_raw` returns one :class:`RawImage` whatever the source:

* anything LibRaw opens (DNG, NEF, CR2, ARW, ...) through rawpy — the visible
  area (``raw_image_visible``), per-channel black levels honoured; the pixels of
  uncompressed, lossless-JPEG and lossy-JPEG DNGs are read by l3 itself
  (:mod:`l3cli.io.dng_direct`, :mod:`l3cli.io.dng_ljpeg`, :mod:`l3cli.io.dng_lossy`),
  to LibRaw's values, with LibRaw's metadata;
* a headerless dump ``NAME.raw`` described by a sidecar ``NAME.raw.toml``
  (``width``, ``height``, ``dtype``, ``cfa``, ``black_level``, ``white_level``);
* a single-channel integer image (16-bit TIFF or PNG mosaic) with a sidecar
  ``NAME.tif.toml`` / ``NAME.png.toml`` — the format :func:`write_raw` uses for
  CFAs that DNG cannot describe (W, NIR).

:func:`write_raw` writes a DNG with tifffile where the DNG colour codes describe
the CFA, and a 16-bit TIFF plus sidecar otherwise.

The mosaic is float32, normalised so that black is 0 and the white level is 1
(``(DN - black_p) / (white - black_p)`` with the black level ``black_p`` of the
pixel's CFA position; values may be slightly negative from noise).
"""

from __future__ import annotations

import logging
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from l3cli import buffers
from l3cli.cfa import CFA
from l3cli.errors import ConfigError, InputError
from l3cli.io import fd2
from l3cli.io.metadata import read_shot_metadata, sidecar_white_balance
from l3cli.io.raw_write import _number, per_position, sidecar_path, write_raw  # re-exported

__all__ = ["RawImage", "read_raw", "write_raw", "sidecar_path", "RAW_SUFFIXES"]

log = logging.getLogger(__name__)

#: File suffixes l3 treats as raw input when scanning folders (lower case).
RAW_SUFFIXES = frozenset(
    {".dng", ".nef", ".nrw", ".cr2", ".cr3", ".crw", ".arw", ".srf", ".sr2", ".orf", ".rw2",
     ".raf", ".pef", ".srw", ".x3f", ".3fr", ".iiq", ".mos", ".mef", ".erf", ".kdc", ".dcr",
     ".raw"}
)

_SIDECAR_KEYS = {
    "width": "image width in pixels (int > 0)",
    "height": "image height in pixels (int > 0)",
    "dtype": "uint8 | uint16 (little-endian) | uint16be",
    "cfa": "CFA pattern string or 2-D list of channel names",
    "black_level": "number, or one number per CFA position",
    "white_level": "number > black_level",
    "offset": "bytes to skip at the start of the file (int >= 0, default 0)",
    "bit_depth": "significant bits (informative)",
    "description": "free text",
    "white_balance": "as-shot white-balance multipliers [r, g, b] (3 finite numbers > 0)",
}
_DTYPES = {"uint8": np.dtype("<u1"), "uint16": np.dtype("<u2"), "uint16be": np.dtype(">u2")}


@dataclass
class RawImage:
    """A raw CFA mosaic, normalised.

    Attributes
    ----------
    mosaic
        float32 (H, W): 0 = black level, 1 = white level.
    cfa
        The colour filter array, phase relative to ``mosaic[0, 0]``.
    black_level
        Black level in DN, per CFA position (float64 array of ``cfa.n_positions``).
    white_level
        White (saturation) level in DN.
    path
        Source file, if any.
    metadata
        Source details (format, camera matrices, crop, ...), JSON-serialisable.
    gain_maps
        A DNG's GainMap opcodes (:class:`l3cli.io.dng_opcodes.DngGainMaps`)
        *not yet applied* to ``mosaic``, or None. :func:`read_raw` parses them
        and leaves the mosaic as stored; a caller that wants the corrected
        mosaic applies them with :func:`l3cli.lens.gainmaps.apply_dng_gains`
        (training, ``l3 info``, the baseline do), and a render folds them into
        the tile kernel (:func:`l3cli.kernelset.prepare_kernels`).
    """

    mosaic: np.ndarray
    cfa: CFA
    black_level: np.ndarray
    white_level: float
    path: Path | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    gain_maps: Any = None

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the mosaic."""
        return self.mosaic.shape  # type: ignore[return-value]

    @property
    def height(self) -> int:
        """Mosaic height in pixels."""
        return int(self.mosaic.shape[0])

    @property
    def width(self) -> int:
        """Mosaic width in pixels."""
        return int(self.mosaic.shape[1])

    def crop(self, y0: int, x0: int, height: int, width: int) -> RawImage:
        """A view of a window; the CFA phase follows the crop origin.

        ``metadata["crop"]`` is the window on the file's full raw (offsets add
        over crops of crops), ``metadata["full_size"]`` that raw's (height, width).

        Raises
        ------
        ValueError
            The raw's DNG gain maps are not applied yet (apply them first:
            their positions are relative to the whole image).
        """
        if self.gain_maps is not None:
            raise ValueError(f"{self.path}: apply the DNG gain maps before cropping "
                             "(l3cli.lens.gainmaps.apply_dng_gains)")
        ph, pw = self.cfa.period
        bl = self.black_level.reshape(ph, pw)
        bl = np.roll(bl, (-y0, -x0), axis=(0, 1)).ravel()
        oy, ox = self.metadata.get("crop", (0, 0, 0, 0))[:2]
        return RawImage(
            mosaic=self.mosaic[y0 : y0 + height, x0 : x0 + width],
            cfa=self.cfa.shifted(y0, x0),
            black_level=bl,
            white_level=self.white_level,
            path=self.path,
            metadata={"full_size": [self.height, self.width], **self.metadata,
                      "crop": [int(oy + y0), int(ox + x0), int(height), int(width)]},
        )

    def planes(self) -> dict[str, np.ndarray]:
        """Sub-sampled planes per CFA position, keyed ``"<pos>_<channel>"``."""
        ph, pw = self.cfa.period
        out = {}
        for y in range(ph):
            for x in range(pw):
                out[f"{y * pw + x}_{self.cfa.pattern[y][x]}"] = self.mosaic[y::ph, x::pw]
        return out


def _normalise(dn: np.ndarray, black: np.ndarray, white: float, cfa: CFA) -> np.ndarray:
    """``(DN - black_p) / (white - black_p)`` with the black level of each pixel's CFA position.

    Every position maps its own black level to 0 and the white level to 1:
    float32 ``(DN - black_p) * (1 / (white - black_p))``, against one row of
    per-column levels per CFA row phase, in blocks of whole periods of about
    64 rows (the subtraction and the scaling meet each block in cache: half
    the time of whole-image passes). ``dn`` may be a view of a decoder's
    buffer (read, never kept; no integer copy is made).
    """
    ph, pw = cfa.period
    black_pos = np.asarray(black, dtype=np.float64).reshape(ph, pw)
    offset = black_pos.astype(np.float32)
    scale = np.array([[1.0 / (white - b) for b in row] for row in black_pos]).astype(np.float32)
    if dn.dtype.itemsize > 2:  # numpy would subtract wider integers in float64
        dn = dn.astype(np.float32)
    (h, w), reps = dn.shape, -(-dn.shape[1] // pw)
    offsets = np.stack([np.tile(row, reps)[:w] for row in offset])  # (ph, w)
    scales = np.stack([np.tile(row, reps)[:w] for row in scale])
    out = buffers.empty((h, w), np.float32)  # a finished file's, in a folder render
    step = ph * max(1, 64 // ph)
    for y0 in range(0, h, step):
        n = min(step, h - y0)
        full = n - n % ph  # whole periods: (periods, ph, w) against the (ph, w) levels
        block = out[y0:y0 + full].reshape(-1, ph, w)
        np.subtract(dn[y0:y0 + full].reshape(-1, ph, w), offsets, out=block)
        block *= scales
        for y in range(y0 + full, y0 + n):  # the last rows of an image of partial periods
            np.subtract(dn[y], offsets[y % ph], out=out[y])
            out[y] *= scales[y % ph]
    return out


#: Type checks of the optional sidecar keys (the required ones are checked where used).
_SIDECAR_TYPES: dict[str, tuple[type, ...]] = {
    "width": (int,), "height": (int,), "dtype": (str,), "offset": (int,),
    "bit_depth": (int,), "description": (str,), "cfa": (str, list),
}


def _read_sidecar(raw_path: Path, sc: Path) -> dict[str, Any]:
    if not sc.exists():
        raise InputError(f"{raw_path}: sidecar {sc.name} is missing (headerless raw needs it)")
    if not sc.is_file():
        raise InputError(f"{sc}: the sidecar is not a file")
    try:
        with open(sc, "rb") as fh:
            meta = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{sc}: TOML syntax error: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{sc}: not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
    except OSError as exc:
        raise InputError(f"{sc}: cannot read the sidecar ({exc.strerror or exc})") from exc
    unknown = sorted(set(meta) - set(_SIDECAR_KEYS))
    if unknown:
        raise ConfigError(
            f"{sc}: unknown key {unknown[0]!r}; allowed keys: {', '.join(_SIDECAR_KEYS)}"
        )
    for key in ("cfa", "black_level", "white_level"):
        if key not in meta:
            raise ConfigError(f"{sc}: missing key {key!r} ({_SIDECAR_KEYS[key]})")
    for key, types in _SIDECAR_TYPES.items():
        v = meta.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, types)):
            raise ConfigError(f"{sc}: {key} has the wrong type ({type(v).__name__}); "
                              f"expected {_SIDECAR_KEYS[key]}")
    return meta


def _sidecar_cfa(meta: dict[str, Any], sc: Path) -> CFA:
    try:
        return CFA.from_spec(meta["cfa"])
    except ConfigError as exc:
        raise ConfigError(f"{sc}: cfa: {exc}") from None
    except (TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"{sc}: cfa: not a CFA pattern ({_SIDECAR_KEYS['cfa']})") from exc


def _levels(meta: dict[str, Any], cfa: CFA, sc: Path,
            dtype_max: float | None = None) -> tuple[np.ndarray, float]:
    cfa_black = per_position(meta["black_level"], cfa, str(sc))
    white = _number(meta["white_level"], "white_level", str(sc))
    if cfa_black.min() < 0:
        raise ConfigError(f"{sc}: black_level must be >= 0, got {cfa_black.min():g}")
    if not white > cfa_black.max():
        raise ConfigError(
            f"{sc}: white_level {white:g} must be greater than black_level {cfa_black.max():g}"
        )
    if dtype_max is not None and white > dtype_max:
        raise ConfigError(f"{sc}: white_level {white:g} exceeds the data's range (max "
                          f"{dtype_max:g})")
    return cfa_black, white


def _check_size(path: Path, h: int, w: int, cfa: CFA) -> None:
    ph, pw = cfa.period
    if h < max(2, ph) or w < max(2, pw):
        raise InputError(f"{path}: a {w}x{h} mosaic is too small (at least one CFA period "
                         f"{pw}x{ph}, and 2x2)")


def _raw_image(path: Path, dn: np.ndarray, cfa: CFA, black, white: float,
               metadata: dict[str, Any], *, checked: bool = False) -> RawImage:
    """The :class:`RawImage` of integer data ``dn`` (size checked unless ``checked``)."""
    if not checked:
        _check_size(path, dn.shape[0], dn.shape[1], cfa)
    return RawImage(mosaic=_normalise(dn, black, white, cfa), cfa=cfa, black_level=black,
                    white_level=white, path=path, metadata=metadata)


def _read_headerless(path: Path) -> RawImage:
    sc = sidecar_path(path)
    meta = _read_sidecar(path, sc)
    for key in ("width", "height", "dtype"):
        if key not in meta:
            raise ConfigError(f"{sc}: missing key {key!r} ({_SIDECAR_KEYS[key]})")
    w, h = meta["width"], meta["height"]
    if not (isinstance(w, int) and isinstance(h, int) and w > 0 and h > 0):
        raise ConfigError(f"{sc}: width and height must be positive integers, got {w!r}x{h!r}")
    if meta["dtype"] not in _DTYPES:
        raise ConfigError(
            f"{sc}: dtype {meta['dtype']!r} is not allowed; use one of {', '.join(_DTYPES)}"
        )
    dtype = _DTYPES[meta["dtype"]]
    offset = meta.get("offset", 0)
    if isinstance(offset, bool) or not isinstance(offset, int) or offset < 0:
        raise ConfigError(f"{sc}: offset must be an integer >= 0 (bytes), got {offset!r}")
    cfa = _sidecar_cfa(meta, sc)
    black, white = _levels(meta, cfa, sc, float(np.iinfo(dtype).max))
    _check_size(path, h, w, cfa)
    expected = offset + w * h * dtype.itemsize
    size = path.stat().st_size
    if size != expected:
        raise InputError(
            f"{path}: file is {size} bytes but {sc.name} describes {w}x{h} {meta['dtype']}"
            f" ({expected} bytes)"
        )
    dn = np.fromfile(path, dtype=dtype, offset=offset).reshape(h, w)
    return _raw_image(path, dn, cfa, black, white, checked=True, metadata={
        "format": "headerless", "dtype": meta["dtype"], "bit_depth": meta.get("bit_depth"),
        "description": meta.get("description"),
        "white_balance": sidecar_white_balance(meta, sc)})


def _read_image_mosaic(path: Path) -> RawImage:
    """A single-channel integer TIFF/PNG mosaic with a ``.toml`` sidecar."""
    sc = sidecar_path(path)
    meta = _read_sidecar(path, sc)
    try:
        if path.suffix.lower() in (".tif", ".tiff"):
            import tifffile

            dn = tifffile.imread(path)
        else:
            import OpenImageIO as oiio

            inp = oiio.ImageInput.open(str(path))
            if inp is None:
                raise InputError(f"{path}: cannot open image mosaic ({oiio.geterror()})")
            spec = inp.spec()
            # the stored integer type: asking for uint16 would rescale 8-bit data by 257
            native = "uint8" if spec.format == oiio.TypeDesc("uint8") else "uint16"
            dn = inp.read_image(0, 0, 0, spec.nchannels, native)
            inp.close()
            if dn is None:
                raise InputError(f"{path}: cannot read image mosaic ({oiio.geterror()})")
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - any decoder failure is a bad input
        raise InputError(f"{path}: cannot read image mosaic ({exc})") from exc
    dn = np.asarray(dn)
    if dn.ndim == 3 and dn.shape[2] == 1:
        dn = dn[:, :, 0]
    if dn.ndim != 2 or dn.dtype.kind not in "ui":
        raise InputError(
            f"{path}: expected a single-channel integer mosaic, got shape {dn.shape} {dn.dtype}"
        )
    cfa = _sidecar_cfa(meta, sc)
    black, white = _levels(meta, cfa, sc, float(np.iinfo(dn.dtype).max))
    return _raw_image(path, dn, cfa, black, white, metadata={
        "format": "mosaic-image", "bit_depth": meta.get("bit_depth"),
        "description": meta.get("description"),
        "white_balance": sidecar_white_balance(meta, sc)})


#: Held while writing to the real stderr from a thread while others may decode.
STDERR_LOCK = fd2.STDERR_LOCK


def _libraw_detail(path: Path, lines: list[str], fallback: str) -> str:
    """LibRaw's own message without the file name it prefixes, or ``fallback``."""
    if not lines:
        return fallback
    msg = lines[-1]
    for prefix in (f"{path}: ", f"{path.name}: "):
        if msg.startswith(prefix):
            msg = msg[len(prefix):]
    return msg


def _visible_pattern(pattern: np.ndarray, top: int, left: int) -> np.ndarray:
    """``raw_colors_visible[:ph, :pw]`` without rawpy's full-size array (the pattern
    tiled from the full raw's origin, cut at the margins)."""
    ph, pw = pattern.shape
    return pattern[np.ix_((top + np.arange(ph)) % ph, (left + np.arange(pw)) % pw)]


def _read_rawpy(path: Path, libraw_only: bool = False, libraw: bool = False) -> RawImage:
    import rawpy

    rp = None
    failure: Exception | None = None
    fast = None
    if path.suffix.lower() == ".dng":
        from l3cli import kernel_store

        # uncompressed and lossless JPEG: numpy, imagecodecs; lossy JPEG: numba
        from l3cli.io import dng_direct, dng_lossy

        fast = None if libraw else dng_direct.read(path)
        if fast is None and not (libraw or libraw_only):
            # its compiled decoder: stored code loads in milliseconds; numba only where it is
            # loaded anyway (render, train), not for a quick look (l3 info: ~0.3 s to import)
            fast = dng_lossy.read(path, compile=kernel_store.in_use())
        elif fast is None:
            dng_lossy.check_whole(path)  # lossy tiles past the end: damaged, whatever LibRaw says
    with fd2.captured(str(path)) as said:
        try:
            if fast is not None:
                rp, vis, _ = fast
            else:
                rp = rawpy.imread(str(path))
                vis = rp.raw_image_visible  # unpacks the raw data
        except (rawpy.LibRawError, OSError, ValueError, AttributeError) as exc:
            failure = exc
    if failure is not None:
        if rp is not None:
            rp.close()
            detail = _libraw_detail(path, said, type(failure).__name__)
            raise InputError(f"{path}: cannot unpack raw data ({detail})") from failure
        kind = type(failure).__name__.replace("LibRaw", "").replace("Error", "")
        detail = _libraw_detail(path, said, kind or str(failure))
        raise InputError(f"{path}: not a raw file LibRaw can read ({detail})") from failure
    for line in said:
        log.debug("LibRaw: %s", line)
    with rp:
        if vis is None or vis.ndim != 2 or rp.raw_type != rawpy.RawType.Flat:
            raise InputError(f"{path}: not a CFA mosaic (linear or Foveon raw); l3 needs a CFA")
        desc = rp.color_desc.decode("ascii")
        pat = np.asarray(rp.raw_pattern)
        ph, pw = pat.shape
        sizes = rp.sizes
        colors = _visible_pattern(pat, sizes.top_margin, sizes.left_margin)
        names = [[desc[int(colors[y, x])] for x in range(pw)] for y in range(ph)]
        # LibRaw reports 4-colour patterns like RGBG: the second G is still green.
        cfa = CFA.from_spec(names)
        bl_per_colour = np.asarray(rp.black_level_per_channel, dtype=np.float64)
        black = np.array(
            [bl_per_colour[int(colors[y, x])] for y in range(ph) for x in range(pw)]
        )
        white = float(rp.white_level)
        meta: dict[str, Any] = {
            "format": "rawpy",
            "suffix": path.suffix.lower(),
            "color_desc": desc,
            "camera_whitebalance": [float(v) for v in rp.camera_whitebalance],
            "rgb_xyz_matrix": np.asarray(rp.rgb_xyz_matrix).tolist(),
            "sizes": {k: int(v) if isinstance(v, int | np.integer) else float(v)
                      for k, v in sizes._asdict().items()},
            "shot": read_shot_metadata(path, rp),
        }
        if vis.size == 0:
            raise InputError(f"{path}: the raw image is empty")
        # normalised straight from the decoder's buffer (no integer copy), before it is freed
        raw = _raw_image(path, vis, cfa, black, white, meta)
    if fast is not None:
        del vis
        buffers.release(fast[2])  # the decoder's array, for the next file's decode
    return raw


def read_raw(path: str | os.PathLike, *, libraw_only: bool = False,
             libraw: bool = False) -> RawImage:
    """Read a raw mosaic from any supported source.

    Parameters
    ----------
    path
        A raw file LibRaw opens, a headerless ``.raw`` with ``.raw.toml``
        sidecar, or a ``.tif``/``.png`` mosaic with a ``.toml`` sidecar.
    libraw_only
        Let LibRaw decode lossy-JPEG DNGs too. Otherwise
        :mod:`l3cli.io.dng_lossy` decodes them (the same values, in a third
        of the time) where its machine code is stored
        (:mod:`l3cli.kernel_store`) or the process runs compiled kernels
        already (:func:`l3cli.kernel_store.in_use`). Uncompressed and
        lossless-JPEG DNGs are still read by :mod:`l3cli.io.dng_direct`
        (numpy and imagecodecs, no numba).
    libraw
        Let LibRaw decode every raw (l3's own DNG readers off).

    Returns
    -------
    RawImage
        Normalised float32 mosaic with its CFA and levels. A DNG's GainMap
        opcodes (its lens shading correction) are parsed into
        ``raw.gain_maps`` and counted in ``raw.metadata["gain_maps"]``, not
        applied: :func:`l3cli.lens.gainmaps.apply_dng_gains` applies them for a
        caller that wants the corrected mosaic.

    Raises
    ------
    InputError
        Missing, truncated, or non-raw file; sidecar missing or not matching;
        a malformed GainMap opcode.
    ConfigError
        Invalid sidecar content.
    """
    from l3cli.startup import test_point

    raw = _read_any(Path(path), libraw_only, libraw)
    test_point("raw-read")
    return raw


def _read_any(path: Path, libraw_only: bool, libraw: bool) -> RawImage:
    """:func:`read_raw` by the file's kind."""
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a raw file")
    suffix = path.suffix.lower()
    if suffix == ".raw":
        return _read_headerless(path)
    if suffix in (".tif", ".tiff", ".png") and sidecar_path(path).exists():
        return _read_image_mosaic(path)
    if suffix in (".png", ".jpg", ".jpeg", ".exr"):
        raise InputError(
            f"{path}: a {suffix} image is not a raw file (a mosaic image needs a sidecar "
            f"{sidecar_path(path).name})"
        )
    raw = _read_rawpy(path, libraw_only, libraw)
    if suffix == ".dng":  # the camera's GainMap opcodes (lens shading): parsed, applied by the model
        from l3cli.io.dng_opcodes import dng_gain_maps

        raw.gain_maps = dng_gain_maps(raw)
        if raw.gain_maps is not None:
            raw.metadata["gain_maps"] = raw.gain_maps.counts()
    return raw
