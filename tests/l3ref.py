"""Plain numpy reference implementations of the L3 classifier and render (tests only).

Written from the rule in the docs of :mod:`l3cli.classify`, independently of the
numba kernels: sliding windows, channel masks, ``np.searchsorted``.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from l3cli.cfa import CFA


def pad_reference(mosaic: np.ndarray, r: int, cfa: CFA) -> np.ndarray:
    """Phase-preserving mirror padding written out pixel by pixel."""
    h, w = mosaic.shape
    ph, pw = cfa.period

    def src(i, n, p):
        if 0 <= i < n:
            return i
        j = -i if i < 0 else 2 * (n - 1) - i
        # nearest index with the same phase, moving inwards
        step = 1 if i < 0 else -1
        while j % p != i % p:
            j += step
        return j

    ys = [src(i, h, ph) for i in range(-r, h + r)]
    xs = [src(i, w, pw) for i in range(-r, w + r)]
    return mosaic[np.ix_(ys, xs)]


def features_reference(mosaic, cfa: CFA, patch: int, sat_thr: float, eps: float):
    h, w = mosaic.shape
    r = patch // 2
    pad = pad_reference(mosaic.astype(np.float64), r, cfa)
    win = sliding_window_view(pad, (patch, patch))  # (H, W, S, S)
    pos = cfa.position_map(h, w)
    level = np.zeros((h, w))
    contrast = np.zeros((h, w))
    sat = np.zeros((h, w), dtype=np.int64)
    for p in range(cfa.n_positions):
        sel = pos == p
        lay = cfa.neighbourhood(p, patch)
        pw_ = win[sel]  # (m, S, S)
        chans = [c for c in range(cfa.n_channels) if np.any(lay == c)]
        means = {c: pw_[:, lay == c].mean(axis=1) for c in chans}
        lev = np.mean([means[c] for c in chans], axis=0)
        spread = np.mean([pw_[:, lay == c].std(axis=1) for c in chans], axis=0)
        con = spread / (np.maximum(lev, 0) + eps)
        s = np.zeros(pw_.shape[0], dtype=np.int64)
        for c in chans:
            s |= (np.any(pw_[:, lay == c] >= sat_thr, axis=1).astype(np.int64) << c)
        level[sel], contrast[sel], sat[sel] = lev, con, s
    return level, contrast, sat, win


def classify_reference(mosaic, definition):
    d = definition
    lev, con, sat, _ = features_reference(mosaic, d.cfa, d.patch, d.saturation_threshold,
                                          d.contrast_eps)
    lbin = np.searchsorted(d.level_cuts, lev, side="right")
    cbin = np.zeros_like(lbin)
    for j in range(d.contrast_cuts.shape[1]):
        cbin += con >= d.contrast_cuts[lbin, j]
    grp = d.position_group[d.cfa.position_map(*mosaic.shape)]
    return d.class_index(grp, sat, lbin, cbin)


def render_reference(table, mosaic):
    d = table.definition
    cls = classify_reference(mosaic, d)
    _, _, _, win = features_reference(mosaic, d.cfa, d.patch, d.saturation_threshold,
                                      d.contrast_eps)
    h, w = mosaic.shape
    X = np.concatenate([win.reshape(h, w, -1), np.ones((h, w, 1))], axis=2)
    K = table.kernels.astype(np.float64)[cls]  # (H, W, q, n_out)
    return np.einsum("hwq,hwqo->hwo", X, K)
