"""Peak signal-to-noise ratio with the data range taken from the encoding.

PSNR = 10 log10(R^2 / MSE) over all pixels and channels, where R is the range
of the encoding: 1 for display-encoded images held in [0, 1] (8-bit or 16-bit
PNG/TIFF/JPEG; equal to 255 on 8-bit codes), and the white level (the Y of the
white point) for linear images such as EXR, whose scale is otherwise arbitrary.

References
----------
Z. Wang and A. C. Bovik, "Mean squared error: love it or leave it?", IEEE Signal
Processing Magazine 26(1), 98-117 (2009).
scikit-image ``skimage.metrics.peak_signal_noise_ratio`` (data range convention).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from l3cli.errors import InputError
from l3cli.metrics._common import as_image, check_same_shape

__all__ = ["ENCODING_DATA_RANGE", "data_range_for", "psnr"]

#: Data range of display encodings whose values l3 holds in [0, 1].
ENCODING_DATA_RANGE = {"srgb": 1.0, "display": 1.0}


def data_range_for(encoding: str, *, white_level: float | None = None) -> float:
    """Data range for PSNR from an image encoding.

    Examples
    --------
    >>> data_range_for("srgb")
    1.0
    >>> data_range_for("linear", white_level=0.5)
    0.5

    Parameters
    ----------
    encoding
        ``"srgb"`` (display-encoded, values in [0, 1]) or ``"linear"`` (EXR).
    white_level
        For ``"linear"``: the value of white on the image's scale (required).

    Raises
    ------
    InputError
        For an unknown encoding, or ``"linear"`` without a positive white level.
    """
    enc = encoding.lower()
    if enc in ENCODING_DATA_RANGE:
        return ENCODING_DATA_RANGE[enc]
    if enc in ("linear", "xyz", "linear-srgb"):
        if white_level is None or not white_level > 0:
            raise InputError(f"PSNR of a linear image needs a positive white level, got {white_level!r}")
        return float(white_level)
    raise InputError(f"unknown image encoding {encoding!r}; allowed: srgb, linear")


def psnr(reference: ArrayLike, test: ArrayLike, *, data_range: float) -> float:
    """Peak signal-to-noise ratio in dB.

    Parameters
    ----------
    reference, test
        Images of the same shape.
    data_range
        Peak value R of the encoding (see :func:`data_range_for`).

    Returns
    -------
    float
        10 log10(R^2 / MSE); ``inf`` for identical images.

    Raises
    ------
    InputError
        If the shapes differ (both sizes are named) or ``data_range`` <= 0.

    Examples
    --------
    >>> import numpy as np
    >>> round(psnr(np.zeros((4, 4)), np.full((4, 4), 0.1), data_range=1.0), 6)
    20.0
    """
    a = as_image(reference, name="reference")
    b = as_image(test, name="test")
    check_same_shape(a, b)
    if not (data_range > 0 and math.isfinite(data_range)):
        raise InputError(f"PSNR data range must be positive, got {data_range!r}")
    mse = float(np.mean((a - b) ** 2))
    if mse == 0:
        return math.inf
    return 10.0 * math.log10(data_range**2 / mse)
