"""Ridge regression with generalised cross-validation from sufficient statistics.

Model (one class, one output channel): ``y ≈ Z β + β₀`` where ``Z`` (n, p) holds
the patch values and ``β₀`` is an unpenalised intercept. Ridge minimises
``‖y - Zβ - β₀‖² + λ‖β‖²``.

Intercept handling: the intercept is not penalised, which is the same as
centring. With ``μ_z = Zᵀ1/n``, ``μ_y = Σy/n`` and centred
``Z_c = Z - 1μ_zᵀ``, ``y_c = y - μ_y``, everything follows from the
statistics of :class:`l3cli.train.stats.ClassStats` (``S = XᵀX`` with the
constant column last, ``b = Xᵀy``, ``Σy²``)::

    Z_cᵀZ_c = S_zz - n μ_z μ_zᵀ        Z_cᵀy_c = b_z - n μ_z μ_y
    y_cᵀy_c = Σy² - n μ_y²

Eigen-decomposition ``Z_cᵀZ_c = V diag(d) Vᵀ``, ``a = Vᵀ Z_cᵀy_c``. Then

* ``β(λ) = V diag(1/(d + λ)) a``, ``β₀ = μ_y - μ_zᵀβ``;
* ``RSS(λ) = y_cᵀy_c - 2βᵀZ_cᵀy_c + βᵀZ_cᵀZ_cβ
  = y_cᵀy_c - Σᵢ aᵢ² (dᵢ + 2λ)/(dᵢ + λ)²``;
* hat matrix ``H = 11ᵀ/n + Z_c(Z_cᵀZ_c + λI)⁻¹Z_cᵀ``, so
  ``df(λ) = tr H = 1 + Σᵢ dᵢ/(dᵢ + λ)``;
* ``GCV(λ) = n · RSS(λ) / (n - df(λ))²`` (Golub, Heath & Wahba 1979).

λ scaling: the grid is relative, ``λ = λ_rel · tr(Z_cᵀZ_c)/p`` (the mean
eigenvalue), so one grid fits every class whatever its signal level.
Directions with ``dᵢ ≤ 1e-12 · max(d)`` carry no data (``aᵢ`` is rounding
noise there) and are dropped from RSS, df and β.

References
----------
.. [1] G. H. Golub, M. Heath, G. Wahba, "Generalized cross-validation as a
   method for choosing a good ridge parameter", Technometrics 21(2), 215-223
   (1979).
.. [2] T. Hastie, R. Tibshirani, J. Friedman, The Elements of Statistical
   Learning, 2nd ed., Springer (2009), sections 3.4.1 and 7.10.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DEFAULT_LAMBDA_GRID", "RidgeSolution", "centred_stats", "gcv_curve", "solve_ridge",
           "solve_class"]

#: Relative λ grid (times the mean eigenvalue of the centred ZᵀZ).
DEFAULT_LAMBDA_GRID = np.concatenate([np.logspace(-9, 1, 41)])

_RANK_TOL = 1e-12


@dataclass
class RidgeSolution:
    """Result for one class.

    Attributes
    ----------
    kernel
        float64 (p + 1, n_out): patch weights then intercept.
    lam
        float64 (n_out,) chosen λ (absolute).
    lam_rel
        float64 (n_out,) chosen λ relative to the mean eigenvalue.
    gcv
        float64 (n_grid, n_out) GCV curve.
    """

    kernel: np.ndarray
    lam: np.ndarray
    lam_rel: np.ndarray
    gcv: np.ndarray


def centred_stats(n: float, xtx: np.ndarray, xty: np.ndarray, yy: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centred statistics ``(Z_cᵀZ_c, Z_cᵀy_c, y_cᵀy_c, μ_z, μ_y)``; constant column last."""
    p = xtx.shape[0] - 1
    mu_z = xtx[:p, p] / n
    mu_y = xty[p] / n
    zz = xtx[:p, :p] - n * np.outer(mu_z, mu_z)
    zz = 0.5 * (zz + zz.T)
    zy = xty[:p] - n * np.outer(mu_z, mu_y)
    yyc = yy - n * mu_y**2
    return zz, zy, yyc, mu_z, mu_y


def _eigen(zz: np.ndarray, zy: np.ndarray):
    d, V = np.linalg.eigh(zz)
    d = np.clip(d, 0.0, None)
    keep = d > _RANK_TOL * max(float(d.max()), np.finfo(float).tiny)
    a = V.T @ zy
    return d, V, a, keep


def gcv_curve(n: float, xtx: np.ndarray, xty: np.ndarray, yy: np.ndarray,
              lambdas: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GCV, RSS and df over absolute ``lambdas`` from the statistics.

    Returns
    -------
    gcv, rss, df
        (n_lambda, n_out), (n_lambda, n_out), (n_lambda,).
    """
    zz, zy, yyc, _, _ = centred_stats(n, xtx, xty, yy)
    d, _, a, keep = _eigen(zz, zy)
    d, a = d[keep], a[keep]
    lam = np.asarray(lambdas, dtype=np.float64)[:, None]  # (L, 1)
    f = (d[None, :] + 2 * lam) / (d[None, :] + lam) ** 2  # (L, r)
    rss = yyc[None, :] - f @ (a**2)  # (L, n_out)
    rss = np.maximum(rss, 0.0)
    df = 1.0 + (d[None, :] / (d[None, :] + lam)).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        gcv = n * rss / ((n - df)[:, None] ** 2)
    gcv[~np.isfinite(gcv)] = np.inf
    return gcv, rss, df


def solve_ridge(n: float, xtx: np.ndarray, xty: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Affine ridge kernel (p + 1, n_out) for one absolute λ per output."""
    zz, zy, _, mu_z, mu_y = centred_stats(n, xtx, xty, np.zeros(xty.shape[1]))
    d, V, a, keep = _eigen(zz, zy)
    lam = np.broadcast_to(np.asarray(lam, dtype=np.float64), (xty.shape[1],))
    with np.errstate(divide="ignore", invalid="ignore"):
        coef = np.where(keep[:, None], a / (d[:, None] + lam[None, :]), 0.0)
    beta = V @ coef  # (p, n_out)
    beta0 = mu_y - mu_z @ beta
    return np.vstack([beta, beta0[None, :]])


def solve_class(n: float, xtx: np.ndarray, xty: np.ndarray, yy: np.ndarray, *,
                grid: np.ndarray = DEFAULT_LAMBDA_GRID) -> RidgeSolution:
    """Choose λ by GCV over the relative ``grid`` and solve, per output channel."""
    p = xtx.shape[0] - 1
    zz, _, _, _, _ = centred_stats(n, xtx, xty, yy)
    scale = max(float(np.trace(zz)) / p, np.finfo(float).tiny)
    lambdas = np.asarray(grid, dtype=np.float64) * scale
    gcv, _, _ = gcv_curve(n, xtx, xty, yy, lambdas)
    best = np.argmin(gcv, axis=0)  # first minimum: the smallest λ on ties
    lam = lambdas[best]
    kernel = solve_ridge(n, xtx, xty, lam)
    return RidgeSolution(kernel=kernel, lam=lam, lam_rel=np.asarray(grid)[best], gcv=gcv)
