"""Histograms of patch features that place the cut points of a class definition.

Training adds every training mosaic's unsaturated patches to a
:class:`ContrastHistogram` (it adds across files and workers), then asks it for
the level range and the per-level contrast thresholds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from l3cli.cfa import CFA
from l3cli.classify.features import context_feature, context_map
from l3cli.classify.kernel import patch_features
from l3cli.errors import InputError

__all__ = ["ContrastHistogram"]

#: Fine log bins used to learn cut points from training data (additive).
_LEVEL_EDGES = np.geomspace(1e-6, 2.0, 531)  # ~100 bins per decade
_CONTRAST_EDGES = np.geomspace(1e-4, 1e2, 301)  # 50 bins per decade
_CONTEXT_EDGES = np.geomspace(1e-6, 1e3, 901)  # 100 bins per decade


@dataclass
class ContrastHistogram:
    """Joint histogram of (level, contrast) of unsaturated patches; adds.

    Used by training to place level cut points "just above the noise floor
    to near saturation" and per-level contrast thresholds at quantiles of the
    data. Bins: 0 = below the first edge, last = above the last edge.
    """

    counts: np.ndarray  # int64 (len(_LEVEL_EDGES)+1, len(_CONTRAST_EDGES)+1)
    #: int64 (len(_CONTEXT_EDGES)+1,): the context feature of the same patches
    #: (all zero unless ``add_mosaic`` was given a context block).
    context: np.ndarray = field(
        default_factory=lambda: np.zeros(_CONTEXT_EDGES.size + 1, dtype=np.int64))

    @classmethod
    def empty(cls) -> ContrastHistogram:
        """A histogram with no patches."""
        return cls(np.zeros((_LEVEL_EDGES.size + 1, _CONTRAST_EDGES.size + 1), dtype=np.int64))

    def __add__(self, other: ContrastHistogram) -> ContrastHistogram:
        return ContrastHistogram(self.counts + other.counts, self.context + other.context)

    def add_mosaic(self, mosaic: np.ndarray, cfa: CFA, *, patch: int,
                   saturation_threshold: float, mask: np.ndarray | None = None,
                   context_block: int = 0, context_rule: str = "mean") -> None:
        """Add the patches of one mosaic (optionally only where ``mask``).

        With ``context_block`` the context feature
        (:func:`~l3cli.classify.features.context_feature`) is counted too.
        """
        lev, con, sat = patch_features(mosaic, cfa, patch=patch,
                                       saturation_threshold=saturation_threshold)
        keep = sat == 0
        if mask is not None:
            keep &= mask
        if context_block:
            ctx = context_map(np.ascontiguousarray(mosaic, dtype=np.float32), cfa,
                              context_block)
            feat = context_feature(lev[keep], ctx[keep], context_rule)
            self.context += np.bincount(np.searchsorted(_CONTEXT_EDGES, feat, side="right"),
                                        minlength=self.context.size)
        li = np.searchsorted(_LEVEL_EDGES, lev[keep], side="right")
        ci = np.searchsorted(_CONTRAST_EDGES, con[keep], side="right")
        flat = li * (_CONTRAST_EDGES.size + 1) + ci
        self.counts += np.bincount(flat, minlength=self.counts.size).reshape(self.counts.shape)

    @property
    def total(self) -> int:
        """Number of patches counted."""
        return int(self.counts.sum())

    def level_range(self, *, low_quantile: float = 0.002, high_quantile: float = 0.998,
                    floor: float = 1e-4, ceiling: float = 0.95) -> tuple[float, float]:
        """Level cut range from quantiles of the data, clamped to [floor, ceiling]."""
        lv = self.counts.sum(axis=1).astype(np.float64)
        if lv.sum() == 0:
            raise InputError("no unsaturated patches in the training data")
        cdf = np.cumsum(lv) / lv.sum()

        def q(p):  # upper edge of the bin holding quantile p
            i = int(np.searchsorted(cdf, min(max(p, 1e-12), 1 - 1e-9)))
            return float(_LEVEL_EDGES[min(i, _LEVEL_EDGES.size - 1)])

        lo = max(q(low_quantile), floor)
        hi = min(q(high_quantile), ceiling)
        if hi <= lo * 1.5:
            hi = min(max(lo * 10.0, hi), max(ceiling, lo * 1.5))
            if hi <= lo:
                lo = hi / 10.0
        return lo, hi

    def context_cuts(self, n_bins: int) -> np.ndarray:
        """``n_bins - 1`` cut points at the quantiles k/n_bins of the context feature.

        Raises
        ------
        InputError
            No patches were counted with a context block.
        """
        tot = self.context.astype(np.float64)
        if tot.sum() == 0:
            raise InputError("no unsaturated patches to place the context bins")
        cdf = np.cumsum(tot) / tot.sum()
        qs = np.arange(1, n_bins) / n_bins
        idx = [min(int(np.searchsorted(cdf, q)), _CONTEXT_EDGES.size - 1) for q in qs]
        cuts = np.unique(_CONTEXT_EDGES[idx])  # upper edge of the bin holding quantile q
        return cuts

    def contrast_cuts(self, level_cuts: np.ndarray, n_contrast: int) -> np.ndarray:
        """Per level bin, thresholds at the quantiles k/n_contrast of the contrast."""
        nl = level_cuts.size + 1
        out = np.zeros((nl, n_contrast - 1))
        if n_contrast < 2:
            return out
        centres = np.sqrt(_LEVEL_EDGES[:-1] * _LEVEL_EDGES[1:])
        fine_level_bin = np.concatenate([[0], np.searchsorted(level_cuts, centres, side="right"),
                                         [nl - 1]])
        cedges = _CONTRAST_EDGES  # cedges[i] = upper edge of fine bin i (last bin clipped)
        qs = np.arange(1, n_contrast) / n_contrast
        total = self.counts.sum(axis=0).astype(np.float64)
        have = np.zeros(nl, dtype=bool)
        for lev in range(nl):
            h = self.counts[fine_level_bin == lev].sum(axis=0).astype(np.float64)
            if h.sum() < 10 * n_contrast:
                continue
            cdf = np.cumsum(h) / h.sum()
            out[lev] = [cedges[min(int(np.searchsorted(cdf, q)), cedges.size - 1)] for q in qs]
            have[lev] = True
        if not have.any():
            cdf = np.cumsum(total) / max(total.sum(), 1.0)
            out[:] = [cedges[min(int(np.searchsorted(cdf, q)), cedges.size - 1)] for q in qs]
            return out
        idx = np.flatnonzero(have)
        for lev in np.flatnonzero(~have):
            out[lev] = out[idx[np.argmin(np.abs(idx - lev))]]
        # thresholds within a level must increase
        return np.maximum.accumulate(out, axis=1)
