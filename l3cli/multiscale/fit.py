"""Fit the multi-scale stage (:mod:`l3cli.multiscale.stage`) of a trained table.

After the L3 table is fitted, each training raw is rendered with it (the
library's float render, :func:`l3cli.kernelset.render_raw`: white balance,
tone curve and adaptation as ``l3 render`` does them) and split into bands;

1. a sample of every image's coarse level and band energy places the class
   cut points (quantiles: levels, then energy within each level);
2. per coarse class, the normal equations of ``target - lp_n`` on the bands
   are summed over the images (the pixels that train: a pairs folder's
   weight mask) and solved by ridge regression shrunk towards ``A = I``.

The targets are read in the table's output space and coded as the stage
codes the render (:func:`l3cli.multiscale.stage.default_transfer`), so the stage
learns what the render still misses in the coding it is applied in.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from l3cli import defaults
from l3cli.errors import InputError
from l3cli.multiscale.stage import Multiscale, default_transfer, encode, feature_maps
from l3cli.pairs import Pair, load_pair

__all__ = ["CUT_SAMPLES", "MultiscaleStats", "accumulate", "attach_multiscale", "cut_sample",
           "fit_multiscale", "place_cuts", "solve"]

log = logging.getLogger(__name__)

#: Pixels per image sampled to place the class cut points.
CUT_SAMPLES = 200_000


def cut_sample(lev: np.ndarray, en: np.ndarray, mask: np.ndarray | None,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One image's share of the sample that places the cut points: the coarse level and
    band energy of at most :data:`CUT_SAMPLES` of its training pixels (``mask``)."""
    idx = np.flatnonzero(mask.ravel()) if mask is not None else np.arange(lev.size)
    if idx.size > CUT_SAMPLES:
        idx = rng.choice(idx, CUT_SAMPLES, replace=False)
    return lev.ravel()[idx], en.ravel()[idx]


def _rendered(table, pair: Pair):
    """The render of ``pair``'s raw by ``table`` (without a stage) and its target, both in
    the stage's coding (:func:`l3cli.multiscale.stage.default_transfer`), and the mask."""
    from l3cli.prepared import render_raw

    loaded = load_pair(pair, target_space=table.output_space)
    if loaded.raw.cfa.spec != table.cfa.spec:
        raise InputError(f"{pair.raw}: CFA {loaded.raw.cfa.spec} differs from the table's "
                         f"{table.cfa.spec}")
    y = render_raw(table, loaded.raw, table_name="the trained table")
    transfer = default_transfer(table.output_space)
    return encode(y, transfer), encode(loaded.target, transfer), loaded.weight_mask


def fit_multiscale(table, pairs: Sequence[Pair], *, sigmas=defaults.MULTISCALE_SIGMAS,
                   levels: int = defaults.MULTISCALE_LEVELS,
                   energy_bins: int = defaults.MULTISCALE_ENERGY_BINS,
                   ridge: float = defaults.MULTISCALE_RIDGE, seed: int = defaults.SEED,
                   show_progress: bool | None = False) -> Multiscale:
    """The multi-scale stage for ``table`` learned from ``pairs``.

    Parameters
    ----------
    table
        The fitted :class:`l3cli.table.TransformTable` (without a stage).
    pairs
        The training pairs (:func:`l3cli.pairs.find_pairs`).
    sigmas
        Increasing low-pass standard deviations, pixels.
    levels, energy_bins
        Coarse classes: level bins x band-energy bins.
    ridge
        Shrinkage towards the identity, relative to each class's mean band power.
    seed
        Seed of the sample that places the cut points.

    Returns
    -------
    Multiscale
    """
    from l3cli.progress import progress

    sigmas = tuple(float(s) for s in sigmas)
    if getattr(table, "multiscale", None) is not None:  # fit on the kernels' own render
        table = copy.copy(table)
        table.multiscale = None
    rng = np.random.default_rng([seed, 27])
    levs, ens = [], []
    for pair in progress(pairs, label="multiscale cuts", enabled=show_progress):
        y, _, mask = _rendered(table, pair)
        _, _, lev, en = feature_maps(y, sigmas)
        lev_s, en_s = cut_sample(lev, en, mask, rng)
        levs.append(lev_s)
        ens.append(en_s)
    if not levs or sum(v.size for v in levs) == 0:
        raise InputError("no training pixels for the multiscale stage")
    lcuts, ecuts = place_cuts(np.concatenate(levs), np.concatenate(ens), levels, energy_bins)
    n_classes = levels * energy_bins
    shape = Multiscale.identity(table.n_out, sigmas, lcuts, ecuts)
    stats = MultiscaleStats.zeros(n_classes, len(sigmas), table.n_out)
    for pair in progress(pairs, label="multiscale fit", enabled=show_progress):
        y, target, mask = _rendered(table, pair)
        stack, coarse, cls = shape.features(y)
        accumulate(stats, stack, coarse, cls, target, mask)
    blend = solve(stats, ridge, table.n_out)
    log.info("multiscale stage: %d classes from %d pixels", n_classes, int(stats.n.sum()))
    return Multiscale(np.asarray(sigmas), lcuts, ecuts, blend, stats.n,
                      default_transfer(table.output_space))


def attach_multiscale(table, pairs: Sequence[Pair], **options) -> None:
    """Fit the stage (:func:`fit_multiscale`) and store it in ``table`` with its record."""
    stage = fit_multiscale(table, pairs, **options)
    table.multiscale = stage
    table.provenance["multiscale"] = {
        "sigmas": stage.sigmas.tolist(), "levels": int(stage.level_cuts.size + 1),
        "energy_bins": int(stage.energy_cuts.shape[1] + 1),
        "ridge": float(options.get("ridge", defaults.MULTISCALE_RIDGE)),
        "transfer": stage.transfer, "pixels": int(stage.counts.sum())}


def place_cuts(lev: np.ndarray, en: np.ndarray, n_levels: int,
               n_energy: int) -> tuple[np.ndarray, np.ndarray]:
    """Level cuts at quantiles of ``lev``, energy cuts at quantiles of ``en`` within each level.

    Returns
    -------
    level_cuts, energy_cuts
        float64 (n_levels - 1,) and (n_levels, n_energy - 1), strictly increasing
        (ties, as in a constant image, are spread by a tiny step).
    """
    lev = np.asarray(lev, dtype=np.float64).ravel()
    en = np.asarray(en, dtype=np.float64).ravel()
    q = np.linspace(0, 1, n_levels + 1)[1:-1]
    lcuts = _increasing(np.quantile(lev, q)) if n_levels > 1 else np.zeros(0)
    lb = np.searchsorted(lcuts, lev, side="right")
    qe = np.linspace(0, 1, n_energy + 1)[1:-1]
    ecuts = np.zeros((n_levels, n_energy - 1))
    for b in range(n_levels):
        sel = en[lb == b]
        ecuts[b] = _increasing(np.quantile(sel if sel.size else en, qe)) if n_energy > 1 else 0
    return lcuts, ecuts


def _increasing(cuts: np.ndarray) -> np.ndarray:
    cuts = np.asarray(cuts, dtype=np.float64).copy()
    for i in range(1, cuts.size):
        if cuts[i] <= cuts[i - 1]:
            cuts[i] = np.nextafter(cuts[i - 1], np.inf) + 1e-12 * max(1.0, abs(cuts[i - 1]))
    return cuts




@dataclass(eq=False)
class MultiscaleStats:
    """Per-class normal equations of the blend (they add across images).

    ``xtx[k] = sum stack stackᵀ``, ``xty[k] = sum stack (target - coarse)ᵀ``
    over the pixels of class ``k``.
    """

    xtx: np.ndarray  # float64 (n_classes, R, R), R = n_scales * C
    xty: np.ndarray  # float64 (n_classes, R, C)
    n: np.ndarray    # int64 (n_classes,)

    @classmethod
    def zeros(cls, n_classes: int, n_scales: int, n_out: int) -> MultiscaleStats:
        r = n_scales * n_out
        return cls(np.zeros((n_classes, r, r)), np.zeros((n_classes, r, n_out)),
                   np.zeros(n_classes, np.int64))

    def __add__(self, other: MultiscaleStats) -> MultiscaleStats:
        return MultiscaleStats(self.xtx + other.xtx, self.xty + other.xty, self.n + other.n)


def accumulate(stats: MultiscaleStats, stack: np.ndarray, coarse: np.ndarray, cls: np.ndarray,
               target: np.ndarray, mask: np.ndarray | None = None) -> MultiscaleStats:
    """Add one image's pixels (``mask``: those that train; None = all) to ``stats``."""
    r = stack.shape[2]
    x = stack.reshape(-1, r).astype(np.float64)
    t = (np.asarray(target, dtype=np.float64) - coarse).reshape(x.shape[0], -1)
    k = cls.reshape(-1)
    if mask is not None:
        m = np.asarray(mask, dtype=bool).reshape(-1)
        x, t, k = x[m], t[m], k[m]
    ok = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(t), axis=1)
    x, t, k = x[ok], t[ok], k[ok]
    order = np.argsort(k, kind="stable")
    x, t, k = x[order], t[order], k[order]
    bounds = np.searchsorted(k, np.arange(stats.n.size + 1))
    for c in range(stats.n.size):
        a, b = bounds[c], bounds[c + 1]
        if b > a:
            stats.xtx[c] += x[a:b].T @ x[a:b]
            stats.xty[c] += x[a:b].T @ t[a:b]
            stats.n[c] += b - a
    return stats


def solve(stats: MultiscaleStats, ridge: float, n_out: int) -> np.ndarray:
    """The blend of each class: ridge regression shrunk towards ``A = I``.

    ``A_k = argmin |t - X A|^2 + lam_k |A - I|^2`` with
    ``lam_k = ridge * trace(XᵀX) / R``: a class with no data keeps the
    identity (the L3 render unchanged).

    Returns
    -------
    numpy.ndarray
        float32 (n_classes, R, C).
    """
    nc, r, _ = stats.xtx.shape
    prior = np.tile(np.eye(n_out), (r // n_out, 1))
    out = np.empty((nc, r, n_out), dtype=np.float64)
    for k in range(nc):
        g = stats.xtx[k]
        lam = ridge * max(np.trace(g) / r, 1e-300)
        out[k] = np.linalg.solve(g + lam * np.eye(r), stats.xty[k] + lam * prior)
    return out.astype(np.float32)
