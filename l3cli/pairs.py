"""Pairs directories: raw files and the images a camera or converter rendered from them.

A *pairs directory* holds raw files (any :data:`l3cli.io.raw.RAW_SUFFIXES`,
including headerless ``NAME.raw`` with ``NAME.raw.toml``, and l3's TIFF/PNG
mosaics with a ``.toml`` sidecar) each with one rendered image of the same
stem (:data:`RENDER_SUFFIXES`): ``a.dng`` + ``a.jpg``, ``b.raw`` +
``b.raw.toml`` + ``b.png``. Training learns the mapping from the raw to the
render (see ``docs/real-camera.md``).

For every pair :func:`iter_pairs` yields a :class:`Pair`: the raw cropped to
the render's area (:mod:`l3cli.align` finds the offset and flip and refuses
renders that do not align), the render in the raw's orientation converted to
the requested target space, and a weight mask of the pixels that may train:

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
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

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
from l3cli.io.raw import RAW_SUFFIXES, RawImage, read_raw, sidecar_path

__all__ = [
    "RENDER_SUFFIXES",
    "CLIP_LOW",
    "CLIP_HIGH",
    "DEFAULT_MARGIN",
    "PairFiles",
    "Pair",
    "is_pairs_dir",
    "find_pairs",
    "load_pair",
    "iter_pairs",
    "weight_mask",
]

log = logging.getLogger(__name__)

#: Suffixes of rendered images (lower case), in order of preference.
RENDER_SUFFIXES: tuple[str, ...] = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".exr")
#: Encoded values at or below this are treated as clipped to black.
CLIP_LOW = 0.5 / 255
#: Encoded values at or above this are treated as clipped to white.
CLIP_HIGH = 254.5 / 255
#: Default border excluded from training, pixels.
DEFAULT_MARGIN = 4


@dataclass(frozen=True)
class PairFiles:
    """A raw file and its rendered image."""

    name: str
    raw: Path
    render: Path


@dataclass
class Pair:
    """One aligned training pair.

    Attributes
    ----------
    name
        The common stem.
    raw
        The raw cropped to the render's area, with the full raw's CFA phase: a
        render whose top-left lies at an odd row or column (of a period-2 CFA)
        is trimmed by that row or column, here and in ``target``.
    target
        float32 (H, W, 3): the render in the raw's orientation, in ``space``.
    weight_mask
        bool (H, W): pixels that may train (not clipped, not in the margin).
    alignment
        Where the render lies on the full raw (:class:`~l3cli.align.ScaledAlignment`
        for a resized render trained with ``scaled=True``).
    space
        Colour space of ``target``.
    files
        The source files.
    """

    name: str
    raw: RawImage
    target: np.ndarray
    weight_mask: np.ndarray
    alignment: Alignment | ScaledAlignment
    space: str
    files: PairFiles


def _is_raw(path: Path) -> bool:
    suffix = path.suffix.lower()
    if suffix in RAW_SUFFIXES:
        return True
    # l3's own mosaics for CFAs DNG cannot describe: NAME.tif + NAME.tif.toml
    return suffix in (".tif", ".tiff", ".png") and sidecar_path(path).exists()


def is_pairs_dir(path: str | os.PathLike) -> bool:
    """True for a folder without a simulation ``manifest.json`` holding at least one raw file."""
    p = Path(path)
    if not p.is_dir() or (p / "manifest.json").exists():
        return False
    return any(f.is_file() and _is_raw(f) for f in p.iterdir())


def _render_for(raw: Path) -> Path:
    stem = raw.name[: -len(raw.suffix)] if raw.suffix else raw.name
    found = [f for f in raw.parent.iterdir()
             if f.is_file() and f != raw and f.suffix.lower() in RENDER_SUFFIXES
             and f.name[: -len(f.suffix)] == stem and not sidecar_path(f).exists()]
    if not found:
        allowed = "/".join(s.lstrip(".") for s in RENDER_SUFFIXES)
        raise InputError(
            f"{raw}: no rendered image with the same stem ({stem}.{{{allowed}}}) in {raw.parent}"
        )
    if len(found) > 1:
        names = ", ".join(sorted(f.name for f in found))
        raise InputError(f"{raw}: several rendered images with the same stem ({names}); keep one")
    return found[0]


def find_pairs(paths: Iterable[str | os.PathLike]) -> list[PairFiles]:
    """List the (raw, render) pairs in pairs directories.

    Parameters
    ----------
    paths
        Pairs directories, or raw files whose render lies next to them.

    Returns
    -------
    list of PairFiles
        Sorted by name within each directory, directories in the order given.

    Raises
    ------
    InputError
        A path is missing, a folder holds no raw file, a raw has no render
        (or several), or a name occurs twice.
    """
    out: list[PairFiles] = []
    seen: dict[str, Path] = {}
    for item in paths:
        p = Path(item)
        if not p.exists():
            raise InputError(f"{p}: no such file or folder")
        if p.is_dir():
            raws = sorted(f for f in p.iterdir() if f.is_file() and _is_raw(f))
            if not raws:
                allowed = ", ".join(sorted(RAW_SUFFIXES))
                raise InputError(
                    f"{p}: no raw files in this folder (a pairs folder holds raw files "
                    f"[{allowed}] each with a rendered image of the same stem)"
                )
            renders = {f for f in p.iterdir()
                       if f.is_file() and f.suffix.lower() in RENDER_SUFFIXES}
        elif _is_raw(p):
            raws, renders = [p], set()
        else:
            raise InputError(f"{p}: not a pairs folder or a raw file")
        for raw in raws:
            render = _render_for(raw)
            renders.discard(render)
            name = render.name[: -len(render.suffix)]
            if name in seen:
                raise InputError(f"{raw}: pair name {name!r} also comes from {seen[name]}")
            seen[name] = raw
            out.append(PairFiles(name=name, raw=raw, render=render))
        for extra in sorted(renders):
            if not sidecar_path(extra).exists():
                log.warning("%s: rendered image without a raw file of the same stem; ignored",
                            extra)
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


def load_pair(files: PairFiles, *, target_space: str | None = None,
              margin: int = DEFAULT_MARGIN, clip_low: float = CLIP_LOW,
              clip_high: float = CLIP_HIGH, flips: Sequence[str] = FLIPS,
              min_score: float = MIN_SCORE, min_sharpness: float = MIN_SHARPNESS,
              scaled: bool = False) -> Pair:
    """Read, align and mask one pair.

    Parameters
    ----------
    files
        From :func:`find_pairs`.
    target_space
        Colour space of :attr:`Pair.target` (:data:`l3cli.colourspace.SPACES`);
        ``None`` keeps the render's own encoding (``srgb`` for TIFF, PNG and
        JPEG; the recorded space for EXR).
    margin, clip_low, clip_high
        See :func:`weight_mask`.
    flips, min_score, min_sharpness
        See :func:`l3cli.align.align`.
    scaled
        Accept a render that is a resized copy of the raw (or of a crop of it)
        and train at its reduced resolution (see the module notes). Renders
        that align pixel for pixel are used as they are either way.

    Returns
    -------
    Pair

    Raises
    ------
    InputError
        Unreadable files, a render that is not RGB, or a render that does not
        align with its raw (with ``scaled``: not even as a resized copy).
    """
    from l3cli.io.image import read_image

    raw = read_raw(files.raw)
    img, space = read_image(files.render)
    if img.shape[2] not in (3, 4):
        raise InputError(
            f"{files.render}: a rendered image must be RGB, got {img.shape[2]} channel(s)"
        )
    img = img[:, :, :3]
    is_float = files.render.suffix.lower() == ".exr"
    try:
        a = align(raw, img, space=space, raw_name=files.raw, render_name=files.render,
                  flips=tuple(flips), min_score=min_score, min_sharpness=min_sharpness)
    except InputError as exc:
        smaller = img.shape[0] * img.shape[1] < raw.height * raw.width
        if not (scaled and smaller):
            hint = (" (if the render is a resized copy of the raw, `l3 train --scaled-renders` "
                    "trains at its reduced resolution)") if smaller and not scaled else ""
            raise InputError(f"{exc}{hint}") from None
        return _load_scaled(files, raw, img, space, target_space=target_space, margin=margin,
                            clip_low=None if is_float else clip_low,
                            clip_high=None if is_float else clip_high, flips=flips,
                            min_score=min_score)
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
    log.info("%s: %s; %.1f%% of pixels train (margin %d, clipped excluded)",
             files.name, a.describe(), 100 * float(mask.mean()), margin)
    return _make_pair(files, crop, encoded, mask, a, space, target_space, margin)


def _make_pair(files: PairFiles, crop: RawImage, encoded: np.ndarray, mask: np.ndarray,
               alignment: Alignment | ScaledAlignment, space: str, target_space: str | None,
               margin: int) -> Pair:
    """The :class:`Pair` of an aligned crop: target converted to ``target_space``."""
    from l3cli.colourspace import check_space, convert

    if not mask.any():
        raise InputError(
            f"{files.render}: no pixel left to train after excluding clipped values and a "
            f"{margin}-pixel margin"
        )
    dst = space if target_space is None else check_space(target_space)
    target = encoded if dst == space else convert(encoded, space, dst)
    target = np.ascontiguousarray(np.nan_to_num(target, nan=0.0), dtype=np.float32)
    return Pair(name=files.name, raw=crop, target=target, weight_mask=mask,
                alignment=alignment, space=dst, files=files)


def _load_scaled(files: PairFiles, raw: RawImage, img: np.ndarray, space: str, *,
                 target_space: str | None, margin: int, clip_low: float | None,
                 clip_high: float | None, flips: Sequence[str], min_score: float) -> Pair:
    """:func:`load_pair` for a resized render (``scaled=True``)."""

    a = align_scaled(raw, img, space=space, raw_name=files.raw, render_name=files.render,
                     flips=tuple(flips), min_score=min_score)
    valid = weight_mask(img, margin=margin, clip_low=clip_low, clip_high=clip_high)
    crop, encoded, mask = scaled_pair(raw, img, a, valid=valid, space=space)
    if margin:
        mask[:margin] = False
        mask[mask.shape[0] - margin:] = False
        mask[:, :margin] = False
        mask[:, mask.shape[1] - margin:] = False
    log.info("%s: %s; trains at the render's reduced resolution on the raw's %dx%d pixels "
             "from (y=%d, x=%d); %.1f%% of them train (margin %d, clipped excluded)",
             files.name, a.describe(), crop.width, crop.height, crop.metadata["crop"][0],
             crop.metadata["crop"][1], 100 * float(mask.mean()), margin)
    return _make_pair(files, crop, encoded, mask, a, space, target_space, margin)


def iter_pairs(paths: Iterable[str | os.PathLike], *, target_space: str | None = None,
               margin: int = DEFAULT_MARGIN, clip_low: float = CLIP_LOW,
               clip_high: float = CLIP_HIGH, flips: Sequence[str] = FLIPS,
               min_score: float = MIN_SCORE, min_sharpness: float = MIN_SHARPNESS,
               scaled: bool = False) -> Iterator[Pair]:
    """Aligned, masked training pairs from pairs directories.

    All pairs are found (and missing renders reported) before the first is
    read; each pair is then read and aligned when the iterator reaches it.

    Parameters
    ----------
    paths
        Pairs directories (or raw files with their render alongside).
    target_space, margin, clip_low, clip_high, flips, min_score, min_sharpness, scaled
        See :func:`load_pair`.

    Yields
    ------
    Pair
    """
    for files in find_pairs(paths):
        yield load_pair(files, target_space=target_space, margin=margin, clip_low=clip_low,
                        clip_high=clip_high, flips=flips, min_score=min_score,
                        min_sharpness=min_sharpness, scaled=scaled)
