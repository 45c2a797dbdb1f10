"""Fit the multi-scale stage (:mod:`l3cli.multiscale`) of a trained table.

After the L3 table is fitted, each training raw is rendered with it (the
library's float render, :func:`l3cli.kernelset.render_raw`: white balance,
tone curve and adaptation as ``l3 render`` does them) and split into bands;

1. a sample of every image's coarse level and band energy places the class
   cut points (quantiles: levels, then energy within each level);
2. per coarse class, the normal equations of ``target - lp_n`` on the bands
   are summed over the images (the pixels that train: a pairs folder's
   weight mask) and solved by ridge regression shrunk towards ``A = I``.

The targets are read in the table's output space and coded as the stage
codes the render (:func:`l3cli.multiscale.default_transfer`), so the stage
learns what the render still misses in the coding it is applied in.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Sequence

import numpy as np

from l3cli import defaults
from l3cli.errors import InputError
from l3cli.multiscale import (
    Multiscale,
    MultiscaleStats,
    accumulate,
    default_transfer,
    encode,
    energy,
    level,
    place_cuts,
    solve,
)
from l3cli.pairs import Pair, load_pair

__all__ = ["CUT_SAMPLES", "attach_multiscale", "cut_sample", "fit_multiscale"]

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
    the stage's coding (:func:`l3cli.multiscale.default_transfer`), and the mask."""
    from l3cli.kernelset import render_raw

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
    probe = Multiscale.identity(table.n_out, sigmas)
    rng = np.random.default_rng([seed, 27])
    levs, ens = [], []
    for pair in progress(pairs, label="multiscale cuts", enabled=show_progress):
        y, _, mask = _rendered(table, pair)
        stack, coarse, _ = probe.features(y)
        lev_s, en_s = cut_sample(level(coarse), energy(y, coarse, sigmas[0]), mask, rng)
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
