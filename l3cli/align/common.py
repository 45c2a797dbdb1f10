"""What both registrations share: orientations, luminances and the match score.

See :mod:`l3cli.align` for the method; :mod:`l3cli.align.pixel` registers
pixel-aligned renders, :mod:`l3cli.align.scaled` resized ones.
"""

from __future__ import annotations

import numpy as np

from l3cli.io.raw import RawImage

__all__ = ["FLIPS", "MIN_SCORE", "MIN_SHARPNESS", "FEATURELESS", "apply_flip", "raw_luminance",
           "render_luminance", "tukey_window", "prepare_for_correlation", "encode_luminance",
           "band_pass", "match_score", "correlation_peak", "phase_correlate"]


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


def apply_flip(img: np.ndarray, flip: str) -> np.ndarray:
    """Re-orient an (H, W, ...) array by one of :data:`FLIPS`.

    ``transpose...`` swaps rows and columns first; then ``horizontal`` mirrors
    left-right, ``vertical`` up-down, ``both`` both (a 180-degree turn).
    A render rotated 90 degrees clockwise from the raw is brought back by
    ``transpose-vertical``, one rotated counter-clockwise by
    ``transpose-horizontal``.

    Examples
    --------
    >>> img = np.arange(6).reshape(2, 3)
    >>> apply_flip(img, "horizontal").tolist()
    [[2, 1, 0], [5, 4, 3]]
    >>> apply_flip(img, "transpose-vertical").tolist()
    [[2, 5], [1, 4], [0, 3]]
    >>> np.array_equal(apply_flip(np.rot90(img, -1), "transpose-vertical"), img)  # a clockwise turn undone
    True
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
def tukey_window(n: int, taper: int) -> np.ndarray:
    """float32 (n,) window: 1 inside, raised-cosine ramps of ``taper`` samples at both ends."""
    w = np.ones(n, dtype=np.float32)
    t = min(taper, n // 2)
    if t > 0:
        ramp = 0.5 - 0.5 * np.cos(np.pi * (np.arange(t, dtype=np.float32) + 0.5) / t)
        w[:t] = ramp
        w[n - t :] = ramp[::-1]
    return w


def prepare_for_correlation(lum: np.ndarray, taper: int) -> np.ndarray:
    """Encoded, mean-removed, Tukey-windowed luminance, ready for phase correlation."""
    # Register in the display domain (sRGB-like); equalises bright and dark edges.
    x = encode_luminance(lum)
    x = x - x.mean()
    return x * tukey_window(x.shape[0], taper)[:, None] * tukey_window(x.shape[1], taper)[None, :]


def encode_luminance(lum: np.ndarray) -> np.ndarray:
    """Luminance scaled by its 99.5th percentile, clipped and sRGB-encoded (float32)."""
    lum = np.asarray(lum, dtype=np.float32)
    scale = float(np.percentile(lum, 99.5)) or 1.0
    x = np.clip(lum / np.float32(scale), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(
        np.float32
    )


def band_pass(x: np.ndarray) -> np.ndarray:
    """Difference of Gaussians (sigma 1 and 3 pixels)."""
    from scipy.ndimage import gaussian_filter

    return gaussian_filter(x, 1.0) - gaussian_filter(x, 3.0)


def match_score(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of band-passed, encoded luminances."""
    fa = band_pass(encode_luminance(a)).ravel().astype(np.float64)
    fb = band_pass(encode_luminance(b)).ravel().astype(np.float64)
    fa -= fa.mean()
    fb -= fb.mean()
    den = np.sqrt((fa @ fa) * (fb @ fb))
    return float(fa @ fb / den) if den > 0 else 0.0


def correlation_peak(surf: np.ndarray, h: int, w: int) -> tuple[float, int, int]:
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


def phase_correlate(raw_lum: np.ndarray, ren: np.ndarray, taper: int) -> tuple[float, int, int]:
    """Phase-correlation peak (sharpness, dy, dx) of ``ren`` inside ``raw_lum``."""
    from scipy import fft

    H, W = raw_lum.shape
    h, w = ren.shape
    canvas = np.zeros((H, W), dtype=np.float32)
    canvas[:h, :w] = prepare_for_correlation(ren, taper)
    cross = fft.rfft2(prepare_for_correlation(raw_lum, taper), workers=-1) * np.conj(fft.rfft2(canvas, workers=-1))
    cross /= np.maximum(np.abs(cross), 1e-12)
    return correlation_peak(fft.irfft2(cross, s=(H, W), workers=-1), h, w)
