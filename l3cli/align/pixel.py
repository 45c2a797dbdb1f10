"""Registration of a pixel-aligned render: integer offset and flip on its raw.

See :mod:`l3cli.align` for the method (phase correlation, band-pass check).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.align.common import (
    FEATURELESS,
    FLIPS,
    MIN_SCORE,
    MIN_SHARPNESS,
    apply_flip,
    band_pass,
    correlation_peak,
    encode_luminance,
    match_score,
    prepare_for_correlation,
    raw_luminance,
    render_luminance,
)
from l3cli.errors import InputError
from l3cli.io.raw import RawImage

__all__ = ["Alignment", "register", "align", "aligned_pair"]

log = logging.getLogger("l3cli.align")


@dataclass(frozen=True)
class Alignment:
    """Where a render lies on its raw.

    Attributes
    ----------
    dy, dx
        Offset in the raw mosaic of the top-left pixel of the render brought
        to the raw's orientation (``apply_flip(render, flip)``).
    flip
        One of :data:`FLIPS`: how to mirror (or transpose) the render to bring
        it to the raw's orientation (``horizontal`` = left-right).
    score
        Band-pass correlation of the aligned luminances (1 = identical structure).
    sharpness
        Peak-to-side-lobe ratio of the phase-correlation peak.
    height, width
        The render's size in pixels, as stored (before ``flip``).
    """

    dy: int
    dx: int
    flip: str
    score: float
    sharpness: float
    height: int
    width: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form."""
        return asdict(self)

    def describe(self) -> str:
        """One-line human summary."""
        return (f"offset (dy={self.dy}, dx={self.dx}), flip {self.flip}, "
                f"score {self.score:.3f}, sharpness {self.sharpness:.0f}")



def register(raw_lum: np.ndarray, render_lum: np.ndarray, *,
             flips: tuple[str, ...] = FLIPS, taper: int = 16) -> Alignment:
    """Best offset and flip of a render luminance within a raw luminance.

    Parameters
    ----------
    raw_lum
        (H, W) luminance of the raw (:func:`raw_luminance`).
    render_lum
        (h, w) luminance of the render, ``h <= H``, ``w <= W``.
    flips
        Flips to try.
    taper
        Width in pixels of the Tukey taper applied at the image edges.

    Returns
    -------
    Alignment
        The best candidate with its score and sharpness; not yet checked
        against thresholds (:func:`align` does that).

    Raises
    ------
    ValueError
        The render is larger than the raw in some dimension.
    """
    from scipy import fft

    H, W = raw_lum.shape
    h0, w0 = render_lum.shape
    fits = [f for f in flips if apply_flip(render_lum, f).shape[0] <= H
            and apply_flip(render_lum, f).shape[1] <= W]
    if not fits:
        raise ValueError(f"render {w0}x{h0} is larger than the raw {W}x{H}")
    fr = fft.rfft2(prepare_for_correlation(raw_lum, taper), workers=-1)
    cands = []
    for flip in fits:
        ren = apply_flip(render_lum, flip)
        h, w = ren.shape
        canvas = np.zeros((H, W), dtype=np.float32)
        canvas[:h, :w] = prepare_for_correlation(ren, taper)
        fc = fft.rfft2(canvas, workers=-1)
        cross = fr * np.conj(fc)
        cross /= np.maximum(np.abs(cross), 1e-12)
        surf = fft.irfft2(cross, s=(H, W), workers=-1)
        sharp, iy, ix = correlation_peak(surf, h, w)
        cands.append((sharp, flip, iy, ix))
        log.debug("flip %s: offset (%d, %d), sharpness %.1f", flip, iy, ix, sharp)
    sharp, flip, iy, ix = max(cands, key=lambda c: c[0])
    ren = apply_flip(render_lum, flip)
    h, w = ren.shape
    score = match_score(raw_lum[iy : iy + h, ix : ix + w], ren)
    return Alignment(iy, ix, flip, score, sharp, int(h0), int(w0))


def align(raw: RawImage, render: np.ndarray, *, space: str = "srgb",
          raw_name: str | Path | None = None, render_name: str | Path | None = None,
          flips: tuple[str, ...] = FLIPS, min_score: float = MIN_SCORE,
          min_sharpness: float = MIN_SHARPNESS) -> Alignment:
    """Find and verify where a rendered image lies on its raw.

    Parameters
    ----------
    raw
        The raw mosaic.
    render
        float (h, W, C) rendered image (as read by :func:`l3cli.io.image.read_image`).
    space
        The render's colour space (``srgb`` for TIFF/PNG/JPEG).
    raw_name, render_name
        File names for messages (default: ``raw.path`` and ``"render"``).
    flips
        Flips to consider.
    min_score, min_sharpness
        Acceptance thresholds (see the module notes).

    Returns
    -------
    Alignment
        ``score`` and ``sharpness`` are NaN for a featureless render of the
        raw's size, taken as pixel-aligned.

    Raises
    ------
    InputError
        The render is larger than the raw, or does not align with it (scaled,
        distorted or a different shot), naming both files.
    """
    rname = str(raw_name if raw_name is not None else (raw.path or "raw"))
    iname = str(render_name if render_name is not None else "render")
    h, w = render.shape[:2]
    transposes = any(f.startswith("transpose") for f in flips)
    if (h > raw.height or w > raw.width) and (
            not transposes or w > raw.height or h > raw.width):
        raise InputError(
            f"{iname} ({w}x{h}) is larger than its raw {rname} ({raw.width}x{raw.height}); "
            "l3 needs a render of the raw's full area or a crop of it"
        )
    if min(h, w) < 32:
        raise InputError(f"{iname} ({w}x{h}) is too small to align with {rname} (need 32x32)")
    rlum = render_luminance(render, space)
    if float(np.std(band_pass(encode_luminance(rlum)))) < FEATURELESS:
        # A flat render (grey card, flat field) holds nothing to register.
        if (h, w) == (raw.height, raw.width):
            log.warning("%s is featureless: cannot verify its alignment with %s; "
                        "assumed pixel-aligned (same size)", iname, rname)
            return Alignment(0, 0, "none", float("nan"), float("nan"), int(h), int(w))
        raise InputError(
            f"{iname} is featureless and smaller than its raw {rname} ({w}x{h} vs "
            f"{raw.width}x{raw.height}): its position cannot be found"
        )
    a = register(raw_luminance(raw), rlum, flips=flips)
    if a.score < min_score or a.sharpness < min_sharpness:
        scaled = ""
        if (h, w) != (raw.height, raw.width):
            scaled = (f" (render {w}x{h} is {w / raw.width:.3f} x {h / raw.height:.3f} of "
                      f"the raw {raw.width}x{raw.height})")
        raise InputError(
            f"{iname} does not align with {rname}{scaled}: best match at offset "
            f"({a.dy}, {a.dx}) flip {a.flip} has structure correlation {a.score:.2f} "
            f"(need {min_score:g}) and peak sharpness {a.sharpness:.0f} (need {min_sharpness:g})"
            " - the render looks scaled, distorted (lens correction) or of a different shot;"
            " l3 trains only on renders of the full raw or a crop of it, possibly mirrored or rotated"
        )
    log.debug("%s aligned with %s: %s", iname, rname, a.describe())
    return a


def aligned_pair(raw: RawImage, render: np.ndarray,
                 alignment: Alignment) -> tuple[RawImage, np.ndarray]:
    """The raw crop under the render and the render in the raw's orientation.

    Parameters
    ----------
    raw
        The full raw.
    render
        (h, w, C) render as read.
    alignment
        From :func:`align`.

    Returns
    -------
    raw_crop, target
        ``raw_crop`` (h, w) (w, h after a transpose) with the CFA phase of the crop origin
        (:meth:`RawImage.crop`), ``target`` float32, ``apply_flip(render, alignment.flip)``, contiguous.
    """
    a = alignment
    h, w = render.shape[:2]
    if (h, w) != (a.height, a.width):
        raise InputError(f"render is {w}x{h} but the alignment was found for {a.width}x{a.height}")
    target = np.ascontiguousarray(apply_flip(np.asarray(render, dtype=np.float32), a.flip))
    crop = raw.crop(a.dy, a.dx, target.shape[0], target.shape[1])
    crop.metadata["alignment"] = a.to_dict()
    return crop, target

