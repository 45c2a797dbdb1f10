"""Smoothness prior over response levels (a weighted smoothing spline).

For one position group, saturation pattern and contrast bin, every kernel
coefficient is a function of the response level. The sensor noise changes
smoothly with the signal, so the ideal kernels do too; the trained ones are
noisy where a level has few samples. This module replaces every coefficient
series ``y_l`` (levels ``l = 0 .. L-1``) by the discrete smoothing spline
(Whittaker-Henderson smoother with divided second differences, [1]_, [2]_)

.. math:: \\hat z = \\arg\\min_z \\sum_l w_l (y_l - z_l)^2
          + \\lambda \\sum_l \\left(\\Delta^2_x z\\right)_l^2,
          \\qquad (W + \\lambda D^\\top D)\\,\\hat z = W y,

over the abscissa ``x_l = ln(level centre)`` (geometric centre of each level
bin; the end bins are placed half a neighbouring bin width beyond the
first/last cut). ``D`` holds the second divided differences on the uneven
grid ``x``, so ``lambda`` does not depend on how many levels there are. The
weights are the class sample counts per coefficient (``n / (S*S + 1)``): a
coefficient's noise variance falls as ``1/n``, so with plentiful data the
fit follows the trained values and with scarce data the penalty dominates.
``lambda -> 0`` interpolates, ``lambda -> infinity`` gives the weighted
straight line in ``ln level``.

One ``lambda`` serves all coefficients of a series (position group,
saturation pattern, contrast bin), chosen by generalised cross-validation
[3]_ over a grid with the residuals of all coefficients pooled
(``strength="auto"``), or given (``strength=FLOAT``). A common ``lambda``
makes the smoothed kernel of each level a fixed linear combination of the
trained kernels with weights summing to one, so every affine property the
trained kernels share (say, that all reproduce grey as grey) survives;
separate ``lambda`` per coefficient would mix taps of different levels in
different proportions and break it.

Empty classes (weight 0) between trained levels are *interpolated* by the same
fit (the minimiser of the roughness through the trained neighbours, a discrete
natural cubic spline). Levels below the lowest / above the highest trained
level are *extrapolated as constants* (the fitted end value), which is safe:
a linear extrapolation of kernel weights in ``ln level`` can run away.

References
----------
.. [1] P. H. C. Eilers, "A perfect smoother", Analytical Chemistry 75(14),
   3631-3636 (2003).
.. [2] E. T. Whittaker, "On a new method of graduation", Proc. Edinburgh Math.
   Soc. 41, 63-75 (1923).
.. [3] P. Craven, G. Wahba, "Smoothing noisy data with spline functions",
   Numerische Mathematik 31, 377-403 (1979).
"""

from __future__ import annotations

import numpy as np

from l3cli import defaults
from l3cli.classify import ClassDefinition
from l3cli.errors import ConfigError

__all__ = ["level_abscissa", "second_difference", "whittaker", "smooth_levels", "smooth_conditions",
           "DEFAULT_STRENGTH",
           "DEFAULT_STRENGTH_GRID"]

#: Default λ (data weights = samples per coefficient, ln-level abscissa):
#: chosen on simulated Bayer data (docs/smoothing.md): it lowers the Macbeth
#: ΔE*ab of tables trained on one small image by ~12 % and costs < 1 % on
#: plentiful data.
DEFAULT_STRENGTH = defaults.SPLINE_STRENGTH
#: λ grid searched by GCV (``strength="auto"``).
DEFAULT_STRENGTH_GRID = np.logspace(-4, 6, 41)


def level_abscissa(definition: ClassDefinition) -> np.ndarray:
    """``ln`` of a representative level of every level bin (increasing).

    Interior bin ``i`` (between cuts ``i-1`` and ``i``) gets the geometric mean
    of its cuts; bin 0 and the last bin are one neighbouring log-width beyond
    the first/last cut (half a width when there is a single cut).
    """
    lc = np.log(np.asarray(definition.level_cuts, dtype=np.float64))
    n = lc.size
    if n == 1:
        return np.array([lc[0] - 0.5, lc[0] + 0.5])
    inner = 0.5 * (lc[:-1] + lc[1:])
    first = lc[0] - 0.5 * (lc[1] - lc[0])
    last = lc[-1] + 0.5 * (lc[-1] - lc[-2])
    return np.concatenate([[first], inner, [last]])


def second_difference(x: np.ndarray) -> np.ndarray:
    """(n-2, n) matrix of second divided differences on the grid ``x``.

    Row ``i`` gives ``2/(x_{i+2}-x_i) [ (z_{i+2}-z_{i+1})/(x_{i+2}-x_{i+1})
    - (z_{i+1}-z_i)/(x_{i+1}-x_i) ]``, which is ``z''`` for a quadratic.
    """
    x = np.asarray(x, dtype=np.float64)
    n = x.size
    d = np.zeros((max(n - 2, 0), n))
    for i in range(n - 2):
        h0 = x[i + 1] - x[i]
        h1 = x[i + 2] - x[i + 1]
        s = 2.0 / (h0 + h1)
        d[i, i] = s / h0
        d[i, i + 1] = -s * (1.0 / h0 + 1.0 / h1)
        d[i, i + 2] = s / h1
    return d


def whittaker(x: np.ndarray, y: np.ndarray, w: np.ndarray, *, strength: float | None = None,
              grid: np.ndarray = DEFAULT_STRENGTH_GRID) -> tuple[np.ndarray, np.ndarray]:
    """Weighted Whittaker smoother of the columns of ``y`` over ``x``.

    Parameters
    ----------
    x
        (n,) increasing abscissa.
    y
        (n, m) data, one series per column.
    w
        (n,) non-negative weights (inverse noise variances, up to one common
        factor that ``strength`` absorbs); with a single positive weight the
        result is the constant through that point.
    strength
        λ for every column; ``None`` picks one λ for all columns by GCV over
        ``grid`` (the residuals of all columns pooled).

    Returns
    -------
    z, lam
        (n, m) smoothed series and (m,) the λ used per column.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    n, m = y.shape
    pos = w > 0
    npos = int(pos.sum())
    if npos == 0:
        raise ConfigError("whittaker: no positive weight")
    if npos == 1:
        z = np.broadcast_to(y[pos][0], (n, m)).copy()
        return z, np.full(m, np.inf)
    wn = w
    d = second_difference(x)
    pen = d.T @ d
    wmat = np.diag(wn)
    wy = wn[:, None] * y
    if strength is not None:
        lam = float(strength)
        z = np.linalg.solve(wmat + lam * pen, wy)
        return z, np.full(m, lam)
    best = np.inf
    lam_best = float(grid[-1])
    for lam in grid:
        a = wmat + lam * pen
        hat = np.linalg.solve(a, wmat)  # H = (W + λP)^{-1} W
        tr = float(np.trace(hat[np.ix_(pos, pos)]))
        if npos - tr < 1e-6:
            continue
        zz = hat @ y
        rss = float((wn[:, None] * (y - zz) ** 2)[pos].sum())
        gcv = npos * rss / (npos - tr) ** 2
        if gcv < best:
            best, lam_best = gcv, float(lam)
    z = np.linalg.solve(wmat + lam_best * pen, wy)
    return z, np.full(m, lam_best)


def smooth_levels(kernels: np.ndarray, weights: np.ndarray, definition: ClassDefinition, *,
                  strength: float | None = None,
                  grid: np.ndarray = DEFAULT_STRENGTH_GRID
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smooth every kernel coefficient over ``ln level``; fill classes without data.

    Parameters
    ----------
    kernels
        (n_classes, S*S + 1, n_out).
    weights
        (n_classes,) sample counts (0 = no data); divided by the number of
        coefficients per output (``S*S + 1``) to give the data term its weight.
    definition
        The class definition (level cuts, class layout).
    strength
        λ; ``None`` = one λ per series by GCV.
    grid
        λ grid for GCV.

    Returns
    -------
    kernels, filled, lam_median
        float64 smoothed kernels; bool (n_classes,) classes that had weight 0
        and received a fitted value; float64 (n_series,) median λ per series
        (NaN where a series had no data and was left alone).
    """
    ng, ns, nl, nc = definition.shape
    q = definition.n_coeffs
    k = np.asarray(kernels, dtype=np.float64).reshape(ng, ns, nl, nc, q, -1)
    w = np.asarray(weights, dtype=np.float64).reshape(ng, ns, nl, nc) / q
    n_out = k.shape[-1]
    x = level_abscissa(definition)
    out = k.copy()
    filled = np.zeros((ng, ns, nl, nc), dtype=bool)
    lam_med = np.full((ng, ns, nc), np.nan)
    for g in range(ng):
        for s in range(ns):
            for c in range(nc):
                ww = w[g, s, :, c]
                have = np.flatnonzero(ww > 0)
                if have.size == 0:
                    continue
                lo, hi = int(have[0]), int(have[-1]) + 1
                y = k[g, s, lo:hi, c].reshape(hi - lo, q * n_out)
                z, lam = whittaker(x[lo:hi], y, ww[lo:hi], strength=strength, grid=grid)
                full = np.empty((nl, q * n_out))
                full[lo:hi] = z
                full[:lo] = z[0]
                full[hi:] = z[-1]
                out[g, s, :, c] = full.reshape(nl, q, n_out)
                filled[g, s, :, c] = ww <= 0
                lam_med[g, s, c] = float(np.median(lam))
    return out.reshape(kernels.shape), filled.ravel(), lam_med.ravel()


def smooth_conditions(values: np.ndarray, kernels: np.ndarray, counts: np.ndarray, n_coeffs: int,
                      *, strength: float | None = None, grid: np.ndarray = DEFAULT_STRENGTH_GRID
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Smooth every class's kernel coefficients over ``ln`` condition value; fill bins.

    The condition axis of a ``--by`` table (:mod:`l3cli.conditions`) is
    treated like the level axis in :func:`smooth_levels`: per class, one
    Whittaker smoother over the bins (abscissa ``ln value``, weights = the
    bin's samples per coefficient), interpolating bins where the class has no
    samples between trained bins. Bins beyond the first/last trained bin of a
    class are left alone (the pooled kernel stands in there at render time):
    on a simulated ISO sweep with one shot per ISO, copying the end bin's
    kernel outwards raised the held-out RMSE from 0.00363 to 0.00451
    (docs/real-camera.md).

    Parameters
    ----------
    values
        (n_bins,) increasing positive condition values.
    kernels
        (n_bins, n_classes, S*S + 1, n_out) per-bin kernels.
    counts
        (n_bins, n_classes) samples per bin and class (0 = not trained there).
    n_coeffs
        ``S*S + 1`` (divides the counts into per-coefficient weights).
    strength
        λ; ``None`` = one λ per class by GCV.
    grid
        λ grid for GCV.

    Returns
    -------
    kernels, filled
        float64 smoothed kernels; bool (n_bins, n_classes) bins that had no
        samples of the class, lie between two that had, and received a fitted
        value.
    """
    x = np.log(np.asarray(values, dtype=np.float64))
    k = np.asarray(kernels, dtype=np.float64)
    nb, ncl = counts.shape
    w = np.asarray(counts, dtype=np.float64) / n_coeffs
    out = k.copy()
    filled = np.zeros((nb, ncl), dtype=bool)
    for c in range(ncl):
        have = np.flatnonzero(w[:, c] > 0)
        if have.size == 0:
            continue
        lo, hi = int(have[0]), int(have[-1]) + 1
        y = k[lo:hi, c].reshape(hi - lo, -1)
        z, _ = whittaker(x[lo:hi], y, w[lo:hi, c], strength=strength, grid=grid)
        out[lo:hi, c] = z.reshape(hi - lo, *k.shape[2:])
        filled[lo:hi, c] = w[lo:hi, c] <= 0
    return out, filled
