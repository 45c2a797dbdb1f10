"""The per-pixel loop of the multi-scale stage (:mod:`l3cli.multiscale`), in numba.

``out[y, x, c] = coarse[y, x, c] + sum_r stack[y, x, r] * blend[cls[y, x], r, c]``:
a gather of a small per-pixel matrix, which numpy could only do with a
(H, W, R, C) temporary; here rows run in parallel and nothing is allocated.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from l3cli.startup import lean_cache

__all__ = ["blend_rows"]


@lean_cache
@nb.njit(cache=True, parallel=True)
def blend_rows(stack: np.ndarray, coarse: np.ndarray, cls: np.ndarray, blend: np.ndarray,
               out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Fill ``out`` (H, W, C) with ``coarse + stack @ blend[cls]`` pixel by pixel."""
    h, w, r = stack.shape
    c = coarse.shape[2]
    for y in nb.prange(h):
        for x in range(w):
            a = blend[cls[y, x]]
            for j in range(c):
                acc = coarse[y, x, j]
                for i in range(r):
                    acc += stack[y, x, i] * a[i, j]
                out[y, x, j] = acc
