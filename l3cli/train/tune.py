"""``l3 train --tune``: choose the training options by cross-validation.

Searched: the target space (:data:`l3cli.train.cv.CV_SPACES`), the patch
size, the number of levels and of contrast bins. Every candidate is scored by
K-fold cross-validation over whole training images (or column blocks of a
single image), with S-CIELAB (ISETCam's 10° opponent transform, 96 dpi at
1 m, 4-pixel border excluded) of the held-out renders, as ``l3 evaluate``
scores them; the folds come from additive statistics (:mod:`l3cli.train.cv`),
never from retraining.

The search has four stages so that its cost stays a few dozen candidates:

1. every target space x every patch size, at the starting levels, contrast
   bins and contrast rule (``--levels``, ``--contrast-bins``,
   ``--contrast-threshold``);
2. for the best space and patch, every levels x contrast-bins pair;
3. for the best of those, every contrast threshold of the grid (a fixed
   threshold, or ``"quantile"``: the per-level quantiles of the data);
4. for the best of those, the dihedral augmentation and the sample weights
   (``--augment`` x ``--sample-weight``, :mod:`l3cli.train.augment`,
   :mod:`l3cli.train.weights`): a pipeline that is not mirror-symmetric, or
   whose dark pixels matter more, is found here.

The best candidate's table is solved from the statistics of all the
training images (the statistics already collected), and its provenance
records the candidates, their scores and the choice (``l3 inspect`` shows
them).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from l3cli.errors import ConfigError, InputError
from l3cli.pairs import Pair
from l3cli.table import TransformTable
from l3cli.train.curve import attach_curve
from l3cli.train.cv import (
    CV_SPACES,
    fold_scores,
    histogram,
    layout_stats,
    load_cv_images,
    make_folds,
    make_units,
    space_stats,
)
from l3cli.train.cvscore import DEFAULT_OPPONENT
from l3cli.train.fit import (
    TONE_CURVE_SPACE,
    TrainOptions,
    default_target_space,
    table_from_stats,
    train,
)

__all__ = ["TuneGrid", "Candidate", "CandidateResult", "TuneResult", "DEFAULT_FOLDS",
           "tune", "format_candidates", "replace_opts", "read_train_config"]

log = logging.getLogger(__name__)

#: Default number of cross-validation folds (leave-one-image-out up to this many images).
DEFAULT_FOLDS = 5


@dataclass(frozen=True)
class TuneGrid:
    """The values searched by :func:`tune` (see the module notes).

    ``spaces`` None: the default target space of the inputs (the linear version
    of the renders' space, :func:`l3cli.train.fit.default_target_space`) and
    ``srgb`` (the renders' encoding).
    """

    spaces: tuple[str, ...] | None = None
    patches: tuple[int, ...] = (5, 7)
    levels: tuple[int, ...] = (24, 36, 48)
    contrast_bins: tuple[int, ...] = (1, 2, 3)
    contrast_thresholds: tuple[float | None, ...] = (None, 0.1, 0.2)
    augments: tuple[str, ...] = ("d4", "none")
    sample_weights: tuple[str, ...] = ("luminance", "none")
    folds: int = DEFAULT_FOLDS

    def __post_init__(self) -> None:
        bad = [s for s in self.spaces or () if s not in CV_SPACES]
        if bad or self.spaces == ():
            raise ConfigError(f"tune spaces {list(self.spaces)} not allowed; choose from "
                              f"{', '.join(CV_SPACES)}")
        for name, vals, lo in (("patches", self.patches, 1), ("levels", self.levels, 2),
                               ("contrast_bins", self.contrast_bins, 1)):
            if not vals or any(int(v) < lo for v in vals):
                raise ConfigError(f"tune {name} {list(vals)} not allowed; use values >= {lo}")
        if any(p % 2 == 0 for p in self.patches):
            raise ConfigError(f"tune patches {list(self.patches)} must be odd")
        if any(t is not None and not t > 0 for t in self.contrast_thresholds):
            raise ConfigError(f"tune contrast thresholds {list(self.contrast_thresholds)} "
                              "must be > 0 (or \"quantile\")")
        if self.folds < 2:
            raise ConfigError(f"tune folds {self.folds} not allowed; use 2 or more")
        from l3cli.train.augment import augment_elements
        from l3cli.train.weights import check_weight

        if not self.augments or not self.sample_weights:
            raise ConfigError("tune augments and sample_weights need at least one value each")
        for a in self.augments:
            augment_elements(a)
        for w in self.sample_weights:
            check_weight(w)

    @classmethod
    def from_dict(cls, d: dict) -> TuneGrid:
        """From a config table (``[train.tune]``): keys as the attributes."""
        known = {"spaces", "patches", "levels", "contrast_bins", "contrast_thresholds", "folds",
                 "augments", "sample_weights"}
        extra = set(d) - known
        if extra:
            raise ConfigError(f"unknown tune keys {sorted(extra)}; allowed: {sorted(known)}")
        kw = {k: (int(v) if k == "folds" else tuple(v)) for k, v in d.items()}
        if "contrast_thresholds" in kw:
            kw["contrast_thresholds"] = tuple(None if t == "quantile" else float(t)
                                              for t in kw["contrast_thresholds"])
        return cls(**kw)


@dataclass(frozen=True)
class Candidate:
    """One setting of the searched options."""

    target_space: str
    patch: int
    levels: int
    contrast_bins: int
    contrast_threshold: float | None = None
    augment: str = "none"
    sample_weight: str = "none"

    def as_dict(self) -> dict:
        """JSON form (``contrast_threshold`` None: per-level quantiles)."""
        return {"target": self.target_space, "patch": self.patch, "levels": self.levels,
                "contrast_bins": self.contrast_bins,
                "contrast_threshold": self.contrast_threshold, "augment": self.augment,
                "sample_weight": self.sample_weight}


@dataclass
class CandidateResult:
    """Cross-validation scores of a candidate (one per held-out unit)."""

    candidate: Candidate
    scores: np.ndarray

    @property
    def mean(self) -> float:
        """Mean S-CIELAB over the held-out units."""
        return float(np.mean(self.scores))


@dataclass
class TuneResult:
    """What :func:`tune` found."""

    results: list[CandidateResult]
    best: CandidateResult
    options: TrainOptions
    table: TransformTable
    units: list[str]
    folds: list[list[int]]
    seconds: float
    record: dict = field(default_factory=dict)


def _next_stage(stage: int, grid: TuneGrid, best: Candidate,
                done: set[Candidate]) -> list[Candidate]:
    b = best
    if stage == 2:
        cands = [replace(b, levels=lv, contrast_bins=nb)
                 for lv in grid.levels for nb in grid.contrast_bins]
    elif stage == 4:  # weights outer: one statistics pass per weighting
        cands = [replace(b, augment=a, sample_weight=w)
                 for w in grid.sample_weights for a in grid.augments]
    elif b.contrast_bins == 1:  # one bin: no contrast threshold to choose
        cands = []
    else:
        cands = [replace(b, contrast_threshold=t) for t in grid.contrast_thresholds]
    return [c for c in cands if c not in done]


def tune(pairs: Sequence[Pair], base: TrainOptions | None = None, grid: TuneGrid | None = None,
         *, show_progress: bool | None = False, opponent: str = DEFAULT_OPPONENT) -> TuneResult:
    """Search target space, patch, levels, contrast bins and rule by cross-validation.

    Parameters
    ----------
    pairs
        Training pairs (two or more images, or one image cut into blocks).
    base
        Options kept fixed (sampling, seed, saturation, ridge grid, ...); its
        levels and contrast bins start stage 1.
    grid
        Values searched.
    show_progress
        Progress bar on stderr (one step per candidate).
    opponent
        S-CIELAB opponent transform of the score.

    Returns
    -------
    TuneResult
        Every candidate's scores, the best one, its options and its table
        (trained on all the pairs), and the provenance record.
    """
    from l3cli.progress import progress

    t0 = time.perf_counter()
    base = base or TrainOptions()
    grid = grid or TuneGrid()
    pairs = list(pairs)
    if not pairs:
        raise InputError("no training pairs")
    shading_record = None
    if base.shading:  # the lens-shading field first: every candidate sees corrected mosaics
        import copy

        from l3cli.train.shading import learn_shading

        base = copy.copy(base)
        base.shading_field, shading_record = learn_shading(pairs, base)
    images = load_cv_images(pairs, base, opponent=opponent)
    units = make_units(images)
    folds = make_folds(units, grid.folds)
    start_levels = base.levels if base.levels in grid.levels else grid.levels[0]
    start_bins = (base.contrast_bins if base.contrast_bins in grid.contrast_bins
                  else grid.contrast_bins[0])
    start_t = base.contrast_threshold
    spaces = grid.spaces or (default_target_space(pairs), "srgb")
    plan = [Candidate(s, p, start_levels, start_bins, start_t, base.augment, base.sample_weight)
            for p in grid.patches for s in spaces]
    stage_ends = [len(plan)]
    n_total = (len(plan) + len(grid.levels) * len(grid.contrast_bins) - 1
               + len(grid.contrast_thresholds)
               + len(grid.augments) * len(grid.sample_weights) - 1)
    hists: dict[int, object] = {}
    layout = None
    layout_key = None
    results: list[CandidateResult] = []

    def stats_for(c: Candidate):
        nonlocal layout, layout_key
        key = (c.patch, c.levels, c.contrast_bins, c.contrast_threshold, c.sample_weight)
        if key != layout_key:
            opts = replace_opts(base, c)
            if c.patch not in hists:
                hists[c.patch] = histogram(images, opts)
            layout = None  # free the previous layout first
            layout = layout_stats(images, units, opts, hists[c.patch])
            layout_key = key
        return layout

    for k in progress(range(n_total), label="tune      ", length=n_total, enabled=show_progress):
        while k == len(plan) and len(stage_ends) < 4:  # a stage is done: plan the next
            best_c = min(results, key=lambda r: r.mean).candidate
            plan += _next_stage(len(stage_ends) + 1, grid, best_c, {r.candidate for r in results})
            stage_ends.append(len(plan))
        if k >= len(plan):
            continue
        c = plan[k]
        opts = replace_opts(base, c)
        scores = fold_scores(images, units, folds, stats_for(c), opts)
        results.append(CandidateResult(c, scores))
        log.info("tune %s: %.4f", c.as_dict(), results[-1].mean)
    best = min(results, key=lambda r: r.mean)
    opts = replace_opts(base, best.candidate)
    names = [u.name(images) for u in units]
    seconds = time.perf_counter() - t0
    record = {
        "metric": f"S-CIELAB mean dE*ab ({opponent}, 96 dpi, 1 m, 4-pixel border excluded)",
        "folds": [[names[u] for u in f] for f in folds],
        "candidates": [{**r.candidate.as_dict(), "cv_mean": round(r.mean, 5),
                        "cv_units": [round(float(v), 5) for v in r.scores]} for r in results],
        "chosen": {**best.candidate.as_dict(), "cv_mean": round(best.mean, 5)},
        "seconds": round(seconds, 1),
        # linear-srgb candidates in the renders' learned tone-curve space (one curve from all images)
        "tone_curve": images[0].curve is not None,
    }
    prov = {"inputs": [str(p.raw) for p in pairs], "targets": [str(p.target) for p in pairs],
            "seed": opts.seed, "tune": record}
    if opts.white_balance:
        # the shots' adaptation model belongs in the table and its targets are fitted in
        # the chosen target space: the regular training path, once, with the chosen options
        table = train(pairs, opts, show_progress=show_progress)
        table.provenance.update(prov)
    else:
        lay = stats_for(best.candidate)
        table = table_from_stats(space_stats(lay, opts.target_space), opts, provenance=prov)
        if opts.tone_curve:
            attach_curve(table, images[0].curve)
    if shading_record is not None:
        table.shading = base.shading_field
        table.provenance["shading"] = shading_record
    return TuneResult(results, best, opts, table, names, folds, seconds, record)


def replace_opts(base: TrainOptions, c: Candidate) -> TrainOptions:
    """``base`` with the candidate's target space, patch, levels, contrast bins and rule,
    augmentation and sample weights."""
    d = base.as_dict()
    d.update(target_space=c.target_space, patch=c.patch, levels=c.levels,
             contrast_bins=c.contrast_bins, contrast_threshold=c.contrast_threshold,
             tone_curve=base.tone_curve and c.target_space == TONE_CURVE_SPACE,
             augment=c.augment, sample_weight=c.sample_weight)
    return TrainOptions(**d)


def format_candidates(record: dict) -> str:
    """The candidate table of a tune record (best marked ``*``), sorted by score."""
    rows = sorted(record["candidates"], key=lambda r: r["cv_mean"])
    chosen = record["chosen"]
    keys = ("target", "patch", "levels", "contrast_bins", "contrast_threshold", "augment",
            "sample_weight")
    out = [f"  {'':1} {'target':<12} {'patch':>5} {'levels':>6} {'bins':>4} {'threshold':>9} "
           f"{'augment':>7} {'weight':>9}  {'CV S-CIELAB':>11}  per held-out unit"]
    for r in rows:
        mark = "*" if all(r.get(k) == chosen.get(k) for k in keys) else ""
        units = " ".join(f"{v:.3f}" for v in r["cv_units"])
        thr = r.get("contrast_threshold")
        thr = "quantile" if thr is None else f"{thr:g}"
        if r["contrast_bins"] == 1:
            thr = "-"
        out.append(f"  {mark:1} {r['target']:<12} {r['patch']:>5} {r['levels']:>6} "
                   f"{r['contrast_bins']:>4} {thr:>9} {r.get('augment', 'none'):>7} "
                   f"{r.get('sample_weight', 'none'):>9}  {r['cv_mean']:>11.4f}  {units}")
    return "\n".join(out)



def read_train_config(path: str | os.PathLike, allowed: set[str]) -> tuple[dict, TuneGrid | None]:
    """The ``[train]`` table of a TOML config (for Makefiles): options and tune grid.

    Keys are ``l3 train``'s long option names (``contrast-bins`` or
    ``contrast_bins``; ``tune = true`` runs the search); a ``[train.tune]``
    sub-table sets the searched values (:meth:`TuneGrid.from_dict`).

    Parameters
    ----------
    path
        The TOML file.
    allowed
        Option names (underscored) the caller accepts.

    Returns
    -------
    options, grid
        Option values by underscored name, and the grid (None when absent).

    Raises
    ------
    ConfigError
        Unreadable TOML, no ``[train]`` table, or an unknown key (named with the file).
    """
    import tomllib

    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config ({exc.strerror})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from exc
    section = doc.get("train")
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: no [train] table")
    section = dict(section)
    grid_d = section.pop("tune", None)
    opts = {}
    if isinstance(grid_d, dict):
        opts["tune"] = True
        try:
            grid = TuneGrid.from_dict(grid_d)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{path}: bad [train.tune] table ({exc})") from exc
    else:
        grid = None
        if grid_d is not None:
            opts["tune"] = bool(grid_d)
    for key, value in section.items():
        name = {"target": "target_space"}.get(key, key).replace("-", "_")
        if name not in allowed:
            raise ConfigError(f"{path}: unknown [train] key {key!r}")
        opts[name] = value
    return opts, grid
