"""The input layer: (raw, target) pairs from ``simulate`` folders and pairs folders.

Training (``l3 train``) and the conventional baseline (``l3 baseline``) read
their inputs through here; one :class:`Pair` describes one capture whatever
folder it comes from, and :func:`find_pairs` lists them:

* a ``simulate`` output folder (``manifest.json`` with ``"format":
  "l3-simulation"``): each capture's raw and its ideal, pixel-aligned target
  (CIE XYZ EXR);
* a *pairs directory*: raw files (any :data:`l3cli.io.raw.RAW_SUFFIXES`,
  including headerless ``NAME.raw`` with ``NAME.raw.toml``, and l3's TIFF/PNG
  mosaics with a ``.toml`` sidecar) each with one rendered image of the same
  stem (:data:`RENDER_SUFFIXES`): ``a.dng`` + ``a.jpg``, ``b.raw`` +
  ``b.raw.toml`` + ``b.png``. Training learns the mapping from the raw to the
  render (see ``docs/real-camera.md``). Images other than EXR are display
  sRGB; EXR carries its space in the ``l3:space`` attribute.

A :class:`Pair` holds paths and small per-capture facts only (cheap and
picklable, so distributed workers read the files themselves);
:func:`load_pair` reads one into a :class:`LoadedPair`. A simulated target is
pixel-aligned already. A rendered image is registered on its raw first: the
raw is cropped to the render's area (:mod:`l3cli.align` finds the offset and
flip and refuses renders that do not align), the render is put in the raw's
orientation, and a weight mask marks the pixels that may train:

Clipped pixels
    A pixel of the render with any channel at or above ``clip_high``
    (default 254.5/255) or at or below ``clip_low`` (default 0.5/255), in the
    file's encoded values, is excluded: its true colour was lost by the
    renderer's clipping and a regression would learn the clip, not the
    pipeline. (Floating-point EXR renders are not clipped; only non-finite
    values are excluded there.)
Border margin
    ``margin`` pixels (default 4) on every side of the render are excluded:
    ISPs treat edges specially (the Infinite-ISP sharpening zero-pads, so its
    outer rows and columns come out brighter), and near the crop edge the raw
    patch would reach outside the pixels the render covers.
Scaled renders (only with ``scaled=True``; ``l3 train --scaled-renders``)
    A render that does not align pixel for pixel is registered as a resized
    copy (:func:`l3cli.align.align_scaled`) and resampled onto the raw's
    pixels (:func:`l3cli.align.scaled_pair`): the pair then trains at the
    render's reduced resolution (the target holds no finer detail than the
    render), on the raw's own pixel grid, so the table still renders raws at
    full size. Clipped render pixels and the margin (in render pixels) are
    excluded wherever they contribute to a target pixel, and ``margin`` raw
    pixels at the crop's edges as well.

References
----------
.. [1] Q. Tian, S. Lansel, J. E. Farrell and B. A. Wandell, "Automating the
   design of image processing pipelines for novel color filter arrays: Local,
   Linear, Learned (L3) method", Proc. SPIE 9023, Digital Photography X, 2014.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.align import (
    FLIPS,
    MIN_SCORE,
    MIN_SHARPNESS,
    Alignment,
    ScaledAlignment,
    align,
    align_scaled,
    aligned_pair,
    scaled_pair,
)
from l3cli.errors import InputError
from l3cli.io import manifest as _manifest
from l3cli.io.raw import RAW_SUFFIXES, RawImage, read_raw, sidecar_path

__all__ = [
    "RENDER_SUFFIXES",
    "CLIP_LOW",
    "CLIP_HIGH",
    "DEFAULT_MARGIN",
    "Pair",
    "LoadedPair",
    "is_pairs_dir",
    "is_raw_file",
    "raw_files",
    "is_simulation_dir",
    "manifest_path",
    "read_simulation_manifest",
    "find_pairs",
    "load_pair",
    "iter_pairs",
    "weight_mask",
]

log = logging.getLogger(__name__)

#: Suffixes of rendered images (lower case), in order of preference (training
#: and evaluation alike).
RENDER_SUFFIXES: tuple[str, ...] = (".exr", ".tif", ".tiff", ".png", ".jpg", ".jpeg")
#: Encoded values at or below this are treated as clipped to black.
CLIP_LOW = 0.5 / 255
#: Encoded values at or above this are treated as clipped to white.
CLIP_HIGH = 254.5 / 255
#: Default border excluded from training, pixels.
DEFAULT_MARGIN = 4


@dataclass(frozen=True)
class Pair:
    """One capture to train on: a raw file and its target image (paths only).

    Attributes
    ----------
    name
        Name of the capture (the simulation stem, or the common file stem).
    raw
        Raw file path.
    target
        Target image path: a simulation's ideal target, or a rendered image.
    space
        Colour space of the target file's values, or ``None`` to take it from
        the file (EXR attribute / display sRGB).
    align
        True for pairs-folder renders: :func:`load_pair` registers the render
        on the raw (crop, flips) and masks clipped pixels and the border.
    scaled
        For pairs-folder renders: a render that is a resized copy of the raw
        is accepted and trained at its reduced resolution.
    metadata
        Per-capture facts that are not pixels, read when the pair is found
        (from a simulation manifest: ``scene``, ``illuminant``, ``lux``,
        ``exposure_s``). The place for white balance, ISO, exposure and
        orientation read from raw files; not compared between pairs.
    """

    name: str
    raw: Path
    target: Path
    space: str | None = None
    align: bool = False
    scaled: bool = False
    metadata: Mapping[str, Any] = field(default_factory=dict, compare=False)


@dataclass
class LoadedPair:
    """One pair read into memory, ready to train on.

    Attributes
    ----------
    name
        The pair's name.
    raw
        The raw; for a rendered pair cropped to the render's area, with the
        full raw's CFA phase: a render whose top-left lies at an odd row or
        column (of a period-2 CFA) is trimmed by that row or column, here and
        in ``target``.
    target
        float32 (H, W, 3): the target (a render in the raw's orientation), in ``space``.
    weight_mask
        bool (H, W): pixels that may train (not clipped, not in the margin), or
        ``None`` where every pixel may (simulated targets).
    alignment
        Where a render lies on the full raw (:class:`~l3cli.align.Alignment`, or
        :class:`~l3cli.align.ScaledAlignment` for a resized render trained with
        ``scaled``); ``None`` for simulated targets.
    space
        Colour space of ``target``.
    pair
        The :class:`Pair` it was read from.
    """

    name: str
    raw: RawImage
    target: np.ndarray
    weight_mask: np.ndarray | None
    alignment: Alignment | ScaledAlignment | None
    space: str
    pair: Pair


def is_raw_file(path: str | os.PathLike) -> bool:
    """True for a raw file: a raw suffix, or an image with a raw sidecar (``X.tif`` + ``X.tif.toml``).

    Examples
    --------
    >>> is_raw_file("a.dng"), is_raw_file("no_sidecar_here.png")
    (True, False)
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in RAW_SUFFIXES:
        return True
    # l3's own mosaics for CFAs DNG cannot describe: NAME.tif + NAME.tif.toml
    return suffix in (".tif", ".tiff", ".png") and sidecar_path(path).exists()


def is_pairs_dir(path: str | os.PathLike) -> bool:
    """True for a folder without a simulation ``manifest.json`` holding at least one raw file."""
    p = Path(path)
    if not p.is_dir() or is_simulation_dir(p):
        return False
    return any(f.is_file() and is_raw_file(f) for f in p.iterdir())


def _render_for(raw: Path) -> Path:
    stem = raw.stem
    found = [f for f in raw.parent.iterdir()
             if f.is_file() and f != raw and f.suffix.lower() in RENDER_SUFFIXES
             and f.stem == stem and not sidecar_path(f).exists()]
    if not found:
        allowed = "/".join(s.lstrip(".") for s in RENDER_SUFFIXES)
        raise InputError(
            f"{raw}: no rendered image with the same stem ({stem}.{{{allowed}}}) in {raw.parent}"
        )
    if len(found) > 1:
        names = ", ".join(sorted(f.name for f in found))
        raise InputError(f"{raw}: several rendered images with the same stem ({names}); keep one")
    return found[0]


#: What a simulation manifest tells of each capture beside its files (:attr:`Pair.metadata`).
_CAPTURE_FACTS = ("scene", "illuminant", "lux", "exposure_s")


def is_simulation_dir(path: str | os.PathLike) -> bool:
    """True for a folder with a simulation manifest (an ``l3 simulate`` output)."""
    return Path(path).is_dir() and _manifest.is_simulation_dir(path)


#: The versioned, validated reader (:func:`l3cli.io.manifest.read_manifest`).
read_simulation_manifest = _manifest.read_manifest
manifest_path = _manifest.manifest_path


def _simulation_pairs(folder: Path) -> list[Pair]:
    """The captures of a ``simulate`` folder, in manifest order."""
    from l3cli.colourspace import check_space

    manifest = read_simulation_manifest(folder)  # validated: each capture has raw, target, stem
    space = check_space(manifest["target"]["space"])
    pairs = []
    for cap in manifest["captures"]:
        facts = {k: cap[k] for k in _CAPTURE_FACTS if k in cap}
        pairs.append(Pair(cap["stem"], folder / cap["raw"], folder / cap["target"], space,
                          metadata=facts))
    return pairs


def raw_files(paths: Iterable[str | os.PathLike]) -> tuple[list[Path], bool]:
    """The raw files named by ``paths``: files as given, folders expanded.

    A ``simulate`` folder gives its captures' raws (manifest order), any other
    folder its raw files (:func:`is_raw_file`, sorted by name).

    Returns
    -------
    raws, any_folder
        The raw paths, and whether a folder was among ``paths`` (its outputs
        then go to a folder, however many raws it holds).

    Raises
    ------
    InputError
        A folder without raws.
    """
    out: list[Path] = []
    any_folder = False
    for p in map(Path, paths):
        if not p.is_dir():
            out.append(p)
            continue
        any_folder = True
        if is_simulation_dir(p):
            found = [pair.raw for pair in _simulation_pairs(p)]
        else:
            found = sorted(f for f in p.iterdir() if f.is_file() and is_raw_file(f))
        if not found:
            allowed = ", ".join(sorted(RAW_SUFFIXES))
            raise InputError(f"{p}: no raw files in the folder ({allowed}, or an image with a "
                             "raw .toml sidecar)")
        out.extend(found)
    return out, any_folder


def _rendered_pairs(p: Path, seen: dict[str, Path], scaled: bool) -> list[Pair]:
    """The (raw, render) pairs of a pairs directory, or of one raw file."""
    if p.is_dir():
        raws = sorted(f for f in p.iterdir() if f.is_file() and is_raw_file(f))
        if not raws:
            allowed = ", ".join(sorted(RAW_SUFFIXES))
            raise InputError(
                f"{p}: no training pairs: no manifest.json and no raw files in this folder "
                f"(a pairs folder holds raw files [{allowed}] each with a rendered image of "
                "the same stem)"
            )
        renders = {f for f in p.iterdir() if f.is_file() and f.suffix.lower() in RENDER_SUFFIXES}
    elif is_raw_file(p):
        raws, renders = [p], set()
    else:
        raise InputError(f"{p}: not a simulate folder, a pairs folder or a raw file")
    out = []
    for raw in raws:
        render = _render_for(raw)
        renders.discard(render)
        name = render.stem
        if name in seen:
            raise InputError(f"{raw}: pair name {name!r} also comes from {seen[name]}")
        seen[name] = raw
        out.append(Pair(name, raw, render, None, align=True, scaled=scaled))
    for extra in sorted(renders):
        if not sidecar_path(extra).exists():
            log.warning("%s: rendered image without a raw file of the same stem; ignored", extra)
    return out


def find_pairs(paths: Iterable[str | os.PathLike], *,
               scaled_renders: bool = False) -> list[Pair]:
    """List the pairs of ``simulate`` folders, pairs directories and raw files.

    Parameters
    ----------
    paths
        ``simulate`` output folders, pairs directories, or raw files whose
        render lies next to them.
    scaled_renders
        Accept renders that are resized copies of their raws (see
        :attr:`Pair.scaled`).

    Returns
    -------
    list of Pair
        Captures in manifest order, rendered pairs sorted by name within each
        directory; inputs in the order given.

    Raises
    ------
    InputError
        A path is missing, a folder holds no pairs, a raw has no render (or
        several), or a rendered pair's name occurs twice.
    """
    out: list[Pair] = []
    seen: dict[str, Path] = {}
    for item in paths:
        p = Path(item)
        if not p.exists():
            raise InputError(f"{p}: no such file or folder")
        if is_simulation_dir(p):
            out.extend(_simulation_pairs(p))
        else:
            out.extend(_rendered_pairs(p, seen, scaled_renders))
    return out


def weight_mask(encoded: np.ndarray, *, margin: int = DEFAULT_MARGIN,
                clip_low: float | None = CLIP_LOW,
                clip_high: float | None = CLIP_HIGH) -> np.ndarray:
    """Pixels of a render that may train.

    Parameters
    ----------
    encoded
        (H, W, C) render values as stored (display-encoded in [0, 1]).
    margin
        Border width excluded on every side, pixels (>= 0).
    clip_low, clip_high
        A pixel with any channel ``<= clip_low`` or ``>= clip_high`` is
        excluded; ``None`` disables that test (floating-point renders).

    Returns
    -------
    numpy.ndarray
        bool (H, W).
    """
    if margin < 0:
        raise InputError(f"margin {margin} is not allowed; use 0 or more pixels")
    img = np.asarray(encoded)
    h, w = img.shape[:2]
    mask = np.all(np.isfinite(img), axis=2)
    if clip_low is not None:
        mask &= ~np.any(img <= clip_low, axis=2)
    if clip_high is not None:
        mask &= ~np.any(img >= clip_high, axis=2)
    if margin:
        mask[:margin] = False
        mask[h - margin :] = False
        mask[:, :margin] = False
        mask[:, w - margin :] = False
    return mask


def load_pair(pair: Pair, *, target_space: str | None = None,
              margin: int = DEFAULT_MARGIN, clip_low: float = CLIP_LOW,
              clip_high: float = CLIP_HIGH, flips: Sequence[str] = FLIPS,
              min_score: float = MIN_SCORE, min_sharpness: float = MIN_SHARPNESS,
              scaled: bool | None = None) -> LoadedPair:
    """Read one pair; register and mask a rendered one.

    Parameters
    ----------
    pair
        From :func:`find_pairs`.
    target_space
        Colour space of :attr:`LoadedPair.target`
        (:data:`l3cli.colourspace.SPACES`); ``None`` keeps the target's own
        (the simulation's, or the render's encoding: ``srgb`` for TIFF, PNG and
        JPEG, the recorded space for EXR).
    margin, clip_low, clip_high
        Rendered pairs: see :func:`weight_mask`.
    flips, min_score, min_sharpness
        Rendered pairs: see :func:`l3cli.align.align`.
    scaled
        Rendered pairs: accept a render that is a resized copy of the raw (or
        of a crop of it) and train at its reduced resolution (see the module
        notes); ``None`` takes :attr:`Pair.scaled`. Renders that align pixel
        for pixel are used as they are either way.

    Returns
    -------
    LoadedPair

    Raises
    ------
    InputError
        Unreadable files, a raw holding NaN or Inf, a target that is not RGB or
        holds NaN or Inf, a simulated target of another size than its raw, or a
        render that does not align with its raw (with ``scaled``: not even as a
        resized copy).
    """
    if not pair.align:
        return _load_simulated(pair, target_space)
    loaded = _load_rendered(pair, target_space=target_space, margin=margin, clip_low=clip_low,
                            clip_high=clip_high, flips=flips, min_score=min_score,
                            min_sharpness=min_sharpness,
                            scaled=pair.scaled if scaled is None else scaled)
    if not np.all(np.isfinite(loaded.raw.mosaic)):
        raise InputError(f"{pair.raw}: raw mosaic holds NaN or Inf")
    return loaded


def _load_simulated(pair: Pair, target_space: str | None) -> LoadedPair:
    """:func:`load_pair` for a pixel-aligned target (a simulation's)."""
    from l3cli.colourspace import check_space, convert
    from l3cli.io.image import read_image

    raw = read_raw(pair.raw)
    img, file_space = read_image(pair.target)
    space = pair.space or file_space
    if img.shape[:2] != raw.mosaic.shape:
        raise InputError(
            f"{pair.target}: target is {img.shape[1]}x{img.shape[0]} but raw {pair.raw.name} is "
            f"{raw.width}x{raw.height}; a pair must be pixel-aligned"
        )
    if img.shape[2] == 4:
        img = img[:, :, :3]
    if img.shape[2] != 3:
        raise InputError(f"{pair.target}: target has {img.shape[2]} channels, expected 3")
    bad = ~np.isfinite(img)
    if bad.any():
        y, x, _ = np.argwhere(bad)[0]
        raise InputError(
            f"{pair.target}: target holds {int(bad.any(axis=2).sum())} pixels with NaN or Inf "
            f"(first at x={x}, y={y})"
        )
    if not np.all(np.isfinite(raw.mosaic)):
        raise InputError(f"{pair.raw}: raw mosaic holds NaN or Inf")
    dst = space if target_space is None else check_space(target_space)
    target = convert(img, space, dst)
    target = np.ascontiguousarray(target, dtype=np.float32)
    return LoadedPair(name=pair.name, raw=raw, target=target, weight_mask=None, alignment=None,
                      space=dst, pair=pair)


#: Alignments found in this process, by the two files' identity (path, size, mtime) and the
#: search's options: ``l3 train`` reads every pair twice (the tone curve's pass, then the
#: kernels'), and so aligns -- and logs the alignment -- once. At most _MEMO_SIZE entries.
_ALIGNMENTS: dict[tuple, Alignment | ScaledAlignment] = {}
_MEMO_SIZE = 256


def _file_id(path: Path) -> tuple:
    st = os.stat(path)
    return (str(Path(path).resolve()), st.st_size, st.st_mtime_ns)


def _remember(key: tuple, a: Alignment | ScaledAlignment) -> None:
    if len(_ALIGNMENTS) >= _MEMO_SIZE:
        _ALIGNMENTS.pop(next(iter(_ALIGNMENTS)))
    _ALIGNMENTS[key] = a


def _load_rendered(pair: Pair, *, target_space: str | None, margin: int, clip_low: float,
                   clip_high: float, flips: Sequence[str], min_score: float,
                   min_sharpness: float, scaled: bool) -> LoadedPair:
    """:func:`load_pair` for a render: registered on its raw, cropped and masked."""
    from l3cli.io.image import read_image

    raw = read_raw(pair.raw)
    img, space = read_image(pair.target)
    if img.shape[2] not in (3, 4):
        raise InputError(
            f"{pair.target}: a rendered image must be RGB, got {img.shape[2]} channel(s)"
        )
    img = img[:, :, :3]
    is_float = pair.target.suffix.lower() == ".exr"
    key = (_file_id(pair.raw), _file_id(pair.target), tuple(flips), float(min_score),
           float(min_sharpness), bool(scaled))
    a = _ALIGNMENTS.get(key)
    reused = a is not None
    scaled_args = dict(target_space=target_space, margin=margin,
                       clip_low=None if is_float else clip_low,
                       clip_high=None if is_float else clip_high, flips=flips,
                       min_score=min_score, key=key)
    if isinstance(a, ScaledAlignment):
        return _load_scaled(pair, raw, img, space, found=a, **scaled_args)
    if a is None:
        try:
            a = align(raw, img, space=space, raw_name=pair.raw, render_name=pair.target,
                      flips=tuple(flips), min_score=min_score, min_sharpness=min_sharpness)
        except InputError as exc:
            smaller = img.shape[0] * img.shape[1] < raw.height * raw.width
            if not (scaled and smaller):
                hint = (" (if the render is a resized copy of the raw, `l3 train "
                        "--scaled-renders` trains at its reduced resolution)"
                        ) if smaller and not scaled else ""
                raise InputError(f"{exc}{hint}") from None
            return _load_scaled(pair, raw, img, space, **scaled_args)
        _remember(key, a)
    crop, encoded = aligned_pair(raw, img, a)
    # Keep the raw's CFA phase: a render starting at an odd row/column of a
    # Bayer raw loses its first row/column, so the crop's CFA equals the raw's
    # (one table per CFA, and renders of whole raws later use that phase).
    ph, pw = raw.cfa.period
    ty, tx = (-a.dy) % ph, (-a.dx) % pw
    if ty or tx:
        crop = raw.crop(a.dy + ty, a.dx + tx, crop.height - ty, crop.width - tx)
        crop.metadata["alignment"] = a.to_dict()
        encoded = encoded[ty:, tx:]
    mask = weight_mask(encoded, margin=margin,
                       clip_low=None if is_float else clip_low,
                       clip_high=None if is_float else clip_high)
    (log.debug if reused else log.info)(
        "%s: %s; %.1f%% of pixels train (margin %d, clipped excluded)%s", pair.name,
        a.describe(), 100 * float(mask.mean()), margin, " (alignment reused)" if reused else "")
    return _make_pair(pair, crop, encoded, mask, a, space, target_space, margin)


def _make_pair(pair: Pair, crop: RawImage, encoded: np.ndarray, mask: np.ndarray,
               alignment: Alignment | ScaledAlignment, space: str, target_space: str | None,
               margin: int) -> LoadedPair:
    """The :class:`LoadedPair` of an aligned crop: target converted to ``target_space``."""
    from l3cli.colourspace import check_space, convert

    if not mask.any():
        raise InputError(
            f"{pair.target}: no pixel left to train after excluding clipped values and a "
            f"{margin}-pixel margin"
        )
    dst = space if target_space is None else check_space(target_space)
    target = encoded if dst == space else convert(encoded, space, dst)
    target = np.ascontiguousarray(np.nan_to_num(target, nan=0.0), dtype=np.float32)
    return LoadedPair(name=pair.name, raw=crop, target=target, weight_mask=mask,
                      alignment=alignment, space=dst, pair=pair)


def _load_scaled(pair: Pair, raw: RawImage, img: np.ndarray, space: str, *,
                 target_space: str | None, margin: int, clip_low: float | None,
                 clip_high: float | None, flips: Sequence[str], min_score: float,
                 key: tuple | None = None, found: ScaledAlignment | None = None) -> LoadedPair:
    """:func:`load_pair` for a resized render (``scaled=True``); ``found``: its alignment
    already known (under ``key`` of the memo)."""

    a = found
    if a is None:
        a = align_scaled(raw, img, space=space, raw_name=pair.raw, render_name=pair.target,
                         flips=tuple(flips), min_score=min_score)
        if key is not None:
            _remember(key, a)
    valid = weight_mask(img, margin=margin, clip_low=clip_low, clip_high=clip_high)
    crop, encoded, mask = scaled_pair(raw, img, a, valid=valid, space=space)
    if margin:
        mask[:margin] = False
        mask[mask.shape[0] - margin:] = False
        mask[:, :margin] = False
        mask[:, mask.shape[1] - margin:] = False
    (log.debug if found is not None else log.info)(
        "%s: %s; trains at the render's reduced resolution on the raw's %dx%d pixels "
        "from (y=%d, x=%d); %.1f%% of them train (margin %d, clipped excluded)%s",
        pair.name, a.describe(), crop.width, crop.height, crop.metadata["crop"][0],
        crop.metadata["crop"][1], 100 * float(mask.mean()), margin,
        " (alignment reused)" if found is not None else "")
    return _make_pair(pair, crop, encoded, mask, a, space, target_space, margin)


def iter_pairs(paths: Iterable[str | os.PathLike], *, target_space: str | None = None,
               margin: int = DEFAULT_MARGIN, clip_low: float = CLIP_LOW,
               clip_high: float = CLIP_HIGH, flips: Sequence[str] = FLIPS,
               min_score: float = MIN_SCORE, min_sharpness: float = MIN_SHARPNESS,
               scaled: bool = False) -> Iterator[LoadedPair]:
    """Loaded pairs of ``simulate`` folders, pairs directories and raw files.

    All pairs are found (and missing renders reported) before the first is
    read; each pair is then read and aligned when the iterator reaches it.

    Parameters
    ----------
    paths
        As :func:`find_pairs`.
    target_space, margin, clip_low, clip_high, flips, min_score, min_sharpness, scaled
        See :func:`load_pair`.

    Yields
    ------
    LoadedPair
    """
    for pair in find_pairs(paths, scaled_renders=scaled):
        yield load_pair(pair, target_space=target_space, margin=margin, clip_low=clip_low,
                        clip_high=clip_high, flips=flips, min_score=min_score,
                        min_sharpness=min_sharpness, scaled=scaled)
