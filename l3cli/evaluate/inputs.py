"""Inputs of an evaluation: (rendered, reference) items, and images read as XYZ.

See :mod:`l3cli.evaluate` for the pairing rules and the XYZ conventions.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from l3cli.errors import ConfigError, InputError
from l3cli.pairs import (
    RENDER_SUFFIXES,
    is_raw_file,
    is_simulation_dir,
    read_simulation_manifest,
)

__all__ = ["IMAGE_SUFFIXES", "EvalItem", "ArrayImage", "find_items", "load_xyz", "load_image"]

log = logging.getLogger("l3cli.evaluate")

#: Suffixes of rendered images looked for in a render folder, in order of
#: preference: the input layer's (:data:`l3cli.pairs.RENDER_SUFFIXES`).
IMAGE_SUFFIXES = RENDER_SUFFIXES


@dataclass(frozen=True, eq=False)
class ArrayImage:
    """An image held in memory, evaluated as a file would be: float (H, W, 3) values in
    colour space ``space`` (linear spaces: a display white has Y = 1; ``srgb``: display
    code values in [0, 1]); ``name`` stands for the file in messages."""

    values: np.ndarray
    space: str
    name: str = "the image"

    def __str__(self) -> str:
        return self.name


@dataclass(frozen=True)
class EvalItem:
    """One (rendered, reference) pair to evaluate.

    Attributes
    ----------
    name
        Name in the report (the capture stem, or the rendered file name).
    rendered, reference
        Image paths (or :class:`ArrayImage`).
    capture
        The manifest's capture record when the reference is a simulation.
    camera
        The manifest's camera record when the reference is a simulation.
    reference_space
        Colour space of the reference declared by the manifest (or None: from the file).
    """

    name: str
    rendered: Path
    reference: Path
    capture: dict | None = None
    camera: dict | None = None
    reference_space: str | None = None



def _images_in(folder: Path) -> list[Path]:
    """Rendered images in a folder: image suffixes, not hidden, not raws.

    A TIFF or PNG with a raw sidecar (``X.tif`` + ``X.tif.toml``) is a raw
    mosaic (``l3 simulate`` writes such files for CFAs DNG cannot describe), never
    a rendering.
    """
    return sorted(
        p for p in folder.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES
        and not is_raw_file(p)
    )


def _by_stem(folder: Path) -> dict[str, Path]:
    """The rendered images of a folder by stem; a stem with two images is refused."""
    found: dict[str, list[Path]] = {}
    for p in _images_in(folder):
        found.setdefault(p.stem, []).append(p)
    for stem, paths in found.items():
        if len(paths) > 1:
            names = ", ".join(p.name for p in paths)
            raise InputError(
                f"{folder}: several images of stem {stem!r} ({names}); give the reference file "
                "itself, or keep one image per stem"
            )
    return {stem: paths[0] for stem, paths in found.items()}


def _render_for(images: list[Path], stem: str) -> Path | None:
    """The render of ``stem`` among a folder's images, by :data:`IMAGE_SUFFIXES` preference."""
    found = {p.suffix.lower(): p for p in images if p.stem == stem}
    return next((found[s] for s in IMAGE_SUFFIXES if s in found), None)


def find_items(
    rendered: Sequence[str | os.PathLike], references: Sequence[str | os.PathLike]
) -> list[EvalItem]:
    """Pair rendered images with references.

    Parameters
    ----------
    rendered
        Rendered image files, or one folder of them.
    references
        Reference image files (one per rendered file, same order), one folder of
        images (matched by stem), or one ``simulate`` folder (matched to the
        captures by stem).

    Returns
    -------
    list of EvalItem

    Raises
    ------
    InputError
        Missing paths, unequal counts, or a render that matches no capture.
    """
    rendered = [Path(p) for p in rendered]
    references = [Path(p) for p in references]
    if not rendered:
        raise InputError("no rendered image given")
    if not references:
        raise InputError("no reference given (--reference)")
    for p in (*rendered, *references):
        if not p.exists():
            raise InputError(f"{p}: no such file or folder")

    if len(references) == 1 and references[0].is_dir():
        ref_dir = references[0]
        if is_simulation_dir(ref_dir):
            return _simulation_items(rendered, ref_dir)
        ref_images = _by_stem(ref_dir)
        renders = _expand_renders(rendered)
        items = []
        for r in renders:
            ref = ref_images.get(r.stem)
            if ref is None:
                raws = [p.name for p in ref_dir.glob(f"{r.stem}.*") if is_raw_file(p)]
                why = f" ({', '.join(raws)} is a raw, not a rendering)" if raws else ""
                raise InputError(f"{r}: no reference image {r.stem}.* in {ref_dir}{why}")
            items.append(EvalItem(r.stem, r, ref))
        return items

    for p in references:
        if p.is_dir():
            raise InputError(f"{p}: give one reference folder, or reference files only")
    renders = _expand_renders(rendered)
    if len(renders) != len(references):
        raise InputError(
            f"{len(renders)} rendered image(s) but {len(references)} reference(s); "
            "give one reference per rendered image, in the same order"
        )
    return [EvalItem(r.name, r, ref) for r, ref in zip(renders, references, strict=True)]


def _expand_renders(rendered: list[Path]) -> list[Path]:
    out: list[Path] = []
    for p in rendered:
        if p.is_dir():
            found = _images_in(p)
            if not found:
                raise InputError(f"{p}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
            out.extend(found)
        else:
            out.append(p)
    return out


def _simulation_items(rendered: list[Path], sim_dir: Path) -> list[EvalItem]:
    manifest = read_simulation_manifest(sim_dir)
    camera = manifest.get("camera") or {}
    space = (manifest.get("target") or {}).get("space", "xyz")
    captures = {}
    for cap in manifest["captures"]:  # validated by the manifest reader
        captures[cap["stem"]] = cap
    items = []
    if len(rendered) == 1 and rendered[0].is_dir():
        folder = rendered[0]
        images = _images_in(folder)
        for stem, cap in captures.items():
            r = _render_for(images, stem)
            if r is None:
                log.info("%s: no render of capture %s; skipped", folder, stem)
                continue
            items.append(EvalItem(stem, r, sim_dir / cap["target"], cap, camera, space))
        if not items:
            raise InputError(
                f"{folder}: no render matches a capture of {sim_dir} "
                f"(expected files like {next(iter(captures), 'STEM')}.exr)"
            )
        return items
    for r in _expand_renders(rendered):
        stem = r.stem
        cap = captures.get(stem)
        if cap is None:
            raise InputError(
                f"{r}: its stem {stem!r} is not a capture of {sim_dir} "
                f"(captures: {', '.join(sorted(captures)[:5])}{', ...' if len(captures) > 5 else ''})"
            )
        items.append(EvalItem(stem, r, sim_dir / cap["target"], cap, camera, space))
    return items


def load_xyz(path: str | os.PathLike, *, space: str | None = None) -> tuple[np.ndarray, str]:
    """Read an image as float64 (H, W, 3) CIE XYZ.

    Parameters
    ----------
    path
        Image file (EXR, TIFF, PNG, JPEG).
    space
        Colour space of the file's values; None takes it from the file
        (EXR ``l3:space`` attribute; display sRGB for the others).

    Returns
    -------
    xyz, space
        XYZ (display-encoded images on the 100 scale: white Y = 100) and the
        space the values were in.

    Raises
    ------
    InputError
        Unreadable file, an unknown colour space (encoding), or not 3 channels.
    """
    xyz, space, _ = load_image(path, space)
    return xyz, space


def load_image(path: str | os.PathLike, space: str | None) -> tuple[np.ndarray, str, np.ndarray]:
    """:func:`load_xyz`, and the file's (3-channel) values as read."""
    from l3cli.colourspace import check_space, convert
    from l3cli.io.image import read_image

    if isinstance(path, ArrayImage):
        img, file_space = np.asarray(path.values, dtype=np.float32), path.space
        if img.ndim == 2:
            img = img[:, :, None]
        if img.ndim != 3:
            raise InputError(f"{path}: an image array is (H, W, 3), not {img.shape}")
    else:
        img, file_space = read_image(path)
    name = space or file_space
    try:
        space = check_space(name)
    except ConfigError:
        raise InputError(
            f"{path}: unknown encoding / colour space {name!r}; allowed: xyz, linear-srgb, srgb, lab"
        ) from None
    if img.shape[2] == 4:
        img = img[:, :, :3]
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    if img.shape[2] != 3:
        raise InputError(f"{path}: has {img.shape[2]} channels; evaluation needs 3 (or 1)")
    if not np.all(np.isfinite(img)):
        raise InputError(f"{path}: holds NaN or infinite values")
    xyz = np.asarray(convert(img, space, "xyz"), dtype=np.float64)
    if space == "srgb":
        xyz *= 100.0
    return xyz, space, img

