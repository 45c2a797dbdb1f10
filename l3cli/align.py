"""Registration of a rendered image against its raw mosaic.

A raw converter's output is rarely the raw's exact pixel grid: RawTherapee
drops 4 pixels on each side, darktable applies the DNG ``DefaultCrop``, camera
JPEGs crop a few pixels, and an image may come out mirrored. Training needs
the render pixel-aligned with the mosaic, so :func:`align` finds

* the integer offset ``(dy, dx)`` of the render's top-left pixel in the raw,
* the flip (``none``, ``horizontal``, ``vertical``, ``both``, and the same
  after a transpose, which covers 90-degree rotations) that maps the render
  back onto the raw's orientation,

by phase correlation [1]_ between a quick luminance of the mosaic and the
luminance of the render, and verifies the match before accepting it.

Convention: with ``a = align(...)`` and ``t = apply_flip(render, a.flip)`` of
size ``(h, w)``, ``raw.mosaic[a.dy:a.dy + h, a.dx:a.dx + w]`` shows the same
scene pixels as ``t``. :func:`aligned_pair` returns exactly that pair, the raw
side as a :class:`~l3cli.io.raw.RawImage` crop whose CFA phase follows the crop
origin.

Raw luminance
    Each CFA channel is scaled to a common mean (grey world), then the mosaic
    is filtered with the separable triangle kernel of length ``2p - 1`` per
    axis (``p`` the CFA period; ``[1, 2, 1] / 4`` for Bayer). That kernel is
    two box filters of one period each, so every output pixel sees every CFA
    position with the same total weight: a full-resolution, phase-free,
    unshifted luminance (the ``[1 2 1]`` filter is the classical bilinear
    luma estimate of a Bayer mosaic [2]_).
Render luminance
    Display-encoded renders (TIFF, PNG, JPEG) are decoded with the sRGB
    transfer function; the channel mean is the luminance.
Registration
    Normalised cross-power spectrum (phase correlation) of the mean-removed,
    Tukey-windowed luminances, the render zero-padded into the raw's frame;
    the peak is searched over the offsets that keep the render inside the
    raw, for each of the orientations that fit.
Verification
    The ``score`` is the Pearson correlation, over the aligned overlap, of
    band-pass (difference of Gaussians, sigma 1 and 3 pixels) versions of both
    luminances after the sRGB encoding (so that tone curves of the render
    matter little). A correct match scores well above 0.5 on real renders
    (0.8-0.95 on the bundled Infinite-ISP pairs); one pixel off, a rescaled
    or distorted render, or a different shot scores near 0. The phase
    correlation peak must also stand out of the rest of the surface (peak to
    side-lobe ratio ``sharpness``).

A featureless render (flat field, grey card) cannot be registered: one of
the raw's exact size is taken as pixel-aligned (with a warning), a smaller
one is refused.

Scaled renders (a camera JPEG at reduced size) are refused by :func:`align`:
training needs pixel-aligned pairs. Only when asked (``l3 train
--scaled-renders``), :func:`align_scaled` registers a render that is a resized
copy of the raw (or of a window of it, possibly mirrored or rotated):
Scale search
    For each orientation, the scale (raw pixels per render pixel) is searched
    over ``[(1 - max_crop) s_fit, s_fit]``, ``s_fit`` being the largest scale
    at which the render still fits inside the raw, with both luminances
    resampled to a coarse grid (about 256 pixels) and registered by phase
    correlation at each candidate.
Refinement
    The best candidate's origin and the two scales (rows, columns) are refined
    to a fraction of a raw pixel by maximising the band-pass correlation
    (Nelder-Mead) between the render and the raw luminance resampled at the
    render's pixel positions, on a grid of at most 768 pixels.
Verification
    The same ``score`` as :func:`align` (at least ``MIN_SCORE``), measured at
    the render's full resolution.
:func:`scaled_pair` then resamples the render onto the raw's pixel grid
(bilinear, in linear light): the pair trains on the raw's own pixels, but
the target holds only the detail of the reduced render.

References
----------
.. [1] C. D. Kuglin and D. C. Hines, "The phase correlation image alignment
   method", Proc. IEEE Int. Conf. Cybernetics and Society, pp. 163-165, 1975.
.. [2] H. S. Malvar, L.-W. He and R. Cutler, "High-quality linear interpolation
   for demosaicing of Bayer-patterned color images", Proc. IEEE ICASSP, 2004.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.errors import InputError
from l3cli.io.raw import RawImage

__all__ = [
    "FLIPS",
    "Alignment",
    "apply_flip",
    "raw_luminance",
    "render_luminance",
    "register",
    "align",
    "aligned_pair",
    "ScaledAlignment",
    "align_scaled",
    "scaled_pair",
    "MIN_SCORE",
    "MIN_SHARPNESS",
]

log = logging.getLogger(__name__)

#: Orientations tried: the four mirrorings, and the same after a transpose
#: (rows <-> columns; with a mirroring, a 90-degree rotation, see
#: :func:`apply_flip`). Transposed ones are tried only where they fit the raw.
FLIPS: tuple[str, ...] = ("none", "horizontal", "vertical", "both",
                          "transpose", "transpose-horizontal", "transpose-vertical",
                          "transpose-both")

#: Smallest verification score (band-pass correlation) accepted by :func:`align`.
MIN_SCORE = 0.5
#: Smallest peak-to-side-lobe ratio of the phase-correlation peak accepted.
MIN_SHARPNESS = 10.0
#: A render whose band-passed encoded luminance varies less than this (RMS,
#: about a tenth of an 8-bit code) has no structure to register.
FEATURELESS = 0.4 / 1020


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


def apply_flip(img: np.ndarray, flip: str) -> np.ndarray:
    """Re-orient an (H, W, ...) array by one of :data:`FLIPS`.

    ``transpose...`` swaps rows and columns first; then ``horizontal`` mirrors
    left-right, ``vertical`` up-down, ``both`` both (a 180-degree turn).
    A render rotated 90 degrees clockwise from the raw is brought back by
    ``transpose-vertical``, one rotated counter-clockwise by
    ``transpose-horizontal``.
    """
    if flip not in FLIPS:
        raise ValueError(f"flip {flip!r} is not one of {FLIPS}")
    if flip.startswith("transpose"):
        img = np.swapaxes(img, 0, 1)
        flip = flip[len("transpose-"):] if "-" in flip else "none"
    if flip in ("horizontal", "both"):
        img = img[:, ::-1]
    if flip in ("vertical", "both"):
        img = img[::-1]
    return img


# ------------------------------------------------------------------ luminances
def raw_luminance(raw: RawImage) -> np.ndarray:
    """Full-resolution luminance of a mosaic, free of the CFA phase.

    Parameters
    ----------
    raw
        The normalised mosaic.

    Returns
    -------
    numpy.ndarray
        float32 (H, W), linear, unshifted (pixel (y, x) is centred on the raw
        pixel (y, x)); borders use reflected data.
    """
    from scipy.ndimage import convolve1d

    m = np.clip(np.asarray(raw.mosaic, dtype=np.float32), 0.0, None)
    ph, pw = raw.cfa.period
    idx = raw.cfa.index_pattern
    sums = np.zeros(raw.cfa.n_channels)
    counts = np.zeros(raw.cfa.n_channels)
    for y in range(ph):
        for x in range(pw):
            plane = m[y::ph, x::pw]
            sums[idx[y, x]] += float(plane.sum(dtype=np.float64))
            counts[idx[y, x]] += plane.size
    means = sums / np.maximum(counts, 1)
    top = max(float(means.max()), 1e-6)
    bal = np.empty_like(m)
    for y in range(ph):
        for x in range(pw):
            bal[y::ph, x::pw] = m[y::ph, x::pw] * np.float32(top / max(means[idx[y, x]], 1e-6))
    out = bal
    for axis, p in ((0, ph), (1, pw)):
        if p > 1:
            k = np.convolve(np.ones(p), np.ones(p))
            out = convolve1d(out, (k / k.sum()).astype(np.float32), axis=axis, mode="reflect")
    return out.astype(np.float32)


def render_luminance(image: np.ndarray, space: str = "srgb") -> np.ndarray:
    """Linear luminance (channel mean) of a rendered image.

    Parameters
    ----------
    image
        float (H, W, C) as read by :func:`l3cli.io.image.read_image`.
    space
        ``srgb`` for display-encoded values (decoded first); any linear space
        (``linear-srgb``, ``xyz``) is used as is.
    """
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = img[:, :, None]
    if space == "srgb":
        from l3cli.colourspace import srgb_decode

        img = srgb_decode(np.clip(img, 0.0, 1.0))
    elif space == "lab":
        from l3cli.colourspace import convert

        img = convert(img, "lab", "xyz")[:, :, 1:2]
    return img[:, :, :3].mean(axis=2).astype(np.float32)


# -------------------------------------------------------------- registration
def _tukey(n: int, taper: int) -> np.ndarray:
    w = np.ones(n, dtype=np.float32)
    t = min(taper, n // 2)
    if t > 0:
        ramp = 0.5 - 0.5 * np.cos(np.pi * (np.arange(t, dtype=np.float32) + 0.5) / t)
        w[:t] = ramp
        w[n - t :] = ramp[::-1]
    return w


def _prepare(lum: np.ndarray, taper: int) -> np.ndarray:
    # Register in the display domain (sRGB-like); equalises bright and dark edges.
    x = _encode(lum)
    x = x - x.mean()
    return x * _tukey(x.shape[0], taper)[:, None] * _tukey(x.shape[1], taper)[None, :]


def _encode(lum: np.ndarray) -> np.ndarray:
    lum = np.asarray(lum, dtype=np.float32)
    scale = float(np.percentile(lum, 99.5)) or 1.0
    x = np.clip(lum / np.float32(scale), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(
        np.float32
    )


def _bandpass(x: np.ndarray) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    return gaussian_filter(x, 1.0) - gaussian_filter(x, 3.0)


def _score(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of band-passed, encoded luminances."""
    fa = _bandpass(_encode(a)).ravel().astype(np.float64)
    fb = _bandpass(_encode(b)).ravel().astype(np.float64)
    fa -= fa.mean()
    fb -= fb.mean()
    den = np.sqrt((fa @ fa) * (fb @ fb))
    return float(fa @ fb / den) if den > 0 else 0.0


def _peak(surf: np.ndarray, h: int, w: int) -> tuple[float, int, int]:
    """Highest point of a phase-correlation surface over the offsets that keep an
    (h, w) render inside it, and its peak-to-side-lobe ratio."""
    H, W = surf.shape
    valid = surf[: H - h + 1, : W - w + 1]
    iy, ix = np.unravel_index(int(np.argmax(valid)), valid.shape)
    peak = float(valid[iy, ix])
    # side lobes: the whole surface less an 11x11 window around the peak
    win = surf[np.ix_((np.arange(iy - 5, iy + 6) % H), (np.arange(ix - 5, ix + 6) % W))]
    n = surf.size - win.size
    s1 = float(surf.sum(dtype=np.float64)) - float(win.sum(dtype=np.float64))
    s2 = float(np.square(surf, dtype=np.float64).sum()) - float(np.square(win).sum())
    mu = s1 / n
    sd = np.sqrt(max(s2 / n - mu * mu, 0.0))
    sharp = (peak - mu) / sd if sd > 0 else 0.0
    return float(sharp), int(iy), int(ix)


def _phase_correlate(raw_lum: np.ndarray, ren: np.ndarray, taper: int) -> tuple[float, int, int]:
    """Phase-correlation peak (sharpness, dy, dx) of ``ren`` inside ``raw_lum``."""
    from scipy import fft

    H, W = raw_lum.shape
    h, w = ren.shape
    canvas = np.zeros((H, W), dtype=np.float32)
    canvas[:h, :w] = _prepare(ren, taper)
    cross = fft.rfft2(_prepare(raw_lum, taper), workers=-1) * np.conj(fft.rfft2(canvas, workers=-1))
    cross /= np.maximum(np.abs(cross), 1e-12)
    return _peak(fft.irfft2(cross, s=(H, W), workers=-1), h, w)


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
    fr = fft.rfft2(_prepare(raw_lum, taper), workers=-1)
    cands = []
    for flip in fits:
        ren = apply_flip(render_lum, flip)
        h, w = ren.shape
        canvas = np.zeros((H, W), dtype=np.float32)
        canvas[:h, :w] = _prepare(ren, taper)
        fc = fft.rfft2(canvas, workers=-1)
        cross = fr * np.conj(fc)
        cross /= np.maximum(np.abs(cross), 1e-12)
        surf = fft.irfft2(cross, s=(H, W), workers=-1)
        sharp, iy, ix = _peak(surf, h, w)
        cands.append((sharp, flip, iy, ix))
        log.debug("flip %s: offset (%d, %d), sharpness %.1f", flip, iy, ix, sharp)
    sharp, flip, iy, ix = max(cands, key=lambda c: c[0])
    ren = apply_flip(render_lum, flip)
    h, w = ren.shape
    score = _score(raw_lum[iy : iy + h, ix : ix + w], ren)
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
    if float(np.std(_bandpass(_encode(rlum)))) < FEATURELESS:
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


# ------------------------------------------------------------- scaled renders
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
    if float(np.std(_bandpass(_encode(rlum)))) < FEATURELESS:
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
            sharp, dy, dx = _phase_correlate(lc, rc, taper=4)
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
    rm = _bandpass(_encode(_reduce(ren, m)))
    rm = (rm - rm.mean()) / max(float(rm.std()), 1e-12)
    lum_b = gaussian_filter(lum, 0.45 * step * m)
    off = 0.5 * m - 0.5  # render position of the first refine-grid pixel

    def cost(p: np.ndarray) -> float:
        py0, px0, sy, sx = p
        s = _sample(lum_b, py0 + off * sy, px0 + off * sx, m * sy, m * sx, rm.shape)
        b = _bandpass(_encode(s))
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
    score = _score(_sample(gaussian_filter(lum, 0.45 * step), y0, x0, sy, sx, (h, w)), ren)
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
