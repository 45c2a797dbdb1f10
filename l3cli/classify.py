"""The L3 patch classifier, shared by training and rendering.

Every pixel of a raw mosaic is assigned a *class* from the patch of
``patch`` x ``patch`` raw values centred on it. The class is the tuple

``(position group, saturation pattern, response level, contrast)``

* **position group** -- the pixel's position in the CFA repeat,
  ``p = (y % ph) * pw + (x % pw)``; positions whose patch layouts coincide
  (:meth:`l3cli.cfa.CFA.equivalent_positions`) may share a group
  (``merge_positions``).
* **saturation pattern** -- a bit mask over the CFA channels: bit ``c`` is set
  when at least one pixel of channel ``c`` in the patch is at or above the
  saturation threshold. Pattern 0 is "nothing saturated"; every other pattern
  has its own classes.
* **response level** -- the mean of the per-channel means of the patch,
  ``L = (1/C') sum_c mean{x_k : channel(k) = c}`` over the ``C'`` channels
  present in the patch, binned by ``n_levels - 1`` cut points (log-spaced by
  default, linear optionally). Bin 0 is below the first cut (at the noise
  floor), the last bin above the last cut (near saturation).
* **contrast** -- the relative within-channel spread
  ``K = [(1/C') sum_c sd_c] / (max(L, 0) + eps)`` where ``sd_c`` is the
  standard deviation of the channel-``c`` pixels of the patch about their own
  mean (so colour differences between channels never count as texture), and
  the division by the level makes the rule the same at every exposure. ``K``
  is binned per level by ``n_contrast - 1`` thresholds; by default the
  thresholds are quantiles of the training data's contrast at that level (the
  median for two bins, flat vs textured), so both bins of every level are
  populated whatever the noise. The standard deviation (not a median-based
  spread) is used because it follows from separable box sums of ``x`` and
  ``x²``, which keeps classification a few operations per pixel; clipped
  outliers are taken out by the saturation classes.

The class index is ``((group * n_sat + sat) * n_levels + level) * n_contrast +
contrast`` with ``n_sat = 2 ** n_channels``.

The numba tile kernel here (:func:`run_tiles`) is the only implementation of
the rule; render and train both call it. Per tile of pixels it computes S-tap
horizontal then vertical sums of each channel's ``x`` and ``x²`` and an OR of
the saturated-channel bits, then level, contrast and class per pixel.

Precision: the features are computed in float32 in a fixed order (no
fast-math), so a pixel's class depends on its patch only. The level is exact
to a few float32 ulps; the contrast to about 1e-4 (``E[x²] - m²`` cancels
where a channel is nearly flat, so a perfectly flat patch has a contrast
between 0 and ~5e-4 rather than 0). Real raw data always carry more relative
noise than that (quantisation alone gives ~1e-4 at 12 bits), and the
comparisons with the cut points are made in float32: a cut point ``c`` acts
as ``float32(c)``.

References
----------
.. [1] Q. Tian, S. Lansel, J. E. Farrell, B. A. Wandell, "Automating the design
   of image processing pipelines for novel color filter arrays: Local, Linear,
   Learned (L3) method", Proc. SPIE 9023, Digital Photography X (2014).
.. [2] H. Jiang, Q. Tian, J. Farrell, B. A. Wandell, "Learning the image
   processing pipeline", IEEE Trans. Image Processing 26(10), 5032-5042 (2017).
"""

from __future__ import annotations

import contextlib
import functools
import os
from dataclasses import dataclass, field

# OpenMP threads that wait passively instead of spinning: on a shared or busy
# machine spinning workers steal the cores the kernels need (2x slower
# training measured under load); set OMP_WAIT_POLICY yourself to override.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba as nb  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import ArrayLike  # noqa: E402

from l3cli.cfa import CFA  # noqa: E402
from l3cli.errors import ConfigError, InputError

__all__ = [
    "ClassDefinition",
    "ContrastHistogram",
    "CONTRAST_RULE",
    "SATURATION_RULE",
    "mirror_indices",
    "pad_mosaic",
    "classify",
    "patch_features",
    "level_cuts_between",
]

#: Name of the contrast rule implemented here (stored in tables).
CONTRAST_RULE = "relative-std-v1"
#: Name of the saturation rule implemented here (stored in tables).
SATURATION_RULE = "any-pixel-per-channel-v1"
#: ``eps`` in the contrast denominator (normalised raw units).
DEFAULT_CONTRAST_EPS = 1e-4

_SPACINGS = ("log", "linear")


def level_cuts_between(lo: float, hi: float, n_levels: int, spacing: str = "log") -> np.ndarray:
    """``n_levels - 1`` cut points from ``lo`` to ``hi`` (both included).

    Parameters
    ----------
    lo, hi
        First and last cut, normalised raw units (0 = black, 1 = white).
    n_levels
        Number of level bins (>= 2).
    spacing
        ``"log"`` (geometric) or ``"linear"``.
    """
    if spacing not in _SPACINGS:
        raise ConfigError(f"level spacing {spacing!r} is not known; use one of {', '.join(_SPACINGS)}")
    if n_levels < 2:
        raise ConfigError(f"levels = {n_levels} is not allowed; use 2 or more")
    if not (0 < lo < hi):
        raise ConfigError(f"level range ({lo}, {hi}) is not allowed; need 0 < low < high")
    n_cuts = n_levels - 1
    if n_cuts == 1:
        return np.array([np.sqrt(lo * hi) if spacing == "log" else 0.5 * (lo + hi)])
    if spacing == "log":
        return np.geomspace(lo, hi, n_cuts)
    return np.linspace(lo, hi, n_cuts)


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
    _tables: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.patch < 1 or self.patch % 2 == 0:
            raise ConfigError(f"patch size {self.patch} is not allowed; use an odd size >= 1")
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
        if cc.shape[1] and (np.any(np.diff(cc, axis=1) < 0) or not np.all(np.isfinite(cc))):
            raise ConfigError("contrast cut points must be finite and increasing per level")
        grp = np.asarray(self.position_group, dtype=np.int64)
        if grp.shape != (self.cfa.n_positions,) or grp.min() != 0 or \
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
        if self.level_spacing not in _SPACINGS:
            raise ConfigError(f"level spacing {self.level_spacing!r} is not known")
        if not np.isfinite(self.saturation_threshold) or self.saturation_threshold <= 0:
            raise ConfigError(f"saturation threshold {self.saturation_threshold} must be > 0")
        if self.contrast_rule != CONTRAST_RULE:
            raise ConfigError(f"contrast rule {self.contrast_rule!r} is not known; "
                              f"this l3 implements {CONTRAST_RULE!r}")
        if self.saturation_rule != SATURATION_RULE:
            raise ConfigError(f"saturation rule {self.saturation_rule!r} is not known; "
                              f"this l3 implements {SATURATION_RULE!r}")
        object.__setattr__(self, "level_cuts", cuts)
        object.__setattr__(self, "contrast_cuts", cc)
        object.__setattr__(self, "position_group", grp)

    # ----------------------------------------------------------------- layout
    @classmethod
    def build(
        cls,
        cfa: CFA | str,
        *,
        patch: int = 5,
        level_cuts: np.ndarray,
        level_spacing: str = "log",
        contrast_cuts: np.ndarray | float | None = None,
        saturation_threshold: float = 0.95,
        merge_positions: bool = True,
        contrast_eps: float = DEFAULT_CONTRAST_EPS,
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
    def n_groups(self) -> int:
        """Number of position groups (CFA positions with distinct patch layouts)."""
        return int(self.position_group.max() + 1)

    @property
    def n_saturation(self) -> int:
        """Number of saturation patterns, ``2 ** n_channels``."""
        return 1 << self.cfa.n_channels

    @property
    def n_classes(self) -> int:
        """Total number of classes (groups x saturation patterns x levels x contrasts)."""
        return self.n_groups * self.n_saturation * self.n_levels * self.n_contrast

    @property
    def n_coeffs(self) -> int:
        """Coefficients per output channel: patch values plus a constant."""
        return self.patch * self.patch + 1

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(n_groups, n_saturation, n_levels, n_contrast): the class index is its ravel."""
        return (self.n_groups, self.n_saturation, self.n_levels, self.n_contrast)

    def class_index(self, group: ArrayLike, sat: ArrayLike, level: ArrayLike,
                    contrast: ArrayLike) -> np.ndarray:
        """Flat class index of (group, saturation pattern, level, contrast)."""
        return np.ravel_multi_index((group, sat, level, contrast), self.shape)

    def class_tuple(self, index: ArrayLike) -> tuple[np.ndarray, ...]:
        """(group, sat, level, contrast) of flat class indices."""
        return np.unravel_index(index, self.shape)

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
        )

    # -------------------------------------------------------- numba tables
    def kernel_args(self) -> tuple:
        """Arrays the tile kernel needs (cached): channel index pattern, per
        position 1/count of each channel in the patch and 1/channels present,
        position groups, the level lookup table (:func:`_level_lookup`), the
        float32 cuts inside each lookup bucket (NaN where none), the float32
        contrast cuts and the float32 thresholds."""
        if "args" not in self._tables:
            cfa, s = self.cfa, self.patch
            npos, nch = cfa.n_positions, cfa.n_channels
            cnt_inv = np.zeros((npos, nch), dtype=np.float32)
            wc = np.zeros((npos, nch), dtype=np.float32)
            for p in range(npos):
                counts = np.bincount(cfa.neighbourhood(p, s).ravel(), minlength=nch)
                present = counts > 0
                cnt_inv[p, present] = 1.0 / counts[present]
                wc[p, present] = 1.0 / present.sum()
            lut, shift, base = _level_lookup(self.level_cuts)
            # the (up to two) cuts inside each bucket, NaN where none (never <= a level)
            c32 = self.level_cuts.astype(np.float32)
            buckets = (c32.view(np.int32).astype(np.int64) >> shift) - base
            cuts = np.full((lut.size, 2), np.nan, dtype=np.float32)
            for j in range(2):
                k = lut.astype(np.int64) + j
                ok = k < c32.size
                ok[ok] &= buckets[k[ok]] == np.flatnonzero(ok)
                cuts[ok, j] = c32[k[ok]]
            self._tables["args"] = (
                cfa.index_pattern.astype(np.int64), cnt_inv, wc,
                self.position_group.astype(np.int64), lut, int(shift), int(base), cuts,
                np.ascontiguousarray(self.contrast_cuts, dtype=np.float32),
                np.float32(self.saturation_threshold), np.float32(self.contrast_eps),
                int(self.n_saturation), int(cfa.period[0]), int(cfa.period[1]),
            )
        return self._tables["args"]

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
        }


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


# ------------------------------------------------------------------- padding
def mirror_indices(n: int, r: int, period: int) -> np.ndarray:
    """Source indices of a CFA-phase-preserving mirror padding by ``r``.

    Index ``i`` in ``[-r, n + r)`` maps to a pixel inside ``[0, n)`` with
    ``j = i (mod period)`` close to the mirror image of ``i`` about the edge:
    the plain reflection ``-i`` (or ``2(n-1) - i``) moved by less than one period
    toward the inside, so the padded mosaic keeps the CFA phase everywhere.

    Returns
    -------
    numpy.ndarray
        int64 (n + 2r,): entry ``k`` is the source of padded index ``k - r``.
    """
    if n < period:
        raise InputError(f"image side {n} is smaller than the CFA period {period}")
    idx = np.arange(-r, n + r)
    out = idx.copy()
    lo = idx < 0
    j = -idx[lo]
    j = j + np.mod(idx[lo] - j, period)
    out[lo] = j
    hi = idx >= n
    j = 2 * (n - 1) - idx[hi]
    j = j - np.mod(j - idx[hi], period)
    out[hi] = j
    # tiny images: fold into range keeping the phase
    while np.any((out < 0) | (out >= n)):
        out = np.where(out < 0, out + period, out)
        out = np.where(out >= n, out - period, out)
    return out.astype(np.int64)


def pad_mosaic(mosaic: np.ndarray, r: int, period: tuple[int, int],
               rows: tuple[int, int] | None = None, extra: int = 0) -> np.ndarray:
    """CFA-phase-preserving mirror padding of ``mosaic`` by ``r`` pixels.

    ``rows=(y0, y1)`` returns only the padded band needed for output rows
    ``y0:y1`` (shape ``(y1 - y0 + 2r, W + 2r)``). ``extra`` zero columns are
    appended on the right (room for the kernels' fixed-width row loads).
    """
    h, w = mosaic.shape
    yi = mirror_indices(h, r, period[0])
    xi = mirror_indices(w, r, period[1])
    if rows is not None:
        yi = yi[rows[0] : rows[1] + 2 * r]
    out = np.zeros((yi.size, xi.size + extra), dtype=np.float32)
    inner = out[:, r : r + w]
    for k, y in enumerate(yi.tolist()):  # row copies; no full-size temporaries
        inner[k] = mosaic[y]
    if r:
        out[:, :r] = inner[:, xi[:r]]
        out[:, r + w : 2 * r + w] = inner[:, xi[r + w :]]
    return out


# ------------------------------------------------------------ numba kernels
#: Output rows and columns of one parallel tile. A tile's padded band, its
#: ring of horizontal sums and its output rows stay in the core's L2 cache.
_TILE_ROWS = 32
_TILE_COLS = 512

#: What the tile kernel does with each pixel's class (see :func:`run_tiles`).
MODE_CLASSES, MODE_FEATURES, MODE_RENDER = 0, 1, 2

#: Output lanes of the vectorised render path (tables with up to 4 outputs).
RENDER_LANES = 4


@contextlib.contextmanager
def _slp_vectorize():
    """Compile with LLVM's SLP vectoriser (numba leaves it off by default).

    It turns the render kernel's per-output multiply-adds into one SIMD
    multiply-add over the output lanes. Only the tile kernel is compiled
    inside this context; the classification arithmetic has no fast-math
    flags, so vectorised and scalar code give bit-identical features.
    """
    old = nb.config.SLP_VECTORIZE
    nb.config.SLP_VECTORIZE = 1
    try:
        yield
    finally:
        nb.config.SLP_VECTORIZE = old


@nb.njit(cache=True, fastmath={"contract"})
def _render_row4(pb, i, x, tw, S, cls_row, K, outf, o, n_out):
    """Render pixels ``x .. tw-1`` of tile row ``i`` for tables of <= 4 outputs.

    ``K`` is (n_classes, 4 * (S*S + 1)): per tap (row-major over the patch,
    then the constant) the 4 output lanes. The 4 lanes are one SIMD register;
    the partial sums per patch row keep the multiply-add chains short.
    """
    P = S * S
    for x in range(tw):
        c = cls_row[x]
        a0 = K[c, 4 * P]
        a1 = K[c, 4 * P + 1]
        a2 = K[c, 4 * P + 2]
        a3 = K[c, 4 * P + 3]
        for dy in range(S):
            r0 = np.float32(0.0)
            r1 = np.float32(0.0)
            r2 = np.float32(0.0)
            r3 = np.float32(0.0)
            for dx in range(S):
                v = pb[i + dy, x + dx]
                k = 4 * (dy * S + dx)
                r0 += v * K[c, k]
                r1 += v * K[c, k + 1]
                r2 += v * K[c, k + 2]
                r3 += v * K[c, k + 3]
            a0 += r0
            a1 += r1
            a2 += r2
            a3 += r3
        # kept as separate branches on purpose: merging the two 4-store cases
        # costs the SLP vector store (render ~10 % slower, measured)
        if n_out == 3:
            if x < tw - 1:  # the 4th lane lands on the next pixel, written next
                outf[o] = a0
                outf[o + 1] = a1
                outf[o + 2] = a2
                outf[o + 3] = a3
            else:
                outf[o] = a0
                outf[o + 1] = a1
                outf[o + 2] = a2
        elif n_out == 4:
            outf[o] = a0
            outf[o + 1] = a1
            outf[o + 2] = a2
            outf[o + 3] = a3
        else:
            outf[o] = a0
            if n_out > 1:
                outf[o + 1] = a1
        o += n_out


@nb.njit(cache=True, fastmath={"contract"})
def _render_row_any(pb, i, tw, S, cls_row, K, outf, o, n_out):
    """Render a tile row for tables of any number of outputs (``K`` (n_classes,
    (S*S + 1) * n_out), tap-major)."""
    P = S * S
    acc = np.empty(n_out, dtype=np.float32)
    for x in range(tw):
        c = cls_row[x]
        for q in range(n_out):
            acc[q] = K[c, P * n_out + q]
        for dy in range(S):
            for dx in range(S):
                v = pb[i + dy, x + dx]
                k = (dy * S + dx) * n_out
                for q in range(n_out):
                    acc[q] += v * K[c, k + q]
        for q in range(n_out):
            outf[o + q] = acc[q]
        o += n_out


@functools.cache
def _tile_kernel(S: int):
    """The classifier (and renderer) compiled for patch size ``S``.

    ``S`` is a compile-time constant, so the S-tap loops unroll and the loops
    along a row vectorise. Parallel over tiles of ``_TILE_ROWS`` x
    ``_TILE_COLS`` output pixels; each tile copies its padded band from the
    mosaic (mirror indices at the image borders), reduces every band row to
    horizontal S-tap sums of ``x`` and ``x²`` per channel present in the row
    (channel masks along the row) and an OR of saturated-channel bits, kept
    in a ring of S rows, and finishes each output row from its S ring rows:
    per channel mean and standard deviation, response level, relative
    contrast, saturation pattern, class. Every sum runs in a fixed order in
    float32 without fast-math, so a pixel's features and class depend on its
    patch only, never on the tiling or on vectorisation.
    """
    r = S // 2
    TR = _TILE_ROWS

    @nb.njit(cache=True, parallel=True)
    def kernel(mosaic, yi, xi, y0, nrows, tc, idx_pattern, cnt_inv, wc, group, lut, lut_shift,
               lut_base, cuts, ccuts, sat_thr, eps, n_sat, mode, out_cls, out_lev, out_con,
               out_sat, K, n_out, outf):
        W = mosaic.shape[1]
        ph, pw = idx_pattern.shape
        nch = cnt_inv.shape[1]
        nl = ccuts.shape[0]
        ncc = ccuts.shape[1]
        nlut = lut.shape[0]
        ccf = ccuts.ravel()
        twp_max = tc + S - 1
        # along-row tables in tile coordinates (tile columns start at multiples of pw)
        mask = np.zeros((ph, nch, twp_max), dtype=np.float32)
        bitv = np.zeros((ph, twp_max), dtype=np.int32)
        row_has = np.zeros((ph, nch), dtype=np.bool_)  # channel present in a row phase
        for py in range(ph):
            for xx in range(twp_max):
                c = idx_pattern[py, (xx - r) % pw]
                mask[py, c, xx] = 1.0
                bitv[py, xx] = 1 << c
                row_has[py, c] = True
        ci_row = np.zeros((ph, nch, tc), dtype=np.float32)
        wc_row = np.zeros((ph, nch, tc), dtype=np.float32)
        g_row = np.zeros((ph, tc), dtype=np.int32)
        for py in range(ph):
            for x in range(tc):
                pos = py * pw + x % pw
                g_row[py, x] = group[pos]
                for c in range(nch):
                    ci_row[py, c, x] = cnt_inv[pos, c]
                    wc_row[py, c, x] = wc[pos, c]
        n_rt = (nrows + TR - 1) // TR
        n_ct = (W + tc - 1) // tc
        for t in nb.prange(n_rt * n_ct):
            i0 = (t // n_ct) * TR
            i1 = min(nrows, i0 + TR)
            x0 = (t % n_ct) * tc
            x1 = min(W, x0 + tc)
            tw = x1 - x0
            twp = tw + S - 1
            nbr = i1 - i0 + S - 1
            # padded band of the tile: row k is padded row y0 + i0 + k (image row - r)
            pb = np.empty((nbr, twp), dtype=np.float32)
            inner = x0 - r >= 0 and x0 - r + twp <= W
            for k in range(nbr):
                src = yi[y0 + i0 + k]
                if inner:
                    for xx in range(twp):
                        pb[k, xx] = mosaic[src, x0 - r + xx]
                else:
                    for xx in range(twp):
                        pb[k, xx] = mosaic[src, xi[x0 + xx]]
            ring_s = np.empty((S, nch, tw), dtype=np.float32)
            ring_q = np.empty((S, nch, tw), dtype=np.float32)
            ring_b = np.empty((S, tw), dtype=np.int32)
            mv = np.empty(twp, dtype=np.float32)
            mq = np.empty(twp, dtype=np.float32)
            bits = np.empty(twp, dtype=np.int32)
            lev = np.empty(tw, dtype=np.float32)
            levi = lev.view(np.int32)
            spr = np.empty(tw, dtype=np.float32)
            va = np.empty(tw, dtype=np.float32)
            vq = np.empty(tw, dtype=np.float32)
            satr = np.empty(tw, dtype=np.int32)
            clsr = np.empty(tw, dtype=np.int32)
            lbr = np.empty(tw, dtype=np.int32)
            kbr = np.empty(tw, dtype=np.int32)
            ccr = np.empty(tw, dtype=np.float32)
            rows_c = np.empty(S, dtype=np.int64)
            for k in range(nbr):
                slot = k % S
                py = (y0 + i0 + k - r) % ph
                for c in range(nch):
                    if not row_has[py, c]:
                        continue  # the ring slot is never read for this channel
                    for xx in range(twp):
                        u = pb[k, xx] * mask[py, c, xx]
                        mv[xx] = u
                        mq[xx] = u * pb[k, xx]
                    for x in range(tw):
                        a = mv[x]
                        q = mq[x]
                        for dx in range(1, S):
                            a += mv[x + dx]
                            q += mq[x + dx]
                        ring_s[slot, c, x] = a
                        ring_q[slot, c, x] = q
                for xx in range(twp):
                    bits[xx] = bitv[py, xx] if pb[k, xx] >= sat_thr else 0
                for x in range(tw):
                    b = bits[x]
                    for dx in range(1, S):
                        b |= bits[x + dx]
                    ring_b[slot, x] = b
                i = k - (S - 1)  # tile output row whose window is now complete
                if i < 0:
                    continue
                po = (y0 + i0 + i) % ph
                for x in range(tw):
                    lev[x] = 0.0
                    spr[x] = 0.0
                for c in range(nch):
                    # rows of the window that hold channel c (others are all zero)
                    nrow = 0
                    for dy in range(S):
                        if row_has[(y0 + i0 + i + dy - r) % ph, c]:
                            rows_c[nrow] = (i + dy) % S
                            nrow += 1
                    if nrow == 0:
                        continue
                    sl = rows_c[0]
                    for x in range(tw):
                        va[x] = ring_s[sl, c, x]
                        vq[x] = ring_q[sl, c, x]
                    for kk in range(1, nrow):  # rows outside, pixels inside: vectorised
                        sl = rows_c[kk]
                        for x in range(tw):
                            va[x] += ring_s[sl, c, x]
                            vq[x] += ring_q[sl, c, x]
                    for x in range(tw):
                        ci = ci_row[po, c, x]
                        m = va[x] * ci
                        var = vq[x] * ci - m * m
                        lev[x] += m * wc_row[po, c, x]
                        spr[x] += np.sqrt(max(var, np.float32(0.0))) * wc_row[po, c, x]
                for x in range(tw):
                    b = ring_b[i % S, x]
                    for dy in range(1, S):
                        b |= ring_b[(i + dy) % S, x]
                    satr[x] = b
                    spr[x] = spr[x] / (max(lev[x], np.float32(0.0)) + eps)  # now the contrast
                if mode == 1:
                    for x in range(tw):
                        out_lev[i0 + i, x0 + x] = lev[x]
                        out_con[i0 + i, x0 + x] = spr[x]
                        out_sat[i0 + i, x0 + x] = satr[x]
                    continue
                # level bin: a lookup on the float's leading bits, then at most two
                # comparisons with the cut points of the bucket (see _level_lookup);
                # the table reads cannot vectorise (gathers), the rest does
                for x in range(tw):
                    kb = (levi[x] >> lut_shift) - lut_base
                    kbr[x] = min(max(kb, 0), nlut - 1)
                for x in range(tw):
                    kb = kbr[x]
                    lv = lev[x]
                    lbr[x] = lut[kb] + np.int32(cuts[kb, 0] <= lv) + np.int32(cuts[kb, 1] <= lv)
                for x in range(tw):
                    clsr[x] = ((g_row[po, x] * n_sat + satr[x]) * nl + lbr[x]) * (ncc + 1)
                for j in range(ncc):  # contrast bin
                    for x in range(tw):
                        kbr[x] = lbr[x] * ncc + j
                    for x in range(tw):
                        ccr[x] = ccf[kbr[x]]
                    for x in range(tw):
                        clsr[x] += np.int32(spr[x] >= ccr[x])
                if mode == 0:
                    for x in range(tw):
                        out_cls[i0 + i, x0 + x] = clsr[x]
                elif n_out <= 4:
                    _render_row4(pb, i, 0, tw, S, clsr, K, outf, ((i0 + i) * W + x0) * n_out,
                                 n_out)
                else:
                    _render_row_any(pb, i, tw, S, clsr, K, outf, ((i0 + i) * W + x0) * n_out,
                                    n_out)

    return kernel


def _level_lookup(cuts: np.ndarray) -> tuple[np.ndarray, int, int]:
    """A table that bins a positive float32 level with at most two comparisons.

    The bit pattern of a positive float32 increases with its value, so
    ``bits >> shift`` numbers buckets of equal relative width. ``lut[k]`` is
    the number of cuts below bucket ``k``; the coarsest buckets holding at
    most two cuts each are chosen. Levels <= 0 fall in bucket 0 (below
    every cut), levels above the last cut in the last bucket.
    """
    cuts32 = np.asarray(cuts, dtype=np.float32)
    bits = cuts32.view(np.int32).astype(np.int64)
    for shift in range(23, -1, -1):
        buckets = bits >> shift
        size = int(buckets[-1] - buckets[0]) + 1
        if size > _LUT_MAX:
            break
        if np.unique(buckets, return_counts=True)[1].max() <= 2:
            base = int(buckets[0])
            k = np.arange(size) + base
            return np.searchsorted(buckets, k, side="left").astype(np.int32), shift, base
    raise ConfigError(
        "level cut points are too close together for their range (ratio of neighbouring "
        "cuts below ~1e-5); use fewer levels")


_LUT_MAX = 1 << 16


def _check_mosaic(mosaic: np.ndarray, cfa: CFA, patch: int) -> np.ndarray:
    mosaic = np.asarray(mosaic)
    if mosaic.ndim != 2:
        raise InputError(f"a raw mosaic must be 2-D (H, W), got shape {mosaic.shape}")
    ph, pw = cfa.period
    if mosaic.shape[0] < max(ph, patch // 2 + 1) or mosaic.shape[1] < max(pw, patch // 2 + 1):
        raise InputError(
            f"raw mosaic {mosaic.shape[1]}x{mosaic.shape[0]} is too small for a "
            f"{patch}x{patch} patch and a {pw}x{ph} CFA"
        )
    return np.ascontiguousarray(mosaic, dtype=np.float32)


def band_rows(height: int, width: int, *, max_pixels: int = 1 << 20) -> list[tuple[int, int]]:
    """Row bands ``(y0, y1)`` holding at most ``max_pixels`` pixels each."""
    step = max(1, max_pixels // max(width, 1))
    return [(y0, min(height, y0 + step)) for y0 in range(0, height, step)]


_NO_F32 = np.zeros((1, 1), dtype=np.float32)
_NO_I32 = np.zeros((1, 1), dtype=np.int32)
_NO_OUT = np.zeros(1, dtype=np.float32)


def run_tiles(mosaic: np.ndarray, definition: ClassDefinition, mode: int, *,
              rows: tuple[int, int] | None = None, out_cls: np.ndarray | None = None,
              out_features: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
              kernels: np.ndarray | None = None, n_out: int = 0,
              out: np.ndarray | None = None) -> None:
    """Run the tile kernel over output rows ``rows`` (default: all) of a mosaic.

    The one entry point to the classifier; :func:`classify`,
    :func:`patch_features`, training and :func:`l3cli.render.render_mosaic`
    all come through here.

    Parameters
    ----------
    mosaic
        float32 (H, W) normalised mosaic, C-contiguous, CFA phase as the definition.
    definition
        The class definition.
    mode
        ``MODE_CLASSES`` (int32 classes into ``out_cls``), ``MODE_FEATURES``
        (float32 level, float32 contrast, int32 saturation bits into
        ``out_features``) or ``MODE_RENDER`` (``out`` = affine kernels of the
        classes applied to the patches).
    rows
        ``(y0, y1)``: output rows; the output arrays have ``y1 - y0`` rows.
    kernels
        Render only: float32 packed kernels (:func:`l3cli.render.pack_kernels`).
    n_out
        Render only: outputs per pixel.
    out
        Render only: float32 C-contiguous (y1 - y0, W, n_out).
    """
    S = definition.patch
    h, w = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    (idx, cnt_inv, wc, group, lut, shift, base, cuts, ccuts, thr, eps, n_sat,
     ph, pw) = definition.kernel_args()
    yi, xi = definition.mirror_maps(h, w)
    tc = pw * max(1, _TILE_COLS // pw)
    cls_o = out_cls if out_cls is not None else _NO_I32
    lev_o, con_o, sat_o = out_features if out_features is not None else (_NO_F32, _NO_F32,
                                                                         _NO_I32)
    K = kernels if kernels is not None else _NO_F32
    outf = out.reshape(-1) if out is not None else _NO_OUT
    with _slp_vectorize():
        _tile_kernel(S)(mosaic, yi, xi, y0, y1 - y0, tc, idx, cnt_inv, wc, group, lut, shift,
                        base, cuts, ccuts, thr, eps, n_sat, mode, cls_o, lev_o, con_o, sat_o, K,
                        n_out, outf)


def classify(mosaic: np.ndarray, definition: ClassDefinition, *,
             rows: tuple[int, int] | None = None) -> np.ndarray:
    """Class index of every pixel of a mosaic.

    Parameters
    ----------
    mosaic
        float32 (H, W) normalised raw mosaic whose CFA phase is ``definition.cfa``.
    definition
        The class definition.
    rows
        Optional ``(y0, y1)``: classify only these rows.

    Returns
    -------
    numpy.ndarray
        int32 (H, W) (or (y1 - y0, W)) flat class indices (see :class:`ClassDefinition`).
    """
    mosaic = _check_mosaic(mosaic, definition.cfa, definition.patch)
    h, w = mosaic.shape
    y0, y1 = rows if rows is not None else (0, h)
    out = np.empty((y1 - y0, w), dtype=np.int32)
    run_tiles(mosaic, definition, MODE_CLASSES, rows=(y0, y1), out_cls=out)
    return out


def patch_features(mosaic: np.ndarray, cfa: CFA | str, *, patch: int = 5,
                   saturation_threshold: float = 0.95,
                   contrast_eps: float = DEFAULT_CONTRAST_EPS
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Response level, relative contrast and saturation bits of every pixel's patch.

    Returns
    -------
    level, contrast, sat
        float32 (H, W), float32 (H, W), int32 (H, W) (bit ``c`` = channel
        ``cfa.channels[c]`` saturated somewhere in the patch).
    """
    cfa = CFA.from_spec(cfa)
    d = ClassDefinition.build(cfa, patch=patch, level_cuts=np.array([0.5]),
                              saturation_threshold=saturation_threshold,
                              contrast_eps=contrast_eps, merge_positions=False)
    mosaic = _check_mosaic(mosaic, cfa, patch)
    h, w = mosaic.shape
    lev = np.empty((h, w), dtype=np.float32)
    con = np.empty((h, w), dtype=np.float32)
    sat = np.empty((h, w), dtype=np.int32)
    run_tiles(mosaic, d, MODE_FEATURES, out_features=(lev, con, sat))
    return lev, con, sat


# ---------------------------------------------------- data-driven cut points
#: Fine log bins used to learn cut points from training data (additive).
_LEVEL_EDGES = np.geomspace(1e-6, 2.0, 531)  # ~100 bins per decade
_CONTRAST_EDGES = np.geomspace(1e-4, 1e2, 301)  # 50 bins per decade


@dataclass
class ContrastHistogram:
    """Joint histogram of (level, contrast) of unsaturated patches; adds.

    Used by training to place level cut points "just above the noise floor
    to near saturation" and per-level contrast thresholds at quantiles of the
    data. Bins: 0 = below the first edge, last = above the last edge.
    """

    counts: np.ndarray  # int64 (len(_LEVEL_EDGES)+1, len(_CONTRAST_EDGES)+1)

    @classmethod
    def empty(cls) -> ContrastHistogram:
        """A histogram with no patches."""
        return cls(np.zeros((_LEVEL_EDGES.size + 1, _CONTRAST_EDGES.size + 1), dtype=np.int64))

    def __add__(self, other: ContrastHistogram) -> ContrastHistogram:
        return ContrastHistogram(self.counts + other.counts)

    def add_mosaic(self, mosaic: np.ndarray, cfa: CFA, *, patch: int,
                   saturation_threshold: float, mask: np.ndarray | None = None) -> None:
        """Add the patches of one mosaic (optionally only where ``mask``)."""
        lev, con, sat = patch_features(mosaic, cfa, patch=patch,
                                       saturation_threshold=saturation_threshold)
        keep = sat == 0
        if mask is not None:
            keep &= mask
        li = np.searchsorted(_LEVEL_EDGES, lev[keep], side="right")
        ci = np.searchsorted(_CONTRAST_EDGES, con[keep], side="right")
        flat = li * (_CONTRAST_EDGES.size + 1) + ci
        self.counts += np.bincount(flat, minlength=self.counts.size).reshape(self.counts.shape)

    @property
    def total(self) -> int:
        """Number of patches counted."""
        return int(self.counts.sum())

    def level_range(self, *, low_quantile: float = 0.002, high_quantile: float = 0.998,
                    floor: float = 1e-4, ceiling: float = 0.95) -> tuple[float, float]:
        """Level cut range from quantiles of the data, clamped to [floor, ceiling]."""
        lv = self.counts.sum(axis=1).astype(np.float64)
        if lv.sum() == 0:
            raise InputError("no unsaturated patches in the training data")
        cdf = np.cumsum(lv) / lv.sum()

        def q(p):  # upper edge of the bin holding quantile p
            i = int(np.searchsorted(cdf, min(max(p, 1e-12), 1 - 1e-9)))
            return float(_LEVEL_EDGES[min(i, _LEVEL_EDGES.size - 1)])

        lo = max(q(low_quantile), floor)
        hi = min(q(high_quantile), ceiling)
        if hi <= lo * 1.5:
            hi = min(max(lo * 10.0, hi), max(ceiling, lo * 1.5))
            if hi <= lo:
                lo = hi / 10.0
        return lo, hi

    def contrast_cuts(self, level_cuts: np.ndarray, n_contrast: int) -> np.ndarray:
        """Per level bin, thresholds at the quantiles k/n_contrast of the contrast."""
        nl = level_cuts.size + 1
        out = np.zeros((nl, n_contrast - 1))
        if n_contrast < 2:
            return out
        centres = np.sqrt(_LEVEL_EDGES[:-1] * _LEVEL_EDGES[1:])
        fine_level_bin = np.concatenate([[0], np.searchsorted(level_cuts, centres, side="right"),
                                         [nl - 1]])
        cedges = _CONTRAST_EDGES  # cedges[i] = upper edge of fine bin i (last bin clipped)
        qs = np.arange(1, n_contrast) / n_contrast
        total = self.counts.sum(axis=0).astype(np.float64)
        have = np.zeros(nl, dtype=bool)
        for lev in range(nl):
            h = self.counts[fine_level_bin == lev].sum(axis=0).astype(np.float64)
            if h.sum() < 10 * n_contrast:
                continue
            cdf = np.cumsum(h) / h.sum()
            out[lev] = [cedges[min(int(np.searchsorted(cdf, q)), cedges.size - 1)] for q in qs]
            have[lev] = True
        if not have.any():
            cdf = np.cumsum(total) / max(total.sum(), 1.0)
            out[:] = [cedges[min(int(np.searchsorted(cdf, q)), cedges.size - 1)] for q in qs]
            return out
        idx = np.flatnonzero(have)
        for lev in np.flatnonzero(~have):
            out[lev] = out[idx[np.argmin(np.abs(idx - lev))]]
        # thresholds within a level must increase
        return np.maximum.accumulate(out, axis=1)
