"""Training: classify, accumulate statistics, solve per class, build the table.

Two passes over the inputs:

1. the (level, contrast) histogram of the raw patches (cheap, additive) places
   the level cut points between the data's noise floor and near saturation
   and the per-level contrast thresholds (skipped when both are given);
2. per-class sufficient statistics (:mod:`l3cli.train.stats`), then ridge +
   GCV per class (:mod:`l3cli.train.ridge`).

Both passes are maps over the inputs (:func:`l3cli.parallel.map_reduce`): a
task (:func:`histogram_task`, :func:`stats_task`) reads one input itself and
returns its histogram or statistics, and the results are summed in input
order -- in process, or on a dask.distributed cluster with the same result
bit for bit (``l3 train --workers/--scheduler``, ``docs/distributed.md``).

Classes with fewer than ``min_samples_factor`` x (S*S + 1) samples are marked
empty and use the kernel of the nearest trained class of the same position
group (same saturation pattern and contrast first, nearest level).
"""

from __future__ import annotations

import logging
import platform
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from l3cli import __version__
from l3cli.cfa import CFA
from l3cli.classify import ClassDefinition, ContrastHistogram, level_cuts_between
from l3cli.colourspace import srgb_encode
from l3cli.errors import InputError, TableError
from l3cli.pairs import Pair, load_pair
from l3cli.table import TransformTable
from l3cli.train.options import (  # re-exported: l3cli.train.fit's public names
    NO_CURVE,
    NOTHING,
    TONE_CURVE_SPACE,
    Fitted,
    TrainOptions,
    check_class_budget,
    default_target_space,
    layout_defaults,
    pairs_kind,
)
from l3cli.train.pixels import sample_mask, training_pixels  # re-exported
from l3cli.train.ridge import solve_class
from l3cli.train.stats import ClassStats, accumulate

__all__ = ["pairs_kind", "layout_defaults", "default_target_space", "TrainOptions", "sample_mask", "training_pixels", "histogram_task", "PartialStats", "stats_task",
           "define_classes", "definition_from_histogram",
           "collect_stats", "solve_stats", "table_from_stats", "fallback_sources", "train",
           "TONE_CURVE_SPACE", "NO_CURVE"]

log = logging.getLogger(__name__)


def _need_histogram(opts: TrainOptions) -> bool:
    return opts.level_range is None or (opts.contrast_bins > 1 and
                                        opts.contrast_threshold is None) or \
        opts.context_block > 0


def _for_workers(pairs: Sequence[Pair], client) -> list[Pair]:
    """Pairs as sent to the tasks: absolute paths on a cluster (workers may run
    elsewhere or in another folder), unchanged in process."""
    if client is None:
        return list(pairs)
    return [replace(p, raw=Path(p.raw).absolute(), target=Path(p.target).absolute())
            for p in pairs]


def histogram_task(item: tuple) -> tuple[int, CFA, ContrastHistogram | None]:
    """Pass 1 on one input (a map task): its CFA and (level, contrast) histogram.

    Parameters
    ----------
    item
        ``(index, pair, opts, with_histogram[, fitted])``; ``index`` numbers the image
        for the sampling seed; ``fitted`` (:class:`Fitted`): the lens-shading field.

    Returns
    -------
    tuple
        ``(index, cfa, histogram or None)``; histograms add.
    """
    from l3cli.io.raw import read_raw
    from l3cli.lens.gainmaps import apply_dng_gains
    from l3cli.whitebalance.model import training_mosaic

    i, pair, opts, with_hist, *rest = item
    fitted = rest[0] if rest else NOTHING
    raw = apply_dng_gains(read_raw(pair.raw))  # the DNG's gain maps applied
    mosaic = training_mosaic(raw, opts, fitted)
    if not with_hist:
        return i, raw.cfa, None
    hist = ContrastHistogram.empty()
    frac = min(opts.sample_fraction, 0.25)
    mask = sample_mask(raw.mosaic.shape, frac, opts.seed, i, stream=1)
    hist.add_mosaic(mosaic, raw.cfa, patch=opts.patch,
                    saturation_threshold=opts.saturation, mask=mask,
                    context_block=opts.context_block, context_rule=opts.context_rule)
    return i, raw.cfa, hist


@dataclass
class PartialStats:
    """Sufficient statistics of one input, kept only for its classes with samples.

    What :func:`stats_task` returns: one image reaches a small part of the
    classes, so this is much smaller to send from a worker than a full
    :class:`~l3cli.train.stats.ClassStats`. :meth:`add_to` adds it into full
    statistics (the classes it lacks have zero statistics, so the sum is the
    same bit for bit as adding the full statistics).
    """

    classes: np.ndarray  # int64 (k,) class indices with samples
    n: np.ndarray  # int64 (k,)
    xtx: np.ndarray  # float64 (k, q, q)
    xty: np.ndarray  # float64 (k, q, n_out)
    yy: np.ndarray  # float64 (k, n_out)
    target_space: str

    @classmethod
    def of(cls, stats: ClassStats) -> PartialStats:
        """The classes of ``stats`` with at least one sample."""
        c = np.flatnonzero(stats.n)
        return cls(c, stats.n[c], stats.xtx[c], stats.xty[c], stats.yy[c], stats.target_space)

    def add_to(self, stats: ClassStats) -> ClassStats:
        """Add into ``stats`` in place and return it."""
        if self.target_space != stats.target_space or self.yy.shape[1] != stats.n_out:
            raise TableError(
                f"cannot add statistics for {self.yy.shape[1]} {self.target_space} outputs "
                f"to {stats.n_out} {stats.target_space} outputs"
            )
        c = self.classes
        stats.n[c] += self.n
        stats.xtx[c] += self.xtx
        stats.xty[c] += self.xty
        stats.yy[c] += self.yy
        return stats


def stats_task(item: tuple) -> PartialStats:
    """Pass 2 on one input (a map task): the sufficient statistics of one pair.

    Parameters
    ----------
    item
        ``(index, pair, definition, opts[, fitted])``; ``index`` numbers the image for
        the sampling seed (:func:`sample_mask`); ``fitted`` (:class:`Fitted`): the
        shading field, white adaptation and tone curve fitted before.

    Returns
    -------
    PartialStats
        The statistics of this pair alone (its classes with samples); they add.
    """
    i, pair, definition, opts, *rest = item
    fitted = rest[0] if rest else NOTHING
    loaded = load_pair(pair, target_space=opts.target_space)
    raw, target, valid = loaded.raw, loaded.target, loaded.weight_mask
    if raw.cfa.spec != definition.cfa.spec:
        raise InputError(
            f"{pair.raw}: CFA {raw.cfa.spec} differs from the table's {definition.cfa.spec}"
        )
    mask = training_pixels(raw.mosaic.shape, valid, opts, i)
    from l3cli.train.weights import luminance, sample_weights
    from l3cli.whitebalance.model import training_mosaic, training_target

    mosaic = training_mosaic(raw, opts, fitted)
    target = training_target(target, pair.raw, opts, fitted)
    weight = None
    if opts.sample_weight != "none":
        weight = sample_weights(luminance(target, opts.target_space), mask, opts.sample_weight)
    if fitted.tone_model is not None:
        target = fitted.tone_model.linearise(srgb_encode(np.clip(target, 0.0, 1.0)))
    stats = ClassStats.zeros(definition, target.shape[2], target_space=opts.target_space)
    accumulate(stats, mosaic, target, mask=mask, weight=weight)
    return PartialStats.of(stats)


def define_classes(pairs: Sequence[Pair], opts: TrainOptions, *, client=None,
                   show_progress: bool | None = False,
                   fitted: Fitted = NOTHING) -> ClassDefinition:
    """Class definition for the data: CFA from the raws, cut points from pass 1.

    Pass 1 maps :func:`histogram_task` over the raws (only the first one when
    both the level range and the contrast thresholds are given) and sums the
    histograms in input order (:func:`l3cli.parallel.map_reduce`).

    Parameters
    ----------
    pairs
        Training pairs.
    opts
        Training options.
    client
        A dask client (:func:`l3cli.parallel.dask_client`), or None for in process.
    show_progress
        Progress bar on stderr.
    """
    from l3cli.parallel import map_reduce

    pairs = list(pairs)
    need_hist = _need_histogram(opts)
    sent = _for_workers(pairs, client)
    items = [(i, p, opts, need_hist, fitted) for i, p in enumerate(sent)]
    if not need_hist:
        items = items[:1]
    first: dict = {}

    def fold(acc: ContrastHistogram | None, res) -> ContrastHistogram | None:
        i, cfa, hist = res
        if not first:
            first.update(cfa=cfa, path=pairs[i].raw)
        elif cfa.spec != first["cfa"].spec:
            raise InputError(
                f"{pairs[i].raw}: CFA {cfa.spec} differs from {first['cfa'].spec} of "
                f"{first['path']}; train one table per CFA"
            )
        if hist is None:
            return acc
        return hist if acc is None else acc + hist

    hist = map_reduce(histogram_task, items, reduce=fold, client=client,
                      label="classes   ", show_progress=show_progress and need_hist)
    return definition_from_histogram(first["cfa"], hist, opts)


def definition_from_histogram(cfa: CFA, hist: ContrastHistogram | None,
                              opts: TrainOptions) -> ClassDefinition:
    """The class definition of ``opts`` from the summed pass-1 histogram.

    ``hist`` may be None when both the level range and the contrast
    thresholds are given. The histogram does not depend on the number of
    levels or contrast bins, so one histogram serves every such layout
    (:mod:`l3cli.train.tune`).
    """
    if hist is not None and not hist.counts.any() and opts.sample_fraction < 1.0:
        raise InputError(f"--sample-fraction {opts.sample_fraction:g} leaves no sample of the "
                         "training data to place the class cut points; raise it")
    if opts.level_range is not None:
        lo, hi = opts.level_range
    else:
        lo, hi = hist.level_range(ceiling=0.95 * opts.saturation)
    cuts = level_cuts_between(lo, hi, opts.levels, opts.spacing)
    if opts.contrast_bins == 1:
        ccuts = None
    elif opts.contrast_threshold is not None:
        ccuts = np.full((opts.levels, opts.contrast_bins - 1), float(opts.contrast_threshold))
        ccuts *= np.arange(1, opts.contrast_bins)[None, :]
    else:
        ccuts = hist.contrast_cuts(cuts, opts.contrast_bins)
    xcuts = hist.context_cuts(opts.context_bins) if opts.context_block else None
    definition = ClassDefinition.build(cfa, patch=opts.patch, level_cuts=cuts,
                                 level_spacing=opts.spacing, contrast_cuts=ccuts,
                                 saturation_threshold=opts.saturation,
                                 merge_positions=opts.merge_positions,
                                 orientation_bins=opts.orientation_bins,
                                 coherence_threshold=opts.coherence,
                                 context_block=opts.context_block, context_cuts=xcuts,
                                 context_rule=opts.context_rule,
                                 highlight_bins=opts.highlight_bins,
                                 highlight_fraction=opts.highlight_fraction)
    check_class_budget(opts, definition.n_classes)  # before pass 2 allocates them
    return definition


def collect_stats(pairs: Sequence[Pair], definition: ClassDefinition, opts: TrainOptions, *,
                  index_offset: int = 0, client=None, show_progress: bool | None = False,
                  fitted: Fitted = NOTHING) -> ClassStats:
    """Sufficient statistics of ``pairs`` (pass 2).

    Maps :func:`stats_task` over the pairs (one task per pair) and sums the
    per-pair statistics in input order, so the result is the same bit for bit
    in process and on any cluster. ``index_offset`` numbers the images for the
    sampling seed, so splitting a list gives the same samples as one run.
    """
    from l3cli.parallel import map_reduce

    sent = _for_workers(pairs, client)
    items = [(i + index_offset, p, definition, opts, fitted) for i, p in enumerate(sent)]
    stats = ClassStats.zeros(definition, 3, target_space=opts.target_space)
    map_reduce(stats_task, items, reduce=lambda acc, part: part.add_to(stats), client=client,
               label="statistics", show_progress=show_progress)
    return stats


def fallback_sources(definition: ClassDefinition, trained: np.ndarray) -> np.ndarray:
    """Class whose kernel each class uses: itself when trained, else the nearest
    trained class of the same position group -- same saturation pattern and
    contrast at the nearest level first, then same saturation pattern, then the
    unsaturated pattern, then any.

    Raises
    ------
    TableError
        No class is trained, or a position group has no trained class.
    """
    if not trained.any():
        raise TableError("no class has enough training samples; train on more data or use "
                         "fewer --levels")
    g, s, lev, c = (np.asarray(a) for a in definition.class_tuple(np.arange(definition.n_classes)))
    src = np.arange(definition.n_classes, dtype=np.int64)
    tr = np.flatnonzero(trained)
    for e in np.flatnonzero(~trained):
        cand = tr[g[tr] == g[e]]
        if cand.size == 0:
            members = np.flatnonzero(definition.position_group == g[e]).tolist()
            raise TableError(f"CFA positions {members} have no trained class; train on more data")
        same_s = s[cand] == s[e]
        same_c = c[cand] == c[e]
        unsat = s[cand] == 0
        tier = np.where(same_s & same_c, 0, np.where(same_s, 1, np.where(unsat & same_c, 2,
                                                                          np.where(unsat, 3, 4))))
        key = np.lexsort((lev[cand], np.abs(c[cand] - c[e]), np.abs(lev[cand] - lev[e]), tier))
        src[e] = cand[key[0]]
    return src


def solve_stats(stats: ClassStats, opts: TrainOptions
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Solve every class with enough samples (ridge + GCV).

    With ``opts.augment`` the statistics are first augmented by the mirrored
    and rotated pairs (:func:`l3cli.train.augment.augment_stats`); a class is
    trained when its count per copy reaches the minimum. Weighted statistics
    (``opts.sample_weight``) are rescaled per class so that the weights sum
    to the class's sample count before the solve (GCV counts samples).

    Returns
    -------
    kernels, lambdas, lam_rel, counts, trained
        float64 (n_classes, q, n_out) (zero where untrained), the chosen λ
        (absolute and relative; NaN where untrained), int64 per-copy sample
        counts and the bool trained mask.
    """
    d = stats.definition
    nc, q, n_out = d.n_classes, d.n_coeffs, stats.n_out
    counts = stats.n
    if opts.augment != "none":
        from l3cli.train.augment import augment_copies, augment_stats

        stats = augment_stats(stats, opts.augment)
        counts = stats.n // augment_copies(d, opts.augment)
    trained = counts >= opts.min_samples_factor * q
    kernels = np.zeros((nc, q, n_out), dtype=np.float64)
    lambdas = np.full((nc, n_out), np.nan)
    lam_rel = np.full((nc, n_out), np.nan)
    # Many small eigenproblems: BLAS threads only fight each other (10-30x slower
    # on a busy machine), so the solves run single-threaded.
    with threadpool_limits(1, user_api="blas"):
        for c in np.flatnonzero(trained):
            n, xtx, xty, yy = float(stats.n[c]), stats.xtx[c], stats.xty[c], stats.yy[c]
            sw = float(xtx[q - 1, q - 1])  # the constant column's product: the weight sum
            if sw != n:  # weighted: weights sum to the count
                f = n / sw
                xtx, xty, yy = xtx * f, xty * f, yy * f
            sol = solve_class(n, xtx, xty, yy, grid=np.asarray(opts.lambda_grid))
            kernels[c] = sol.kernel
            lambdas[c] = sol.lam
            lam_rel[c] = sol.lam_rel
    return kernels, lambdas, lam_rel, counts, trained


def _no_class_trained(stats: ClassStats, opts: TrainOptions, min_n: float) -> None:
    """Raise the error for statistics in which no class reached ``min_n`` samples,
    naming what to change: the option that thinned the samples, else the data."""
    total, most = int(stats.n.sum()), int(stats.n.max(initial=0))
    what = (f"no class has enough training samples ({total:,} samples in all, at most "
            f"{most:,} in one class; a class needs {min_n:g})")
    if total < min_n and opts.sample_fraction < 1.0:
        raise TableError(f"{what}: --sample-fraction {opts.sample_fraction:g} keeps too few "
                         "pixels; raise it")
    if total < min_n:
        raise TableError(f"{what}: train on more data, a smaller --patch or a lower "
                         "--min-samples")
    raise TableError(f"{what}: train on more data or use fewer --levels")


def table_from_stats(stats: ClassStats, opts: TrainOptions, *,
                     provenance: dict | None = None) -> TransformTable:
    """Solve every class (:func:`solve_stats`) and assemble the table."""
    d = stats.definition
    nc, q = d.n_classes, d.n_coeffs
    min_n = opts.min_samples_factor * q
    kernels, lambdas, lam_rel, counts, trained = solve_stats(stats, opts)
    if not trained.any():
        _no_class_trained(stats, opts, min_n)
    src = fallback_sources(d, trained)
    kernels = kernels[src]
    prov = dict(provenance or {})
    prov.setdefault("l3_version", __version__)
    prov.setdefault("python", platform.python_version())
    prov["options"] = opts.as_dict()
    prov["trained_classes"] = int(trained.sum())
    prov["n_classes"] = int(nc)
    prov["samples"] = int(stats.n.sum())
    prov["min_samples"] = float(min_n)
    with np.errstate(all="ignore"):
        prov["lambda_rel_median"] = float(np.nanmedian(lam_rel)) if trained.any() else None
    log.info("trained %d of %d classes from %d samples", trained.sum(), nc, stats.n.sum())
    return TransformTable(definition=d, kernels=kernels.astype(np.float32), counts=counts,
                          lambdas=lambdas, empty=~trained, source_class=src,
                          output_space=stats.target_space, provenance=prov)


def train(pairs: Iterable[Pair], opts: TrainOptions | None = None, *,
          workers: int | None = None, scheduler: str | None = None, client=None,
          show_progress: bool | None = False, shading_field=None) -> TransformTable:
    """Train a table from pairs with these options: both passes, in process or on a
    dask cluster. (What ``l3 train`` does, input-kind defaults and self-tuning
    included, is :func:`l3cli.train.api.train`.)

    Each pass is a map over the inputs (one task reads one pair and returns
    its histogram or statistics) folded in input order; the solve runs here.
    The table is the same bit for bit whichever way the passes run.

    Parameters
    ----------
    pairs
        Training pairs (:func:`l3cli.pairs.find_pairs`).
    opts
        Options; defaults when ``None``.
    workers
        Run the passes on a local dask cluster of this many worker processes.
    scheduler
        Run them on the running dask scheduler at this address.
    client
        An open dask client (:func:`l3cli.parallel.dask_client`) to run them on
        (takes precedence over ``workers`` and ``scheduler``).
    show_progress
        Progress bars on stderr.
    shading_field
        A lens-shading gain field learned already (:mod:`l3cli.lens.train`), used
        instead of learning one (``opts.shading``).

    Raises
    ------
    InputError, TableError
        Bad inputs, or not enough data.
    l3cli.parallel.ParallelError
        The cluster cannot be reached or a task failed on every attempt.
    """
    from l3cli.parallel import dask_client

    opts = opts or TrainOptions()
    pairs = list(pairs)
    if not pairs:
        raise InputError("no training pairs")
    if client is None and (workers is not None or scheduler is not None):
        with dask_client(workers, scheduler) as c:
            return train(pairs, opts, client=c, show_progress=show_progress,
                         shading_field=shading_field)
    prov = {"inputs": [str(p.raw) for p in pairs], "targets": [str(p.target) for p in pairs],
            "seed": opts.seed}
    groups: dict[float, list[int]] = {}
    if opts.by:  # read every raw's condition first: a raw without it fails before any work
        from l3cli.conditions import group_pairs

        groups = group_pairs(pairs, opts.by)
    shading_record = None
    fitted = Fitted(shading_field=shading_field)
    if opts.shading and shading_field is None:  # lens shading: corrected in every pass
        from l3cli.lens.train import learn_shading

        field, shading_record = learn_shading(pairs, opts)
        fitted = Fitted(shading_field=field)
    definition = define_classes(pairs, opts, client=client, show_progress=show_progress,
                                fitted=fitted)
    model = None
    curve_record = None
    if opts.white_balance:  # whites differ: train on targets with the adaptation taken out
        from l3cli.whitebalance.fit import fit_white_adaptation

        model, adapt = fit_white_adaptation(pairs, opts)
        fitted = replace(fitted, target_adapt=adapt or None)
    if opts.tone_curve:  # the renders' own curve: train in its linear space
        from l3cli.tone.fit import fit_pairs_curve

        tone_model, curve_record = fit_pairs_curve(pairs, opts, fitted)
        fitted = replace(fitted, tone_model=tone_model)
    if opts.by:
        parts = [collect_stats([pairs[i] for i in idx], definition, opts,
                               index_offset=min(idx), client=client,
                               show_progress=show_progress, fitted=fitted)
                 for idx in groups.values()]
        stats = parts[0]
        for part in parts[1:]:
            stats = stats + part
    else:
        stats = collect_stats(pairs, definition, opts, client=client,
                              show_progress=show_progress, fitted=fitted)
    table = table_from_stats(stats, opts, provenance=prov)
    if opts.tone_curve:
        from l3cli.tone.fit import attach_curve

        attach_curve(table, fitted.tone_model, curve_record)
    if model is not None:
        table.white_balance = model.as_dict()
    if fitted.shading_field is not None or shading_record is not None:
        table.shading = fitted.shading_field
    if shading_record is not None:
        table.provenance["shading"] = shading_record
    if opts.by:
        from l3cli.conditions import Conditioned

        kernels, counts = [], []
        for part in parts:
            k = np.array(table.kernels)
            part_k, _, _, part_n, part_tr = solve_stats(part, opts)
            k[part_tr] = part_k[part_tr]
            kernels.append(k)
            counts.append(np.where(part_tr, part_n, 0))
        table.conditions = Conditioned(opts.by, list(groups), np.array(kernels), np.array(counts))
        table.provenance["conditions"] = {"by": opts.by, "values": list(groups),
                                          "trained_classes": [int((c > 0).sum()) for c in counts]}
    return table
