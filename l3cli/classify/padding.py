"""CFA-phase-preserving mirror padding of raw mosaics (borders of train and render)."""

from __future__ import annotations

import numpy as np

from l3cli.errors import InputError

__all__ = ["mirror_indices", "pad_mosaic"]


def mirror_indices(n: int, r: int, period: int) -> np.ndarray:
    """Source indices of a CFA-phase-preserving mirror padding by ``r``.

    Index ``i`` in ``[-r, n + r)`` maps to a pixel inside ``[0, n)`` with
    ``j = i (mod period)`` close to the mirror image of ``i`` about the edge:
    the plain reflection ``-i`` (or ``2(n-1) - i``) moved by less than one period
    toward the inside, so the padded mosaic keeps the CFA phase everywhere.

    Returns
    -------
    numpy.ndarray
        int64 (n + 2r,): entry ``k`` is the source of padded index ``k - r``.

    Examples
    --------
    A row of 6 pixels of a period-2 CFA padded by 2 on each side: every
    padded index keeps its parity (its CFA phase).

    >>> mirror_indices(6, 2, 2).tolist()
    [2, 1, 0, 1, 2, 3, 4, 5, 4, 3]
    """
    if n < period:
        raise InputError(f"image side {n} is smaller than the CFA period {period}")
    idx = np.arange(-r, n + r)
    out = idx.copy()
    lo = idx < 0
    j = -idx[lo]
    j = j + np.mod(idx[lo] - j, period)
    out[lo] = j
    hi = idx >= n
    j = 2 * (n - 1) - idx[hi]
    j = j - np.mod(j - idx[hi], period)
    out[hi] = j
    # tiny images: fold into range keeping the phase
    while np.any((out < 0) | (out >= n)):
        out = np.where(out < 0, out + period, out)
        out = np.where(out >= n, out - period, out)
    return out.astype(np.int64)


def pad_mosaic(mosaic: np.ndarray, r: int, period: tuple[int, int],
               rows: tuple[int, int] | None = None, extra: int = 0) -> np.ndarray:
    """CFA-phase-preserving mirror padding of ``mosaic`` by ``r`` pixels.

    ``rows=(y0, y1)`` returns only the padded band needed for output rows
    ``y0:y1`` (shape ``(y1 - y0 + 2r, W + 2r)``). ``extra`` zero columns are
    appended on the right (room for the kernels' fixed-width row loads).
    """
    h, w = mosaic.shape
    yi = mirror_indices(h, r, period[0])
    xi = mirror_indices(w, r, period[1])
    if rows is not None:
        yi = yi[rows[0] : rows[1] + 2 * r]
    out = np.zeros((yi.size, xi.size + extra), dtype=np.float32)
    inner = out[:, r : r + w]
    for k, y in enumerate(yi.tolist()):  # row copies; no full-size temporaries
        inner[k] = mosaic[y]
    if r:
        out[:, :r] = inner[:, xi[:r]]
        out[:, r + w : 2 * r + w] = inner[:, xi[r + w :]]
    return out
