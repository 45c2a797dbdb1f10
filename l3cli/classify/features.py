"""Class features beyond the patch statistics: edge orientation and context.

Both are optional class dimensions of a :class:`~l3cli.classify.ClassDefinition`
(off by default; a table without them classifies as before).

**Orientation** (``orientation_bins = N``, N even): the structure tensor of
the patch, ``J = sum (gx², gx gy; gx gy, gy²)`` over the ``(S - ph) x (S - pw)``
quads of same-channel pixels ``a = p[y, x]``, ``b = p[y, x + pw]``,
``c = p[y + ph, x]``, ``d = p[y + ph, x + pw]`` of the patch, with
``gx = (b - a) + (d - c)`` and ``gy = (c - a) + (d - b)`` (each difference
joins two pixels of the same colour, so colour never reads as an edge; the
quad set is mapped onto itself by every mirror and rotation of the square
patch). With ``u = Jxx - Jyy``, ``v = 2 Jxy`` and ``T = Jxx + Jyy``, the
coherence is ``sqrt(u² + v²) / T`` (0 = isotropic, 1 = one straight edge)
and ``atan2(v, u) / 2`` is the dominant gradient angle (as in RAISR's filter
hash, Romano et al. 2017). Orientation bin 0 is "isotropic" (coherence at
most the threshold, or a flat patch); bins ``1 .. N`` are the N gradient
angles ``j * 180° / N`` (nearest centre: the largest ``u cos 2θ_j + v sin 2θ_j``;
no trigonometry at run time, so train and render agree bit for bit).

**Context** (``context_block = B``): a low-resolution guide of the mosaic,
the mean of the per-channel means over ``B x B`` blocks (the same average of
the channels as the response level), bilinearly interpolated to every pixel
(:func:`context_map`). Its bins (``context_cuts``) condition the kernel on
the brightness of the surroundings (``rule "mean"``) or on the patch level
relative to it (``"ratio"``, what local tone mapping responds to; HDRNet
conditions its colour transforms on such a low-resolution guide, Gharbi et
al. 2017). Training and rendering compute it with the same function.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from l3cli.cfa import CFA

__all__ = ["CONTEXT_RULES", "ORIENTATION_RULE", "CONTEXT_EPS", "ContextGuide",
           "orientation_centres", "orientation_permutation", "block_means", "context_guide",
           "context_map", "context_feature"]

#: Context features: the guide value itself, or the patch level over it.
CONTEXT_RULES = ("mean", "ratio")
#: Name of the orientation rule implemented here (stored in tables).
ORIENTATION_RULE = "quad-structure-tensor-v1"
#: ``eps`` of the ratio rule's denominator (normalised raw units).
CONTEXT_EPS = 1e-4


def orientation_centres(n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """float32 ``(cos 2θ_j, sin 2θ_j)`` of the N bin centres ``θ_j = j π / N``."""
    two_theta = 2.0 * np.pi * np.arange(n_bins) / n_bins
    return np.cos(two_theta).astype(np.float32), np.sin(two_theta).astype(np.float32)


def orientation_permutation(matrix: np.ndarray, n_bins: int) -> np.ndarray:
    """Where each orientation bin goes when the patch is moved by a D4 element.

    Parameters
    ----------
    matrix
        2x2 integer matrix acting on centred ``(dy, dx)`` tap coordinates
        (:data:`l3cli.smooth.symmetry.D4_ELEMENTS`).
    n_bins
        Number of angle bins N (even); 0 for no orientation.

    Returns
    -------
    numpy.ndarray
        int64 (N + 1,) (or (1,) when ``n_bins == 0``): ``perm[o]`` is the bin
        of the moved patch; the isotropic bin 0 stays 0.

    Examples
    --------
    >>> orientation_permutation(np.array([[0, 1], [1, 0]]), 4).tolist()  # transpose
    [0, 3, 2, 1, 4]
    """
    if n_bins == 0:
        return np.zeros(1, dtype=np.int64)
    m = np.asarray(matrix, dtype=np.float64)
    theta = np.pi * np.arange(n_bins) / n_bins
    g = np.stack([np.sin(theta), np.cos(theta)])  # (gy, gx) of each bin centre
    moved = m @ g  # a gradient is a vector of (dy, dx): it moves with the taps
    t2 = np.mod(np.arctan2(moved[0], moved[1]), np.pi)
    j = np.mod(np.rint(t2 * n_bins / np.pi).astype(np.int64), n_bins)
    return np.concatenate([[0], 1 + j]).astype(np.int64)


def block_means(mosaic: np.ndarray, cfa: CFA, block: int) -> np.ndarray:
    """Mean of the per-channel means of every ``block x block`` block of a mosaic.

    Blocks start at the origin; the last row/column of blocks may be partial
    (each channel's mean is then over the pixels the block holds).

    Returns
    -------
    numpy.ndarray
        float32 (ceil(H / block), ceil(W / block)).
    """
    h, w = mosaic.shape
    ph, pw = cfa.period
    pat = cfa.index_pattern
    nch = cfa.n_channels
    nby, nbx = -(-h // block), -(-w // block)
    sums = np.zeros((nch, nby, nbx))
    counts = np.zeros((nch, nby, nbx))
    for py in range(ph):
        for px in range(pw):
            plane = mosaic[py::ph, px::pw]  # one CFA position: a strided view
            if plane.size == 0:
                continue
            ys = (np.arange(0, h, block) - py + ph - 1) // ph  # first plane row of each block
            xs = (np.arange(0, w, block) - px + pw - 1) // pw
            n_y = np.diff(np.append(ys, plane.shape[0]))
            n_x = np.diff(np.append(xs, plane.shape[1]))
            # a last, partial block may hold no pixel of this position (9 rows, block 8,
            # period 2: row 8 is phase 0 only); reduceat takes only in-range starts
            ky, kx = int(np.sum(n_y > 0)), int(np.sum(n_x > 0))
            c = pat[py, px]
            sums[c, :ky, :kx] += np.add.reduceat(
                np.add.reduceat(plane, ys[:ky], axis=0, dtype=np.float64), xs[:kx], axis=1)
            counts[c] += n_y[:, None] * n_x[None, :]
    means = sums / np.maximum(counts, 1)
    return (means.sum(axis=0) / np.maximum((counts > 0).sum(axis=0), 1)).astype(np.float32)


class ContextGuide(NamedTuple):
    """The context guide of a mosaic as the tile kernel reads it.

    The guide at pixel ``(y, x)`` is, in float32,
    ``row = grid[r0[y]] * (1 - wy[y]) + grid[r1[y]] * wy[y]`` and then
    ``row[c0[x]] * (1 - wx[x]) + row[c1[x]] * wx[x]`` (bilinear between block
    centres, constant beyond the outer centres).
    """

    #: float32 (n_block_rows, n_block_cols): block means (:func:`block_means`).
    grid: np.ndarray
    #: int64 (H,): upper block row of each pixel row.
    r0: np.ndarray
    #: int64 (H,): lower block row.
    r1: np.ndarray
    #: float32 (H,): weight of ``r1``.
    wy: np.ndarray
    #: int64 (W,): left block column of each pixel column.
    c0: np.ndarray
    #: int64 (W,): right block column.
    c1: np.ndarray
    #: float32 (W,): weight of ``c1``.
    wx: np.ndarray


def _interp_weights(n: int, block: int, n_blocks: int) -> tuple[np.ndarray, np.ndarray,
                                                                 np.ndarray]:
    """Bilinear lower index, upper index and weight of each pixel between block centres."""
    f = np.clip((np.arange(n) + 0.5) / block - 0.5, 0.0, n_blocks - 1.0)
    i0 = np.floor(f).astype(np.int64)
    i1 = np.minimum(i0 + 1, n_blocks - 1)
    return i0, i1, (f - i0).astype(np.float32)


def context_guide(mosaic: np.ndarray, cfa: CFA, block: int) -> ContextGuide:
    """The :class:`ContextGuide` of a mosaic (what the tile kernel interpolates)."""
    h, w = mosaic.shape
    g = np.ascontiguousarray(block_means(mosaic, cfa, block))
    return ContextGuide(g, *_interp_weights(h, block, g.shape[0]),
                        *_interp_weights(w, block, g.shape[1]))


def context_map(mosaic: np.ndarray, cfa: CFA, block: int,
                rows: tuple[int, int] | None = None) -> np.ndarray:
    """The context guide at every pixel, computed as the tile kernel computes it.

    Parameters
    ----------
    mosaic
        float32 (H, W) normalised mosaic.
    cfa
        Its CFA.
    block
        Block size in pixels.
    rows
        ``(y0, y1)``: only these rows (the blocks are those of the whole mosaic).

    Returns
    -------
    numpy.ndarray
        float32 C-contiguous (y1 - y0, W).
    """
    h, _ = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    g, r0, r1, wy, c0, c1, wx = context_guide(mosaic, cfa, block)
    one = np.float32(1.0)
    wy = wy[y0:y1, None]
    rows_ = g[r0[y0:y1]] * (one - wy) + g[r1[y0:y1]] * wy  # (y1 - y0, n_block_cols)
    out = rows_[:, c0] * (one - wx) + rows_[:, c1] * wx
    return np.ascontiguousarray(out, dtype=np.float32)


def context_feature(level: np.ndarray, context: np.ndarray, rule: str) -> np.ndarray:
    """The binned context feature from the patch level and the guide (float32).

    ``"mean"``: the guide itself; ``"ratio"``: ``max(level, 0) / (max(guide, 0) + eps)``.
    The tile kernel computes the same expression in float32.
    """
    if rule == "mean":
        return np.asarray(context, dtype=np.float32)
    lev = np.maximum(np.asarray(level, dtype=np.float32), np.float32(0.0))
    den = np.maximum(np.asarray(context, dtype=np.float32), np.float32(0.0)) + np.float32(
        CONTEXT_EPS)
    return (lev / den).astype(np.float32)
