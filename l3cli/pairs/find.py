"""Finding pairs: which raws and targets the inputs name (:class:`Pair`, :func:`find_pairs`).

See :mod:`l3cli.pairs` for the input kinds; :mod:`l3cli.pairs.load` reads a pair.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from l3cli.errors import InputError
from l3cli.io import manifest as _manifest
from l3cli.io.raw import RAW_SUFFIXES, sidecar_path

log = logging.getLogger("l3cli.pairs")  # one logger name for the package

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
