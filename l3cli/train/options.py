"""Training options: :class:`TrainOptions` and the defaults that depend on the inputs.

One home for what ``l3 train`` is asked to do (class layout, target space,
fit, white balance, tone curve, augmentation, sample weights); the defaults
themselves live in :mod:`l3cli.defaults`. Used by :mod:`l3cli.train.fit`
(which re-exports these names), the cross-validation and ``--tune``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from l3cli import defaults
from l3cli.buffers import available_memory  # re-exported
from l3cli.classify import check_patch
from l3cli.colourspace import check_space
from l3cli.errors import ConfigError
from l3cli.pairs import Pair
from l3cli.train.ridge import DEFAULT_LAMBDA_GRID

__all__ = ["pairs_kind", "layout_defaults", "default_target_space", "TrainOptions",
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

    Named after the option that multiplies the count most (``--levels`` unless
    another count is larger), so an absurd ``--levels 100000000`` fails at once,
    before any input is read, and ``--levels 100000`` with a clear message
    instead of "out of memory".

    Raises
    ------
    ConfigError
        The statistics need more than the available memory.
    """
    need = stats_bytes(n_classes, opts.patch)
    have = available_memory()
    if need <= have:
        return
    counts = {"--levels": opts.levels, "--contrast-bins": opts.contrast_bins,
              "--context-bins": opts.context_bins if opts.context_block else 0,
              "--orientation-bins": opts.orientation_bins, "--patch": opts.patch}
    name = max(counts, key=lambda k: counts[k])
    gib = 1 << 30
    raise ConfigError(f"{name} {counts[name]} is too large: {what + ' ' if what else ''}"
                      f"{n_classes:,} classes, whose training statistics need "
                      f"{need / gib:,.1f} GiB, more than the {have / gib:,.1f} GiB of memory "
                      f"available; use fewer {name}")


class TrainOptions:
    """Options of :func:`train` (keyword-only; see ``l3 train --help``)."""

    def __init__(self, *, patch: int = defaults.PATCH, levels: int = defaults.LEVELS,
                 spacing: str = defaults.LEVEL_SPACING,
                 contrast_bins: int = defaults.CONTRAST_BINS,
                 saturation: float = defaults.SATURATION,
                 level_range: tuple[float, float] | None = None,
                 contrast_threshold: float | None = None,
                 merge_positions: bool = defaults.MERGE_POSITIONS,
                 target_space: str = "xyz", sample_fraction: float = defaults.SAMPLE_FRACTION,
                 seed: int = defaults.SEED, min_samples_factor: float = defaults.MIN_SAMPLES_FACTOR,
                 lambda_grid: Sequence[float] = tuple(DEFAULT_LAMBDA_GRID),
                 white_balance: bool = False,
                 wb_override: Sequence[float] | None = None,
                 target_adapt: dict[str, list] | None = None,
                 by: str | None = None,
                 orientation_bins: int = defaults.ORIENTATION_BINS,
                 coherence: float = defaults.COHERENCE,
                 context_block: int = defaults.CONTEXT_BLOCK,
                 context_bins: int = defaults.CONTEXT_BINS,
                 context_rule: str = defaults.CONTEXT_RULE,
                 highlight_bins: int = defaults.HIGHLIGHT_BINS,
                 highlight_fraction: float = defaults.HIGHLIGHT_FRACTION,
                 tone_curve: bool = defaults.TONE_CURVE,
                 augment: str = defaults.AUGMENT,
                 sample_weight: str = defaults.SAMPLE_WEIGHT,
                 shading: bool = defaults.SHADING) -> None:
        from l3cli.train.augment import augment_elements
        from l3cli.train.weights import check_weight

        # comparisons written so that NaN fails them
        if levels < 2:
            raise ConfigError(f"--levels {levels} is not allowed; use 2 or more")
        if contrast_bins < 1:
            raise ConfigError(f"contrast bins {contrast_bins} is not allowed; use 1 or more")
        if not 0.0 < sample_fraction <= 1.0:
            raise ConfigError(f"--sample-fraction {sample_fraction} is not allowed; use (0, 1]")
        if not 0.0 < saturation <= 1.5:
            raise ConfigError(f"saturation threshold {saturation} is not allowed; use (0, 1.5]")
        if not 1.0 < min_samples_factor < np.inf:
            raise ConfigError(f"--min-samples {min_samples_factor} is not allowed; use a "
                              "finite number > 1")
        if level_range is not None:
            lo, hi = (float(v) for v in level_range)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 < lo < hi):
                raise ConfigError(f"--level-range {lo:g} {hi:g} is not allowed; use two finite "
                                  "numbers 0 < LOW < HIGH (normalised raw units)")
            level_range = (lo, hi)
        if orientation_bins < 0 or orientation_bins % 2 or orientation_bins > 16:
            raise ConfigError(f"--orientation-bins {orientation_bins} is not allowed; use 0 "
                              "(off) or an even number from 2 to 16")
        if not 0.0 <= coherence < 1.0:
            raise ConfigError(f"--coherence {coherence} is not allowed; use [0, 1)")
        if context_block < 0:
            raise ConfigError(f"--context-block {context_block} is not allowed; use 0 (off) "
                              "or a block size in pixels")
        if context_block and context_bins < 2:
            raise ConfigError(f"--context-bins {context_bins} is not allowed; use 2 or more")
        if highlight_bins not in (0, 2):
            raise ConfigError(f"--highlight-bins {highlight_bins} is not allowed; use 0 or 2")
        if not 0.0 < highlight_fraction <= 1.0:
            raise ConfigError(f"--highlight-fraction {highlight_fraction} is not allowed; "
                              "use (0, 1]")
        self.patch = check_patch(patch, "--patch")
        self.levels = int(levels)
        self.spacing = spacing
        self.contrast_bins = int(contrast_bins)
        self.saturation = float(saturation)
        self.level_range = level_range
        if contrast_threshold is not None and not float(contrast_threshold) > 0:
            raise ConfigError(f"contrast threshold {contrast_threshold} is not allowed; use > 0")
        self.contrast_threshold = (None if contrast_threshold is None
                                   else float(contrast_threshold))
        self.merge_positions = bool(merge_positions)
        self.target_space = check_space(target_space)
        self.sample_fraction = float(sample_fraction)
        self.seed = int(seed)
        self.min_samples_factor = float(min_samples_factor)
        self.lambda_grid = np.asarray(lambda_grid, dtype=np.float64)
        # White balance as an input (l3cli.whitebalance): normalise each raw by its
        # as-shot gains (or wb_override); target_adapt maps a capture's raw path to the
        # 3x3 adaptation taken out of its target (set by train() itself).
        self.white_balance = bool(white_balance)
        self.wb_override = None if wb_override is None else [float(v) for v in wb_override]
        self.target_adapt = target_adapt
        self.by = by  # condition bins: None or one of l3cli.conditions.CONDITIONS
        self.orientation_bins = int(orientation_bins)
        self.coherence = float(coherence)
        self.context_block = int(context_block)
        self.context_bins = int(context_bins)
        self.context_rule = context_rule
        self.highlight_bins = int(highlight_bins)
        self.highlight_fraction = float(highlight_fraction)
        if tone_curve and self.target_space != TONE_CURVE_SPACE:
            raise ConfigError(f"a learned tone curve needs the {TONE_CURVE_SPACE} target, not "
                              f"{self.target_space}; use --no-tone-curve")
        self.tone_curve = bool(tone_curve)
        self.tone_model = None  # the fitted l3cli.tonecurve.ToneCurve (set by train())
        augment_elements(augment)  # a known choice
        self.augment = augment
        self.sample_weight = check_weight(sample_weight)
        self.shading = bool(shading)  # learn a lens-shading gain field (l3cli.shading)
        self.shading_field = None  # the fitted l3cli.shading.GainField (set by train())
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
        d = dict(vars(self))
        d["lambda_grid"] = self.lambda_grid.tolist()
        if not self.orientation_bins:
            del d["orientation_bins"], d["coherence"]
        if not self.context_block:
            del d["context_block"], d["context_bins"], d["context_rule"]
        if not self.highlight_bins:
            del d["highlight_bins"], d["highlight_fraction"]
        del d["tone_model"], d["shading_field"]
        if not self.shading:
            del d["shading"]
        if not self.tone_curve:
            del d["tone_curve"]
        if self.augment == "none":
            del d["augment"]
        if self.sample_weight == "none":
            del d["sample_weight"]
        return d
