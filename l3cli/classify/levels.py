"""Response-level bins: cut points and the float32 lookup the tile kernel bins with."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from l3cli.errors import ConfigError

__all__ = ["SPACINGS", "LevelLookup", "level_cuts_between", "level_lookup"]

#: How cut points may be spaced.
SPACINGS = ("log", "linear")

#: Largest lookup table (buckets) :func:`level_lookup` builds.
_LUT_MAX = 1 << 16


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

    Returns
    -------
    numpy.ndarray
        float64 (n_levels - 1,), increasing.

    Examples
    --------
    >>> level_cuts_between(0.001, 0.1, 4).round(6).tolist()
    [0.001, 0.01, 0.1]
    >>> level_cuts_between(0.1, 0.5, 3, "linear").tolist()
    [0.1, 0.5]
    >>> level_cuts_between(0.01, 0.04, 2).tolist()  # one cut: the geometric mean
    [0.02]
    """
    if spacing not in SPACINGS:
        raise ConfigError(f"level spacing {spacing!r} is not known; use one of {', '.join(SPACINGS)}")
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


class LevelLookup(NamedTuple):
    """A table that bins a positive float32 level with at most two comparisons.

    The bin of a float32 level ``v`` is
    ``lut[k] + (cuts[k, 0] <= v) + (cuts[k, 1] <= v)`` with the bucket
    ``k = clip((bits(v) >> shift) - base, 0, lut.size - 1)``, which equals
    ``searchsorted(float32(level_cuts), v, side="right")``.
    """

    #: int32 (n_buckets,): the number of cuts below each bucket.
    lut: np.ndarray
    #: Right shift of the float32 bit pattern that numbers the buckets.
    shift: int
    #: Bucket number of the first cut.
    base: int
    #: float32 (n_buckets, 2): the (up to two) cuts inside each bucket, NaN where none.
    cuts: np.ndarray


def level_lookup(level_cuts: np.ndarray) -> LevelLookup:
    """The :class:`LevelLookup` of increasing cut points.

    The bit pattern of a positive float32 increases with its value, so
    ``bits >> shift`` numbers buckets of equal relative width. ``lut[k]`` is
    the number of cuts below bucket ``k``; the coarsest buckets holding at
    most two cuts each are chosen. Levels <= 0 fall in bucket 0 (below
    every cut), levels above the last cut in the last bucket.

    Examples
    --------
    >>> t = level_lookup(np.array([0.01, 0.1]))
    >>> v = np.float32(0.05)
    >>> k = min(max((int(np.array(v).view(np.int32)) >> t.shift) - t.base, 0), t.lut.size - 1)
    >>> int(t.lut[k] + (t.cuts[k, 0] <= v) + (t.cuts[k, 1] <= v))
    1
    """
    c32 = np.asarray(level_cuts, dtype=np.float32)
    bits = c32.view(np.int32).astype(np.int64)
    for shift in range(23, -1, -1):
        buckets = bits >> shift
        size = int(buckets[-1] - buckets[0]) + 1
        if size > _LUT_MAX:
            break
        if np.unique(buckets, return_counts=True)[1].max() <= 2:
            base = int(buckets[0])
            lut = np.searchsorted(buckets, np.arange(size) + base, side="left").astype(np.int32)
            # the (up to two) cuts inside each bucket, NaN where none (never <= a level)
            buckets = buckets - base
            inside = np.full((lut.size, 2), np.nan, dtype=np.float32)
            for j in range(2):
                k = lut.astype(np.int64) + j
                ok = k < c32.size
                ok[ok] &= buckets[k[ok]] == np.flatnonzero(ok)
                inside[ok, j] = c32[k[ok]]
            return LevelLookup(lut, int(shift), base, inside)
    raise ConfigError(
        "level cut points are too close together for their range (ratio of neighbouring "
        "cuts below ~1e-5); use fewer levels")
