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

import numpy as np

from l3cli.cfa import CFA

__all__ = ["CONTEXT_RULES", "ORIENTATION_RULE", "CONTEXT_EPS", "orientation_centres",
           "orientation_permutation", "block_means", "context_map", "context_feature"]

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
    (their mean is over the pixels they hold).

    Returns
    -------
    numpy.ndarray
        float32 (ceil(H / block), ceil(W / block)).
    """
    h, w = mosaic.shape
    ph, pw = cfa.period
    pat = cfa.index_pattern
    nch = cfa.n_channels
    per_ch = np.bincount(pat.ravel(), minlength=nch)
    # weight of each period position: 1 / (channels * positions of its channel)
    wpos = (pat.size / (nch * per_ch[pat])).astype(np.float64)
    wmap = np.tile(wpos, (-(-h // ph), -(-w // pw)))[:h, :w]
    ys = np.arange(0, h, block)
    xs = np.arange(0, w, block)
    s = np.add.reduceat(np.add.reduceat(mosaic.astype(np.float64) * wmap, ys, axis=0), xs,
                        axis=1)
    n = np.add.reduceat(np.add.reduceat(wmap, ys, axis=0), xs, axis=1)
    return (s / n).astype(np.float32)


def _interp_weights(n: int, block: int, n_blocks: int) -> tuple[np.ndarray, np.ndarray,
                                                                 np.ndarray]:
    """Bilinear lower index, upper index and weight of each pixel between block centres."""
    f = np.clip((np.arange(n) + 0.5) / block - 0.5, 0.0, n_blocks - 1.0)
    i0 = np.floor(f).astype(np.int64)
    i1 = np.minimum(i0 + 1, n_blocks - 1)
    return i0, i1, (f - i0).astype(np.float32)


def context_map(mosaic: np.ndarray, cfa: CFA, block: int,
                rows: tuple[int, int] | None = None) -> np.ndarray:
    """The context guide at every pixel: block means, bilinearly interpolated.

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
    h, w = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    g = block_means(mosaic, cfa, block)
    r0, r1, wy = _interp_weights(h, block, g.shape[0])
    c0, c1, wx = _interp_weights(w, block, g.shape[1])
    r0, r1, wy = r0[y0:y1], r1[y0:y1], wy[y0:y1]
    cols = g[:, c0] * (1 - wx) + g[:, c1] * wx  # (Hb, W)
    out = cols[r0] * (1 - wy)[:, None] + cols[r1] * wy[:, None]
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
