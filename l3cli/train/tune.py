"""``l3 train``'s self-tuning (on by default for pairs folders): options by cross-validation.

Searched by default (:data:`l3cli.defaults.TUNE_GRID`): the target space
(:data:`l3cli.train.cv.CV_SPACES`), the patch size, lens shading on or off
(:mod:`l3cli.lens.train`) and the multi-scale stage on or off
(:mod:`l3cli.multiscale.cv`); a ``[train.tune]`` config table can add
the number of levels, contrast bins and threshold, the dihedral augmentation
and the sample weights. Every candidate is scored by K-fold cross-validation
over whole training images (or column blocks of a single image), with
S-CIELAB (ISETCam's 10° opponent transform, 96 dpi at 1 m, 4-pixel border
excluded) of the held-out renders, as ``l3 evaluate`` scores them; the folds
come from additive statistics (:mod:`l3cli.train.cv`: the normal equations
of every unit are summed once per class layout, for all target spaces at
once, and a fold is the total minus its held-out units), never from
retraining.

The search is coarse to fine, cheap candidates first, each stage around the
best candidate so far (and the one the rule below would pick, where they
differ):

1. every target space at the smallest patch (one statistics pass);
2. the larger patches for the better half of the spaces (successive halving);
3. levels x contrast bins, 4. contrast thresholds, 5. augmentation x sample
   weights, where the grid lists more than one value;
6. lens shading off (where a gain field was learned and kept: the field is
   learned once, before the search);
7. the multi-scale stage on (each fold fits its own stage on its table's
   renders of its training images).

Stages 6 and 7 change the cheaper of the two anchors first and the other
only where the change helped the cheaper one.

**The choice (one-standard-error rule).** Render speed matters, so the
chosen candidate is not simply the best: among the candidates whose mean CV
score is within one standard error of the best's -- the standard error of
the per-unit score differences to the best (paired, as every candidate is
scored on the same held-out units), and never more than
:data:`l3cli.defaults.TUNE_TOLERANCE` (5 %) of the best score -- the one
with the lowest render cost is chosen (:meth:`Candidate.cost_key`: the
multi-scale stage, then the patch size, then the shading gain; equal cost:
the lower score).

The chosen candidate's table is solved from the statistics of all the
training images (the statistics already collected), and its provenance
records the candidates, their scores, the rule and the choice (``l3
inspect`` shows them).
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from l3cli import defaults
from l3cli.errors import ConfigError, InputError
from l3cli.pairs import Pair
from l3cli.table import TransformTable
from l3cli.tone.fit import attach_curve
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

__all__ = ["TuneGrid", "Candidate", "CandidateResult", "TuneResult", "DEFAULT_FOLDS", "RULE",
           "tune", "choose", "format_candidates", "replace_opts", "read_train_config"]

log = logging.getLogger(__name__)

#: Default number of cross-validation folds (leave-one-image-out up to this many images).
DEFAULT_FOLDS = defaults.TUNE_GRID["folds"]

#: The choice rule, as the output and the table's provenance state it.
RULE = (f"one-standard-error rule: the cheapest to render (multi-scale stage, then patch size, "
        f"then shading) of the candidates whose CV score is within one standard error of the "
        f"paired per-unit differences (at most {defaults.TUNE_TOLERANCE:.0%}) of the best")

_G = defaults.TUNE_GRID


@dataclass(frozen=True)
class TuneGrid:
    """The values searched by :func:`tune` (see the module notes); the defaults are
    :data:`l3cli.defaults.TUNE_GRID`.

    ``spaces`` None: the default target space of the inputs (the linear version
    of the renders' space, :func:`l3cli.train.fit.default_target_space`) and
    ``srgb`` (the renders' encoding). An empty tuple: not searched (the value
    of the options :func:`tune` is given).
    """

    spaces: tuple[str, ...] | None = _G["spaces"]
    patches: tuple[int, ...] = _G["patches"]
    levels: tuple[int, ...] = _G["levels"]
    contrast_bins: tuple[int, ...] = _G["contrast_bins"]
    contrast_thresholds: tuple[float | None, ...] = _G["contrast_thresholds"]
    augments: tuple[str, ...] = _G["augments"]
    sample_weights: tuple[str, ...] = _G["sample_weights"]
    shading: tuple[bool, ...] = _G["shading"]
    multiscale: tuple[bool, ...] = _G["multiscale"]
    folds: int = _G["folds"]

    def __post_init__(self) -> None:
        bad = [s for s in self.spaces or () if s not in CV_SPACES]
        if bad or self.spaces == ():
            raise ConfigError(f"tune spaces {list(self.spaces)} not allowed; choose from "
                              f"{', '.join(CV_SPACES)}")
        for name, vals, lo in (("patches", self.patches, 1), ("levels", self.levels, 2),
                               ("contrast_bins", self.contrast_bins, 1)):
            if any(int(v) < lo for v in vals):
                raise ConfigError(f"tune {name} {list(vals)} not allowed; use values >= {lo}")
        if any(p % 2 == 0 for p in self.patches):
            raise ConfigError(f"tune patches {list(self.patches)} must be odd")
        if any(t is not None and not t > 0 for t in self.contrast_thresholds):
            raise ConfigError(f"tune contrast thresholds {list(self.contrast_thresholds)} "
                              "must be > 0 (or \"quantile\")")
        if self.folds < 2:
            raise ConfigError(f"tune folds {self.folds} not allowed; use 2 or more")
        for name in ("shading", "multiscale"):
            if any(not isinstance(v, bool) for v in getattr(self, name)):
                raise ConfigError(f"tune {name} {list(getattr(self, name))} not allowed; use "
                                  "true and/or false")
        from l3cli.train.augment import augment_elements
        from l3cli.train.weights import check_weight

        for a in self.augments:
            augment_elements(a)
        for w in self.sample_weights:
            check_weight(w)

    @classmethod
    def from_dict(cls, d: dict) -> TuneGrid:
        """From a config table (``[train.tune]``): keys as the attributes."""
        known = {"spaces", "patches", "levels", "contrast_bins", "contrast_thresholds", "folds",
                 "augments", "sample_weights", "shading", "multiscale"}
        extra = set(d) - known
        if extra:
            raise ConfigError(f"unknown tune keys {sorted(extra)}; allowed: {sorted(known)}")
        kw = {k: (int(v) if k == "folds" else tuple(v)) for k, v in d.items()}
        if "contrast_thresholds" in kw:
            kw["contrast_thresholds"] = tuple(None if t == "quantile" else float(t)
                                              for t in kw["contrast_thresholds"])
        return cls(**kw)

    #: The option each searched dimension sets (``l3 train``'s parameter names).
    OPTIONS = {"patch": "patches", "target_space": "spaces", "levels": "levels",
               "contrast_bins": "contrast_bins", "contrast_threshold": "contrast_thresholds",
               "augment": "augments", "sample_weight": "sample_weights",
               "shading": "shading", "multiscale": "multiscale"}

    def fixed(self, **values) -> TuneGrid:
        """The grid with these dimensions held at one value each (options the user gave),
        keyed by option name (:attr:`OPTIONS`)."""
        return replace(self, **{self.OPTIONS[k]: (v,) for k, v in values.items()})


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
    shading: bool = False
    multiscale: bool = False

    def as_dict(self) -> dict:
        """JSON form (``contrast_threshold`` None: per-level quantiles)."""
        return {"target": self.target_space, "patch": self.patch, "levels": self.levels,
                "contrast_bins": self.contrast_bins,
                "contrast_threshold": self.contrast_threshold, "augment": self.augment,
                "sample_weight": self.sample_weight, "shading": self.shading,
                "multiscale": self.multiscale}

    def cost_key(self) -> tuple:
        """Render cost order: the multi-scale stage (about 1.3 s per megapixel), then the
        patch (9 x 9 about 1.4 x the time of 5 x 5), then the shading gain (one multiply)."""
        return (self.multiscale, self.patch, self.shading)


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
    """What :func:`tune` found (``best``: the lowest score; ``chosen``: the rule's pick,
    whose options and table these are)."""

    results: list[CandidateResult]
    best: CandidateResult
    options: TrainOptions
    table: TransformTable
    units: list[str]
    folds: list[list[int]]
    seconds: float
    record: dict = field(default_factory=dict)
    chosen: CandidateResult | None = None


def choose(results: Sequence[CandidateResult], tolerance: float = defaults.TUNE_TOLERANCE
           ) -> tuple[CandidateResult, CandidateResult, dict]:
    """The one-standard-error rule (module notes): ``(chosen, best, margins)``.

    ``margins`` maps each candidate to the largest score above the best's it
    may have to be chosen (the paired standard error, capped at ``tolerance``
    times the best score).
    """
    best = min(results, key=lambda r: r.mean)
    margins = {}
    ok = []
    for r in results:
        d = np.asarray(r.scores, float) - np.asarray(best.scores, float)
        se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size > 1 else 0.0
        margins[r.candidate] = min(se, tolerance * best.mean)
        if r.mean - best.mean <= margins[r.candidate]:
            ok.append(r)
    chosen = min(ok, key=lambda r: (r.candidate.cost_key(), r.mean))
    return chosen, best, margins


class _Search:
    """The state of one search: images per shading setting, statistics cache, results."""

    def __init__(self, pairs, base, grid, field, opponent, report, client=None):
        self.pairs, self.base, self.grid, self.field = pairs, base, grid, field
        self.opponent, self.report, self.client = opponent, report, client
        self.images: dict[bool, list] = {}
        self.remote_images = {}  # on a cluster: the images' futures
        self.hists: dict[tuple, object] = {}
        self.layouts: dict[tuple, object] = {}
        self.results: list[CandidateResult] = []
        self.t0 = time.perf_counter()

    def opts(self, c: Candidate) -> TrainOptions:
        return replace_opts(self.base, c)

    def field_for(self, shading: bool):
        """The lens-shading gain field of candidates with ``shading`` (None: none)."""
        return self.field if shading else None

    def images_for(self, shading: bool):
        if shading not in self.images:
            self.images[shading] = load_cv_images(self.pairs, self.base, opponent=self.opponent,
                                                  shading_field=self.field_for(shading))
        return self.images[shading]

    def images_on_cluster(self, shading: bool):
        """The images of ``shading`` scattered to every worker (once: a task whose worker
        is lost is retried on another, which has them too), or None in process."""
        if self.client is None:
            return None
        if shading not in self.remote_images:
            self.remote_images[shading] = self.client.scatter(
                list(self.images_for(shading)), broadcast=True, hash=False)
        return self.remote_images[shading]

    @staticmethod
    def layout_key(c: Candidate) -> tuple:
        return (c.shading, c.patch, c.levels, c.contrast_bins, c.contrast_threshold, c.sample_weight)

    def remote(self, c: Candidate):
        """``(images, layout)`` of ``c`` on the cluster (futures), or None in process."""
        if self.client is None:
            return None
        return self.images_on_cluster(c.shading), self.layout(c).for_task()

    def layout(self, c: Candidate):
        key = self.layout_key(c)
        if key not in self.layouts:
            images = self.images_for(c.shading)
            opts = self.opts(c)
            if (c.shading, c.patch) not in self.hists:
                self.hists[(c.shading, c.patch)] = histogram(images, opts,
                                                             self.field_for(c.shading))
            while len(self.layouts) >= 2:  # bounded memory: the two latest layouts
                del self.layouts[next(iter(self.layouts))]  # (on the workers too)
            self.layouts[key] = layout_stats(images, self.units, opts,
                                             self.hists[(c.shading, c.patch)],
                                             client=self.client,
                                             remote_images=self.images_on_cluster(c.shading))
        return self.layouts[key]

    def evaluate(self, cands: Sequence[Candidate]) -> None:
        done = {r.candidate for r in self.results}
        for c in cands:
            if c in done:
                continue
            done.add(c)
            images = self.images_for(c.shading)
            opts = self.opts(c)
            lay = self.layout(c)
            if c.multiscale:
                from l3cli.multiscale.cv import multiscale_fold_scores

                try:
                    scores, _ = multiscale_fold_scores(images, self.units, self.folds, lay,
                                                       opts, seed=opts.seed,
                                                       client=self.client,
                                                       remote=self.remote(c))
                except InputError as exc:  # too little data for the stage: not a candidate
                    log.warning("tune: the multi-scale stage is not scored: %s", exc)
                    continue
            else:
                scores = fold_scores(images, self.units, self.folds, lay, opts,
                                     client=self.client, remote=self.remote(c))
            self.results.append(CandidateResult(c, scores))
            log.info("tune %s: %.4f", c.as_dict(), self.results[-1].mean)
            if self.report is not None:
                self.report(len(self.results), c, self.results[-1].mean,
                            time.perf_counter() - self.t0)

    def try_change(self, name: str, values: Sequence) -> None:
        """``name`` set to each of ``values`` on the cheapest anchor; on the other anchors
        only for the values that beat the cheapest anchor's own score."""
        anchors = sorted(self.anchors(), key=lambda c: (c.cost_key(), c.target_space))
        first = anchors[0]
        self.evaluate([replace(first, **{name: v}) for v in values])
        score = {r.candidate: r.mean for r in self.results}
        good = [v for v in values
                if score.get(replace(first, **{name: v}), np.inf) < score[first]]
        self.evaluate([replace(a, **{name: v}) for a in anchors[1:] for v in good])

    def anchors(self) -> list[Candidate]:
        """The best candidate so far and the rule's pick (once each)."""
        chosen, best, _ = choose(self.results)
        return list(dict.fromkeys([best.candidate, chosen.candidate]))


def tune(pairs: Sequence[Pair], base: TrainOptions | None = None, grid: TuneGrid | None = None,
         *, show_progress: bool | None = False, opponent: str = DEFAULT_OPPONENT,
         report: Callable[[int, Candidate, float, float], None] | None = None,
         client=None) -> TuneResult:
    """Search the options of ``grid`` by cross-validation; train the chosen candidate.

    Parameters
    ----------
    pairs
        Training pairs (two or more images, or one image cut into blocks).
    base
        Options kept fixed (sampling, seed, saturation, ridge grid, ...), and the
        values of the dimensions the grid leaves empty.
    grid
        Values searched (:data:`l3cli.defaults.TUNE_GRID` when None).
    show_progress
        Progress bars on stderr (the multi-scale stage of the chosen table).
    opponent
        S-CIELAB opponent transform of the score.
    report
        Called after every candidate with (number, candidate, CV score, seconds so far).
    client
        A dask client (:func:`l3cli.parallel.dask_client`): the statistics of every
        unit and the folds of every candidate run as tasks on its workers, over the
        images and statistics scattered to them; the result is the same bit for bit
        as in process (None).

    Returns
    -------
    TuneResult
        Every candidate's scores, the best one, the chosen one, its options and its
        table (trained on all the pairs; with its multi-scale stage when chosen),
        and the provenance record.
    """
    base = base or TrainOptions()
    grid = grid or TuneGrid()
    pairs = list(pairs)
    if not pairs:
        raise InputError("no training pairs")
    shadings = grid.shading or (base.shading,)
    field, shading_record = None, None
    if True in shadings:  # the lens-shading field first, once: every candidate with it
        from l3cli.lens.train import learn_shading  # sees the corrected mosaics

        field, shading_record = learn_shading(pairs, replace(base, shading=True))
        if field is None:  # not kept: shading on is shading off
            shadings = (False,)
    s = _Search(pairs, base, grid, field, opponent, report, client)
    images = s.images_for(shadings[0])
    s.units = make_units(images)
    s.folds = make_folds(s.units, grid.folds)
    spaces = grid.spaces or (default_target_space(pairs), "srgb")
    patches = tuple(sorted(grid.patches or (base.patch,)))
    start = Candidate(spaces[0], patches[0], (grid.levels or (base.levels,))[0],
                      (grid.contrast_bins or (base.contrast_bins,))[0],
                      (grid.contrast_thresholds or (base.contrast_threshold,))[0],
                      (grid.augments or (base.augment,))[0],
                      (grid.sample_weights or (base.sample_weight,))[0],
                      shadings[0], (grid.multiscale or (False,))[0])
    # 1. every space at the smallest patch; 2. larger patches, the better half of the spaces
    s.evaluate([replace(start, target_space=sp) for sp in spaces])
    ranked = sorted(s.results, key=lambda r: r.mean)
    keep = [r.candidate for r in ranked[:max(1, math.ceil(len(spaces) / 2))]]
    s.evaluate([replace(c, patch=p) for p in patches[1:] for c in keep])
    # 3.-5. the layout, augmentation and weights, where the grid lists several values
    if len(grid.levels) > 1 or len(grid.contrast_bins) > 1:
        s.evaluate([replace(a, levels=lv, contrast_bins=nb) for a in s.anchors()
                    for lv in grid.levels or (a.levels,)
                    for nb in grid.contrast_bins or (a.contrast_bins,)])
    if len(grid.contrast_thresholds) > 1:
        s.evaluate([replace(a, contrast_threshold=t) for a in s.anchors()
                    if a.contrast_bins > 1 for t in grid.contrast_thresholds])
    if len(grid.augments) > 1 or len(grid.sample_weights) > 1:
        s.evaluate([replace(a, augment=au, sample_weight=w) for a in s.anchors()
                    for w in grid.sample_weights or (a.sample_weight,)
                    for au in grid.augments or (a.augment,)])
    # 6. shading, 7. the multi-scale stage: on the cheaper anchor first, on the other
    # only where the change helped there (successive halving)
    s.try_change("shading", shadings)
    s.try_change("multiscale", grid.multiscale)
    chosen, best, margins = choose(s.results)
    return _finish(s, chosen, best, margins, shading_record, show_progress)


def _finish(s: _Search, chosen: CandidateResult, best: CandidateResult, margins: dict,
            shading_record, show_progress) -> TuneResult:
    """The chosen candidate's table and the provenance record."""
    c = chosen.candidate
    opts = s.opts(c)
    images = s.images_for(c.shading)
    names = [u.name(images) for u in s.units]
    order = sorted(s.results, key=lambda r: r.candidate.cost_key())
    rank = {r.candidate: i + 1 for i, r in enumerate(order)}
    record = {
        "metric": (f"S-CIELAB mean dE*ab ({s.opponent}, 96 dpi, 1 m, 4-pixel border "
                   "excluded)"),
        "rule": RULE,
        "folds": [[names[u] for u in f] for f in s.folds],
        "candidates": [{**r.candidate.as_dict(), "cv_mean": round(r.mean, 5),
                        "margin": round(margins[r.candidate], 5),
                        "cost_rank": rank[r.candidate],
                        "cv_units": [round(float(v), 5) for v in r.scores]} for r in s.results],
        "chosen": {**c.as_dict(), "cv_mean": round(chosen.mean, 5)},
        "best": {**best.candidate.as_dict(), "cv_mean": round(best.mean, 5)},
        # linear-srgb candidates in the renders' learned tone-curve space (one curve from all images)
        "tone_curve": images[0].curve is not None,
    }
    if shading_record is not None and s.field is None:
        record["shading"] = "no gain field kept: " + str(shading_record.get("reason", ""))
    prov = {"inputs": [str(p.raw) for p in s.pairs], "targets": [str(p.target) for p in s.pairs],
            "seed": opts.seed, "tune": record}
    if opts.white_balance:
        # the shots' adaptation model belongs in the table and its targets are fitted in
        # the chosen target space: the regular training path, once, with the chosen options
        # (the field learned for the search, not learned again)
        table = train(s.pairs, replace(opts, shading=False), shading_field=s.field_for(c.shading),
                      client=s.client)
        table.provenance.update(prov)
        table.provenance["options"] = opts.as_dict()
    else:
        lay = s.layout(c)
        if s.client is not None:  # the units' statistics, from the workers
            lay = lay.gather(s.client)
        table = table_from_stats(space_stats(lay, opts.target_space), opts, provenance=prov)
        if opts.tone_curve:  # with the curve's record, as l3 train writes it
            attach_curve(table, images[0].curve, images[0].curve_record)
    if c.shading:
        table.shading = s.field
        table.provenance["shading"] = shading_record
    if c.multiscale:
        from l3cli.multiscale.fit import attach_multiscale

        attach_multiscale(table, s.pairs, seed=opts.seed, show_progress=show_progress)
    seconds = time.perf_counter() - s.t0
    record["seconds"] = round(seconds, 1)
    return TuneResult(s.results, best, opts, table, names, s.folds, seconds, record, chosen)


def replace_opts(base: TrainOptions, c: Candidate) -> TrainOptions:
    """``base`` with the candidate's target space, patch, levels, contrast bins and rule,
    augmentation, sample weights and shading."""
    return replace(base, target_space=c.target_space, patch=c.patch, levels=c.levels,
                   contrast_bins=c.contrast_bins, contrast_threshold=c.contrast_threshold,
                   tone_curve=base.tone_curve and c.target_space == TONE_CURVE_SPACE,
                   augment=c.augment, sample_weight=c.sample_weight, shading=c.shading)


def format_candidates(record: dict) -> str:
    """The candidate table of a tune record, sorted by score: the chosen candidate
    marked ``*``, the best ``b`` (where the rule chose a cheaper one)."""
    rows = sorted(record["candidates"], key=lambda r: r["cv_mean"])
    keys = ("target", "patch", "levels", "contrast_bins", "contrast_threshold", "augment",
            "sample_weight", "shading", "multiscale")

    def same(r, d):
        return d is not None and all(r.get(k, False) == d.get(k, False) for k in keys)

    out = [f"  {'':1} {'target':<12} {'patch':>5} {'levels':>6} {'bins':>4} {'threshold':>9} "
           f"{'augment':>7} {'weight':>9} {'shading':>7} {'multi':>5} {'cost':>4}  "
           f"{'CV S-CIELAB':>11} {'margin':>6}  per held-out unit"]
    for r in rows:
        mark = "*" if same(r, record["chosen"]) else "b" if same(r, record.get("best")) else ""
        units = " ".join(f"{v:.3f}" for v in r["cv_units"])
        thr = r.get("contrast_threshold")
        thr = "quantile" if thr is None else f"{thr:g}"
        if r["contrast_bins"] == 1:
            thr = "-"
        onoff = {True: "on", False: "off"}
        margin = f"{r['margin']:.4f}" if "margin" in r else "-"
        out.append(f"  {mark:1} {r['target']:<12} {r['patch']:>5} {r['levels']:>6} "
                   f"{r['contrast_bins']:>4} {thr:>9} {r.get('augment', 'none'):>7} "
                   f"{r.get('sample_weight', 'none'):>9} {onoff[r.get('shading', False)]:>7} "
                   f"{onoff[r.get('multiscale', False)]:>5} {r.get('cost_rank', '-'):>4}  "
                   f"{r['cv_mean']:>11.4f} {margin:>6}  {units}")
    if "rule" in record:
        out.append(f"  chosen (*) by the {record['rule']}")
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
