"""Loading pairs: one :class:`~l3cli.pairs.find.Pair` read into a :class:`LoadedPair`.

See :mod:`l3cli.pairs` for the registration, clipping and margin rules.
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
from l3cli.io.raw import RawImage, read_raw
from l3cli.lens.gainmaps import apply_dng_gains
from l3cli.pairs.find import (
    CLIP_HIGH,
    CLIP_LOW,
    DEFAULT_MARGIN,
    Pair,
    find_pairs,
)

log = logging.getLogger("l3cli.pairs")  # one logger name for the package


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

    raw = apply_dng_gains(read_raw(pair.raw))  # the DNG's gain maps applied
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

    raw = apply_dng_gains(read_raw(pair.raw))  # the DNG's gain maps applied
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
