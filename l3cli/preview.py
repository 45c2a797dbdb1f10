"""Training from raws alone: the camera's own JPEG preview embedded in the raw as the render.

Many raw files embed a full-size (or a reduced) JPEG of the camera's own
rendering. ``l3 train --embedded-preview`` uses it as each raw's render:
:func:`preview_pairs` extracts every raw's largest embedded preview with
rawpy (LibRaw's ``extract_thumb``; JPEG previews are written out byte for
byte, bitmap previews as lossless PNG) into a working folder, and returns
pairs-folder :class:`l3cli.pairs.Pair` records for them. They are
registered like any render (:mod:`l3cli.align`: crop, flips and rotations),
and a reduced preview is accepted as a resized copy of the raw
(``scaled``: trained at its resolution on the raw's pixel grid, as with
``--scaled-renders``). A preview smaller than :data:`MIN_PREVIEW_FRACTION`
of the raw's width is refused: it holds too little detail to learn from.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from l3cli.errors import InputError

__all__ = ["MIN_PREVIEW_FRACTION", "extract_preview", "preview_pairs"]

log = logging.getLogger(__name__)

#: Smallest preview width accepted, as a fraction of the raw's width.
MIN_PREVIEW_FRACTION = 0.25


def extract_preview(raw_path: str | os.PathLike, out_stem: str | os.PathLike) -> Path:
    """Write ``raw_path``'s embedded preview to ``out_stem`` + ``.jpg`` (or ``.png``).

    Raises
    ------
    InputError
        LibRaw cannot open the file, it embeds no preview, or the preview is
        too small.
    """
    import rawpy

    raw_path = Path(raw_path)
    try:
        with rawpy.imread(str(raw_path)) as rp:
            width = int(rp.sizes.width)
            try:
                thumb = rp.extract_thumb()
            except (rawpy.LibRawNoThumbnailError, rawpy.LibRawUnsupportedThumbnailError):
                thumb = None
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise InputError(f"{raw_path}: not a raw file LibRaw can read, so no embedded "
                         f"preview ({type(exc).__name__})") from exc
    if thumb is None:
        raise InputError(f"{raw_path}: no embedded preview (LibRaw finds none); give a "
                         "rendered image of the same stem instead of --embedded-preview")
    out_stem = Path(out_stem)
    if thumb.format == rawpy.ThumbFormat.JPEG:
        out = out_stem.with_suffix(".jpg")
        out.write_bytes(bytes(thumb.data))
        from l3cli.io.image import read_image

        pw = read_image(out)[0].shape[1]
    else:
        from PIL import Image

        arr = np.asarray(thumb.data)
        if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
            raise InputError(f"{raw_path}: embedded preview is not an 8-bit RGB image "
                             f"({arr.shape} {arr.dtype})")
        out = out_stem.with_suffix(".png")
        Image.fromarray(arr).save(out)
        pw = arr.shape[1]
    short = min(pw, width) / max(pw, width)  # rotated previews: compare the long sides too
    if short < MIN_PREVIEW_FRACTION and pw < width:
        out.unlink()
        raise InputError(f"{raw_path}: embedded preview is {pw} pixels wide for a {width}-pixel "
                         f"raw, below {MIN_PREVIEW_FRACTION:g} of its size: too small to train")
    return out


def preview_pairs(inputs: Iterable[str | os.PathLike], workdir: str | os.PathLike) -> list:
    """Training pairs of every raw in ``inputs`` (folders) with its embedded preview.

    Previews are written into ``workdir`` (one file per raw). Headerless dumps
    (``.raw`` + sidecar) and l3's mosaics have no preview and are refused.

    Raises
    ------
    InputError
        A missing folder, a folder without raw files, a raw without a usable
        preview.
    """
    from l3cli.io.raw import sidecar_path
    from l3cli.pairs import Pair, is_raw_file

    work = Path(workdir)
    pairs = []
    for inp in inputs:
        folder = Path(inp)
        if not folder.is_dir():
            raise InputError(f"{folder}: no such folder")
        raws = sorted(f for f in folder.iterdir() if f.is_file() and is_raw_file(f))
        if not raws:
            raise InputError(f"{folder}: no raw files for --embedded-preview")
        for raw in raws:
            if sidecar_path(raw).exists():
                raise InputError(f"{raw}: a headerless dump or mosaic has no embedded preview")
            stem = raw.name[: -len(raw.suffix)]
            out = extract_preview(raw, work / f"{len(pairs):04d}_{stem}")
            log.info("%s: embedded preview %s", raw.name, out.name)
            pairs.append(Pair(stem, raw, out, None, align=True, scaled=True))
    return pairs
