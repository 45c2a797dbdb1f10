"""Per-sample weights of the per-class least-squares fit (``l3 train --sample-weight``).

``"luminance"``: each training pixel weighs its target's luminance ``Y``
(CIE Y, white = 1), floored at :data:`l3cli.defaults.WEIGHT_FLOOR`, to the
power :data:`l3cli.defaults.WEIGHT_EXPONENT`, normalised to mean 1 over an
image's training pixels. Within a class (one raw level and contrast) the fit
then favours the pixels the render shows brighter: on the bundled
Infinite-ISP frames, with the D4 augmentation, this lowered the
leave-one-image-out S-CIELAB from 1.368 to 1.302, while weights that favour
dark pixels (the slope of the display encoding) raised it to 1.43-1.51
(docs/training.md, "Augmentation and sample weights"). The statistics stay additive: the weighted products add
over images like the unweighted ones (:func:`l3cli.train.stats.accumulate`).
"""

from __future__ import annotations

import numpy as np

from l3cli import defaults
from l3cli.errors import ConfigError

__all__ = ["WEIGHT_CHOICES", "check_weight", "luminance", "sample_weights"]

#: Values of ``--sample-weight``.
WEIGHT_CHOICES = ("none", "luminance")


def check_weight(mode: str) -> str:
    """``mode`` when it is one of :data:`WEIGHT_CHOICES`, else :class:`ConfigError`."""
    if mode not in WEIGHT_CHOICES:
        raise ConfigError(f"--sample-weight {mode!r} is not known; use "
                          f"{', '.join(WEIGHT_CHOICES)}")
    return mode


def luminance(target: np.ndarray, space: str) -> np.ndarray:
    """CIE Y (white = 1) of a (H, W, 3) target in ``space``; float32 (H, W)."""
    from l3cli.colourspace import convert

    if space == "xyz":
        return np.asarray(target[..., 1], dtype=np.float32)
    return np.asarray(convert(np.asarray(target[..., :3], dtype=np.float32), space,
                              "xyz")[..., 1], dtype=np.float32)


def sample_weights(y: np.ndarray, mask: np.ndarray | None, mode: str, *,
                   floor: float = defaults.WEIGHT_FLOOR,
                   exponent: float = defaults.WEIGHT_EXPONENT) -> np.ndarray | None:
    """Weights of an image's training pixels from their target luminance.

    Parameters
    ----------
    y
        float (H, W) target luminance (:func:`luminance`).
    mask
        bool (H, W) training pixels (None: all); the weights have mean 1 over them.
    mode
        ``"none"`` (returns None: unweighted) or ``"luminance"``.
    floor
        Luminance below which the weight stays at its floor value (> 0).
    exponent
        The weight is the floored luminance to this power.

    Returns
    -------
    numpy.ndarray or None
        float32 (H, W) non-negative weights.
    """
    if check_weight(mode) == "none":
        return None
    w = np.maximum(np.nan_to_num(np.asarray(y, dtype=np.float32), nan=0.0), np.float32(floor))
    w = w ** np.float32(exponent)
    sel = w if mask is None else w[mask]
    mean = float(sel.mean(dtype=np.float64)) if sel.size else 1.0
    return (w / np.float32(mean)).astype(np.float32)
