"""``l3 train`` as a library call: the training policy in one place.

:func:`train` (also ``l3cli.train(...)``) does what ``l3 train`` does; the
command only maps its flags onto it. Beyond the two passes of
:func:`l3cli.train.fit.train` it decides, from the inputs:

* **the defaults of the inputs' kind**: every option left None takes the
  class layout and target space of pairs folders or of simulate folders
  (:data:`l3cli.defaults.PAIRS_LAYOUT`, :data:`~l3cli.defaults.SIMULATION_LAYOUT`);
* **as-shot white balance**: on when every input is a pairs folder and every
  raw carries a white balance (or when ``white_balance`` gains are given);
* **self-tuning** (:mod:`l3cli.train.tune`): on by default for pairs
  folders; the options given are held fixed, the others searched; when the
  default search cannot score the inputs, the fixed defaults are trained,
  with a note (an explicit ``tune=True`` reports the problem instead);
* **the multi-scale stage** after the kernels (``multiscale=True`` without
  tuning; the search decides it otherwise).

The options are a frozen, validated :class:`TrainRequest`; a bad value
raises :class:`~l3cli.errors.OptionError` naming the parameter (the command
line says its flag instead). What is fitted is returned in the table, never
stored on the options.

Examples
--------
>>> TrainRequest(levels=1)
Traceback (most recent call last):
...
l3cli.errors.OptionError: levels 1 is not allowed; use 2 or more
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

from l3cli import defaults
from l3cli.errors import ConfigError, InputError, OptionError, TableError
from l3cli.pairs import Pair
from l3cli.train.options import (
    TONE_CURVE_SPACE,
    TrainOptions,
    layout_defaults,
    pairs_kind,
)

__all__ = ["TrainRequest", "Note", "resolve_options", "wants_tune", "train"]



def _choices() -> dict[str, tuple[str, ...]]:
    """The allowed values of the options with a choice (each from its one definition)."""
    from l3cli.classify.features import CONTEXT_RULES
    from l3cli.classify.levels import SPACINGS
    from l3cli.colourspace import SPACES
    from l3cli.conditions import CONDITIONS
    from l3cli.train.augment import AUGMENT_CHOICES
    from l3cli.train.weights import WEIGHT_CHOICES

    return {"spacing": SPACINGS, "target_space": SPACES, "by": CONDITIONS,
            "augment": AUGMENT_CHOICES, "sample_weight": WEIGHT_CHOICES,
            "context_rule": CONTEXT_RULES}


@dataclass(frozen=True, kw_only=True)
class TrainRequest:
    """What ``l3 train`` is asked to do, as the library's keywords (``l3 train --help``
    describes each; a flag ``--min-samples`` is the parameter ``min_samples_factor``,
    ``--target`` is ``target_space``).

    None means "the default of the inputs' kind" (pairs folders or simulate
    folders, module notes). ``contrast_threshold`` may be ``"quantile"``;
    ``white_balance`` is gains ``(r, g, b)`` for every training raw;
    ``tune_grid`` the values self-tuning searches
    (:class:`l3cli.train.tune.TuneGrid`; None: :data:`l3cli.defaults.TUNE_GRID`).
    """

    patch: int | None = None
    levels: int | None = None
    spacing: str = defaults.LEVEL_SPACING
    level_range: tuple[float, float] | None = None
    contrast_bins: int | None = None
    contrast_threshold: float | str | None = None
    saturation: float = defaults.SATURATION
    merge_positions: bool = defaults.MERGE_POSITIONS
    target_space: str | None = None
    tone_curve: bool | None = None
    shading: bool | None = None
    sample_fraction: float = defaults.SAMPLE_FRACTION
    min_samples_factor: float = defaults.MIN_SAMPLES_FACTOR
    scaled_renders: bool = False
    by: str | None = None
    embedded_preview: bool = False
    as_shot_wb: bool | None = None
    white_balance: tuple[float, float, float] | None = None
    tune: bool | None = None
    tune_grid: object = None
    orientation_bins: int = defaults.ORIENTATION_BINS
    coherence: float = defaults.COHERENCE
    context_block: int = defaults.CONTEXT_BLOCK
    context_bins: int = defaults.CONTEXT_BINS
    context_rule: str = defaults.CONTEXT_RULE
    highlight_bins: int = defaults.HIGHLIGHT_BINS
    highlight_fraction: float = defaults.HIGHLIGHT_FRACTION
    augment: str | None = None
    sample_weight: str | None = None
    multiscale: bool | None = None
    seed: int = defaults.SEED

    def __post_init__(self) -> None:
        for name, allowed in _choices().items():
            v = getattr(self, name)
            if v is not None and v not in allowed:
                raise OptionError(name, f"{v!r} is not allowed; choose from "
                                  f"{', '.join(allowed)}")
        t = self.contrast_threshold
        if t is not None and t != "quantile":
            try:
                ok = 0 < float(t) < float("inf")
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise OptionError("contrast_threshold", f"{t!r} is not allowed; use a finite "
                                  "number > 0 or 'quantile'")
        if self.white_balance is not None:
            from l3cli.io.metadata import check_gains

            try:
                gains = check_gains(self.white_balance, "{name}")
            except (InputError, ConfigError) as exc:  # InputError: as a file's value
                raise OptionError("white_balance", str(exc)) from None
            if self.as_shot_wb is False:
                raise OptionError("white_balance", "{name} needs white-balanced training "
                                  "(as-shot white balance on)")
            object.__setattr__(self, "white_balance", tuple(float(v) for v in gains))
        if self.tune_grid is not None:
            from l3cli.train.tune import TuneGrid

            if not isinstance(self.tune_grid, TuneGrid):
                raise OptionError("tune_grid", "{name} must be an l3cli.train.tune.TuneGrid")
        # everything TrainOptions checks, on the values given (the inputs' defaults are valid)
        given = {f.name: getattr(self, f.name) for f in dataclasses.fields(TrainOptions)
                 if hasattr(self, f.name) and getattr(self, f.name) is not None}
        given.pop("white_balance", None)  # here: gains; there: as-shot normalisation on/off
        if given.get("contrast_threshold") == "quantile":
            given["contrast_threshold"] = None
        if given.get("tone_curve") and "target_space" not in given:
            given["target_space"] = TONE_CURVE_SPACE
        TrainOptions(**given)

    @classmethod
    def of(cls, options: dict) -> TrainRequest:
        """From keywords; an unknown keyword is an :class:`OptionError` naming it."""
        known = {f.name for f in dataclasses.fields(cls)}
        for name in options:
            if name not in known:
                raise OptionError(name, "{name} is not an option of l3cli.train (see "
                                  "l3cli.train.api.TrainRequest)")
        return cls(**options)


@dataclass(frozen=True)
class Note:
    """A note for the user (training goes on): ``{name}`` is where a parameter's name
    goes (``parameter``; the command line puts its flag there)."""

    template: str
    parameter: str | None = None

    def named(self, name: str | None = None) -> str:
        return self.template.replace("{name}", name or self.parameter or "")

    def __str__(self) -> str:
        return self.named()


def resolve_options(request: TrainRequest, pairs: Sequence[Pair]) -> TrainOptions:
    """The training options of ``request`` for these pairs: the inputs' defaults for what
    it leaves None, and the as-shot white balance (module notes)."""
    r = request
    layout = layout_defaults(pairs)
    target_space = r.target_space or layout["target_space"]
    tone_curve = r.tone_curve
    if tone_curve is None:  # the layout's, where its target space is used
        tone_curve = layout["tone_curve"] and target_space == TONE_CURVE_SPACE
    threshold = r.contrast_threshold
    if threshold is None:
        threshold = layout["contrast_threshold"]
    elif threshold == "quantile":
        threshold = None
    as_shot = r.as_shot_wb
    if r.white_balance is not None:
        as_shot = True
    if as_shot is None:  # real cameras: on when every raw says its white balance
        from l3cli.whitebalance.model import file_gains

        as_shot = all(p.align for p in pairs) and all(file_gains(p.raw) is not None
                                                      for p in pairs)
    return TrainOptions(
        patch=layout["patch"] if r.patch is None else r.patch,
        levels=layout["levels"] if r.levels is None else r.levels, spacing=r.spacing,
        level_range=r.level_range,
        contrast_bins=layout["contrast_bins"] if r.contrast_bins is None else r.contrast_bins,
        contrast_threshold=threshold, saturation=r.saturation,
        merge_positions=r.merge_positions, target_space=target_space,
        sample_fraction=r.sample_fraction, seed=r.seed,
        min_samples_factor=r.min_samples_factor, white_balance=as_shot,
        wb_override=r.white_balance, by=r.by, orientation_bins=r.orientation_bins,
        coherence=r.coherence, context_block=r.context_block, context_bins=r.context_bins,
        context_rule=r.context_rule, highlight_bins=r.highlight_bins,
        highlight_fraction=r.highlight_fraction, tone_curve=tone_curve,
        augment=r.augment or layout["augment"],
        sample_weight=r.sample_weight or layout["sample_weight"],
        shading=layout["shading"] if r.shading is None else r.shading)


def wants_tune(request: TrainRequest, pairs: Sequence[Pair], opts: TrainOptions
               ) -> tuple[bool, Note | None]:
    """Whether to self-tune: ``request.tune``, else the default of the inputs' kind
    (:data:`l3cli.defaults.TUNE_PAIRS`); a defaulted search gives way, with a note, to
    what it cannot do (``by``, a target space it cannot score)."""
    from l3cli.train.cv import CV_SPACES

    if request.tune is not None:
        return request.tune, None
    if not (defaults.TUNE_PAIRS if pairs_kind(pairs) == "pairs" else defaults.TUNE_SIMULATE):
        return False, None
    if opts.by:
        why = Note("{name} " + opts.by, "by")
    elif opts.target_space not in CV_SPACES:
        why = Note("{name} " + opts.target_space, "target_space")
    else:
        return True, None
    return False, Note(why.template + ": training the fixed defaults (the self-tuning of "
                       "pairs folders runs without it; docs/training.md)", why.parameter)


@contextlib.contextmanager
def _found_pairs(inputs, request: TrainRequest, scratch) -> Iterator[list[Pair]]:
    """The pairs of ``inputs`` (embedded previews extracted into a temporary folder in
    ``scratch``, removed at the end)."""
    if isinstance(inputs, str | os.PathLike):
        inputs = [inputs]
    inputs = [os.fspath(p) for p in inputs]
    if not request.embedded_preview:
        from l3cli.pairs import find_pairs

        yield find_pairs(inputs, scaled_renders=request.scaled_renders)
        return
    import tempfile

    from l3cli.preview import preview_pairs

    if scratch is not None and not os.path.isdir(scratch):
        scratch = None
    with tempfile.TemporaryDirectory(prefix=".l3-tmp-previews-", dir=scratch) as work:
        yield preview_pairs(inputs, work)


def train(inputs: str | os.PathLike | Sequence[str | os.PathLike], *,
          workers: int | None = None, scheduler: str | None = None,
          show_progress: bool | None = False,
          report: Callable | None = None, note: Callable[[Note], None] | None = None,
          scratch: str | os.PathLike | None = None, **options):
    """Train a table from simulate folders, pairs folders or raw files: ``l3 train``.

    Parameters
    ----------
    inputs
        A folder or file, or several (``l3 train INPUT...``).
    workers, scheduler
        Run on a local dask cluster of this many worker processes, or on the running
        scheduler at this address (``--workers``, ``--scheduler``); the table is the
        same bit for bit.
    show_progress
        Progress bars on stderr.
    report
        Called after each self-tuning candidate with (number, candidate, CV score,
        seconds so far).
    note
        Called with each :class:`Note` (default: logged as a warning).
    scratch
        Folder for temporary files (embedded previews); default: the system's.
    **options
        :class:`TrainRequest`'s fields, e.g. ``seed=1``, ``tune=False``, ``patch=7``.

    Returns
    -------
    l3cli.model.Table
        The table (a :class:`~l3cli.table.TransformTable` that renders:
        ``.render(raw)``), its tuning record in ``.tuning`` (None without tuning).

    Raises
    ------
    OptionError
        A bad option (naming it).
    InputError, TableError, l3cli.parallel.ParallelError
        Bad inputs, not enough data, a cluster that fails.
    """
    import logging

    from l3cli.model import Table

    request = TrainRequest.of(options)
    if note is None:
        def note(n: Note) -> None:
            logging.getLogger(__name__).warning("%s", n)
    with _found_pairs(inputs, request, scratch) as pairs:
        return Table.of(_train_pairs(pairs, request, workers=workers, scheduler=scheduler,
                                     show_progress=show_progress, report=report, note=note))


def _train_pairs(pairs: list[Pair], request: TrainRequest, *, workers, scheduler,
                 show_progress, report, note):
    from l3cli.parallel import dask_client
    from l3cli.train.fit import train as fit_table

    opts = resolve_options(request, pairs)
    tune, why = wants_tune(request, pairs, opts)
    if why is not None:
        note(why)
    table = None
    with dask_client(workers, scheduler) as client:  # None: in process
        if tune:
            from l3cli.train.tune import TuneGrid
            from l3cli.train.tune import tune as run_tune

            grid = request.tune_grid or TuneGrid()
            values = {**dataclasses.asdict(opts), "multiscale": request.multiscale}
            given = {k for k in TuneGrid.OPTIONS if getattr(request, k) is not None}
            if request.tone_curve:  # the curve is the space of its candidates: held too
                given.add("target_space")
            grid = grid.fixed(**{k: values[k] for k in given})
            try:
                table = run_tune(pairs, opts, grid, show_progress=show_progress,
                                 report=report, client=client).table
            except (InputError, TableError) as exc:
                if request.tune:  # asked for: its error is the user's answer
                    raise
                # the default search cannot score these inputs (e.g. too little data for
                # its folds): the fixed defaults, which need less, with a note
                tune = False
                note(Note(f"self-tuning skipped ({exc}); training the fixed defaults"))
        if table is None:
            table = fit_table(pairs, opts, client=client, show_progress=show_progress)
    if request.multiscale and not tune:  # the learned stage after the kernels
        from l3cli.multiscale.fit import attach_multiscale

        attach_multiscale(table, pairs, seed=opts.seed, show_progress=show_progress)
    record = table.provenance.get("shading") or {}
    if request.shading and getattr(table, "shading", None) is None and not record.get(
            "unusable"):  # asked for and not kept (an unusable fit has had its warning)
        why = record.get("reason") or "not learned"
        note(Note(f"{{name}}: no lens-shading field kept ({why}); the table has none",
                  "shading"))
    return table
