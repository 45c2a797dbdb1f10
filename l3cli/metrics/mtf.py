"""MTF by the ISO 12233 slanted-edge method, in the manner of Burns' ``sfrmat``.

Steps (for an edge within 45 degrees of vertical; a near-horizontal edge is
transposed first):

1. Luminance from linear RGB with weights (0.213, 0.715, 0.072) (ISETCam's
   ``ISO12233``); a single-channel image is used as is.
2. Per row, the derivative ``a[x+1] - a[x]`` is windowed by a Hamming window and
   its centroid gives the edge location; a line ``x = a + b y`` is fitted. A
   second pass centres the window on the fitted line and refits.
3. Only an integer number of phase cycles of rows is kept (as ``sfrmat``).
4. Every pixel's perpendicular distance to the line, ``(x - a - b y) cos(atan b)``,
   is binned at 1/4 pixel: the 4x oversampled edge-spread function (ESF). Empty
   bins are filled by linear interpolation.
5. Line-spread function = central difference of the ESF; Hamming window centred
   on its centroid; FFT; modulus normalised at zero frequency; divided by the
   frequency response of the central difference, sinc(2 f d) with d = 1/4 pixel
   (``sfrmat``'s derivative correction).
6. MTF50 = first frequency where the MTF drops below 0.5, linearly interpolated.

Frequencies are in cycles per pixel (along the edge normal), and in cycles/mm
given the pixel pitch.

References
----------
ISO 12233:2017, Photography - Electronic still picture imaging - Resolution and
spatial frequency responses, Annex D (edge-based SFR).
P. D. Burns, "Slanted-edge MTF for digital camera and scanner analysis", Proc.
IS&T PICS 2000, 135-138; ``sfrmat3``/``sfrmat4`` (2015-2021).
ISETCam ``ISO12233``, https://github.com/ISET/isetcam.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from l3cli.errors import InputError

__all__ = ["LUMINANCE_WEIGHTS", "MTFResult", "slanted_edge_mtf", "mtf50"]

#: Weights of linear R, G, B for the luminance used by ISETCam's ISO12233.
LUMINANCE_WEIGHTS = (0.213, 0.715, 0.072)

_OVERSAMPLING = 4


@dataclass(frozen=True)
class MTFResult:
    """Result of a slanted-edge measurement.

    Attributes
    ----------
    frequencies
        (N,) frequencies in cycles per pixel, 0 .. 1 (twice Nyquist).
    mtf
        (N,) MTF, 1 at zero frequency.
    mtf50_cy_per_px
        Frequency where the MTF first drops below 0.5 (cycles/pixel).
    mtf50_cy_per_mm
        The same in cycles/mm, or None without a pixel pitch.
    angle_deg
        Edge angle from the vertical (or horizontal for a transposed edge), degrees.
    orientation
        ``"vertical"`` or ``"horizontal"``: the edge's near direction.
    """

    frequencies: NDArray
    mtf: NDArray
    mtf50_cy_per_px: float
    mtf50_cy_per_mm: float | None
    angle_deg: float
    orientation: str


def _hamming(n: int, centre: float) -> NDArray:
    # Hamming window of n samples whose peak is at ``centre`` and that reaches
    # 0.08 at the farther end (Burns' ``ahamming``).
    x = np.arange(n, dtype=np.float64)
    half = max(centre, n - 1 - centre, 1.0)
    return 0.54 + 0.46 * np.cos(np.pi * (x - centre) / half)


def _centroid(v: NDArray) -> float:
    s = v.sum()
    if s == 0 or not np.isfinite(s):
        return float("nan")
    return float((np.arange(v.size) * v).sum() / s)


def _no_edge(msg: str) -> InputError:
    return InputError(f"no edge found in the MTF region: {msg}")


def _edge_line(a: NDArray) -> tuple[float, float]:
    """Fit x = p0 + p1 * y to the per-row centroids of the windowed derivative."""
    nrows, ncols = a.shape
    d = np.diff(a, axis=1)  # located at x + 0.5
    rows = np.arange(nrows, dtype=np.float64)
    win = _hamming(ncols - 1, (ncols - 2) / 2.0)
    loc = np.array([_centroid(d[r] * win) for r in range(nrows)]) + 0.5
    p = _fit(rows, loc)
    for _ in range(2):
        centres = p[1] + p[0] * rows - 0.5
        loc = np.array(
            [_centroid(d[r] * _hamming(ncols - 1, centres[r])) for r in range(nrows)]
        ) + 0.5
        p = _fit(rows, loc)
    return float(p[1]), float(p[0])


def _fit(rows: NDArray, loc: NDArray) -> NDArray:
    ok = np.isfinite(loc)
    if ok.sum() < 3:
        raise _no_edge("the edge location could not be found in enough rows")
    return np.polyfit(rows[ok], loc[ok], 1)


def slanted_edge_mtf(
    image: ArrayLike,
    *,
    roi: tuple[int, int, int, int] | None = None,
    pixel_pitch_um: float | None = None,
    weights: tuple[float, float, float] = LUMINANCE_WEIGHTS,
) -> MTFResult:
    """Spatial frequency response of a slanted edge (ISO 12233, after Burns' ``sfrmat``).

    Parameters
    ----------
    image
        (H, W) or (H, W, C) linear image; with 3 channels the luminance
        ``weights @ RGB`` is used, with 1 channel the values as they are.
    roi
        ``(x0, y0, x1, y1)`` region holding one straight edge (x1, y1
        exclusive); the whole image when None.
    pixel_pitch_um
        Pixel pitch in micrometres, to report cycles/mm.
    weights
        Luminance weights of linear R, G, B.

    Returns
    -------
    MTFResult
        Frequencies (cycles/pixel), MTF curve, MTF50 in cycles/pixel and cycles/mm.

    Raises
    ------
    InputError
        If the region is outside the image or too small, or no usable edge is
        found in it (flat or noise-only region, edge leaving the region, edge
        not slanted enough for 4x oversampling); the message says so.

    Notes
    -----
    For a point-sampled edge blurred by a Gaussian of standard deviation
    sigma (pixels), MTF(f) = exp(-2 pi^2 sigma^2 f^2), hence
    MTF50 = sqrt(ln 2 / 2) / (pi sigma) cycles/pixel.

    References
    ----------
    ISO 12233:2017 Annex D; Burns (2000), ``sfrmat3``; ISETCam ``ISO12233``.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3:
        if img.shape[2] != 3:
            raise InputError(f"slanted-edge MTF needs 1 or 3 channels, got {img.shape[2]}")
        img = img @ np.asarray(weights, dtype=np.float64)
    if img.ndim != 2:
        raise InputError(f"slanted-edge MTF needs an (H, W[, C]) image, got shape {img.shape}")
    h, w = img.shape
    if roi is not None:
        x0, y0, x1, y1 = (int(v) for v in roi)
        if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
            raise InputError(
                f"MTF region [{x0}, {y0}, {x1}, {y1}] is not inside the {w}x{h} image"
            )
        img = img[y0:y1, x0:x1]
    if min(img.shape) < 8:
        raise InputError(f"MTF region of {img.shape[1]}x{img.shape[0]} pixels is too small (8x8 at least)")
    if not np.all(np.isfinite(img)):
        raise InputError("MTF region holds NaN or infinite values")

    # Orientation: rows must cross the edge.
    gx = np.abs(np.diff(img, axis=1)).sum() / max(img.shape[0] * (img.shape[1] - 1), 1)
    gy = np.abs(np.diff(img, axis=0)).sum() / max((img.shape[0] - 1) * img.shape[1], 1)
    orientation = "vertical"
    if gy > gx:
        img = img.T
        orientation = "horizontal"
    nrows, ncols = img.shape

    # Is there an edge at all? Compare the step between the two sides with the noise.
    k = max(2, ncols // 8)
    step = img[:, -k:].mean() - img[:, :k].mean()
    noise = float(np.median(np.abs(np.diff(img, axis=0)))) / 0.6745 / math.sqrt(2.0)
    scale = max(float(np.abs(img).max()), 1e-30)
    if abs(step) <= max(5.0 * noise, 1e-6 * scale):
        raise _no_edge(
            f"the two sides differ by {abs(step):.3g}, not clearly more than the noise ({noise:.3g})"
        )
    if step < 0:
        img = -img

    intercept, slope = _edge_line(img)
    rows = np.arange(nrows, dtype=np.float64)
    edge_x = intercept + slope * rows
    if edge_x.min() < 1 or edge_x.max() > ncols - 2:
        raise _no_edge("the fitted edge leaves the region; centre the region on the edge")
    angle = math.degrees(math.atan(slope))
    if abs(slope) * nrows < 1.0:
        raise _no_edge(
            f"the edge is only {abs(angle):.2f} degrees from the pixel grid; "
            f"it must cross at least one pixel over the region's {nrows} rows (tilt it 2-10 degrees)"
        )
    # Keep an integer number of phase cycles (sfrmat).
    n_use = int(round(math.floor(nrows * abs(slope)) / abs(slope)))
    n_use = min(max(n_use, 3), nrows)
    img = img[:n_use]
    rows = rows[:n_use]

    cosang = math.cos(math.atan(slope))
    xx = np.arange(ncols, dtype=np.float64)
    dist = (xx[None, :] - (intercept + slope * rows)[:, None]) * cosang
    fac = _OVERSAMPLING
    bins = np.floor(dist * fac).astype(np.int64).ravel()
    bmin = bins.min()
    bins -= bmin
    nb = int(bins.max()) + 1
    counts = np.bincount(bins, minlength=nb)
    sums = np.bincount(bins, weights=img.ravel(), minlength=nb)
    # Keep the span of bins that is well populated on both sides of the edge.
    centre_bin = -bmin
    half = min(centre_bin, nb - 1 - centre_bin)
    half = int(min(half, (ncols * fac) // 2))
    if half < 4 * fac:
        raise _no_edge("the edge is too close to the region's side; centre the region on the edge")
    lo, hi = centre_bin - half, centre_bin + half
    counts = counts[lo:hi]
    sums = sums[lo:hi]
    filled = counts > 0
    if filled.sum() < 0.5 * counts.size:
        raise _no_edge("too few samples across the edge")
    idx = np.arange(counts.size)
    esf = np.interp(idx, idx[filled], sums[filled] / counts[filled])

    lsf = np.zeros_like(esf)
    lsf[1:-1] = 0.5 * (esf[2:] - esf[:-2])
    lsf[0], lsf[-1] = lsf[1], lsf[-2]
    c = _centroid(np.clip(lsf, 0, None))
    if not np.isfinite(c):
        raise _no_edge("the line-spread function is empty")
    lsf = lsf * _hamming(lsf.size, c)
    spectrum = np.abs(np.fft.rfft(lsf))
    if spectrum[0] <= 0:
        raise _no_edge("the line-spread function has no area")
    mtf = spectrum / spectrum[0]
    delta = 1.0 / fac
    freqs = np.fft.rfftfreq(lsf.size, d=delta)
    # Derivative correction: the central difference has response sinc(2 f delta).
    corr = np.sinc(2.0 * freqs * delta)
    corr = np.maximum(corr, 0.1)
    mtf = mtf / corr
    keep = freqs <= 1.0 + 1e-12
    freqs, mtf = freqs[keep], mtf[keep]
    f50 = mtf50(freqs, mtf)
    f50_mm = None if pixel_pitch_um is None else f50 / (float(pixel_pitch_um) * 1e-3)
    return MTFResult(
        frequencies=freqs,
        mtf=mtf,
        mtf50_cy_per_px=f50,
        mtf50_cy_per_mm=f50_mm,
        angle_deg=angle,
        orientation=orientation,
    )


def mtf50(frequencies: ArrayLike, mtf: ArrayLike) -> float:
    """First frequency where ``mtf`` drops below 0.5, linearly interpolated.

    Examples
    --------
    >>> mtf50([0.0, 0.25, 0.5], [1.0, 0.75, 0.25])  # 0.5 lies half way from 0.25 to 0.5
    0.375

    Raises
    ------
    InputError
        If the curve never drops below 0.5 in the given range.
    """
    f = np.asarray(frequencies, dtype=np.float64)
    m = np.asarray(mtf, dtype=np.float64)
    below = np.nonzero(m < 0.5)[0]
    if below.size == 0 or below[0] == 0:
        raise InputError("the MTF does not fall below 0.5 up to 1 cycle/pixel; no MTF50")
    i = int(below[0])
    f0, f1, m0, m1 = f[i - 1], f[i], m[i - 1], m[i]
    return float(f0 + (m0 - 0.5) * (f1 - f0) / (m0 - m1))
