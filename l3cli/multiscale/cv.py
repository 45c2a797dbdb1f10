"""Cross-validation of the multi-scale stage (``--multiscale``) for ``l3 train``'s search.

The stage is fitted after the table, on the table's own renders of its
training raws (:mod:`l3cli.multiscale.fit`). A fold does the same with the
fold's table: it renders every image of the fold (the held-out units and the
units it trains on), places the stage's class cut points on the training
units' renders, sums the stage's normal equations over their training pixels,
solves, applies the stage to the held-out render and scores it with
S-CIELAB, as :func:`l3cli.train.cv.score_fold` scores the table alone. Each
image is rendered once per fold; the score without the stage comes from the
same render, so both are returned.

The targets are each image's XYZ channels converted to the table's output
space (for a ``linear-srgb`` table with a tone curve: linear sRGB, the space
its renders come out in), coded as the stage codes the render.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from l3cli import defaults
from l3cli.colourspace import convert
from l3cli.errors import InputError
from l3cli.multiscale.fit import MultiscaleStats, accumulate, cut_sample, place_cuts, solve
from l3cli.multiscale.stage import (
    Multiscale,
    blend_features,
    classes,
    decode,
    default_transfer,
    encode,
    feature_maps,
    radius,
)
from l3cli.tone.fit import attach_curve
from l3cli.train.cv import (
    CV_SPACES,
    CVImage,
    LayoutStats,
    Unit,
    as_layout,
    display_xyz,
    fold_stats,
)
from l3cli.train.fit import TrainOptions, table_from_stats

__all__ = ["multiscale_fold_scores", "multiscale_fold_task"]


def _train_mask(img: CVImage, image: int, units: Sequence[Unit], train_units: Sequence[int],
                guard: int) -> np.ndarray | None:
    """The pixels of ``image`` that train the fold's stage: its training units' columns
    (less ``guard`` columns at an inner edge), within the image's training mask."""
    mine = [units[u] for u in train_units if units[u].image == image]
    if not mine:
        return np.zeros(img.mosaic.shape, dtype=bool)
    if all(u.columns is None for u in mine):
        return img.mask
    h, w = img.mosaic.shape
    m = np.zeros((h, w), dtype=bool)
    for u in mine:
        x0, x1 = u.columns
        m[:, (x0 + guard if x0 > 0 else 0):max(0, (x1 - guard if x1 < w else w))] = True
    return m if img.mask is None else m & img.mask


def multiscale_fold_scores(images: Sequence[CVImage], units: Sequence[Unit],
                           folds: Sequence[Sequence[int]], layout: LayoutStats,
                           opts: TrainOptions, *, seed: int = defaults.SEED,
                           sigmas=defaults.MULTISCALE_SIGMAS,
                           levels: int = defaults.MULTISCALE_LEVELS,
                           energy_bins: int = defaults.MULTISCALE_ENERGY_BINS,
                           ridge: float = defaults.MULTISCALE_RIDGE, client=None, remote=None
                           ) -> tuple[np.ndarray, np.ndarray]:
    """S-CIELAB of every unit when its fold is held out, with and without the stage.

    With a dask ``client`` each fold is a task (:func:`multiscale_fold_task`) over
    the images and layout statistics on the workers (``remote``: as
    :func:`l3cli.train.cv.fold_scores` takes it); the scores are the same bit for bit.

    Returns
    -------
    with_stage, without
        float64 (n_units,) each.
    """
    from l3cli.parallel import map_reduce

    stage = (tuple(float(s) for s in sigmas), int(levels), int(energy_bins), float(ridge))
    imgs, lay = (images, layout) if client is None else remote
    items = [(imgs, units, folds, f, lay, opts, seed, stage) for f in range(len(folds))]
    results = map_reduce(multiscale_fold_task, items, client=client, label="cv folds",
                         show_progress=False)
    with_stage = np.full(len(units), np.nan)
    without = np.full(len(units), np.nan)
    for held, (w, wo) in zip(folds, results, strict=True):
        with_stage[list(held)] = w
        without[list(held)] = wo
    return with_stage, without


def multiscale_fold_task(item: tuple) -> tuple[list[float], list[float]]:
    """One fold of :func:`multiscale_fold_scores` (a map task): ``(images, units, folds,
    f, layout, opts, seed, (sigmas, levels, energy_bins, ridge))`` -> the held-out units'
    scores with and without the stage."""
    from l3cli import prepared

    images, units, folds, f, layout, opts, seed, (sigmas, levels, energy_bins, ridge) = item
    layout = as_layout(layout)
    held = folds[f]
    space = opts.target_space
    transfer = default_transfer(space)
    guard = radius(sigmas[0]) + radius(sigmas[-1])
    k = CV_SPACES.index("xyz")
    table = table_from_stats(fold_stats(layout, held, space), opts)
    if opts.tone_curve:
        attach_curve(table, images[0].curve)
    train_units = [u for u in range(len(units)) if u not in held]
    rng = np.random.default_rng([seed, 27, f])
    feats, levs, ens = {}, [], []
    for i, img in enumerate(images):  # each image's render and bands, once per fold
        plain = prepared.plain(table, img.mosaic).render()
        stack, coarse, lev, en = feature_maps(encode(plain, transfer), sigmas)
        mask = _train_mask(img, i, units, train_units, guard)
        feats[i] = (plain, stack, coarse, lev, en, mask)
        lev_s, en_s = cut_sample(lev, en, mask, rng)
        levs.append(lev_s)
        ens.append(en_s)
    if sum(v.size for v in levs) == 0:
        raise InputError("no training pixels for the multi-scale stage in a fold (images "
                         f"too small for its {guard}-pixel guard bands)")
    lcuts, ecuts = place_cuts(np.concatenate(levs), np.concatenate(ens), levels, energy_bins)
    stats = MultiscaleStats.zeros(levels * energy_bins, len(sigmas), table.n_out)
    for i, img in enumerate(images):
        plain, stack, coarse, lev, en, mask = feats[i]
        cls = classes(lev, en, lcuts, ecuts)
        feats[i] = (plain, stack, coarse, cls)
        if mask is not None and not mask.any():
            continue
        target = encode(convert(img.targets[:, :, 3 * k:3 * k + 3], "xyz", space), transfer)
        accumulate(stats, stack, coarse, cls, target, mask)
    blend = Multiscale(np.asarray(sigmas), lcuts, ecuts, solve(stats, ridge, table.n_out),
                       stats.n, transfer).blend
    with_stage, without = [], []
    for u in held:
        unit = units[u]
        img = images[unit.image]
        plain, stack, coarse, cls = feats[unit.image]
        # the stage on the whole image (apply_stage's blend of the same features)
        staged = decode(blend_features(stack, coarse, cls, blend), transfer)
        for out, arr in ((without, plain), (with_stage, staged)):
            out.append(img.scorer.mean(display_xyz(arr, space, img.display),
                                       columns=unit.columns))
    return with_stage, without
