"""Registration of a resized render (``l3 train --scaled-renders``).

See :mod:`l3cli.align` for the method (scale search, refinement, check).
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
    apply_flip,
    band_pass,
    encode_luminance,
    match_score,
    phase_correlate,
    raw_luminance,
    render_luminance,
)
from l3cli.errors import InputError
from l3cli.io.raw import RawImage

__all__ = ["ScaledAlignment", "align_scaled", "scaled_pair"]

log = logging.getLogger("l3cli.align")


@dataclass(frozen=True)
class ScaledAlignment:
    """Where a resized render lies on its raw.

    A pixel ``(r, q)`` of ``apply_flip(render, flip)`` is centred on the raw
    position ``(y0 + r * step_y, x0 + q * step_x)`` (raw pixel centres at
    integers).

    Attributes
    ----------
    y0, x0
        Raw position of the centre of the re-oriented render's first pixel.
    step_y, step_x
        Raw pixels per render pixel along rows and columns (> 1 for a
        reduced render).
    flip
        One of :data:`FLIPS`, as in :class:`Alignment`.
    score
        Band-pass correlation of the aligned luminances at the render's
        resolution.
    height, width
        The render's size in pixels, as stored (before ``flip``).
    """

    y0: float
    x0: float
    step_y: float
    step_x: float
    flip: str
    score: float
    height: int
    width: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form."""
        return asdict(self)

    def describe(self) -> str:
        """One-line human summary."""
        return (f"resized render: scale {1 / self.step_y:.4f} x {1 / self.step_x:.4f} of the raw, "
                f"origin (y={self.y0:.2f}, x={self.x0:.2f}), flip {self.flip}, "
                f"score {self.score:.3f}")


#: Largest grid (pixels, longer side) on which the scale is searched / refined.
_COARSE_SIDE = 256
_REFINE_SIDE = 768


def _sample(lum: np.ndarray, y0: float, x0: float, dy: float, dx: float,
            shape: tuple[int, int]) -> np.ndarray:
    """``lum`` bilinearly sampled at ``(y0 + i dy, x0 + j dx)`` for an output of ``shape``."""
    from scipy.ndimage import map_coordinates

    yy = (y0 + dy * np.arange(shape[0], dtype=np.float64)).astype(np.float32)
    xx = (x0 + dx * np.arange(shape[1], dtype=np.float64)).astype(np.float32)
    coords = np.stack(np.broadcast_arrays(yy[:, None], xx[None, :]))
    return map_coordinates(lum, coords, order=1, mode="nearest").astype(np.float32)


def _reduce(lum: np.ndarray, factor: float, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Anti-aliased resampling of ``lum`` to one pixel per ``factor`` pixels."""
    from scipy.ndimage import gaussian_filter

    if factor <= 1.0:
        return np.asarray(lum, dtype=np.float32)
    if shape is None:
        shape = (int(lum.shape[0] / factor), int(lum.shape[1] / factor))
    blurred = gaussian_filter(np.asarray(lum, dtype=np.float32), 0.45 * factor)
    off = 0.5 * factor - 0.5
    return _sample(blurred, off, off, factor, factor, shape)


def align_scaled(raw: RawImage, render: np.ndarray, *, space: str = "srgb",
                 raw_name: str | Path | None = None, render_name: str | Path | None = None,
                 flips: tuple[str, ...] = FLIPS, min_score: float = MIN_SCORE,
                 max_crop: float = 0.15) -> ScaledAlignment:
    """Register a render that is a resized copy of the raw or of a window of it.

    Parameters
    ----------
    raw
        The raw mosaic.
    render
        float (h, w, C) rendered image, smaller than the raw.
    space
        The render's colour space (``srgb`` for TIFF/PNG/JPEG).
    raw_name, render_name
        File names for messages.
    flips
        Orientations to consider.
    min_score
        Smallest accepted band-pass correlation.
    max_crop
        Largest fraction of the raw's extent (along the axis the render fills
        best) that the render may leave out.

    Returns
    -------
    ScaledAlignment

    Raises
    ------
    InputError
        The render is not smaller than the raw, is featureless, or does not
        match the raw at any scale searched (distorted, a different shot, or
        cropped by more than ``max_crop``), naming both files.

    Notes
    -----
    See the module notes ("Scale search", "Refinement"). The scales along rows
    and columns are refined separately, since a resize rounds each side to
    whole pixels.
    """
    from scipy.ndimage import gaussian_filter
    from scipy.optimize import minimize

    rname = str(raw_name if raw_name is not None else (raw.path or "raw"))
    iname = str(render_name if render_name is not None else "render")
    h0, w0 = render.shape[:2]
    if min(h0, w0) < 32:
        raise InputError(f"{iname} ({w0}x{h0}) is too small to align with {rname} (need 32x32)")
    rlum = render_luminance(render, space)
    if float(np.std(band_pass(encode_luminance(rlum)))) < FEATURELESS:
        raise InputError(f"{iname} is featureless: its scale and position on {rname} "
                         "cannot be found")
    lum = raw_luminance(raw)
    H, W = lum.shape

    best = None  # (sharpness, flip, step, dy, dx, coarse factor)
    for flip in flips:
        ren = apply_flip(rlum, flip)
        h, w = ren.shape
        s_fit = min(H / h, W / w)
        if s_fit < 1.0:
            continue
        s_lo = max(1.0, s_fit * (1.0 - max_crop))
        c = max(1.0, max(h, w) / _COARSE_SIDE)
        rc = _reduce(ren, c)
        base_f = s_lo * c
        base = _reduce(lum, base_f)  # one large reduction, then small ones per candidate
        n = int(np.ceil((s_fit - s_lo) / (0.004 * s_fit))) + 1
        for step in np.linspace(s_fit, s_lo, n):
            f = step * c
            lc = _reduce(base, f / base_f) if f / base_f > 1.0 + 1e-9 else base
            if lc.shape[0] < rc.shape[0] or lc.shape[1] < rc.shape[1]:
                continue
            sharp, dy, dx = phase_correlate(lc, rc, taper=4)
            if best is None or sharp > best[0]:
                best = (sharp, flip, float(step), dy, dx, c)
    if best is None:
        raise InputError(f"{iname} ({w0}x{h0}) is not smaller than its raw {rname} "
                         f"({raw.width}x{raw.height}) in any orientation; it is not a reduced render")
    _, flip, step, cdy, cdx, c = best
    ren = apply_flip(rlum, flip)
    h, w = ren.shape
    # coarse pixel i of the raw grid is centred on raw (i + 0.5) step c - 0.5; render
    # coarse pixel i on render (i + 0.5) c - 0.5; hence render pixel 0 on:
    y0 = cdy * step * c + 0.5 * step - 0.5
    x0 = cdx * step * c + 0.5 * step - 0.5

    # Refinement on a grid of at most _REFINE_SIDE pixels (m render pixels each).
    m = max(1.0, max(h, w) / _REFINE_SIDE)
    rm = band_pass(encode_luminance(_reduce(ren, m)))
    rm = (rm - rm.mean()) / max(float(rm.std()), 1e-12)
    lum_b = gaussian_filter(lum, 0.45 * step * m)
    off = 0.5 * m - 0.5  # render position of the first refine-grid pixel

    def cost(p: np.ndarray) -> float:
        py0, px0, sy, sx = p
        s = _sample(lum_b, py0 + off * sy, px0 + off * sx, m * sy, m * sx, rm.shape)
        b = band_pass(encode_luminance(s))
        sd = float(b.std())
        if sd <= 0:
            return 1.0
        return -float(np.mean(rm * (b - b.mean()))) / sd

    p0 = np.array([y0, x0, step, step])
    simplex = np.array([p0, p0 + [1.5, 0, 0, 0], p0 + [0, 1.5, 0, 0],
                        p0 + [0, 0, 0.003 * step, 0], p0 + [0, 0, 0, 0.003 * step]])
    res = minimize(cost, p0, method="Nelder-Mead",
                   options={"initial_simplex": simplex, "xatol": 0.01, "fatol": 1e-5,
                            "maxiter": 600})
    y0, x0, sy, sx = (float(v) for v in res.x)
    inside = (y0 >= -0.5 and x0 >= -0.5 and y0 + (h - 1) * sy <= H - 0.5
              and x0 + (w - 1) * sx <= W - 0.5)
    score = match_score(_sample(gaussian_filter(lum, 0.45 * step), y0, x0, sy, sx, (h, w)), ren)
    log.debug("%s on %s: scale search %s", iname, rname,
              f"flip {flip}, step {sy:.4f}/{sx:.4f}, origin ({y0:.2f}, {x0:.2f}), score {score:.3f}")
    if score < min_score or not inside or sy < 1.0 or sx < 1.0:
        raise InputError(
            f"{iname} does not align with {rname} even as a resized copy: best match "
            f"scale {1 / sy:.3f} x {1 / sx:.3f} at ({y0:.1f}, {x0:.1f}) flip {flip} has "
            f"structure correlation {score:.2f} (need {min_score:g})"
            + ("" if inside else " and lies partly outside the raw")
            + f" - the render looks distorted (lens correction), of a different shot, or "
            f"cropped by more than {max_crop:.0%} of the raw"
        )
    return ScaledAlignment(y0, x0, sy, sx, flip, score, int(h0), int(w0))


def scaled_pair(raw: RawImage, render: np.ndarray, alignment: ScaledAlignment, *,
                valid: np.ndarray | None = None, space: str = "srgb",
                ) -> tuple[RawImage, np.ndarray, np.ndarray]:
    """The raw crop under a resized render and the render resampled onto its pixels.

    Parameters
    ----------
    raw
        The full raw.
    render
        (h, w, C) render as read (values in ``space``).
    alignment
        From :func:`align_scaled`.
    valid
        bool (h, w) pixels of the render that may train (clipping, margin), or
        None for all.
    space
        The render's colour space; display sRGB is resampled in linear light
        and encoded again.

    Returns
    -------
    raw_crop, target, valid
        ``raw_crop`` keeps the raw's CFA phase (its origin is a multiple of the
        CFA period); ``target`` float32 (H', W', C) in ``space``, bilinear
        between render pixels; ``valid`` bool (H', W'): True where every render
        pixel that contributes is valid.
    """
    from scipy.ndimage import map_coordinates

    from l3cli.colourspace import srgb_decode, srgb_encode

    a = alignment
    h, w = render.shape[:2]
    if (h, w) != (a.height, a.width):
        raise InputError(f"render is {w}x{h} but the alignment was found for {a.width}x{a.height}")
    img = np.asarray(apply_flip(np.asarray(render, dtype=np.float32), a.flip))
    ok = np.ones(img.shape[:2], bool) if valid is None else np.asarray(apply_flip(valid, a.flip))
    rh, rw = img.shape[:2]
    ph, pw = raw.cfa.period
    ya = int(np.ceil(a.y0 - 1e-9))
    xa = int(np.ceil(a.x0 - 1e-9))
    ya += (-ya) % ph
    xa += (-xa) % pw
    yb = int(np.floor(a.y0 + (rh - 1) * a.step_y + 1e-9))
    xb = int(np.floor(a.x0 + (rw - 1) * a.step_x + 1e-9))
    if yb < ya or xb < xa:
        raise InputError("the resized render covers no whole raw pixel")
    crop = raw.crop(ya, xa, yb - ya + 1, xb - xa + 1)
    crop.metadata["alignment"] = a.to_dict()
    ry = ((np.arange(ya, yb + 1) - a.y0) / a.step_y).astype(np.float32)
    rx = ((np.arange(xa, xb + 1) - a.x0) / a.step_x).astype(np.float32)
    coords = np.stack(np.broadcast_arrays(ry[:, None], rx[None, :]))
    lin = srgb_decode(np.clip(img, 0.0, 1.0)) if space == "srgb" else img
    chans = [map_coordinates(lin[..., k], coords, order=1, mode="nearest")
             for k in range(lin.shape[2])]
    target = np.stack(chans, axis=-1).astype(np.float32)
    if space == "srgb":
        target = srgb_encode(target).astype(np.float32)
    good = map_coordinates(ok.astype(np.float32), coords, order=1, mode="nearest") > 0.999
    return crop, np.ascontiguousarray(target), good

