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

from l3cli.align.common import (
    FLIPS,
    MIN_SCORE,
    MIN_SHARPNESS,
    apply_flip,
    raw_luminance,
    render_luminance,
)
from l3cli.align.pixel import Alignment, align, aligned_pair, register
from l3cli.align.scaled import ScaledAlignment, align_scaled, scaled_pair

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
