"""Lens shading: a smooth gain over sensor position, per CFA channel.

Cameras correct lens shading (the fall-off of a lens's relative illumination
toward the corners, different per colour) on the raw data before anything
else. l3's classes know a pixel's CFA phase but not where on the sensor it
lies, so a camera whose renders are shading-corrected is learned here in two
parts: a gain field that corrects the raw first, then the table.

The gain field (:class:`GainField`)
    Per CFA position ``p``, a polynomial in the squared radius about an optical
    centre ``(cy, cx)``: ``g_p(r) = c_p0 + c_p1 r^2 + c_p2 r^4 (+ c_p3 r^6``: the order that predicts
    held-out images best), with
    ``r`` in normalised sensor coordinates (:func:`normalised_coords`: the
    image centre is 0, the half-diagonal is 1). Positions of one colour share
    their coefficients when learned. The gains are scaled so that their
    smallest value over the training raws' area is 1: a correction brightens
    the corners and keeps the centre, as a camera's does, so the mosaic keeps
    the scale of the raw where the lens shades least. As the camera (and the
    DNG SDK's ``GainMap``) clips at the white level after its correction, a
    corrected pixel is not lifted above 1, so clipped pixels stay at 1 and
    the saturation classes see the camera's clipping. A gain below one (a raw
    of another size) never lowers a pixel at or above the threshold.
Learning (:func:`fit_field`, glue in :mod:`l3cli.train.shading`)
    The pairs are cut into blocks; each block's per-channel raw means ``m``
    and its target's linear means ``t`` should follow ``t = M_i (g(r) m)``
    with one colour matrix ``M_i`` per image (it absorbs each render's white
    balance and the field's per-channel scale). The matrices and the gain
    coefficients are fitted by alternating least squares (each step is
    linear), the centre by Nelder-Mead around the image centre. The field is
    kept only where it predicts held-out images' blocks better than no field
    (leave one image out), so unshaded cameras train as before.
Application (:func:`corrected`, :func:`correct_mosaic`)
    Before classification. Training multiplies the mosaic by the per-pixel
    gain map (computed once per raw size, cached); a render evaluates the
    same gains per pixel inside the tile kernel, with the raw's DNG gain maps
    and white balance (:mod:`l3cli.gainmaps`).
DNG ``GainMap`` opcodes
    The camera's own correction, parsed from a DNG's OpcodeList2/3 by
    :mod:`l3cli.io.dng_opcodes` and applied as the DNG SDK does by
    :mod:`l3cli.gainmaps`.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from l3cli.errors import TableError
from l3cli.io.dng_opcodes import GAIN_RANGE  # the range a gain may take (the DNG SDK's)
from l3cli.tablekeys import optional_group

__all__ = ["SHADING_RULE", "GainField", "normalised_coords", "gain_map", "corrected",
           "corrected_raw", "correct_mosaic", "block_samples", "BlockSamples", "fit_field"]

log = logging.getLogger(__name__)

#: Name of the gain-field rule recorded in tables.
SHADING_RULE = "radial-poly-r2-v1"
#: Polynomial orders tried (powers of r^2 beyond the constant): the one that predicts
#: held-out images best is kept (:func:`fit_field`).
ORDERS = (2, 3)
#: Terms of a field's polynomial at most (powers r^0 .. r^14; the fit uses up to 4).
MAX_TERMS = 8
#: Sensor side in pixels at most (``shading_size``).
MAX_SIZE = 1 << 20


def normalised_coords(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates ``(v, u)`` (float64 (H,), (W,)): 0 at the image
    centre, 1 at the half-diagonal."""
    half = 0.5 * float(np.hypot(height, width))
    v = (np.arange(height) + 0.5 - 0.5 * height) / half
    u = (np.arange(width) + 0.5 - 0.5 * width) / half
    return v, u


@dataclass(eq=False)
class GainField:
    """A radial gain per CFA position (see the module notes).

    Attributes
    ----------
    centre
        float64 (2,): optical centre ``(cy, cx)`` in normalised coordinates.
    coeffs
        float64 (n_positions, k): ``g_p(r) = sum_j coeffs[p, j] r^(2j)``.
    size
        ``(height, width)`` of the training raws.
    """

    centre: np.ndarray
    coeffs: np.ndarray
    size: tuple[int, int]

    def __post_init__(self) -> None:
        self.centre = np.asarray(self.centre, dtype=np.float64)
        self.coeffs = np.asarray(self.coeffs, dtype=np.float64)
        self.size = (int(self.size[0]), int(self.size[1]))
        problem = self._problem()
        if problem:
            raise TableError(f"bad shading gain field: {problem}")

    def _problem(self) -> str | None:
        """What makes the field unusable (naming its table key), or None: a field that
        passes gives finite gains within :data:`GAIN_RANGE` on every pixel of any raw."""
        if self.centre.shape != (2,) or self.coeffs.ndim != 2 or self.coeffs.shape[1] < 1:
            return f"centre {self.centre.shape} / coeffs {self.coeffs.shape} have the wrong shape"
        if self.coeffs.shape[1] > MAX_TERMS:
            return (f"shading_coeffs has {self.coeffs.shape[1]} terms per position, at most "
                    f"{MAX_TERMS}")
        if not (np.all(np.isfinite(self.centre)) and np.all(np.isfinite(self.coeffs))):
            return "centre or coefficients hold NaN or Inf"
        if np.any(np.abs(self.centre) > 1.0):
            return f"centre {self.centre.tolist()} lies outside the sensor"
        if min(self.size) < 1 or max(self.size) > MAX_SIZE:
            return f"shading_size {self.size} is not a sensor size (1 .. {MAX_SIZE} pixels a side)"
        lo, hi = self.extremes()
        if not (np.isfinite(lo) and np.isfinite(hi)):
            return "shading_coeffs: gains overflow over the sensor"
        if not lo > 0:
            return f"shading_coeffs: gains are not positive over the sensor (down to {lo:.3g})"
        if not (lo >= GAIN_RANGE[0] and hi <= GAIN_RANGE[1]):
            return (f"shading_coeffs: gains from {lo:.3g} to {hi:.3g} over the sensor, outside "
                    f"the {GAIN_RANGE[0]:g} .. {GAIN_RANGE[1]:g} a gain field may give")
        return None

    def extremes(self) -> tuple[float, float]:
        """The smallest and largest gain of any position over any raw's sensor (``r^2``
        from 0 to ``(1 + |centre|)^2``, the farthest corner): each polynomial at the
        ends, on a grid and at its derivative's real roots (its extremes, exactly).
        NaN when a gain overflows."""
        from numpy.polynomial import polynomial as P

        t_max = (1.0 + float(np.hypot(*self.centre))) ** 2
        ts = [np.linspace(0.0, t_max, 257)]
        with np.errstate(all="ignore"):
            for c in self.coeffs:
                d = P.polyder(c)
                if d.size < 2 or not np.any(d[1:]):
                    continue
                try:
                    roots = P.polyroots(d)
                except (np.linalg.LinAlgError, ValueError):
                    continue
                roots = roots[np.isfinite(roots)]
                real = roots.real[np.abs(roots.imag) <= 1e-9 * (1.0 + np.abs(roots.real))]
                ts.append(real[(real > 0) & (real < t_max)])
            g = self.gains(np.concatenate(ts))
        if not np.all(np.isfinite(g)):
            return float("nan"), float("nan")
        return float(g.min()), float(g.max())

    def gains(self, r2: np.ndarray) -> np.ndarray:
        """Gains (n_positions, *r2.shape) at squared radii ``r2``."""
        r2 = np.asarray(r2, dtype=np.float64)
        out = np.zeros((self.coeffs.shape[0], *r2.shape))
        for k in range(self.coeffs.shape[1] - 1, -1, -1):  # Horner
            out = out * r2 + self.coeffs[:, k].reshape((-1,) + (1,) * r2.ndim)
        return out

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The table keys (``shading_*``)."""
        return {"shading_rule": np.array(SHADING_RULE),
                "shading_centre": self.centre.copy(),
                "shading_coeffs": self.coeffs.copy(),
                "shading_size": np.array(self.size, dtype=np.int64)}

    @classmethod
    def from_arrays(cls, arrs: dict[str, np.ndarray], n_positions: int) -> GainField | None:
        """The field stored in a table's arrays, or None when it has none.

        Raises
        ------
        TableError
            Keys missing, another rule, wrong dtypes or shapes, non-finite or
            non-positive gains.
        """
        keys = ("shading_rule", "shading_centre", "shading_coeffs", "shading_size")
        if optional_group(arrs, keys, SHADING_RULE) is None:
            return None
        for k in keys[1:]:
            if arrs[k].dtype.kind not in ("f", "i", "u"):
                raise TableError(f"key {k!r} has dtype {arrs[k].dtype}, expected numbers")
        coeffs = arrs["shading_coeffs"]
        if coeffs.ndim != 2 or coeffs.shape[0] != n_positions:
            raise TableError(f"shading_coeffs has shape {coeffs.shape}, the CFA needs "
                             f"({n_positions}, k)")
        size = arrs["shading_size"]
        if size.shape != (2,):
            raise TableError(f"shading_size has shape {size.shape}, expected (2,)")
        fsize = size.astype(np.float64)
        if not (np.all(np.isfinite(fsize)) and np.all(fsize == np.round(fsize))
                and np.all(fsize >= 1) and np.all(fsize <= MAX_SIZE)):
            raise TableError(f"shading_size {size.tolist()} is not a sensor size (whole "
                             f"numbers, 1 .. {MAX_SIZE} pixels a side)")
        return cls(arrs["shading_centre"], coeffs, (int(size[0]), int(size[1])))

    def key(self) -> bytes:
        """Bytes that identify the field (the gain-map cache's key)."""
        return self.centre.tobytes() + self.coeffs.tobytes() + np.array(self.size).tobytes()


@functools.lru_cache(maxsize=4)
def _cached_map(key: bytes, field_ref: Any, shape: tuple[int, int],
                period: tuple[int, int]) -> np.ndarray:
    field = field_ref[0]
    h, w = shape
    ph, pw = period
    v, u = normalised_coords(h, w)
    cy, cx = field.centre
    out = np.empty((h, w), dtype=np.float32)
    for y in range(ph):
        for x in range(pw):
            r2 = (v[y::ph, None] - cy) ** 2 + (u[None, x::pw] - cx) ** 2
            c = field.coeffs[y * pw + x]
            g = np.zeros_like(r2)
            for k in range(c.size - 1, -1, -1):  # Horner, as gains() (this position only)
                g *= r2
                g += c[k]
            out[y::ph, x::pw] = g
    out.flags.writeable = False
    return out


def gain_map(field: GainField, shape: tuple[int, int], period: tuple[int, int]) -> np.ndarray:
    """The field's per-pixel gains on a full raw of ``shape`` (float32 (H, W), read-only;
    computed once per field and size). ``period`` is the CFA's, its phase that of the
    table (position ``p = (y % ph) * pw + x % pw``)."""
    return _cached_map(field.key(), (field,), (int(shape[0]), int(shape[1])),
                       (int(period[0]), int(period[1])))


def _placement(raw: Any) -> tuple[tuple[int, int], int, int]:
    """``(full shape, y0, x0)``: where a (possibly cropped) raw lies on its full raw."""
    crop = raw.metadata.get("crop") if isinstance(raw.metadata, dict) else None
    full = raw.metadata.get("full_size") if isinstance(raw.metadata, dict) else None
    if crop is None or full is None:
        return (int(raw.mosaic.shape[0]), int(raw.mosaic.shape[1])), 0, 0
    return (int(full[0]), int(full[1])), int(crop[0]), int(crop[1])


def correct_mosaic(mosaic: np.ndarray, field: GainField, cfa: Any, saturation: float, *,
                   full_shape: tuple[int, int] | None = None, origin: tuple[int, int] = (0, 0),
                   out: np.ndarray | None = None, name: Any = "raw") -> np.ndarray:
    """``mosaic`` times the field's gains (float32), clipped at the white level (1) as a
    camera clips after its correction (a pixel already above 1 is not lowered); a gain
    below one leaves pixels at or above ``saturation`` as they are.

    ``full_shape`` and ``origin`` place a cropped mosaic on its full raw. ``out`` may be
    ``mosaic`` itself (in place). A raw of another size than the training
    raws' is corrected in normalised coordinates, with a warning.
    """
    full = tuple(mosaic.shape) if full_shape is None else tuple(full_shape)
    if full != field.size:
        log.warning("%s: the raw is %dx%d, the table's shading gain field was learned on "
                    "%dx%d raws; applying it in coordinates relative to the frame",
                    name, full[1], full[0], field.size[1], field.size[0])
    y0, x0 = origin
    ph, pw = cfa.period
    gmap = gain_map(field, full, (ph, pw))
    # the map's positions are the full raw's; the crop starts at (y0, x0) of it
    g = gmap[y0:y0 + mosaic.shape[0], x0:x0 + mosaic.shape[1]]
    if out is None:
        out = np.array(mosaic, dtype=np.float32, copy=True)
    if float(g.min()) >= 1.0:  # the usual case: every pixel brightened, up to white
        cap = np.maximum(mosaic, np.float32(1.0))  # before ``out`` (maybe ``mosaic``) changes
        np.multiply(mosaic, g, out=out)
        np.minimum(out, cap, out=out)
    else:  # a gain below one does not hide clipping from the saturation classes
        np.multiply(mosaic, g, out=out, where=(mosaic < saturation) | (g >= 1.0))
    return out


def corrected(table: Any, raw: Any, *, inplace: bool = False) -> Any:
    """The raw as the table's kernels expect it: shading-corrected when the table holds
    a gain field (``table.shading``), else ``raw`` itself.

    The one render-side call: every render path passes its raw through it
    before the kernel runs. ``inplace`` multiplies ``raw.mosaic`` itself (for
    callers that own the raw); otherwise a corrected copy is returned. A raw
    corrected once is not corrected again.
    """
    field = getattr(table, "shading", None)
    if field is None:
        return raw
    return corrected_raw(field, raw, table.definition.saturation_threshold, inplace=inplace)


def corrected_raw(field: GainField, raw: Any, saturation: float, *,
                  inplace: bool = False) -> Any:
    """``raw`` corrected by ``field`` (:func:`correct_mosaic`; a cropped raw is placed on its
    full raw by its ``crop`` and ``full_size`` metadata). Training and rendering both call it."""
    if raw.metadata.get("shading_corrected"):
        return raw
    import dataclasses

    full, y0, x0 = _placement(raw)
    mosaic = correct_mosaic(raw.mosaic, field, raw.cfa, saturation,
                            full_shape=full, origin=(y0, x0),
                            out=raw.mosaic if inplace else None, name=raw.path or "raw")
    meta = {**raw.metadata, "shading_corrected": True}
    if inplace:
        raw.metadata = meta
        return raw
    return dataclasses.replace(raw, mosaic=mosaic, metadata=meta)


# ------------------------------------------------------------------- learning
@dataclass
class BlockSamples:
    """One image's blocks: normalised centres, per-channel raw means, target means."""

    v: np.ndarray  # float64 (n,)
    u: np.ndarray  # float64 (n,)
    raw: np.ndarray  # float64 (n, n_channels)
    target: np.ndarray  # float64 (n, 3) linear


def block_samples(mosaic: np.ndarray, cfa: Any, target: np.ndarray, mask: np.ndarray | None,
                  *, full_shape: tuple[int, int], origin: tuple[int, int] = (0, 0),
                  saturation: float = 0.95, block: int = 16,
                  floor: float = 0.01) -> BlockSamples:
    """Block means of one pair for :func:`fit_field`.

    Blocks (``block`` pixels, a whole number of CFA periods) count when every
    pixel may train (``mask``), no raw pixel reaches 0.9 x ``saturation`` and
    every channel's mean is above ``floor``.
    """
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
    ok = m.max(axis=(1, 3)) < 0.9 * saturation
    ok &= np.all(means > floor, axis=-1) & np.all(np.isfinite(t), axis=-1)
    if mask is not None:
        ok &= np.asarray(mask[:hh, :ww]).reshape(ny, by, nx, bx).all(axis=(1, 3))
    v, u = normalised_coords(*full_shape)
    y0, x0 = origin
    vc = v[y0:y0 + hh].reshape(ny, by).mean(axis=1)
    uc = u[x0:x0 + ww].reshape(nx, bx).mean(axis=1)
    vv, uu = np.meshgrid(vc, uc, indexing="ij")
    return BlockSamples(vv[ok], uu[ok], means[ok], t[ok])


def _design(s: BlockSamples, centre: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Powers r^2 .. r^(2 order) of the blocks (n, order) and their residual weights (n,)."""
    r2 = (s.v - centre[0]) ** 2 + (s.u - centre[1]) ** 2
    powers = np.stack([r2 ** (k + 1) for k in range(order)], axis=1)
    return powers, 1.0 / (s.target.mean(axis=1) + 0.05)  # relative residuals


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


def _matrix_sse(s: BlockSamples, a: np.ndarray | None, centre: np.ndarray) -> float:
    """Weighted SSE of one image with only its matrix fitted (``a`` None: no field)."""
    powers, wt = _design(s, centre, 1 if a is None else a.shape[1])
    z = s.raw
    if a is not None:
        z = z * (1.0 + powers @ a.T)
    z = z * wt[:, None]
    y = s.target * wt[:, None]
    mt, *_ = np.linalg.lstsq(z, y, rcond=None)
    return float(np.sum((z @ mt - y) ** 2))


def _scores(samples: Sequence[BlockSamples], order: int, n_blocks: int) -> tuple[float, float]:
    """RMS block residual with a field of ``order`` and without one: held out (each
    image by the field of the others, its own matrix refitted) when there are several
    images, else in-sample."""
    if len(samples) == 1:
        a, centre, _ = _fit_samples(samples, order)
        with_f, without = _matrix_sse(samples[0], a, centre), _matrix_sse(samples[0], None, centre)
    else:
        with_f = without = 0.0
        for i, s in enumerate(samples):
            ai, ci, _ = _fit_samples(samples[:i] + samples[i + 1:], order)
            with_f += _matrix_sse(s, ai, ci)
            without += _matrix_sse(s, None, ci)
    return float(np.sqrt(with_f / (3 * n_blocks))), float(np.sqrt(without / (3 * n_blocks)))


def fit_field(samples: Sequence[BlockSamples], cfa: Any, size: tuple[int, int], *,
              orders: Sequence[int] = ORDERS, min_gain: float = 0.02
              ) -> tuple[GainField | None, dict]:
    """Learn a gain field from the block samples of the training pairs.

    Each polynomial order of ``orders`` (powers of r² beyond the constant) is
    scored on held-out images; the lowest order within 1 % of the best score
    is fitted to all the images.

    Returns
    -------
    field, record
        The field (None when it does not predict held-out images better than
        no field, the samples are too few, or the fitted field is not usable over
        the whole sensor: ``unusable`` in the record), and a JSON record of the fit
        (``heldout_rms`` with and without the field, ``reason`` when none). A fit
        never raises for its data: an unusable field is dropped.
    """
    samples = [s for s in samples if s.raw.shape[0] >= 8 * (max(orders) + 3)]
    record: dict[str, Any] = {"rule": SHADING_RULE, "images": len(samples)}
    if not samples:
        record["reason"] = "too few unclipped blocks"
        return None, record
    n_blocks = sum(s.raw.shape[0] for s in samples)
    scores = {o: _scores(samples, o, n_blocks) for o in orders}
    best = min(v[0] for v in scores.values())
    order = min(o for o in orders if scores[o][0] <= 1.01 * best)
    with_f, without = scores[order]
    key = "heldout_rms" if len(samples) > 1 else "rms"
    record.update({key: with_f, "none_" + key: without, "order": order,
                   "order_" + key: {str(o): v[0] for o, v in scores.items()}})
    keep = with_f < (0.98 if len(samples) > 1 else 0.9) * without
    a, centre, _ = _fit_samples(samples, order)
    if not keep:
        record["reason"] = "no better than no correction on held-out images"
        return None, record
    chans = list(dict.fromkeys(cfa.channels))
    ph, pw = cfa.period
    per_pos = np.array([np.concatenate([[1.0], a[chans.index(cfa.channel_at(y, x))]])
                        for y in range(ph) for x in range(pw)])
    # scale so the smallest gain over the training area is 1
    v, u = normalised_coords(*size)
    r2max = float(np.max((v[[0, 0, -1, -1]] - centre[0]) ** 2
                         + (u[[0, -1, 0, -1]] - centre[1]) ** 2))
    r2 = np.linspace(0.0, r2max, 513)
    poly = np.zeros((per_pos.shape[0], r2.size))
    for k in range(per_pos.shape[1] - 1, -1, -1):
        poly = poly * r2 + per_pos[:, k:k + 1]
    if poly.min() <= min_gain * poly.max():
        record["reason"] = "the fitted gains are not positive over the sensor"
        return None, record
    try:  # usable over the whole sensor of any raw, as a table that loads must be
        field = GainField(centre, per_pos / poly.min(), size)
    except TableError as exc:
        record.update(reason=f"the fitted field is not usable ({exc})", unusable=True)
        return None, record
    record.update(centre=centre.tolist(), coeffs=field.coeffs.tolist(),
                  size=list(size), blocks=int(n_blocks))
    return field, record
