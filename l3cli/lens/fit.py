"""Learning a lens-shading gain field from training pairs' blocks (:mod:`l3cli.lens.field`).

The pairs are cut into blocks (:func:`block_samples`); each block's per-channel
raw means ``m`` and its target's linear means ``t`` should follow
``t = M_i (g(v, u) m)`` with one colour matrix ``M_i`` per image (it absorbs
each render's white balance and the field's per-channel scale). Two kinds of
field are fitted:

* radial (:class:`l3cli.lens.field.GainField`): a polynomial in r² per colour
  about one optical centre; the matrices are solved inside a trust-region
  least-squares fit of the coefficients and the centre (variable projection);
* spline grid (:class:`l3cli.lens.grid.SplineField`): a smooth surface per
  colour, matrices and control values solved in turn
  (:func:`l3cli.lens.grid.fit_spline`).

:func:`fit_field` scores every candidate (:func:`models`) on held-out blocks
(:func:`heldout_folds`: each image held out in turn, or the spatial folds of a
single image), keeps the least complex within 0.2 % of the best, and keeps no
field unless it predicts held-out blocks better than none, so unshaded cameras
train as before.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from l3cli.errors import TableError
from l3cli.lens.field import SHADING_RULE, GainField, normalised_coords
from l3cli.lens.grid import (
    SPLINE_RULE,
    SplineField,
    block_weights,
    fit_spline,
    frame_extent,
    spline_basis,
)

__all__ = ["BlockSamples", "block_samples", "fit_field", "models", "heldout_folds",
           "spatial_folds", "ORDERS", "SPLINE_INTERVALS"]

#: Polynomial orders tried (powers of r^2 beyond the constant) and spline grids
#: (:mod:`l3cli.lens.grid`, intervals along the sensor's longer side): the least
#: complex that predicts held-out blocks within CHOICE_TOLERANCE of the best is kept
#: (:func:`fit_field`).
ORDERS = (2, 3)
SPLINE_INTERVALS = (2, 3, 4, 6)
#: The block residual is mostly what the block model cannot follow (the pipeline's
#: non-linear steps), the same for every field, so a field closer to the truth by a third
#: lowers it by well under 1 % (the stand-in camera, docs/training.md): 0.2 %.
CHOICE_TOLERANCE = 0.002
#: Side (pixels) of the neighbourhood over which a block's colour variation is measured
#: (:func:`block_samples`' ``context``; :func:`l3cli.lens.grid.block_weights`): twice a
#: wide noise reduction's reach (65 did no better on the stand-in camera).
CONTEXT = 33
#: Spatial folds of a single image (:func:`spatial_folds`): tiles per side, each held out.
#: The model is chosen on 3 x 3 tiles: on quadrants (2 x 2) every fold was an extrapolation
#: into a quarter of the frame, which a spline grid does poorly and a radial field well, so
#: one shot kept the radial field, which cannot follow colours about different centres
#: (issue 41, stand-in camera, exact tone inverse, Outdoor1_crop and Indoor1_crop: radial
#: r^4, 1.4 / 3.1 / 4.5 % and 2.6 / 1.9 / 6.3 % G / R / B; on 3 x 3 tiles the 2 x 2 grid,
#: 0.57 / 0.93 / 0.80 % and 0.20 / 0.18 / 0.89 %). Whether the chosen field is kept at all
#: is checked on quadrants (CHECK_TILES): on 3 x 3 tiles the unshaded bundled
#: Outdoor1_crop kept a spurious field (0.92x the held-out residual of none, corner gains
#: up to 1.25), and the tuner, starting from it, chose a table 2x worse on the holdout.
TILES = 3
CHECK_TILES = 2


@dataclass
class BlockSamples:
    """One image's blocks: normalised centres, per-channel raw means, target means, and the
    render's local contrast and neighbourhood colour variation (None: every block weighs
    alike; :func:`block_samples`)."""

    v: np.ndarray  # float64 (n,)
    u: np.ndarray  # float64 (n,)
    raw: np.ndarray  # float64 (n, n_channels)
    target: np.ndarray  # float64 (n, 3) linear
    texture: np.ndarray | None = None  # float64 (n,)
    context: np.ndarray | None = None  # float64 (n,)


def block_samples(mosaic: np.ndarray, cfa: Any, target: np.ndarray, mask: np.ndarray | None,
                  *, full_shape: tuple[int, int], origin: tuple[int, int] = (0, 0),
                  saturation: float = 0.95, block: int = 16,
                  floor: float = 0.01) -> BlockSamples:
    """Block means of one pair for :func:`fit_field`.

    Blocks (``block`` pixels, a whole number of CFA periods) count when every
    pixel may train (``mask``), no raw pixel reaches 0.9 x ``saturation`` and
    every channel's mean is above ``floor``. A block's ``texture`` is the mean over
    its pixels of the target's local contrast (the standard deviation of the mean of
    its channels over 3 x 3 pixels, over their mean + 0.02), which
    :func:`l3cli.lens.grid.block_weights` weighs by.
    """
    from scipy.ndimage import uniform_filter

    ph, pw = cfa.period
    by = max(ph, block // ph * ph)
    bx = max(pw, block // pw * pw)
    h, w = mosaic.shape
    ny, nx = h // by, w // bx
    hh, ww = ny * by, nx * bx
    m = np.asarray(mosaic[:hh, :ww], dtype=np.float64).reshape(ny, by, nx, bx)
    chans = list(dict.fromkeys(cfa.channels))
    pos = (np.arange(by)[:, None] % ph) * pw + np.arange(bx)[None, :] % pw
    cidx = np.array([chans.index(cfa.channel_at(p // pw, p % pw)) for p in range(ph * pw)])[pos]
    means = np.stack([(m * (cidx == c)[None, :, None, :]).sum(axis=(1, 3)) / (cidx == c).sum()
                      for c in range(len(chans))], axis=-1)  # (ny, nx, n_ch)
    t = np.asarray(target[:hh, :ww], dtype=np.float64).reshape(ny, by, nx, bx, -1).mean(axis=(1, 3))
    y = np.asarray(target[:hh, :ww], dtype=np.float64).mean(axis=-1)
    y = np.where(np.isfinite(y), y, 0.0)
    mu = uniform_filter(y, 3, mode="reflect")
    sd = np.sqrt(np.maximum(uniform_filter(y * y, 3, mode="reflect") - mu * mu, 0.0))
    texture = (sd / (np.abs(mu) + 0.02)).reshape(ny, by, nx, bx).mean(axis=(1, 3))
    context = _context(np.asarray(target[:hh, :ww], dtype=np.float64)).reshape(
        ny, by, nx, bx).mean(axis=(1, 3))
    ok = m.max(axis=(1, 3)) < 0.9 * saturation
    ok &= np.all(means > floor, axis=-1) & np.all(np.isfinite(t), axis=-1)
    if mask is not None:
        ok &= np.asarray(mask[:hh, :ww]).reshape(ny, by, nx, bx).all(axis=(1, 3))
    v, u = normalised_coords(*full_shape)
    y0, x0 = origin
    vc = v[y0:y0 + hh].reshape(ny, by).mean(axis=1)
    uc = u[x0:x0 + ww].reshape(nx, bx).mean(axis=1)
    vv, uu = np.meshgrid(vc, uc, indexing="ij")
    return BlockSamples(vv[ok], uu[ok], means[ok], t[ok], texture[ok], context[ok])


def _context(target: np.ndarray) -> np.ndarray:
    """Each pixel's colour variation over its neighbourhood (:data:`CONTEXT` pixels a side):
    per channel the standard deviation over the mean + 0.02, the largest of the channels."""
    from scipy.ndimage import uniform_filter

    t = np.where(np.isfinite(target), target, 0.0)
    size = (CONTEXT, CONTEXT, 1)
    mu = uniform_filter(t, size, mode="reflect")
    sd = np.sqrt(np.maximum(uniform_filter(t * t, size, mode="reflect") - mu * mu, 0.0))
    return (sd / (np.abs(mu) + 0.02)).max(axis=-1)


def _design(s: BlockSamples, centre: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Powers r^2 .. r^(2 order) of the blocks (n, order) and their residual weights (n,)."""
    r2 = (s.v - centre[0]) ** 2 + (s.u - centre[1]) ** 2
    powers = np.stack([r2 ** (k + 1) for k in range(order)], axis=1)
    return powers, block_weights(s)


def _projected(samples: Sequence[BlockSamples], centre: np.ndarray, a: np.ndarray
               ) -> np.ndarray:
    """Weighted residuals of every image with its own best matrix for the field
    ``(centre, a)`` (variable projection: the matrices are solved, not searched)."""
    out = []
    for s in samples:
        powers, wt = _design(s, centre, a.shape[1])
        z = s.raw * (1.0 + powers @ a.T) * wt[:, None]
        y = s.target * wt[:, None]
        mt, *_ = np.linalg.lstsq(z, y, rcond=None)
        out.append((y - z @ mt).ravel())
    return np.concatenate(out)


def _fit_samples(samples: Sequence[BlockSamples], order: int
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """Least squares (trust region) over the centre and the gain coefficients
    (n_ch, order) of r^2 .. r^(2 order) (constant 1), each image's matrix solved
    inside; returns the coefficients, the centre and the weighted sum of squares."""
    from scipy.optimize import least_squares

    n_ch = samples[0].raw.shape[1]

    def residuals(x):
        return _projected(samples, x[:2], x[2:].reshape(n_ch, order))

    x0 = np.zeros(2 + n_ch * order)
    lo, hi = np.full(x0.size, -np.inf), np.full(x0.size, np.inf)
    lo[:2], hi[:2] = -0.5, 0.5
    res = least_squares(residuals, x0, bounds=(lo, hi), method="trf", x_scale=1.0,
                        xtol=1e-8, ftol=1e-10, max_nfev=60)
    return res.x[2:].reshape(n_ch, order), res.x[:2].copy(), float(2 * res.cost)


def _intervals(n: int, size: tuple[int, int]) -> tuple[int, int]:
    """Spline intervals (rows, columns): ``n`` along the longer side, in proportion on the other."""
    h, w = size
    long = max(h, w)
    return max(1, round(n * h / long)), max(1, round(n * w / long))


def _fit_model(model: tuple, samples: Sequence[BlockSamples], size: tuple[int, int]
               ) -> tuple[Callable[[BlockSamples], np.ndarray], tuple]:
    """Fit a model (``("radial", order)`` or ``("spline", n)``) to the samples: the function
    that gives any blocks' gains (n, n_ch), and the fitted parameters."""
    kind, n = model
    if kind == "radial":
        a, centre, _ = _fit_samples(samples, n)
        return (lambda s: 1.0 + _design(s, centre, n)[0] @ a.T), (a, centre)
    iv = _intervals(n, size)
    ctrl, _ = fit_spline(samples, size, iv)
    flat = ctrl.reshape(ctrl.shape[0], -1)
    return (lambda s: spline_basis(s, size, *iv) @ flat.T), (ctrl,)


def _gain_sse(s: BlockSamples, g: np.ndarray | None) -> float:
    """Weighted SSE of blocks with gains ``g`` (None: no field), their matrix fitted."""
    wt = block_weights(s)
    z = (s.raw if g is None else s.raw * g) * wt[:, None]
    y = s.target * wt[:, None]
    mt, *_ = np.linalg.lstsq(z, y, rcond=None)
    return float(np.sum((z @ mt - y) ** 2))


def _subset(s: BlockSamples, keep: np.ndarray) -> BlockSamples:
    return BlockSamples(s.v[keep], s.u[keep], s.raw[keep], s.target[keep],
                        None if s.texture is None else s.texture[keep],
                        None if s.context is None else s.context[keep])


def spatial_folds(s: BlockSamples, tiles: int | None = None) -> list[np.ndarray]:
    """Held-out blocks (bool masks) of the spatial folds of one image: its blocks fall in
    ``tiles`` x ``tiles`` tiles over their extent (:data:`TILES` by default), each held out
    in turn. Large contiguous tiles, so that the scene does not carry over: a field
    fitted on interleaved small tiles learns the scene's own brightness across the
    frame from their neighbours (measured: a field was "kept" on unshaded single shots),
    whereas a lens's fall-off carries over to a whole held-out tile."""
    tiles = TILES if tiles is None else tiles

    def tile(x: np.ndarray) -> np.ndarray:
        lo, hi = float(x.min()), float(x.max())
        return np.minimum((tiles * (x - lo) / max(hi - lo, 1e-12)).astype(int), tiles - 1)

    t = tile(s.v) * tiles + tile(s.u)
    return [t == f for f in range(tiles * tiles)]


def heldout_folds(samples: Sequence[BlockSamples], tiles: int | None = None
                  ) -> list[tuple[list[BlockSamples], list[BlockSamples]]]:
    """(training, held-out) block samples of every fold: each image held out in turn when
    there are several, else the spatial folds of the one image (:func:`spatial_folds`,
    ``tiles`` a side)."""
    if len(samples) > 1:
        return [(list(samples[:i]) + list(samples[i + 1:]), [s]) for i, s in enumerate(samples)]
    s = samples[0]
    return [([_subset(s, ~m)], [_subset(s, m)]) for m in spatial_folds(s, tiles)]


def _scores(samples: Sequence[BlockSamples], model: tuple, size: tuple[int, int],
            n_blocks: int, tiles: int | None = None) -> tuple[float, float]:
    """Held-out RMS block residual with a field of ``model`` and without one (each fold's
    held-out blocks by the field of its training blocks, their matrix refitted)."""
    with_f = without = 0.0
    for train, test in heldout_folds(samples, tiles):
        gains, _ = _fit_model(model, train, size)
        with_f += sum(_gain_sse(t, gains(t)) for t in test)
        without += sum(_gain_sse(t, None) for t in test)
    return float(np.sqrt(with_f / (3 * n_blocks))), float(np.sqrt(without / (3 * n_blocks)))


def models(orders: Sequence[int] = ORDERS, intervals: Sequence[int] = SPLINE_INTERVALS
           ) -> list[tuple]:
    """The candidate fields, least complex first: radial orders, then spline grids."""
    return [("radial", o) for o in orders] + [("spline", n) for n in intervals]


def fit_field(samples: Sequence[BlockSamples], cfa: Any, size: tuple[int, int], *,
              orders: Sequence[int] = ORDERS, intervals: Sequence[int] = SPLINE_INTERVALS,
              min_gain: float = 0.02) -> tuple[GainField | SplineField | None, dict]:
    """Learn a gain field from the block samples of the training pairs.

    Each candidate (:func:`models`: radial polynomials of ``orders``, spline grids of
    ``intervals``) is scored on held-out blocks (:func:`heldout_folds`: other images,
    or the spatial folds of a single image, :data:`TILES` a side); the least complex within
    0.2 % of the best score is fitted to all the blocks, where it predicts held-out blocks
    better than none (a single image: on its quadrants, :data:`CHECK_TILES`).

    Returns
    -------
    field, record
        The field (None when it does not predict held-out blocks better than no
        field by 2 %, or the samples are too few), and a JSON record of the fit
        (``heldout_rms`` with and without the field, ``reason`` when none).
    """
    samples = [s for s in samples if s.raw.shape[0] >= 8 * (max(orders, default=0) + 3)]
    record: dict[str, Any] = {"rule": SHADING_RULE, "images": len(samples)}
    if len(samples) == 1 and samples[0].raw.shape[0] < 64:
        samples = []
    if not samples:
        record["reason"] = "too few unclipped blocks"
        return None, record
    n_blocks = sum(s.raw.shape[0] for s in samples)
    cands = models(orders, intervals)
    scores = {m: _scores(samples, m, size, n_blocks) for m in cands}
    best = min(v[0] for v in scores.values())
    model = next(m for m in cands if scores[m][0] <= (1 + CHOICE_TOLERANCE) * best)
    with_f, without = scores[model]
    if len(samples) == 1:  # kept only where it carries over to whole quadrants (CHECK_TILES)
        with_f, without = _scores(samples, model, size, n_blocks, CHECK_TILES)
    record.update({"heldout_rms": with_f, "none_heldout_rms": without,
                   "folds": "images" if len(samples) > 1 else "spatial",
                   "model": f"{model[0]} {model[1]}",
                   "model_heldout_rms": {f"{m[0]} {m[1]}": v[0] for m, v in scores.items()}})
    if model[0] == "radial":
        record["order"] = model[1]
    else:
        record["rule"] = SPLINE_RULE
    if not with_f < 0.98 * without:
        record["reason"] = "no better than no correction on held-out blocks"
        return None, record
    _, params = _fit_model(model, samples, size)
    chans = list(dict.fromkeys(cfa.channels))
    ph, pw = cfa.period
    chan_of = [chans.index(cfa.channel_at(y, x)) for y in range(ph) for x in range(pw)]
    try:
        if model[0] == "radial":
            a, centre = params
            raw_field: GainField | SplineField = GainField(
                centre, np.array([np.concatenate([[1.0], a[c]]) for c in chan_of]), size)
        else:
            raw_field = SplineField(params[0][chan_of], size)
    except TableError as exc:  # not usable over the whole sensor of any raw: dropped
        record.update(reason=f"the fitted field is not usable ({exc})", unusable=True)
        return None, record
    # scale so the smallest gain over the training area is 1
    vh, uh = frame_extent(*size)
    v = np.linspace(-vh, vh, 129)
    u = np.linspace(-uh, uh, 129)
    planes = np.stack([raw_field.plane(v, u, p) for p in range(ph * pw)])
    if planes.min() <= min_gain * planes.max():
        record["reason"] = "the fitted gains are not positive over the sensor"
        return None, record
    lo = float(planes.min())
    try:  # usable over the whole sensor of any raw, as a table that loads must be
        if model[0] == "radial":  # the least gain over the radii the sensor spans
            v, u = normalised_coords(*size)
            r2max = float(np.max((v[[0, 0, -1, -1]] - raw_field.centre[0]) ** 2
                                 + (u[[0, -1, 0, -1]] - raw_field.centre[1]) ** 2))
            lo = min(lo, float(raw_field.gains(np.linspace(0.0, r2max, 513)).min()))
            field: GainField | SplineField = GainField(raw_field.centre,
                                                       raw_field.coeffs / lo, size)
            record.update(centre=field.centre.tolist(), coeffs=field.coeffs.tolist())
        else:
            field = SplineField(raw_field.grid / lo, size)
            record.update(intervals=list(field.intervals))
    except TableError as exc:
        record.update(reason=f"the fitted field is not usable ({exc})", unusable=True)
        return None, record
    record.update(size=list(size), blocks=int(n_blocks))
    return field, record


