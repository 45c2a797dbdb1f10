"""Shared helpers of the metrics package: input checks and CIELAB through colour-science."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from l3cli.errors import InputError

__all__ = ["as_image", "check_same_shape", "xyz_to_lab", "delta_e"]


def as_image(image: ArrayLike, *, name: str = "image", channels: int | None = None) -> NDArray:
    """Return ``image`` as a float64 (H, W, C) array, checking its shape.

    Parameters
    ----------
    image
        (H, W) or (H, W, C) array.
    name
        Name used in error messages.
    channels
        Required number of channels, or None for any.

    Raises
    ------
    InputError
        If the array is not 2-D or 3-D, is empty, or has the wrong channel count.
    """
    arr = np.asarray(image, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise InputError(f"{name}: expected an (H, W) or (H, W, C) image, got shape {arr.shape}")
    if channels is not None and arr.shape[2] != channels:
        raise InputError(f"{name}: expected {channels} channels, got {arr.shape[2]}")
    return arr


def check_same_shape(a: NDArray, b: NDArray, *, name_a: str = "reference", name_b: str = "test") -> None:
    """Raise :class:`InputError` naming both sizes when two images differ in shape."""
    if a.shape != b.shape:
        raise InputError(
            f"{name_b} is {_size(b)} but {name_a} is {_size(a)}: images must have the same size"
        )


def _size(a: NDArray) -> str:
    h, w = a.shape[:2]
    c = a.shape[2] if a.ndim == 3 else 1
    return f"{w}x{h} pixels with {c} channel{'s' if c != 1 else ''}"


def xyz_to_lab(xyz: ArrayLike, white_xyz: ArrayLike) -> NDArray:
    """CIE 1976 L*a*b* of ``xyz`` relative to the white ``white_xyz`` (same absolute scale).

    A thin wrapper around :func:`colour.XYZ_to_Lab`: colour-science wants XYZ with the
    white's Y = 1 and the white as a chromaticity, so both are rescaled by the
    white's Y first.

    Parameters
    ----------
    xyz
        (..., 3) CIE XYZ on any scale.
    white_xyz
        (3,) XYZ of the reference white on the same scale (Y > 0).

    Returns
    -------
    ndarray
        (..., 3) L*, a*, b*; L* = 100 for the white.

    Examples
    --------
    >>> white = np.array([95.047, 100.0, 108.883])  # D65 on a scale of 100
    >>> [abs(round(float(v), 6)) for v in xyz_to_lab(white, white)]
    [100.0, 0.0, 0.0]
    >>> round(float(xyz_to_lab(white * 0.18, white)[0]), 2)  # 18 % grey
    49.5

    References
    ----------
    CIE 015:2018 Colorimetry, 4th ed., section 8.2.1 (CIE 1976 L*a*b*).
    """
    import colour

    white = np.asarray(white_xyz, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(white)) or white[1] <= 0 or np.any(white <= 0):
        raise InputError(f"white point must be positive XYZ, got {white.tolist()}")
    xy = white[:2] / white.sum()
    return np.asarray(colour.XYZ_to_Lab(np.asarray(xyz, dtype=np.float64) / white[1], xy))


def delta_e(lab_a: ArrayLike, lab_b: ArrayLike, *, method: str = "CIE 1976") -> NDArray:
    """ΔE between two CIELAB arrays through :func:`colour.delta_E` (``"CIE 1976"`` or ``"CIE 2000"``).

    Examples
    --------
    ΔE*ab (CIE 1976) is the Euclidean distance in L*a*b*:

    >>> float(delta_e([50.0, 0.0, 0.0], [50.0, 3.0, 4.0]))
    5.0
    """
    import colour

    return np.asarray(colour.delta_E(lab_a, lab_b, method=method))
