"""The class definition of a table: what decides every pixel's class.

:class:`ClassDefinition` holds the CFA, the patch size, the level and
contrast cut points, the saturation threshold and the position groups, and
validates them on construction; the rule itself is documented in
:mod:`l3cli.classify`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from l3cli import defaults
from l3cli.cfa import CFA
from l3cli.classify.features import CONTEXT_RULES, ORIENTATION_RULE
from l3cli.classify.levels import SPACINGS
from l3cli.classify.padding import mirror_indices
from l3cli.errors import ConfigError

__all__ = ["CONTRAST_RULE", "SATURATION_RULE", "DEFAULT_CONTRAST_EPS", "ClassDefinition",
           "check_patch", "describe_difference", "position_groups"]

#: Name of the contrast rule implemented here (stored in tables).
CONTRAST_RULE = "relative-std-v1"
#: Name of the saturation rule implemented here (stored in tables).
SATURATION_RULE = "any-pixel-per-channel-v1"
#: ``eps`` in the contrast denominator (normalised raw units).
DEFAULT_CONTRAST_EPS = 1e-4
#: The largest finite float32: thresholds beyond it become infinite in the kernels.
_F32_MAX = float(np.finfo(np.float32).max)


def check_patch(patch: int, name: str = "patch size") -> int:
    """``patch`` if it is an allowed patch size (odd, >= 1); else raise :class:`ConfigError`.

    Examples
    --------
    >>> check_patch(5)
    5
    >>> check_patch(4, "--patch")
    Traceback (most recent call last):
    ...
    l3cli.errors.ConfigError: --patch 4 is not allowed; use an odd size >= 1
    """
    if patch < 1 or patch % 2 == 0:
        raise ConfigError(f"{name} {patch} is not allowed; use an odd size >= 1")
    return int(patch)


@dataclass(frozen=True, eq=False)
class ClassDefinition:
    """Everything that defines the classes of a table.

    Parameters
    ----------
    cfa
        The CFA the table is for (phase relative to the image origin).
    patch
        Odd patch size (5 gives 5x5 patches).
    level_cuts
        float64 (n_levels - 1,), increasing cut points of the response level.
    level_spacing
        ``"log"`` or ``"linear"`` (how the cuts were made; informative).
    contrast_cuts
        float64 (n_levels, n_contrast - 1): per level, increasing thresholds of
        the relative contrast.
    saturation_threshold
        A pixel at or above this normalised value is saturated.
    position_group
        int64 (n_positions,): group index of each CFA position.
    contrast_eps
        ``eps`` of the contrast rule.
    orientation_bins
        Edge-angle bins N (even; 0 = no orientation dimension); the
        orientation axis has N + 1 entries, 0 = isotropic
        (:mod:`l3cli.classify.features`).
    coherence_threshold
        A patch whose structure-tensor coherence is at most this is isotropic.
    context_block
        Block size (pixels) of the context guide; 0 = no context dimension.
    context_cuts
        float64 (n_context - 1,): increasing cut points of the context feature.
    context_rule
        ``"mean"`` (the guide) or ``"ratio"`` (patch level / guide).
    highlight_bins
        0 (off) or 2: bin 1 when at least ``highlight_fraction`` of the
        patch's pixels are saturated (how much clips, beside which channels).
    highlight_fraction
        The fraction that separates the two highlight bins.

    The last class axis, *texture*, combines contrast, orientation and
    context: ``texture = (contrast * n_orientation + orientation) * n_context
    + context) * n_highlight + highlight`` (just the contrast bin when the extra
    features are off).

    Examples
    --------
    >>> d = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.01, 0.1], contrast_cuts=0.2)
    >>> d.shape  # position groups, saturation patterns, levels, contrast bins
    (4, 8, 3, 2)
    >>> d.n_classes, d.n_coeffs
    (192, 26)
    >>> int(d.class_index(1, 0, 2, 1))  # ((1 * 8 + 0) * 3 + 2) * 2 + 1
    53
    """

    cfa: CFA
    patch: int
    level_cuts: np.ndarray
    level_spacing: str
    contrast_cuts: np.ndarray
    saturation_threshold: float
    position_group: np.ndarray
    contrast_eps: float = DEFAULT_CONTRAST_EPS
    contrast_rule: str = CONTRAST_RULE
    saturation_rule: str = SATURATION_RULE
    orientation_bins: int = 0
    coherence_threshold: float = 0.0
    orientation_rule: str = ORIENTATION_RULE
    context_block: int = 0
    context_cuts: np.ndarray = field(default_factory=lambda: np.zeros(0))
    context_rule: str = "mean"
    highlight_bins: int = 0
    highlight_fraction: float = 0.0
    # not an init field: dataclasses.replace gives the copy its own (a copy that kept
    # these, built for another patch or CFA, sent the kernel out of its arrays)
    _tables: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        check_patch(self.patch)
        cuts = np.asarray(self.level_cuts, dtype=np.float64)
        if cuts.ndim != 1 or cuts.size < 1 or np.any(np.diff(cuts) <= 0) or not np.all(np.isfinite(cuts)):
            raise ConfigError("level cut points must be a finite increasing 1-D list")
        if cuts[0] <= 0:
            raise ConfigError(f"level cut points must be > 0 (normalised raw units), got {cuts[0]}")
        cc = np.asarray(self.contrast_cuts, dtype=np.float64)
        if cc.ndim != 2 or cc.shape[0] != cuts.size + 1:
            raise ConfigError(
                f"contrast cut points must have shape (n_levels, n_contrast - 1) = "
                f"({cuts.size + 1}, k), got {cc.shape}"
            )
        if cc.shape[1] and (np.any(np.diff(cc, axis=1) < 0) or not np.all(np.isfinite(cc))
                            or np.any(cc < 0)):
            raise ConfigError("contrast cut points must be finite, >= 0 and increasing per level")
        # the kernels compare in float32: every threshold must stay finite there
        if np.any(np.abs(cuts) > _F32_MAX) or np.any(np.abs(cc) > _F32_MAX):
            raise ConfigError("level or contrast cut points are beyond float32 range")
        eps = float(self.contrast_eps)
        if not 0.0 < eps <= 1.0:
            raise ConfigError(f"contrast eps {self.contrast_eps} must be in (0, 1] (normalised "
                              "raw units)")
        grp = np.asarray(self.position_group, dtype=np.int64)
        if grp.shape != (self.cfa.n_positions,) or grp.min() != 0 or \
                grp.max() >= self.cfa.n_positions or \
                set(grp.tolist()) != set(range(int(grp.max()) + 1)):
            raise ConfigError(
                f"position groups must number the {self.cfa.n_positions} CFA positions 0..G-1"
            )
        # every position of a group must have the same patch layout
        for g in range(int(grp.max()) + 1):
            members = np.flatnonzero(grp == g)
            lay = [self.cfa.neighbourhood(int(p), self.patch).tobytes() for p in members]
            if len(set(lay)) > 1:
                raise ConfigError(
                    f"positions {members.tolist()} have different {self.patch}x{self.patch} "
                    "layouts and cannot share classes"
                )
        if self.level_spacing not in SPACINGS:
            raise ConfigError(f"level spacing {self.level_spacing!r} is not known")
        if not 0 < self.saturation_threshold <= _F32_MAX:
            raise ConfigError(f"saturation threshold {self.saturation_threshold} must be a "
                              "finite number > 0")
        if self.contrast_rule != CONTRAST_RULE:
            raise ConfigError(f"contrast rule {self.contrast_rule!r} is not known; "
                              f"this l3 implements {CONTRAST_RULE!r}")
        if self.saturation_rule != SATURATION_RULE:
            raise ConfigError(f"saturation rule {self.saturation_rule!r} is not known; "
                              f"this l3 implements {SATURATION_RULE!r}")
        nb = int(self.orientation_bins)
        if nb < 0 or nb % 2 or nb > 16:
            raise ConfigError(f"orientation bins {nb} is not allowed; use 0 (off) or an even "
                              "number from 2 to 16")
        if nb and self.patch <= max(self.cfa.period):
            raise ConfigError(f"orientation bins need a patch larger than the CFA period; "
                              f"patch {self.patch} is too small")
        if nb and not 0.0 <= self.coherence_threshold < 1.0:
            raise ConfigError(f"coherence threshold {self.coherence_threshold} must be in [0, 1)")
        if self.orientation_rule != ORIENTATION_RULE:
            raise ConfigError(f"orientation rule {self.orientation_rule!r} is not known; "
                              f"this l3 implements {ORIENTATION_RULE!r}")
        xc = np.asarray(self.context_cuts, dtype=np.float64).reshape(-1)
        blk = int(self.context_block)
        ph, pw = self.cfa.period
        if blk < 0 or (blk and (blk % ph or blk % pw or blk < 2 * max(ph, pw))):
            raise ConfigError(f"context block {blk} is not allowed; use 0 (off) or a multiple "
                              f"of the CFA period {pw}x{ph}")
        if blk and (xc.size < 1 or np.any(np.diff(xc) <= 0) or not np.all(np.isfinite(xc))
                    or xc[0] <= 0 or xc[-1] > _F32_MAX):
            raise ConfigError("context cut points must be a finite, positive, increasing list")
        if not blk and xc.size:
            raise ConfigError("context cut points given without a context block size")
        if self.context_rule not in CONTEXT_RULES:
            raise ConfigError(f"context rule {self.context_rule!r} is not known; use one of "
                              f"{', '.join(CONTEXT_RULES)}")
        if self.highlight_bins not in (0, 2):
            raise ConfigError(f"highlight bins {self.highlight_bins} is not allowed; use 0 or 2")
        if self.highlight_bins and not 0.0 < self.highlight_fraction <= 1.0:
            raise ConfigError(f"highlight fraction {self.highlight_fraction} must be in (0, 1]")
        object.__setattr__(self, "contrast_eps", eps)
        object.__setattr__(self, "highlight_bins", int(self.highlight_bins))
        object.__setattr__(self, "highlight_fraction", float(self.highlight_fraction))
        object.__setattr__(self, "orientation_bins", nb)
        object.__setattr__(self, "coherence_threshold", float(self.coherence_threshold))
        object.__setattr__(self, "context_block", blk)
        object.__setattr__(self, "context_cuts", xc)
        object.__setattr__(self, "level_cuts", cuts)
        object.__setattr__(self, "contrast_cuts", cc)
        object.__setattr__(self, "position_group", grp)

    # ----------------------------------------------------------------- layout
    @classmethod
    def build(
        cls,
        cfa: CFA | str,
        *,
        patch: int = defaults.PATCH,
        level_cuts: np.ndarray,
        level_spacing: str = "log",
        contrast_cuts: np.ndarray | float | None = None,
        saturation_threshold: float = defaults.SATURATION,
        merge_positions: bool = defaults.MERGE_POSITIONS,
        contrast_eps: float = DEFAULT_CONTRAST_EPS,
        orientation_bins: int = 0,
        coherence_threshold: float = defaults.COHERENCE,
        context_block: int = 0,
        context_cuts: np.ndarray | None = None,
        context_rule: str = "mean",
        highlight_bins: int = 0,
        highlight_fraction: float = defaults.HIGHLIGHT_FRACTION,
    ) -> ClassDefinition:
        """Build a definition; ``contrast_cuts`` may be one threshold for all levels.

        ``contrast_cuts=None`` gives a single contrast bin.
        """
        cfa = CFA.from_spec(cfa)
        level_cuts = np.asarray(level_cuts, dtype=np.float64)
        n_levels = level_cuts.size + 1
        if contrast_cuts is None:
            cc = np.zeros((n_levels, 0))
        else:
            cc = np.asarray(contrast_cuts, dtype=np.float64)
            if cc.ndim == 0:
                cc = np.full((n_levels, 1), float(cc))
            elif cc.ndim == 1:
                cc = np.broadcast_to(cc, (n_levels, cc.size)).copy()
        return cls(
            cfa=cfa,
            patch=int(patch),
            level_cuts=level_cuts,
            level_spacing=level_spacing,
            contrast_cuts=cc,
            saturation_threshold=float(saturation_threshold),
            position_group=position_groups(cfa, patch, merge=merge_positions),
            contrast_eps=float(contrast_eps),
            orientation_bins=int(orientation_bins),
            coherence_threshold=float(coherence_threshold) if orientation_bins else 0.0,
            context_block=int(context_block),
            context_cuts=np.zeros(0) if context_cuts is None else np.asarray(context_cuts),
            context_rule=context_rule,
            highlight_bins=int(highlight_bins),
            highlight_fraction=float(highlight_fraction) if highlight_bins else 0.0,
        )

    @property
    def n_levels(self) -> int:
        """Number of response-level bins (cut points + 1)."""
        return int(self.level_cuts.size + 1)

    @property
    def n_contrast(self) -> int:
        """Number of contrast bins per level."""
        return int(self.contrast_cuts.shape[1] + 1)

    @property
    def n_orientation(self) -> int:
        """Entries of the orientation axis (1 when off; else isotropic + angle bins)."""
        return self.orientation_bins + 1 if self.orientation_bins else 1

    @property
    def n_context(self) -> int:
        """Context bins (1 when off)."""
        return int(self.context_cuts.size + 1) if self.context_block else 1

    @property
    def n_highlight(self) -> int:
        """Highlight bins (1 when off)."""
        return self.highlight_bins or 1

    @property
    def _texture_shape(self) -> tuple[int, int, int, int]:
        return (self.n_contrast, self.n_orientation, self.n_context, self.n_highlight)

    @property
    def n_texture(self) -> int:
        """Entries of the last class axis: contrast x orientation x context x highlight bins."""
        return self.n_contrast * self.n_orientation * self.n_context * self.n_highlight

    @property
    def n_groups(self) -> int:
        """Number of position groups (CFA positions with distinct patch layouts)."""
        return int(self.position_group.max() + 1)

    @property
    def n_saturation(self) -> int:
        """Number of saturation patterns, ``2 ** n_channels``."""
        return 1 << self.cfa.n_channels

    @property
    def n_classes(self) -> int:
        """Total number of classes (groups x saturation patterns x levels x texture bins)."""
        return self.n_groups * self.n_saturation * self.n_levels * self.n_texture

    @property
    def n_coeffs(self) -> int:
        """Coefficients per output channel: patch values plus a constant."""
        return self.patch * self.patch + 1

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(n_groups, n_saturation, n_levels, n_texture): the class index is its ravel.

        ``n_texture == n_contrast`` unless orientation or context is on.
        """
        return (self.n_groups, self.n_saturation, self.n_levels, self.n_texture)

    def class_index(self, group: ArrayLike, sat: ArrayLike, level: ArrayLike,
                    contrast: ArrayLike, orientation: ArrayLike = 0,
                    context: ArrayLike = 0, highlight: ArrayLike = 0) -> np.ndarray:
        """Flat class index of (group, saturation pattern, level, contrast[, orientation,
        context, highlight])."""
        tex = np.ravel_multi_index((contrast, orientation, context, highlight),
                                   self._texture_shape)
        return np.ravel_multi_index((group, sat, level, tex), self.shape)

    def class_tuple(self, index: ArrayLike) -> tuple[np.ndarray, ...]:
        """(group, sat, level, texture) of flat class indices (:meth:`texture_tuple` splits texture)."""
        return np.unravel_index(index, self.shape)

    def texture_tuple(self, texture: ArrayLike) -> tuple[np.ndarray, ...]:
        """(contrast, orientation, context, highlight) of texture indices."""
        return np.unravel_index(texture, self._texture_shape)

    def texture_permutation(self, matrix: np.ndarray) -> np.ndarray:
        """int64 (n_texture,): texture index of each texture bin after a D4 move of the patch.

        Contrast and context are unchanged by mirrors and rotations; the
        orientation bin moves (:func:`~l3cli.classify.features.orientation_permutation`).
        """
        from l3cli.classify.features import orientation_permutation

        perm = orientation_permutation(matrix, self.orientation_bins)
        c, o, x, hl = self.texture_tuple(np.arange(self.n_texture))
        return np.asarray(self.class_index(0, 0, 0, c, perm[o], x, hl), dtype=np.int64)

    @property
    def has_extra_features(self) -> bool:
        """True when orientation or context is on."""
        return bool(self.orientation_bins or self.context_block or self.highlight_bins)

    def same_as(self, other: ClassDefinition) -> bool:
        """True when both definitions give every pixel the same class."""
        return (
            self.cfa.spec == other.cfa.spec
            and self.patch == other.patch
            and np.array_equal(self.level_cuts, other.level_cuts)
            and np.array_equal(self.contrast_cuts, other.contrast_cuts)
            and self.saturation_threshold == other.saturation_threshold
            and np.array_equal(self.position_group, other.position_group)
            and self.contrast_eps == other.contrast_eps
            and self.contrast_rule == other.contrast_rule
            and self.saturation_rule == other.saturation_rule
            and self.orientation_bins == other.orientation_bins
            and self.coherence_threshold == other.coherence_threshold
            and self.orientation_rule == other.orientation_rule
            and self.context_block == other.context_block
            and np.array_equal(self.context_cuts, other.context_cuts)
            and self.context_rule == other.context_rule
            and self.highlight_bins == other.highlight_bins
            and self.highlight_fraction == other.highlight_fraction
        )

    # ---------------------------------------------------- cached tables
    def mirror_maps(self, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
        """Source row and column of every padded row/column (:func:`mirror_indices`)."""
        key = ("mirror", height, width)
        if key not in self._tables:
            r = self.patch // 2
            ph, pw = self.cfa.period
            self._tables[key] = (mirror_indices(height, r, ph), mirror_indices(width, r, pw))
        return self._tables[key]

    def to_dict(self) -> dict:
        """Plain arrays for the table file (see :mod:`l3cli.table`)."""
        return {
            "cfa": np.array(self.cfa.spec),
            "patch": np.array(self.patch, dtype=np.int64),
            "level_cuts": self.level_cuts.astype(np.float64),
            "level_spacing": np.array(self.level_spacing),
            "contrast_rule": np.array(self.contrast_rule),
            "contrast_cuts": self.contrast_cuts.astype(np.float64),
            "contrast_eps": np.array(self.contrast_eps, dtype=np.float64),
            "saturation_rule": np.array(self.saturation_rule),
            "saturation_threshold": np.array(self.saturation_threshold, dtype=np.float64),
            "position_group": self.position_group.astype(np.int64),
        } | self._extra_dict()

    def _extra_dict(self) -> dict:
        """Keys of the optional features, present only when a feature is on
        (so tables without them are written exactly as before)."""
        out: dict = {}
        if self.orientation_bins:
            out["orientation_bins"] = np.array(self.orientation_bins, dtype=np.int64)
            out["coherence_threshold"] = np.array(self.coherence_threshold, dtype=np.float64)
            out["orientation_rule"] = np.array(self.orientation_rule)
        if self.context_block:
            out["context_block"] = np.array(self.context_block, dtype=np.int64)
            out["context_cuts"] = self.context_cuts.astype(np.float64)
            out["context_rule"] = np.array(self.context_rule)
        if self.highlight_bins:
            out["highlight_bins"] = np.array(self.highlight_bins, dtype=np.int64)
            out["highlight_fraction"] = np.array(self.highlight_fraction, dtype=np.float64)
        return out


def describe_difference(a: ClassDefinition, b: ClassDefinition) -> str:
    """What makes two class definitions classify differently, in words."""
    diffs = []
    if a.cfa.spec != b.cfa.spec:
        diffs.append(f"CFA {a.cfa.spec} vs {b.cfa.spec}")
    if a.patch != b.patch:
        diffs.append(f"patch {a.patch}x{a.patch} vs {b.patch}x{b.patch}")
    if not np.array_equal(a.level_cuts, b.level_cuts):
        diffs.append(f"level cut points ({a.n_levels} vs {b.n_levels} levels"
                     + (", different values)" if a.n_levels == b.n_levels else ")"))
    if not np.array_equal(a.contrast_cuts, b.contrast_cuts):
        diffs.append("contrast cut points")
    if a.saturation_threshold != b.saturation_threshold:
        diffs.append(f"saturation threshold {a.saturation_threshold} vs {b.saturation_threshold}")
    if not np.array_equal(a.position_group, b.position_group):
        diffs.append("position groups")
    if (a.orientation_bins, a.coherence_threshold) != (b.orientation_bins, b.coherence_threshold):
        diffs.append(f"orientation bins {a.orientation_bins} vs {b.orientation_bins}")
    if a.context_block != b.context_block or a.context_rule != b.context_rule or \
            not np.array_equal(a.context_cuts, b.context_cuts):
        diffs.append("context bins")
    if (a.highlight_bins, a.highlight_fraction) != (b.highlight_bins, b.highlight_fraction):
        diffs.append("highlight bins")
    if a.contrast_eps != b.contrast_eps or a.contrast_rule != b.contrast_rule \
            or a.saturation_rule != b.saturation_rule:
        diffs.append("classification rules")
    return "; ".join(diffs) or "identical"


def position_groups(cfa: CFA, patch: int, *, merge: bool = True) -> np.ndarray:
    """Group index per CFA position; equal layouts share a group when ``merge``."""
    if not merge:
        return np.arange(cfa.n_positions, dtype=np.int64)
    grp = np.empty(cfa.n_positions, dtype=np.int64)
    for g, members in enumerate(sorted(cfa.equivalent_positions(patch), key=min)):
        grp[members] = g
    return grp

