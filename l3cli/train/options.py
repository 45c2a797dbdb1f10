"""Training options: :class:`TrainOptions` and the defaults that depend on the inputs.

One home for what ``l3 train`` is asked to do (class layout, target space,
fit, white balance, tone curve, augmentation, sample weights); the defaults
themselves live in :mod:`l3cli.defaults`. Used by :mod:`l3cli.train.fit`
(which re-exports these names), the cross-validation and ``--tune``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from l3cli import defaults
from l3cli.buffers import available_memory  # re-exported
from l3cli.classify import check_patch
from l3cli.colourspace import check_space
from l3cli.errors import ConfigError, OptionError
from l3cli.pairs import Pair
from l3cli.train.ridge import DEFAULT_LAMBDA_GRID

__all__ = ["pairs_kind", "layout_defaults", "default_target_space", "TrainOptions", "Fitted",
           "TONE_CURVE_SPACE", "NO_CURVE", "check_class_budget", "stats_bytes"]

#: The target space a learned tone curve works with (its encoding is display sRGB).
TONE_CURVE_SPACE = "linear-srgb"
#: The warning when the renders cannot teach a tone curve.
NO_CURVE = ("too few flat, unclipped areas in the training renders to learn their tone "
            "curve; training without one (as --no-tone-curve)")

def pairs_kind(pairs: Sequence[Pair]) -> str:
    """``"pairs"`` when every input is a rendered pair (a real camera), else ``"simulation"``."""
    pairs = list(pairs)
    return "pairs" if pairs and all(p.align for p in pairs) else "simulation"


def layout_defaults(pairs: Sequence[Pair]) -> dict:
    """The default class layout and target space for these inputs.

    :data:`l3cli.defaults.PAIRS_LAYOUT` when every input is a pairs folder,
    else :data:`l3cli.defaults.SIMULATION_LAYOUT` (keys ``patch``, ``levels``,
    ``contrast_bins``, ``contrast_threshold``, ``target_space``).
    """
    kind = pairs_kind(pairs)
    return dict(defaults.PAIRS_LAYOUT if kind == "pairs" else defaults.SIMULATION_LAYOUT)


def default_target_space(pairs: Sequence[Pair]) -> str:
    """The default target space for these inputs (:func:`layout_defaults`)."""
    return layout_defaults(pairs)["target_space"]


#: Bytes of training statistics per class beyond its q x q Gram matrix (in units
#: of q: the q x n_out cross products and the sums; :class:`l3cli.train.stats.ClassStats`).
_STATS_BYTES_PER_Q = 8 * (3 + 2)


def stats_bytes(n_classes: int, patch: int) -> int:
    """Bytes of the training statistics of ``n_classes`` classes of ``patch`` x ``patch``
    kernels (float64 Gram matrix, cross products, sums and counts of each class)."""
    q = patch * patch + 1
    return int(n_classes) * (8 * q * q + _STATS_BYTES_PER_Q * q)


def check_class_budget(opts: TrainOptions, n_classes: int, *, what: str = "") -> None:
    """Refuse a class layout whose training statistics cannot fit in memory.

    Named after the option that multiplies the count most (``levels`` unless
    another count is larger), so an absurd ``levels=100000000`` fails at once,
    before any input is read, and ``levels=100000`` with a clear message
    instead of "out of memory".

    Raises
    ------
    OptionError
        The statistics need more than the available memory (naming the parameter).
    """
    need = stats_bytes(n_classes, opts.patch)
    have = available_memory()
    if need <= have:
        return
    counts = {"levels": opts.levels, "contrast_bins": opts.contrast_bins,
              "context_bins": opts.context_bins if opts.context_block else 0,
              "orientation_bins": opts.orientation_bins, "patch": opts.patch}
    name = max(counts, key=lambda k: counts[k])
    gib = 1 << 30
    raise OptionError(name, f"{{name}} {counts[name]} is too large: "
                      f"{what + ' ' if what else ''}{n_classes:,} classes, whose training "
                      f"statistics need {need / gib:,.1f} GiB, more than the "
                      f"{have / gib:,.1f} GiB of memory available; use fewer {{name}}")


@dataclass(frozen=True, kw_only=True, eq=False)
class TrainOptions:
    """What :func:`train` is asked to do: a frozen, validated value (see ``l3 train --help``).

    Every field is an option; nothing fitted is stored here (the fitted lens-shading
    field, tone curve and white adaptation travel as :class:`Fitted`). A value out of
    range raises :class:`~l3cli.errors.OptionError` naming the parameter (``l3 train``
    names the flag instead). :func:`dataclasses.replace` makes a changed copy.
    """

    patch: int = defaults.PATCH
    levels: int = defaults.LEVELS
    spacing: str = defaults.LEVEL_SPACING
    contrast_bins: int = defaults.CONTRAST_BINS
    saturation: float = defaults.SATURATION
    level_range: tuple[float, float] | None = None
    contrast_threshold: float | None = None
    merge_positions: bool = defaults.MERGE_POSITIONS
    target_space: str = "xyz"
    sample_fraction: float = defaults.SAMPLE_FRACTION
    seed: int = defaults.SEED
    min_samples_factor: float = defaults.MIN_SAMPLES_FACTOR
    lambda_grid: Sequence[float] = tuple(float(v) for v in DEFAULT_LAMBDA_GRID)
    #: White balance as an input (l3cli.whitebalance.model): normalise each raw by its as-shot
    #: gains, or by ``wb_override`` for every raw.
    white_balance: bool = False
    wb_override: Sequence[float] | None = None
    by: str | None = None  # condition bins: None or one of l3cli.conditions.CONDITIONS
    orientation_bins: int = defaults.ORIENTATION_BINS
    coherence: float = defaults.COHERENCE
    context_block: int = defaults.CONTEXT_BLOCK
    context_bins: int = defaults.CONTEXT_BINS
    context_rule: str = defaults.CONTEXT_RULE
    highlight_bins: int = defaults.HIGHLIGHT_BINS
    highlight_fraction: float = defaults.HIGHLIGHT_FRACTION
    tone_curve: bool = defaults.TONE_CURVE
    augment: str = defaults.AUGMENT
    sample_weight: str = defaults.SAMPLE_WEIGHT
    shading: bool = defaults.SHADING  # learn a lens-shading gain field (l3cli.lens.field)

    def __post_init__(self) -> None:
        from l3cli.train.augment import augment_elements
        from l3cli.train.weights import check_weight

        set_ = functools.partial(object.__setattr__, self)
        # comparisons written so that NaN fails them
        if not self.levels >= 2:
            raise OptionError("levels", f"{self.levels} is not allowed; use 2 or more")
        if not self.contrast_bins >= 1:
            raise OptionError("contrast_bins", f"{self.contrast_bins} is not allowed; use 1 "
                              "or more")
        if not 0.0 < self.sample_fraction <= 1.0:
            raise OptionError("sample_fraction", f"{self.sample_fraction} is not allowed; "
                              "use (0, 1]")
        if not 0.0 < self.saturation <= 1.5:
            raise OptionError("saturation", f"{self.saturation} is not allowed; use (0, 1.5]")
        if not 1.0 < self.min_samples_factor < np.inf:
            raise OptionError("min_samples_factor", f"{self.min_samples_factor} is not "
                              "allowed; use a finite number > 1")
        if self.level_range is not None:
            lo, hi = (float(v) for v in self.level_range)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 < lo < hi):
                raise OptionError("level_range", f"{lo:g} {hi:g} is not allowed; use two "
                                  "finite numbers 0 < LOW < HIGH (normalised raw units)")
            set_("level_range", (lo, hi))
        if (self.orientation_bins < 0 or self.orientation_bins % 2
                or self.orientation_bins > 16):
            raise OptionError("orientation_bins", f"{self.orientation_bins} is not allowed; "
                              "use 0 (off) or an even number from 2 to 16")
        if not 0.0 <= self.coherence < 1.0:
            raise OptionError("coherence", f"{self.coherence} is not allowed; use [0, 1)")
        if self.context_block < 0:
            raise OptionError("context_block", f"{self.context_block} is not allowed; use 0 "
                              "(off) or a block size in pixels")
        if self.context_block and self.context_bins < 2:
            raise OptionError("context_bins", f"{self.context_bins} is not allowed; use 2 or "
                              "more")
        if self.highlight_bins not in (0, 2):
            raise OptionError("highlight_bins", f"{self.highlight_bins} is not allowed; use 0 "
                              "or 2")
        if not 0.0 < self.highlight_fraction <= 1.0:
            raise OptionError("highlight_fraction", f"{self.highlight_fraction} is not "
                              "allowed; use (0, 1]")
        if self.spacing not in ("log", "linear"):
            raise OptionError("spacing", f"{self.spacing!r} is not allowed; use log or linear")
        try:
            set_("patch", check_patch(self.patch, "patch"))
        except ConfigError as exc:
            raise OptionError("patch", str(exc).removeprefix("patch ")) from None
        set_("levels", int(self.levels))
        set_("contrast_bins", int(self.contrast_bins))
        set_("saturation", float(self.saturation))
        if self.contrast_threshold is not None:
            if not float(self.contrast_threshold) > 0:
                raise OptionError("contrast_threshold", f"{self.contrast_threshold} is not "
                                  "allowed; use > 0")
            set_("contrast_threshold", float(self.contrast_threshold))
        set_("merge_positions", bool(self.merge_positions))
        set_("target_space", check_space(self.target_space))
        set_("sample_fraction", float(self.sample_fraction))
        set_("seed", int(self.seed))
        set_("min_samples_factor", float(self.min_samples_factor))
        set_("lambda_grid", tuple(float(v) for v in self.lambda_grid))
        set_("white_balance", bool(self.white_balance))
        if self.wb_override is not None:
            set_("wb_override", tuple(float(v) for v in self.wb_override))
        for name in ("orientation_bins", "context_block", "context_bins", "highlight_bins"):
            set_(name, int(getattr(self, name)))
        for name in ("coherence", "highlight_fraction"):
            set_(name, float(getattr(self, name)))
        if self.tone_curve and self.target_space != TONE_CURVE_SPACE:
            raise OptionError("tone_curve", f"needs the {TONE_CURVE_SPACE} target, not "
                              f"{self.target_space}; turn it off")
        set_("tone_curve", bool(self.tone_curve))
        augment_elements(self.augment)  # a known choice
        set_("sample_weight", check_weight(self.sample_weight))
        set_("shading", bool(self.shading))
        # the smallest class layout these options can make (one CFA position group,
        # one channel): refused now if even its statistics cannot fit in memory
        check_class_budget(self, self.min_classes(), what="at least")

    def min_classes(self) -> int:
        """The fewest classes these options make (one position group, one channel)."""
        n = 2 * self.levels * self.contrast_bins
        n *= self.orientation_bins + 1 if self.orientation_bins else 1
        n *= self.context_bins if self.context_block else 1
        return n * (self.highlight_bins or 1)

    def as_dict(self) -> dict:
        """The options as a JSON-serialisable dict (recorded in the table's provenance).

        The feature options appear only when a feature is on, so the
        provenance of a table without them is as before.
        """
        d = {}
        for f in dataclasses.fields(self):
            d[f.name] = getattr(self, f.name)
            if f.name == "wb_override":  # where tables before 0.2 recorded it (always null:
                d["target_adapt"] = None  # the adaptation is fitted, Fitted.target_adapt)
        d["lambda_grid"] = list(self.lambda_grid)
        d["level_range"] = None if self.level_range is None else list(self.level_range)
        d["wb_override"] = None if self.wb_override is None else list(self.wb_override)
        if not self.orientation_bins:
            del d["orientation_bins"], d["coherence"]
        if not self.context_block:
            del d["context_block"], d["context_bins"], d["context_rule"]
        if not self.highlight_bins:
            del d["highlight_bins"], d["highlight_fraction"]
        if not self.shading:
            del d["shading"]
        if not self.tone_curve:
            del d["tone_curve"]
        if self.augment == "none":
            del d["augment"]
        if self.sample_weight == "none":
            del d["sample_weight"]
        return d


@dataclass(frozen=True)
class Fitted:
    """What training fits from the pairs before the statistics (returned, never stored
    on the options), as every later pass needs it.

    Attributes
    ----------
    shading_field
        The lens-shading gain field (:class:`l3cli.lens.field.GainField`), applied to every
        training mosaic (:func:`l3cli.whitebalance.model.training_mosaic`); None: none.
    tone_model
        The renders' tone curve (:class:`l3cli.tone.curve.ToneCurve`): the statistics are
        accumulated in its linear space; None: none.
    target_adapt
        Per capture (its raw's absolute path), the 3x3 white adaptation taken out of its
        target (:func:`l3cli.whitebalance.model.training_target`); None: none.
    """

    shading_field: object = None
    tone_model: object = None
    target_adapt: dict | None = None


#: Nothing fitted.
NOTHING = Fitted()
