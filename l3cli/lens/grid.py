"""A lens-shading gain field as a smooth 2-D spline grid per CFA position (issue 41).

The radial field of :mod:`l3cli.lens.field` (a polynomial in r² about one optical
centre) cannot follow colour shading whose channels fall off about different
centres, or not radially (elliptical fall-off, a tilted lens, microlens
shifts): on a red fall-off to 0.5 in the far corner it misses by several
percent. :class:`SplineField` gives every CFA position its own smooth surface
over the sensor, as a DNG ``GainMap`` does per plane: a uniform cubic B-spline
on a grid of control values (``grid[p]``, (ny + 3) x (nx + 3) for ny x nx
intervals over the full raw), in the normalised coordinates of
:func:`l3cli.lens.field.normalised_coords` (a raw of another size: the same
frame-relative positions, clamped at the frame's edges).

Learning (:func:`fit_spline`): the block model of :mod:`l3cli.lens.field`,
``t = M_i (g(v, u) m)`` (``m`` a block's per-channel raw means, ``t`` its
target's linear means, ``M_i`` one 3x3 matrix per image), is bilinear in the
matrices and the control values, so both are solved in turn, each step a
linear least-squares solve (the control values with a small second-difference
penalty that keeps the surface smooth where blocks are few), until the
residual stops falling. The number of intervals is chosen by held-out error in
:func:`l3cli.lens.fit.fit_field`.

This module imports nothing of l3 but the errors: :mod:`l3cli.lens.field` (table
keys, gain maps) and :mod:`l3cli.lens.fit` (the choice of model) build on it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from l3cli.errors import TableError

#: Intervals of a spline grid on an axis at most (l3 fits up to 6).
MAX_INTERVALS = 64
#: Sensor side in pixels at most (a stored field's ``shading_size``, either kind).
MAX_SIZE = 1 << 20


def sensor_size(size: np.ndarray) -> tuple[int, int]:
    """A table's ``shading_size`` as ``(height, width)``, either field kind's.

    Raises
    ------
    TableError
        Not two whole numbers from 1 to :data:`MAX_SIZE`.
    """
    size = np.asarray(size)
    if size.shape != (2,):
        raise TableError(f"shading_size has shape {size.shape}, expected (2,)")
    f = size.astype(np.float64)
    if not (np.all(np.isfinite(f)) and np.all(f == np.round(f)) and np.all(f >= 1)
            and np.all(f <= MAX_SIZE)):
        raise TableError(f"shading_size {size.tolist()} is not a sensor size (whole "
                         f"numbers, 1 .. {MAX_SIZE} pixels a side)")
    return int(f[0]), int(f[1])

__all__ = ["SPLINE_RULE", "SplineField", "block_weights", "bspline_weights", "bspline_matrix",
           "fit_spline", "frame_extent", "spline_basis"]

#: Name of the spline-grid rule recorded in tables (``shading_rule``).
SPLINE_RULE = "spline-grid-v1"
#: Relative penalty of the control values' second differences (times the mean diagonal of
#: the normal equations): smooths where blocks are few, negligible where they are many.
#: 1e-3 flattened a 2 x 3 grid's corners by 0.1-0.3 % on the stand-in camera (issue 41;
#: the truth's own best 2 x 3 fit is within 0.03 %): 1e-4.
SMOOTHNESS = 1e-4
#: Local contrast of a block's render (:func:`l3cli.lens.fit.block_samples`) at which its
#: weight falls to 1/sqrt(2) (:func:`block_weights`): the block model holds where the render
#: is flat; on texture a camera's non-linear steps (noise reduction and sharpening on the
#: display-encoded image, clipping) move a block's mean, by an amount that follows the scene
#: across the frame and so bends the field (issue 41: R and B 0.6 % off on the stand-in
#: camera with all blocks alike, 0.3-0.4 % with this weight).
TEXTURE_SCALE = 0.015
#: Colour variation of a block's neighbourhood (:func:`l3cli.lens.fit.block_samples`'
#: ``context``: per channel the standard deviation over the mean, 33 x 33 pixels) at which
#: its weight falls to 1/sqrt(2) (:func:`block_weights`): a camera's noise reduction on the
#: display-encoded image (the stand-in's guided filter, radius 8, guided by the luminance)
#: mixes a block's colour with its neighbours' non-linearly, more where they differ; the
#: local contrast of the render (``texture``, 3 x 3 pixels of the denoised luminance) does
#: not see it. Issue 41, stand-in camera, exact tone inverse: the top-to-bottom bias of
#: the block model on Outdoor1_crop (true field) from +1.2 / -0.25 % (R) to +0.2 / -0.2 %,
#: the three-shot field from 0.19 / 0.23 / 0.44 % (G / R / B) to 0.15 / 0.17 / 0.36 %
#: (0.2: 0.17 / 0.21 / 0.35; 0.05: 0.14 / 0.15 / 0.37).
CONTEXT_SCALE = 0.1
#: Alternations of matrices and control values at most, and the relative fall of the
#: residual below which they stop.
MAX_ALTERNATIONS, TOLERANCE = 200, 1e-7
#: Robust rounds: the blocks reweighted by Huber's rule (residuals beyond HUBER robust
#: standard deviations count linearly) so that blocks the block model cannot follow
#: (clipped colours, edges the pipeline treats non-linearly) do not bend the field.
ROBUST_ROUNDS, HUBER = 2, 2.0


def frame_extent(height: int, width: int) -> tuple[float, float]:
    """Half extents ``(vh, uh)`` of a raw's frame in normalised coordinates (the frame
    covers ``[-vh, vh] x [-uh, uh]``; its half-diagonal is 1)."""
    half = 0.5 * float(np.hypot(height, width))
    return 0.5 * height / half, 0.5 * width / half


def bspline_weights(x: np.ndarray, lo: float, hi: float, n: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Uniform cubic B-spline on ``n`` intervals over ``[lo, hi]`` (``x`` clamped to it):
    each position's first control index (int (len,)) and its four weights (len, 4)."""
    s = (np.clip(np.asarray(x, dtype=np.float64), lo, hi) - lo) / (hi - lo) * n
    i = np.minimum(np.floor(s).astype(np.int64), n - 1)
    f = s - i
    f2, f3 = f * f, f * f * f
    w = np.stack([(1 - f) ** 3, 3 * f3 - 6 * f2 + 4, -3 * f3 + 3 * f2 + 3 * f + 1, f3],
                 axis=-1) / 6.0
    return i, w


def bspline_matrix(x: np.ndarray, lo: float, hi: float, n: int) -> np.ndarray:
    """The basis of :func:`bspline_weights` as a matrix (len(x), n + 3)."""
    i, w = bspline_weights(x, lo, hi, n)
    out = np.zeros((i.size, n + 3))
    rows = np.arange(i.size)
    for k in range(4):
        out[rows, i + k] = w[:, k]
    return out


@dataclass(eq=False)
class SplineField:
    """Per CFA position a cubic B-spline surface of gains (see the module notes).

    Attributes
    ----------
    grid
        float64 (n_positions, ny + 3, nx + 3): the control values.
    size
        ``(height, width)`` of the training raws (the frame the grid spans).
    """

    #: Not a radial field (:attr:`l3cli.lens.field.GainField.radial`): the tile kernel reads
    #: its gain map in the band copy (:mod:`l3cli.lens.gainmaps`); the export evaluates it
    #: in the graph (:func:`l3cli.export.stages.shading`).
    radial = False

    grid: np.ndarray
    size: tuple[int, int]

    def __post_init__(self) -> None:
        self.grid = np.asarray(self.grid, dtype=np.float64)
        self.size = (int(self.size[0]), int(self.size[1]))
        problem = self._problem()
        if problem:
            raise TableError(f"bad shading gain field: {problem}")

    @property
    def n_positions(self) -> int:
        return int(self.grid.shape[0])

    @property
    def intervals(self) -> tuple[int, int]:
        return int(self.grid.shape[1]) - 3, int(self.grid.shape[2]) - 3

    def _problem(self) -> str | None:
        from l3cli.io.dng_opcodes import GAIN_RANGE

        if self.grid.ndim != 3 or min(self.grid.shape[1:]) < 4:
            return (f"shading_grid {self.grid.shape} has the wrong shape (n_positions, >= 4, "
                    ">= 4)")
        if max(self.grid.shape[1:]) > MAX_INTERVALS + 3:
            return (f"shading_grid {self.grid.shape}: more than {MAX_INTERVALS} intervals "
                    "on an axis")
        if not np.all(np.isfinite(self.grid)):
            return "shading_grid holds NaN or Inf"
        if min(self.size) < 1 or max(self.size) > MAX_SIZE:
            return f"shading_size {self.size} is not a sensor size (1 .. {MAX_SIZE} pixels a side)"
        # a B-spline lies within the hull of its control values (its basis is non-negative
        # and sums to one): controls within the range a gain may take keep every gain there
        lo, hi = float(self.grid.min()), float(self.grid.max())
        if hi > GAIN_RANGE[1] or (lo > 0 and lo < GAIN_RANGE[0]):
            return (f"shading_grid: gains from {lo:.3g} to {hi:.3g}, outside the "
                    f"{GAIN_RANGE[0]:g} .. {GAIN_RANGE[1]:g} a gain field may give")
        # positive controls suffice for positive gains; otherwise check the surface itself
        # on a fine lattice
        if not np.all(self.grid > 0):
            vh, uh = frame_extent(*self.size)
            ny, nx = self.intervals
            v = np.linspace(-vh, vh, 8 * ny + 1)
            u = np.linspace(-uh, uh, 8 * nx + 1)
            if not all(np.all(self.plane(v, u, p) > 0) for p in range(self.n_positions)):
                return "gains are not positive over the sensor"
        return None

    def plane(self, v: np.ndarray, u: np.ndarray, p: int) -> np.ndarray:
        """Gains (len(v), len(u)) of position ``p`` on the lattice of rows ``v`` and
        columns ``u`` (normalised coordinates of a raw of the training size)."""
        vh, uh = frame_extent(*self.size)
        ny, nx = self.intervals
        return bspline_matrix(v, -vh, vh, ny) @ self.grid[p] @ bspline_matrix(u, -uh, uh, nx).T

    def values(self, v: np.ndarray, u: np.ndarray, p: np.ndarray | int) -> np.ndarray:
        """Gains at the points ``(v[k], u[k])`` of positions ``p[k]`` (broadcast)."""
        v, u, p = np.broadcast_arrays(np.asarray(v, float), np.asarray(u, float),
                                      np.asarray(p, np.int64))
        vh, uh = frame_extent(*self.size)
        ny, nx = self.intervals
        iv, wv = bspline_weights(v.ravel(), -vh, vh, ny)
        iu, wu = bspline_weights(u.ravel(), -uh, uh, nx)
        pp = p.ravel()
        out = np.zeros(v.size)
        for a in range(4):
            for b in range(4):
                out += wv[:, a] * wu[:, b] * self.grid[pp, iv + a, iu + b]
        return out.reshape(v.shape)

    def summary(self) -> dict[str, Any]:
        """What ``l3 inspect`` shows: the rule, the grid's intervals, the size, and each
        position's gain in the farthest-corrected corner over its gain at the centre."""
        vh, uh = frame_extent(*self.size)
        corners = [self.plane(np.array([sv * vh]), np.array([su * uh]), p)[0, 0]
                   for p in range(self.n_positions) for sv in (-1, 1) for su in (-1, 1)]
        centre = [self.plane(np.zeros(1), np.zeros(1), p)[0, 0] for p in range(self.n_positions)]
        ratio = np.array(corners).reshape(self.n_positions, 4).max(axis=1) / np.array(centre)
        return {"rule": SPLINE_RULE, "intervals": list(self.intervals), "size": list(self.size),
                "max_corner_gain": ratio.round(4).tolist()}

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The table keys (``shading_*``)."""
        return {"shading_rule": np.array(SPLINE_RULE), "shading_grid": self.grid.copy(),
                "shading_size": np.array(self.size, dtype=np.int64)}

    @classmethod
    def from_arrays(cls, arrs: dict[str, np.ndarray], n_positions: int) -> SplineField:
        """The field of a table whose ``shading_rule`` is :data:`SPLINE_RULE`."""
        for k in ("shading_grid", "shading_size"):
            if k not in arrs:
                raise TableError(f"damaged table, missing key {k}")
            if arrs[k].dtype.kind not in ("f", "i", "u"):
                raise TableError(f"key {k!r} has dtype {arrs[k].dtype}, expected numbers")
        grid, size = arrs["shading_grid"], arrs["shading_size"]
        if grid.ndim != 3 or grid.shape[0] != n_positions:
            raise TableError(f"shading_grid has shape {grid.shape}, the CFA needs "
                             f"({n_positions}, ny, nx)")
        return cls(grid, sensor_size(size))

    def key(self) -> bytes:
        """Bytes that identify the field (the gain-map cache's key)."""
        return b"spline" + self.grid.tobytes() + np.array(self.size).tobytes()


# ------------------------------------------------------------------- learning
def _second_differences(n: int) -> np.ndarray:
    d = np.zeros((max(n - 2, 0), n))
    for i in range(n - 2):
        d[i, i:i + 3] = (1.0, -2.0, 1.0)
    return d


def _penalty(ny: int, nx: int) -> np.ndarray:
    """Second differences of a (ny + 3) x (nx + 3) control grid along both axes (DᵀD)."""
    dv = np.kron(_second_differences(ny + 3), np.eye(nx + 3))
    du = np.kron(np.eye(ny + 3), _second_differences(nx + 3))
    return dv.T @ dv + du.T @ du


def spline_basis(s: Any, size: tuple[int, int], ny: int, nx: int) -> np.ndarray:
    """Tensor B-spline basis of the blocks' centres (n, (ny + 3)(nx + 3))."""
    vh, uh = frame_extent(*size)
    bv = bspline_matrix(s.v, -vh, vh, ny)
    bu = bspline_matrix(s.u, -uh, uh, nx)
    return (bv[:, :, None] * bu[:, None, :]).reshape(len(s.v), -1)


def block_weights(s: Any) -> np.ndarray:
    """Residual weights (n,) of block samples (:class:`l3cli.lens.fit.BlockSamples`), the
    one rule of every shading fit: relative residuals (one over the target's mean, plus
    0.05 for dark blocks), times ``1 / sqrt(1 + (texture / TEXTURE_SCALE)^2)`` where the
    blocks know their render's local contrast (``texture``) and
    ``1 / sqrt(1 + (context / CONTEXT_SCALE)^2)`` where they know their neighbourhood's
    colour variation (``context``)."""
    w = 1.0 / (s.target.mean(axis=1) + 0.05)
    texture = getattr(s, "texture", None)
    if texture is not None:
        w = w / np.sqrt(1.0 + (np.asarray(texture) / TEXTURE_SCALE) ** 2)
    context = getattr(s, "context", None)
    if context is not None:
        w = w / np.sqrt(1.0 + (np.asarray(context) / CONTEXT_SCALE) ** 2)
    return w


def _matrix(z: np.ndarray, t: np.ndarray, wt: np.ndarray) -> np.ndarray:
    m, *_ = np.linalg.lstsq(z * wt[:, None], t * wt[:, None], rcond=None)
    return m


def fit_spline(samples: Sequence[Any], size: tuple[int, int], intervals: tuple[int, int]
               ) -> tuple[np.ndarray, float]:
    """Control values per channel (n_ch, ny + 3, nx + 3) fitted to block samples
    (:class:`l3cli.lens.fit.BlockSamples`), and the weighted sum of squares.

    With the matrices fixed, the normal equations of the control values are
    sums over blocks that do not depend on the matrices but through ``M Mᵀ``
    and ``M``: ``Bᵀ diag(w² m_c m_c') B`` and ``Bᵀ (w² m_c t_o)`` are summed once
    per image, so an alternation costs one small solve. The gauge (a channel's
    scale goes into the matrices) is fixed by a mean gain of one per channel
    over the blocks.
    """
    ny, nx = intervals
    n_ch = samples[0].raw.shape[1]
    k = (ny + 3) * (nx + 3)
    bases = [spline_basis(s, size, ny, nx) for s in samples]
    base_w = [block_weights(s) for s in samples]
    wts = list(base_w)
    pen = np.kron(np.eye(n_ch), _penalty(ny, nx))
    a = np.ones((n_ch, k))
    sse = np.inf
    for rnd in range(ROBUST_ROUNDS + 1):
        prods, rhs = [], []
        for s, b, w in zip(samples, bases, wts, strict=True):
            w2 = w * w
            prods.append(np.stack([np.stack([(b * (w2 * s.raw[:, c] * s.raw[:, d])[:, None]).T
                                             @ b for d in range(n_ch)]) for c in range(n_ch)]))
            rhs.append(np.einsum("nk,nc,no->cok", b, s.raw * w2[:, None], s.target))
        prev = np.inf
        for _ in range(MAX_ALTERNATIONS):
            gains = [b @ a.T for b in bases]
            mats = [_matrix(s.raw * g, s.target, w)
                    for s, g, w in zip(samples, gains, wts, strict=True)]
            sse = sum(float(np.sum((((s.raw * g) @ m - s.target) * w[:, None]) ** 2))
                      for s, g, w, m in zip(samples, gains, wts, mats, strict=True))
            if np.isfinite(prev) and prev - sse <= TOLERANCE * prev:
                break
            prev = sse
            ata = np.zeros((n_ch, k, n_ch, k))
            atb = np.zeros((n_ch, k))
            for p, r, m in zip(prods, rhs, mats, strict=True):
                mm = m @ m.T  # (n_ch, n_ch): sum over outputs of M[c, o] M[c', o]
                ata += (mm[:, :, None, None] * p).transpose(0, 2, 1, 3)
                atb += np.einsum("co,cok->ck", m, r)
            ata = ata.reshape(n_ch * k, n_ch * k)
            ata += SMOOTHNESS * float(np.mean(np.diag(ata))) * pen
            a = np.linalg.solve(ata, atb.ravel()).reshape(n_ch, k)
            a /= np.concatenate([b @ a.T for b in bases]).mean(axis=0)[:, None]
        if rnd < ROBUST_ROUNDS:  # Huber weights of the blocks from their residuals
            res = [np.sqrt(np.sum((((s.raw * g) @ m - s.target) * w[:, None]) ** 2, axis=1))
                   for s, g, w, m in zip(samples, gains, base_w, mats, strict=True)]
            scale = HUBER * 1.4826 * float(np.median(np.concatenate(res)))
            wts = [w * np.sqrt(np.minimum(1.0, scale / np.maximum(r, 1e-300)))
                   for w, r in zip(base_w, res, strict=True)]
    return a.reshape(n_ch, ny + 3, nx + 3), float(sse)
