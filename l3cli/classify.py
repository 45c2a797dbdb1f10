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

The numba kernels here are the only implementation of the rule; render and
train both call them. Per band of rows they compute S-tap horizontal then
vertical sums of each channel's ``x`` and ``x²`` (float64) and an OR of the
saturated-channel bits, then level, contrast and class per pixel.

References
----------
.. [1] Q. Tian, S. Lansel, J. E. Farrell, B. A. Wandell, "Automating the design
   of image processing pipelines for novel color filter arrays: Local, Linear,
   Learned (L3) method", Proc. SPIE 9023, Digital Photography X (2014).
.. [2] H. Jiang, Q. Tian, J. Farrell, B. A. Wandell, "Learning the image
   processing pipeline", IEEE Trans. Image Processing 26(10), 5032-5042 (2017).
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field

# OpenMP threads that wait passively instead of spinning: on a shared or busy
# machine spinning workers steal the cores the kernels need (2x slower
# training measured under load); set OMP_WAIT_POLICY yourself to override.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba as nb  # noqa: E402
import numpy as np  # noqa: E402

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
        return int(self.level_cuts.size + 1)

    @property
    def n_contrast(self) -> int:
        return int(self.contrast_cuts.shape[1] + 1)

    @property
    def n_groups(self) -> int:
        return int(self.position_group.max() + 1)

    @property
    def n_saturation(self) -> int:
        return 1 << self.cfa.n_channels

    @property
    def n_classes(self) -> int:
        return self.n_groups * self.n_saturation * self.n_levels * self.n_contrast

    @property
    def n_coeffs(self) -> int:
        """Coefficients per output channel: patch values plus a constant."""
        return self.patch * self.patch + 1

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(n_groups, n_saturation, n_levels, n_contrast): the class index is its ravel."""
        return (self.n_groups, self.n_saturation, self.n_levels, self.n_contrast)

    def class_index(self, group, sat, level, contrast):
        """Flat class index of (group, saturation pattern, level, contrast)."""
        return np.ravel_multi_index((group, sat, level, contrast), self.shape)

    def class_tuple(self, index):
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
        """Arrays the numba kernels need (cached): channel index pattern, per
        position 1/count of each channel in the patch and 1/channels present."""
        if "args" not in self._tables:
            cfa, s = self.cfa, self.patch
            npos, nch = cfa.n_positions, cfa.n_channels
            cnt_inv = np.zeros((npos, nch), dtype=np.float64)
            wc = np.zeros((npos, nch), dtype=np.float64)
            for p in range(npos):
                counts = np.bincount(cfa.neighbourhood(p, s).ravel(), minlength=nch)
                present = counts > 0
                cnt_inv[p, present] = 1.0 / counts[present]
                wc[p, present] = 1.0 / present.sum()
            self._tables["args"] = (
                cfa.index_pattern.astype(np.int64), cnt_inv, wc,
                self.position_group.astype(np.int64), self.level_cuts, self.contrast_cuts,
                float(self.saturation_threshold), float(self.contrast_eps),
                int(self.n_saturation), int(cfa.period[0]), int(cfa.period[1]), int(s),
            )
        return self._tables["args"]

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


def padded_width(s: int) -> int:
    """Row width of kernels padded to a multiple of 8 (vectorisable inner loops)."""
    return 8 * ((s + 7) // 8)


# ------------------------------------------------------------ numba kernels
_FM = {"reassoc", "contract"}  # allow vectorised reductions; keep NaN/Inf semantics


_ROWS = 16  # output rows per parallel task


@functools.cache
def _kernels(S: int):
    """The feature kernel compiled for patch size ``S`` (a compile-time constant, so
    the S-tap loops unroll and the loops along a row vectorise). Cached on disk.

    Per task of ``_ROWS`` output rows, each padded band row is reduced once to
    horizontal S-tap sums of ``x`` and ``x²`` per channel (channel masks along
    the row) and an OR of saturated-channel bits, kept in a ring of S rows;
    each output row then sums its S ring rows (in a fixed order, so results do
    not depend on how the image is split) and finishes level, contrast,
    saturation and class per pixel.
    """
    r = S // 2

    @nb.njit(cache=True, parallel=True, fastmath=_FM)
    def features(band, y0, idx_pattern, cnt_inv, wc, sat_thr, eps, level, contrast, sat,
                 store, do_class, group, level_cuts, contrast_cuts, n_sat, out_cls):
        H, W = out_cls.shape if do_class else level.shape
        Wp = W + S - 1
        ph, pw = idx_pattern.shape
        nch = cnt_inv.shape[1]
        ncut = level_cuts.shape[0]
        nl = ncut + 1
        ncc = contrast_cuts.shape[1]
        # along-row tables per row phase (band column xx is image column xx - r)
        mask = np.zeros((ph, nch, Wp), dtype=np.float64)
        bitv = np.zeros((ph, Wp), dtype=np.int32)
        row_has = np.zeros((ph, nch), dtype=np.bool_)  # channel present in a row phase
        for py in range(ph):
            for xx in range(Wp):
                c = idx_pattern[py, (xx - r) % pw]
                mask[py, c, xx] = 1.0
                bitv[py, xx] = 1 << c
                row_has[py, c] = True
        ci_row = np.zeros((ph, nch, W), dtype=np.float64)
        wc_row = np.zeros((ph, nch, W), dtype=np.float64)
        g_row = np.zeros((ph, W), dtype=np.int64)
        for py in range(ph):
            for x in range(W):
                pos = py * pw + x % pw
                g_row[py, x] = group[pos]
                for c in range(nch):
                    ci_row[py, c, x] = cnt_inv[pos, c]
                    wc_row[py, c, x] = wc[pos, c]
        ntask = (H + _ROWS - 1) // _ROWS
        for task in nb.prange(ntask):
            i0 = task * _ROWS
            i1 = min(H, i0 + _ROWS)
            ring_s = np.empty((S, nch, W), dtype=np.float64)
            ring_q = np.empty((S, nch, W), dtype=np.float64)
            ring_b = np.empty((S, W), dtype=np.int32)
            mv = np.empty(Wp, dtype=np.float64)
            mq = np.empty(Wp, dtype=np.float64)
            bits = np.empty(Wp, dtype=np.int32)
            lev = np.empty(W, dtype=np.float64)
            spr = np.empty(W, dtype=np.float64)
            rows_c = np.empty(S, dtype=np.int64)
            satr = np.empty(W, dtype=np.int32)
            va = np.empty(W, dtype=np.float64)
            vq = np.empty(W, dtype=np.float64)
            for yy in range(i0, i1 + S - 1):
                slot = yy % S
                py = (y0 - r + yy) % ph
                for c in range(nch):
                    if not row_has[py, c]:
                        continue  # the ring slot is never read for this channel
                    for xx in range(Wp):
                        t = np.float64(band[yy, xx])
                        u = t * mask[py, c, xx]
                        mv[xx] = u
                        mq[xx] = u * t
                    for x in range(W):
                        a = 0.0
                        q = 0.0
                        for dx in range(S):
                            a += mv[x + dx]
                            q += mq[x + dx]
                        ring_s[slot, c, x] = a
                        ring_q[slot, c, x] = q
                for xx in range(Wp):
                    bits[xx] = bitv[py, xx] if band[yy, xx] >= sat_thr else 0
                for x in range(W):
                    b = 0
                    for dx in range(S):
                        b |= bits[x + dx]
                    ring_b[slot, x] = b
                i = yy - (S - 1)
                if i < i0:
                    continue
                po = (y0 + i) % ph
                for x in range(W):
                    lev[x] = 0.0
                    spr[x] = 0.0
                for c in range(nch):
                    # rows of the window that hold channel c (others are all zero)
                    nrow = 0
                    for dy in range(S):
                        if row_has[(y0 - r + i + dy) % ph, c]:
                            rows_c[nrow] = (i + dy) % S
                            nrow += 1
                    for x in range(W):
                        va[x] = 0.0
                        vq[x] = 0.0
                    for k in range(nrow):  # rows outside, pixels inside: vectorised
                        sl = rows_c[k]
                        for x in range(W):
                            va[x] += ring_s[sl, c, x]
                            vq[x] += ring_q[sl, c, x]
                    for x in range(W):
                        ci = ci_row[po, c, x]
                        m = va[x] * ci
                        var = vq[x] * ci - m * m
                        lev[x] += m * wc_row[po, c, x]
                        spr[x] += np.sqrt(max(var, 0.0)) * wc_row[po, c, x]
                for x in range(W):
                    b = 0
                    for dy in range(S):
                        b |= ring_b[(i + dy) % S, x]
                    satr[x] = b
                    spr[x] = spr[x] / (max(lev[x], 0.0) + eps)  # now the contrast
                if store:
                    for x in range(W):
                        level[i, x] = lev[x]
                        contrast[i, x] = spr[x]
                        sat[i, x] = satr[x]
                if do_class:
                    lb = 0
                    for x in range(W):
                        # count of cuts <= level, walking from the previous pixel's
                        # bin (levels of neighbours are close: usually 0-1 steps)
                        lv = lev[x]
                        while lb < ncut and level_cuts[lb] <= lv:
                            lb += 1
                        while lb > 0 and level_cuts[lb - 1] > lv:
                            lb -= 1
                        con = 0
                        cv = spr[x]
                        for j in range(ncc):
                            con += cv >= contrast_cuts[lb, j]
                        out_cls[i, x] = ((g_row[po, x] * n_sat + satr[x]) * nl + lb) * (ncc + 1) + con

    return features


def band_features(band: np.ndarray, y0: int, rows: int, width: int, args: tuple,
                  out_cls: np.ndarray | None = None, *, store: bool = True
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Level, contrast and saturation bits of output rows ``y0 : y0 + rows``.

    ``band`` is the padded band (:func:`pad_mosaic` with ``rows``), ``args``
    :meth:`ClassDefinition.kernel_args`. When ``out_cls`` (int32 (rows, width))
    is given, the class indices are written into it too; ``store=False``
    then skips the feature arrays (returns None).
    """
    (idx, cnt_inv, wc, group, lc, cc, thr, eps, n_sat, ph, pw, S) = args
    do_class = out_cls is not None
    if not do_class:
        store = True
        out_cls = np.empty((1, 1), dtype=np.int32)
    shape = (rows, width) if store else (1, 1)
    level = np.empty(shape)
    contrast = np.empty(shape)
    sat = np.empty(shape, dtype=np.int32)
    _kernels(S)(band, y0, idx, cnt_inv, wc, thr, eps, level, contrast, sat,
                store, do_class, group, lc, cc, n_sat, out_cls)
    return (level, contrast, sat) if store else None


def band_classes(band: np.ndarray, y0: int, rows: int, width: int, args: tuple,
                 out: np.ndarray | None = None) -> np.ndarray:
    """int32 class indices of output rows ``y0 : y0 + rows`` (see :func:`band_features`)."""
    if out is None:
        out = np.empty((rows, width), dtype=np.int32)
    band_features(band, y0, rows, width, args, out_cls=out, store=False)
    return out


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
    return mosaic


def band_rows(height: int, width: int, *, max_pixels: int = 1 << 20) -> list[tuple[int, int]]:
    """Row bands ``(y0, y1)`` holding at most ``max_pixels`` pixels each."""
    step = max(1, max_pixels // max(width, 1))
    return [(y0, min(height, y0 + step)) for y0 in range(0, height, step)]


def classify(mosaic: np.ndarray, definition: ClassDefinition) -> np.ndarray:
    """Class index of every pixel of a mosaic.

    Parameters
    ----------
    mosaic
        float32 (H, W) normalised raw mosaic whose CFA phase is ``definition.cfa``.
    definition
        The class definition.

    Returns
    -------
    numpy.ndarray
        int32 (H, W) flat class indices (see :class:`ClassDefinition`).
    """
    mosaic = _check_mosaic(mosaic, definition.cfa, definition.patch)
    args = definition.kernel_args()
    S = definition.patch
    ph, pw = definition.cfa.period
    h, w = mosaic.shape
    out = np.empty((h, w), dtype=np.int32)
    for y0, y1 in band_rows(h, w):
        band = pad_mosaic(mosaic, S // 2, (ph, pw), rows=(y0, y1))
        band_classes(band, y0, y1 - y0, w, args, out=out[y0:y1])
    return out


def patch_features(mosaic: np.ndarray, cfa: CFA | str, *, patch: int = 5,
                   saturation_threshold: float = 0.95,
                   contrast_eps: float = DEFAULT_CONTRAST_EPS
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Response level, relative contrast and saturation bits of every pixel's patch.

    Returns
    -------
    level, contrast, sat
        float64 (H, W), float64 (H, W), int32 (H, W) (bit ``c`` = channel
        ``cfa.channels[c]`` saturated somewhere in the patch).
    """
    cfa = CFA.from_spec(cfa)
    d = ClassDefinition.build(cfa, patch=patch, level_cuts=np.array([0.5]),
                              saturation_threshold=saturation_threshold,
                              contrast_eps=contrast_eps, merge_positions=False)
    mosaic = _check_mosaic(mosaic, cfa, patch)
    args = d.kernel_args()
    h, w = mosaic.shape
    lev = np.empty((h, w))
    con = np.empty((h, w))
    sat = np.empty((h, w), dtype=np.int32)
    for y0, y1 in band_rows(h, w):
        band = pad_mosaic(mosaic, patch // 2, cfa.period, rows=(y0, y1))
        lev[y0:y1], con[y0:y1], sat[y0:y1] = band_features(band, y0, y1 - y0, w, args)
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
