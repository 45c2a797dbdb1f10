"""Cross-validation of training options from additive per-unit statistics.

The training statistics add (:class:`l3cli.train.stats.ClassStats`), so a
fold needs no retraining: the statistics of every *unit* (a whole image, or a
large block of columns when there is a single image) are computed once per
class layout, a fold's training statistics are the total minus the held-out
units' statistics, the fold's table is solved from them (ridge + GCV, as
``l3 train``), and the held-out units are rendered and scored with S-CIELAB
(:class:`l3cli.train.cvscore.ReferenceSCIELAB`).

Units never share pixels: whole images are held out when there are two or
more; a single image is cut into column blocks, and the statistics of a
block leave out a guard band of half a patch at each inner edge, so no
training patch reaches into the held-out block.

One statistics pass per unit collects the targets of every candidate colour
space at once (:data:`CV_SPACES`, 9 target channels): the patch products
``XᵀX`` are shared, and a space's statistics are its 3 columns of ``XᵀY`` and
``Σy²`` -- the same numbers ``l3 train --target SPACE`` accumulates.

The class definition (level and contrast cut points) comes from the raws of
all units (pass 1 of ``l3 train``); it uses no target values.

With a learned tone curve (``TrainOptions.tone_curve``, :mod:`l3cli.tone.curve`)
the ``linear-srgb`` channels hold the curve space of one curve fitted to all
the units (a global per-channel curve of ~17 values per channel from every
flat block: the held-out unit's share in it is small; the defaults were chosen
with curves fitted per fold, ``scripts/experiments/loo_tone_curve.py``),
and that space's renders are mapped back through it before scoring.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from l3cli.cfa import CFA
from l3cli.classify import ClassDefinition, ContrastHistogram
from l3cli.colourspace import D65_XYZ, convert, srgb_decode, srgb_encode
from l3cli.errors import ConfigError, InputError
from l3cli.pairs import Pair, load_pair
from l3cli.tone.fit import attach_curve, chosen_curve, curve_samples
from l3cli.train.cvscore import DEFAULT_OPPONENT, ReferenceSCIELAB
from l3cli.train.fit import (
    TONE_CURVE_SPACE,
    Fitted,
    TrainOptions,
    definition_from_histogram,
    histogram_task,
    table_from_stats,
    training_pixels,
)
from l3cli.train.stats import ClassStats, accumulate

__all__ = ["CV_SPACES", "CVImage", "Unit", "load_cv_images", "make_units", "make_folds", "histogram",
           "space_stats", "display_xyz",
           "LayoutStats", "RemoteLayout", "as_layout", "layout_stats", "unit_stats_task", "fold_stats", "score_fold",
           "score_fold_task", "fold_scores"]

log = logging.getLogger(__name__)

#: Target spaces collected by one statistics pass, in channel order.
CV_SPACES: tuple[str, ...] = ("linear-srgb", "srgb", "xyz")

#: Column blocks a single training image is cut into.
SINGLE_IMAGE_BLOCKS = 3


@dataclass
class CVImage:
    """One training image held in memory for cross-validation.

    Attributes
    ----------
    pair
        Where it came from.
    mosaic
        float32 (H, W) normalised raw (aligned to the target).
    cfa
        Its CFA.
    targets
        float32 (H, W, 9): the target in each of :data:`CV_SPACES`.
    mask
        bool (H, W) training pixels (valid render pixels and ``--sample-fraction``), or None.
    display
        True for display renders (pairs folders): candidates are scored as
        the 8-bit display sRGB ``l3 render`` writes.
    scorer
        S-CIELAB against this image's target.
    curve
        The tone curve of the ``linear-srgb`` channels (None: none).
    """

    pair: Pair
    mosaic: np.ndarray
    cfa: CFA
    targets: np.ndarray
    mask: np.ndarray | None
    display: bool
    scorer: ReferenceSCIELAB
    curve: object = None
    curve_record: dict | None = None


def load_cv_images(pairs: Sequence[Pair], opts: TrainOptions, *,
                   opponent: str = DEFAULT_OPPONENT, shading_field=None) -> list[CVImage]:
    """Read every pair once, with its targets in all :data:`CV_SPACES`.

    With ``shading_field`` (:class:`l3cli.lens.field.GainField`) the mosaics are
    corrected by it, as ``l3 train`` corrects them.

    With ``opts.white_balance`` (raws that carry a white balance) the images
    are what ``l3 train`` trains on: mosaics normalised by their white
    balance and targets with their shot's modelled adaptation taken out
    (:func:`l3cli.whitebalance.fit.fit_white_adaptation`, fitted once on all the
    images, as the tone curve is), so a fold scores the table's colour
    mapping before the adaptation that ``l3 render`` puts back.
    """
    from l3cli.whitebalance.model import training_mosaic, training_target

    fitted = Fitted(shading_field=shading_field)
    wb_opts = None
    if opts.white_balance:
        from l3cli.whitebalance.fit import fit_white_adaptation

        wb_opts = replace(opts, target_space="linear-srgb")
        fitted = replace(fitted, target_adapt=fit_white_adaptation(pairs, wb_opts)[1] or None)
    images = []
    for i, pair in enumerate(pairs):
        loaded = load_pair(pair, target_space="linear-srgb")
        raw, lin, valid = loaded.raw, loaded.target, loaded.weight_mask
        if wb_opts is not None:
            raw.mosaic = training_mosaic(raw, wb_opts, fitted)
            lin = training_target(lin, pair.raw, wb_opts, fitted)
        elif shading_field is not None:  # lens shading corrected
            raw.mosaic = training_mosaic(raw, opts, fitted)
        targets = np.empty(lin.shape[:2] + (3 * len(CV_SPACES),), dtype=np.float32)
        for k, space in enumerate(CV_SPACES):
            targets[:, :, 3 * k:3 * k + 3] = convert(lin, "linear-srgb", space)
        mask = training_pixels(raw.mosaic.shape, valid, opts, i)
        xyz = targets[:, :, 6:9]
        images.append(CVImage(pair, raw.mosaic, raw.cfa, targets, mask, bool(pair.align),
                              ReferenceSCIELAB(xyz, white=D65_XYZ, opponent=opponent)))
        if raw.cfa.spec != images[0].cfa.spec:
            raise InputError(f"{pair.raw}: CFA {raw.cfa.spec} differs from "
                             f"{images[0].cfa.spec} of {images[0].pair.raw}")
    if opts.tone_curve:
        _use_curve(images, opts)
    return images


def _use_curve(images: list[CVImage], opts: TrainOptions) -> None:
    """Fit one tone curve to all images; their linear-srgb channels become its space.

    No curve (:func:`l3cli.train.fit.chosen_curve`: it does not beat the sRGB
    decoding, or too few flat blocks): the channels stay linear-srgb.
    """
    k = CV_SPACES.index(TONE_CURVE_SPACE)
    curve, record = chosen_curve([curve_samples(img.mosaic, img.cfa,
                                                img.targets[:, :, 3 * k:3 * k + 3], img.mask, opts)
                                  for img in images])
    for img in images:
        img.curve_record = record
    if curve is None:
        return
    for img in images:
        lin = img.targets[:, :, 3 * k:3 * k + 3]
        lin[...] = curve.linearise(srgb_encode(np.clip(lin, 0.0, 1.0)))
        img.curve = curve


@dataclass(frozen=True)
class Unit:
    """What a fold holds out: image ``image``, columns ``[x0, x1)`` (None: all)."""

    image: int
    columns: tuple[int, int] | None = None

    def name(self, images: Sequence[CVImage]) -> str:
        """Readable name: the image's stem, with the columns of a block."""
        stem = images[self.image].pair.name
        return stem if self.columns is None else f"{stem}[x {self.columns[0]}:{self.columns[1]}]"


def make_units(images: Sequence[CVImage]) -> list[Unit]:
    """Whole images when there are two or more, else column blocks of the one image."""
    if len(images) >= 2:
        return [Unit(i) for i in range(len(images))]
    w = images[0].mosaic.shape[1]
    edges = np.linspace(0, w, SINGLE_IMAGE_BLOCKS + 1).round().astype(int)
    return [Unit(0, (int(a), int(b))) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def make_folds(units: Sequence[Unit], k: int) -> list[list[int]]:
    """``k`` folds (unit indices), units dealt round-robin; ``k`` is capped at the units."""
    if k < 2:
        raise ConfigError(f"cross-validation needs at least 2 folds, got {k}")
    k = min(k, len(units))
    if k < 2:
        raise InputError("cross-validation needs at least 2 images or blocks")
    return [list(range(f, len(units), k)) for f in range(k)]


def _unit_mask(img: CVImage, unit: Unit, guard: int) -> np.ndarray | None:
    if unit.columns is None:
        return img.mask
    h, w = img.mosaic.shape
    x0, x1 = unit.columns
    x0g = x0 + guard if x0 > 0 else 0
    x1g = x1 - guard if x1 < w else w
    m = np.zeros((h, w), dtype=bool)
    m[:, x0g:max(x0g, x1g)] = True
    return m if img.mask is None else m & img.mask


@dataclass
class LayoutStats:
    """Statistics of one class layout: per unit and their total (9 target channels)."""

    definition: ClassDefinition
    units: list[ClassStats]
    total: ClassStats

    @classmethod
    def of(cls, definition: ClassDefinition, per_unit: Sequence[ClassStats]) -> LayoutStats:
        """The layout of these units' statistics, their total summed in unit order."""
        total = ClassStats.zeros(definition, 3 * len(CV_SPACES), target_space="cv")
        for st in per_unit:
            total += st
        return cls(definition, list(per_unit), total)


@dataclass
class RemoteLayout:
    """A layout whose units' statistics stay on a dask cluster (``units``: futures).

    A fold task receives ``(definition, units)`` and makes the layout itself
    (:meth:`LayoutStats.of`: the same sums as in process); :meth:`gather`
    brings it here (the chosen candidate's table)."""

    definition: ClassDefinition
    units: list

    def gather(self, client) -> LayoutStats:
        return LayoutStats.of(self.definition, client.gather(self.units))

    def for_task(self) -> tuple:
        return self.definition, self.units


def as_layout(layout) -> LayoutStats:
    """A task's layout argument: a :class:`LayoutStats`, or ``(definition, units)``."""
    return layout if isinstance(layout, LayoutStats) else LayoutStats.of(*layout)


def histogram(images: Sequence[CVImage], opts: TrainOptions,
              shading_field=None) -> ContrastHistogram:
    """Pass 1 of ``l3 train`` over the raws (for ``opts.patch``; corrected by the lens
    shading ``shading_field`` when given), summed in input order."""
    hist = ContrastHistogram.empty()
    for i, img in enumerate(images):
        hist = hist + histogram_task((i, img.pair, opts, True, Fitted(shading_field)))[2]
    return hist


def layout_stats(images: Sequence[CVImage], units: Sequence[Unit], opts: TrainOptions,
                 hist: ContrastHistogram | None, *, client=None,
                 remote_images=None) -> LayoutStats | RemoteLayout:
    """One statistics pass per unit for the layout of ``opts`` (patch, levels, contrast
    bins), weighted as ``opts.sample_weight`` (:func:`l3cli.train.weights.sample_weights`).

    The augmentation of ``opts.augment`` applies later, when a fold's table is
    solved (:func:`l3cli.train.fit.table_from_stats`). With a dask ``client``
    each unit is a task (:func:`unit_stats_task`) over the images scattered to
    the workers (``remote_images``, futures of ``images``), whose result stays
    there for the fold tasks (a :class:`RemoteLayout`; a result lost with its
    worker is computed again).
    """
    d = definition_from_histogram(images[0].cfa, hist, opts)
    if client is None:
        return LayoutStats.of(d, [unit_stats_task((images, u, d, opts)) for u in units])
    return RemoteLayout(d, [client.submit(unit_stats_task, (remote_images, u, d, opts),
                                          retries=1, pure=False) for u in units])


def unit_stats_task(item: tuple) -> ClassStats:
    """The statistics of one unit (a map task): ``(images, unit, definition, opts)``,
    every target space's channels (:data:`CV_SPACES`)."""
    from l3cli.train.weights import sample_weights

    images, u, d, opts = item
    img = images[u.image]
    st = ClassStats.zeros(d, 3 * len(CV_SPACES), target_space="cv")
    mask = _unit_mask(img, u, guard=opts.patch // 2)
    # as l3 train: weights from the target's Y (the xyz channels), mean 1 over the image
    weight = sample_weights(img.targets[:, :, 3 * CV_SPACES.index("xyz") + 1], img.mask,
                            opts.sample_weight)
    accumulate(st, img.mosaic, img.targets, mask=mask, weight=weight)
    return st


def fold_stats(layout: LayoutStats, held_out: Sequence[int], space: str) -> ClassStats:
    """Training statistics of a fold in ``space``: the total minus the held-out units."""
    k = CV_SPACES.index(space)
    t = layout.total
    n, xtx = t.n.copy(), t.xtx.copy()
    xty, yy = t.xty[:, :, 3 * k:3 * k + 3].copy(), t.yy[:, 3 * k:3 * k + 3].copy()
    for u in held_out:
        s = layout.units[u]
        n -= s.n
        xtx -= s.xtx
        xty -= s.xty[:, :, 3 * k:3 * k + 3]
        yy -= s.yy[:, 3 * k:3 * k + 3]
    return ClassStats(layout.definition, n, xtx, xty, yy, space)


def space_stats(layout: LayoutStats, space: str) -> ClassStats:
    """The total statistics in ``space`` (what ``l3 train --target SPACE`` collects)."""
    return fold_stats(layout, [], space)


#: Bins of the linear -> 8-bit code look-up (finer than the closest codes, near black).
_CODE_BINS = 1 << 16


@functools.cache
def _display_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """8-bit display sRGB by look-up: the linear value of each code, the code
    of each of :data:`_CODE_BINS` linear bins, and the linear-sRGB -> XYZ
    matrix (all from :mod:`l3cli.colourspace`)."""
    codes = np.arange(256, dtype=np.float32) / np.float32(255.0)
    values = np.asarray(srgb_decode(codes), dtype=np.float32)
    centres = (np.arange(_CODE_BINS, dtype=np.float32) + 0.5) / np.float32(_CODE_BINS - 1)
    code_of = np.rint(srgb_encode(np.minimum(centres, 1.0)) * 255.0).astype(np.uint8)
    m = convert(np.eye(3, dtype=np.float32)[None], "linear-srgb", "xyz")[0].T
    return values, code_of, np.asarray(m, dtype=np.float32)


def display_xyz(rendered: np.ndarray, space: str, display: bool) -> np.ndarray:
    """XYZ (white Y = 1) of a render as a user sees it.

    For display renders, the 8-bit display sRGB that ``l3 render`` writes to
    PNG (clipped to [0, 1], encoded, rounded to the nearest code), by table
    look-up (a value within 1e-5 of a code boundary may land on the
    neighbouring code).
    """
    if not display:
        return convert(rendered, space, "xyz")
    values, code_of, m = _display_tables()
    if space == "srgb":
        codes = np.rint(np.clip(rendered, 0.0, 1.0) * np.float32(255.0)).astype(np.uint8)
    else:
        lin = rendered if space == "linear-srgb" else rendered @ np.linalg.inv(m).T.astype(
            np.float32)
        idx = np.clip(lin * np.float32(_CODE_BINS - 1), 0, _CODE_BINS - 1).astype(np.int32)
        codes = code_of[idx]
    return values[codes] @ m.T


def score_fold(images: Sequence[CVImage], units: Sequence[Unit], layout: LayoutStats,
               held_out: Sequence[int], opts: TrainOptions) -> list[float]:
    """Solve the fold's table in ``opts.target_space`` and score each held-out unit."""
    from l3cli.prepared import plain

    table = table_from_stats(fold_stats(layout, held_out, opts.target_space), opts)
    if opts.tone_curve:
        attach_curve(table, images[0].curve)
    scores = []
    for u in held_out:
        unit = units[u]
        img = images[unit.image]
        out = plain(table, img.mosaic).render()
        scores.append(img.scorer.mean(display_xyz(out, opts.target_space, img.display),
                                      columns=unit.columns))
    return scores


def score_fold_task(item: tuple) -> list[float]:
    """:func:`score_fold` as a map task: ``(images, units, layout, held_out, opts)``
    (the layout as :func:`as_layout` takes it)."""
    images, units, layout, held, opts = item
    return score_fold(images, units, as_layout(layout), held, opts)


def fold_scores(images: Sequence[CVImage], units: Sequence[Unit], folds: Sequence[Sequence[int]],
                layout: LayoutStats, opts: TrainOptions, *, client=None, remote=None
                ) -> np.ndarray:
    """S-CIELAB of every unit when its fold is held out (float64 (n_units,)).

    With a dask ``client`` each fold is a task (:func:`score_fold_task`) over the
    images and layout statistics on the workers (``remote``: the images' futures
    and :meth:`RemoteLayout.for_task`); the scores are the same bit for bit.
    """
    from l3cli.parallel import map_reduce

    imgs, lay = (images, layout) if client is None else remote
    scores = map_reduce(score_fold_task, [(imgs, units, lay, held, opts) for held in folds],
                        client=client, label="cv folds", show_progress=False)
    out = np.full(len(units), np.nan)
    for held, sc in zip(folds, scores, strict=True):
        out[list(held)] = sc
    return out
