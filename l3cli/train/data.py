"""Training inputs: aligned (raw mosaic, target image) pairs.

Two kinds of input folder give pairs:

* a ``simulate`` output folder (``manifest.json`` with ``"format":
  "l3-simulation"``): each capture's raw and ideal target (CIE XYZ EXR);
* a *pairs* folder: every raw file with a rendered image of the same stem
  (``a.dng`` + ``a.jpg``; ``b.raw`` + ``b.raw.toml`` + ``b.png``; a mosaic
  ``c.tif`` + ``c.tif.toml`` + ``c.png``). Images other than EXR are display
  sRGB; EXR carries its space in the ``l3:space`` attribute.

:func:`find_pairs` lists :class:`Pair` records (paths only, cheap and
picklable so distributed workers can read them themselves); :func:`load_pair`
reads one, converts the target to the requested space and checks it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from l3cli.colourspace import check_space, convert
from l3cli.errors import InputError
from l3cli.io.raw import RAW_SUFFIXES as _RAW_SUFFIXES
from l3cli.pairs import RENDER_SUFFIXES

__all__ = ["Pair", "find_pairs", "load_pair", "RAW_SUFFIXES", "IMAGE_SUFFIXES"]

#: Suffixes of raw files in a pairs folder (plus mosaics with a .toml sidecar);
#: the one list of :mod:`l3cli.io.raw`.
RAW_SUFFIXES = _RAW_SUFFIXES
#: Suffixes of rendered images in a pairs folder (:data:`l3cli.pairs.RENDER_SUFFIXES`).
IMAGE_SUFFIXES = RENDER_SUFFIXES


@dataclass(frozen=True)
class Pair:
    """One training pair.

    Attributes
    ----------
    raw
        Raw file path.
    target
        Target image path (pixel-aligned with the raw).
    stem
        Name of the capture.
    space
        Colour space of the target file's values, or ``None`` to take it from
        the file (EXR attribute / display sRGB).
    align
        True for pairs-folder renders: :func:`load_pair` registers the render
        on the raw (crop, flips; :mod:`l3cli.align`) and masks clipped pixels
        and the border (:mod:`l3cli.pairs`).
    scaled
        For pairs-folder renders: a render that is a resized copy of the raw
        is accepted and trained at its reduced resolution
        (:func:`l3cli.pairs.load_pair` with ``scaled=True``).
    """

    raw: Path
    target: Path
    stem: str
    space: str | None = None
    align: bool = False
    scaled: bool = False


def _simulation_pairs(folder: Path) -> list[Pair]:
    from l3cli.io.manifest import read_manifest

    manifest = read_manifest(folder)  # validated: each capture has raw, target, stem
    space = check_space(manifest["target"]["space"])
    pairs = [Pair(folder / cap["raw"], folder / cap["target"], cap["stem"], space)
             for cap in manifest["captures"]]
    return pairs


def _pairs_folder(folder: Path, scaled: bool) -> list[Pair]:
    # One definition of a pairs folder: l3cli.pairs (raw suffixes, one render per raw).
    from l3cli.pairs import find_pairs as find_pair_files
    from l3cli.pairs import is_pairs_dir

    if not is_pairs_dir(folder):
        return []
    return [Pair(f.raw, f.render, f.name, None, align=True, scaled=scaled)
            for f in find_pair_files([folder])]


def find_pairs(inputs: list[str | os.PathLike], *, scaled_renders: bool = False) -> list[Pair]:
    """Training pairs of every input folder, in a stable order.

    Parameters
    ----------
    inputs
        ``simulate`` output folders and pairs folders.
    scaled_renders
        Accept pairs-folder renders that are resized copies of their raws
        (see :attr:`Pair.scaled`).

    Raises
    ------
    InputError
        A missing path, a folder without pairs, or a raw without its target.
    """
    pairs: list[Pair] = []
    for inp in inputs:
        folder = Path(inp)
        if not folder.exists():
            raise InputError(f"{folder}: no such folder")
        if not folder.is_dir():
            raise InputError(f"{folder}: training input must be a simulate or pairs folder")
        found = (_simulation_pairs(folder) if (folder / "manifest.json").exists()
                 else _pairs_folder(folder, scaled_renders))
        if not found:
            raise InputError(
                f"{folder}: no training pairs (no manifest.json and no raw file with a "
                "same-stem image)"
            )
        pairs.extend(found)
    return pairs


def load_pair(pair: Pair, *, target_space: str = "xyz", with_mask: bool = False) -> tuple:
    """Read a pair: ``(RawImage, target float32 (H, W, 3) in target_space)``.

    Pairs-folder pairs (``pair.align``) are aligned by :func:`l3cli.pairs.load_pair`:
    the raw comes back cropped to the render's area. With ``with_mask`` a third
    item is returned: bool (H, W) pixels that may train (clipped render pixels
    and a border margin excluded), or ``None`` (all pixels).

    Raises
    ------
    InputError
        Unreadable files, raw and target of different sizes, a target with NaN
        or Inf, or a target that is not a 3-channel image.
    """
    from l3cli.io.image import read_image
    from l3cli.io.raw import read_raw

    if pair.align:
        from l3cli.pairs import PairFiles
        from l3cli.pairs import load_pair as load_aligned

        al = load_aligned(PairFiles(pair.stem, pair.raw, pair.target), target_space=target_space,
                          scaled=pair.scaled)
        if not np.all(np.isfinite(al.raw.mosaic)):
            raise InputError(f"{pair.raw}: raw mosaic holds NaN or Inf")
        return (al.raw, al.target, al.weight_mask) if with_mask else (al.raw, al.target)
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
    target = convert(img, space, check_space(target_space))
    if with_mask:
        return raw, np.ascontiguousarray(target, dtype=np.float32), None
    return raw, np.ascontiguousarray(target, dtype=np.float32)
