"""Mosaic checks and row bands shared by the tile kernel's callers.

:func:`check_mosaic` turns any array into the C-contiguous float32 mosaic the
tile kernel (:mod:`l3cli.classify.kernel`) reads, or refuses it in one line;
:func:`band_rows` cuts an image into bands of bounded size (training's
statistics, band-wise renders).
"""

from __future__ import annotations

import numpy as np

from l3cli.cfa import CFA
from l3cli.errors import InputError

__all__ = ["band_rows", "check_mosaic"]


def check_mosaic(mosaic: np.ndarray, cfa: CFA, patch: int) -> np.ndarray:
    """``mosaic`` as a C-contiguous, aligned, writable float32 (H, W) array (copied only
    when it is not: numba compiles the tile kernel apart for an unaligned or read-only
    array); raise if it cannot be classified.

    Raises
    ------
    InputError
        When the mosaic is not 2-D or is smaller than the CFA period or half a patch.
    """
    mosaic = np.asarray(mosaic)
    if mosaic.ndim != 2:
        raise InputError(f"a raw mosaic must be 2-D (H, W), got shape {mosaic.shape}")
    ph, pw = cfa.period
    if mosaic.shape[0] < max(ph, patch // 2 + 1) or mosaic.shape[1] < max(pw, patch // 2 + 1):
        raise InputError(
            f"raw mosaic {mosaic.shape[1]}x{mosaic.shape[0]} is too small for a "
            f"{patch}x{patch} patch and a {pw}x{ph} CFA"
        )
    return np.require(mosaic, np.float32, ("C", "A", "W"))


def band_rows(height: int, width: int, *, max_pixels: int = 1 << 20) -> list[tuple[int, int]]:
    """Row bands ``(y0, y1)`` holding at most ``max_pixels`` pixels each."""
    step = max(1, max_pixels // max(width, 1))
    return [(y0, min(height, y0 + step)) for y0 in range(0, height, step)]
