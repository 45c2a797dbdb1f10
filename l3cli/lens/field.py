"""Lens shading: a smooth gain over sensor position, per CFA channel.

Cameras correct lens shading (the fall-off of a lens's relative illumination
toward the corners, different per colour) on the raw data before anything
else. l3's classes know a pixel's CFA phase but not where on the sensor it
lies, so a camera whose renders are shading-corrected is learned here in two
parts: a gain field that corrects the raw first, then the table.

The gain field (:class:`GainField`, :class:`~l3cli.lens.grid.SplineField`)
    Per CFA position ``p``, either a polynomial in the squared radius about an
    optical centre ``(cy, cx)``: ``g_p(r) = c_p0 + c_p1 r^2 + c_p2 r^4 (+ c_p3
    r^6)``, ``r`` in normalised sensor coordinates (:func:`normalised_coords`:
    the image centre is 0, the half-diagonal is 1), or a smooth spline surface
    over the sensor (:mod:`l3cli.lens.grid`: colour shading about different
    centres or not radial). Positions of one colour share their gains when
    learned. The gains are scaled so that their
    smallest value over the training raws' area is 1: a correction brightens
    the corners and keeps the centre, as a camera's does, so the mosaic keeps
    the scale of the raw where the lens shades least. As the camera (and the
    DNG SDK's ``GainMap``) clips at the white level after its correction, a
    corrected pixel is not lifted above 1, so clipped pixels stay at 1 and
    the saturation classes see the camera's clipping. A gain below one (a raw
    of another size) never lowers a pixel at or above the threshold. Either
    kind gives its gains on a lattice (``plane``) and at points (``values``):
    :func:`gain_map` (a raw's map), :func:`gains_at` (given pixels).
Learning (:mod:`l3cli.lens.fit`, glue in :mod:`l3cli.lens.train`)
    From blocks of the training pairs; the model (radial order or spline grid)
    chosen by held-out error (other images, or spatial folds of one image);
    kept only where it predicts held-out blocks better than no field, so
    unshaded cameras train as before.
Application (:func:`corrected`, :func:`correct_mosaic`)
    Before classification. Training multiplies the mosaic by the per-pixel
    gain map (computed once per raw size, cached); a render evaluates the
    same gains per pixel inside the tile kernel, with the raw's DNG gain maps
    and white balance (:mod:`l3cli.lens.gainmaps`).
DNG ``GainMap`` opcodes
    The camera's own correction, parsed from a DNG's OpcodeList2/3 by
    :mod:`l3cli.io.dng_opcodes` and applied as the DNG SDK does by
    :mod:`l3cli.lens.gainmaps`.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from l3cli.errors import TableError
from l3cli.io.dng_opcodes import GAIN_RANGE  # the range a gain may take (the DNG SDK's)
from l3cli.lens.grid import MAX_SIZE, SPLINE_RULE, SplineField, sensor_size
from l3cli.tablekeys import optional_group

__all__ = ["SHADING_RULE", "GainField", "SplineField", "normalised_coords", "gain_map", "gains_at",
           "field_from_arrays", "corrected",
           "corrected_raw", "correct_mosaic"]

log = logging.getLogger(__name__)

#: Name of the gain-field rule recorded in tables.
SHADING_RULE = "radial-poly-r2-v1"
#: Terms of a field's polynomial at most (powers r^0 .. r^14; the fit uses up to 4).
MAX_TERMS = 8


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

    #: Which kind of field (``SplineField.radial`` is False): the tile kernel evaluates
    #: a radial field's polynomial in its band copy (any other field: its gain map) and
    #: the export evaluates it in the graph.
    radial = True

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

    @property
    def n_positions(self) -> int:
        return int(self.coeffs.shape[0])

    def plane(self, v: np.ndarray, u: np.ndarray, p: int) -> np.ndarray:
        """Gains (len(v), len(u)) of position ``p`` on the lattice of rows ``v`` and
        columns ``u`` (normalised coordinates)."""
        r2 = (np.asarray(v, float)[:, None] - self.centre[0]) ** 2 \
            + (np.asarray(u, float)[None, :] - self.centre[1]) ** 2
        c = self.coeffs[p]
        g = np.zeros_like(r2)
        for k in range(c.size - 1, -1, -1):  # Horner, as gains() (this position only)
            g *= r2
            g += c[k]
        return g

    def values(self, v: np.ndarray, u: np.ndarray, p: np.ndarray | int) -> np.ndarray:
        """Gains at the points ``(v[k], u[k])`` of positions ``p[k]`` (broadcast)."""
        v, u, p = np.broadcast_arrays(np.asarray(v, float), np.asarray(u, float),
                                      np.asarray(p, np.int64))
        r2 = (v - self.centre[0]) ** 2 + (u - self.centre[1]) ** 2
        out = np.zeros(r2.shape)
        for k in range(self.coeffs.shape[1] - 1, -1, -1):  # Horner
            out = out * r2 + self.coeffs[p, k]
        return out

    def gains(self, r2: np.ndarray) -> np.ndarray:
        """Gains (n_positions, *r2.shape) at squared radii ``r2``."""
        r2 = np.asarray(r2, dtype=np.float64)
        out = np.zeros((self.coeffs.shape[0], *r2.shape))
        for k in range(self.coeffs.shape[1] - 1, -1, -1):  # Horner
            out = out * r2 + self.coeffs[:, k].reshape((-1,) + (1,) * r2.ndim)
        return out

    def summary(self) -> dict[str, Any]:
        """What ``l3 inspect`` shows: centre, size, gain at r = 1 over the centre's."""
        return {"centre": self.centre.tolist(), "size": list(self.size),
                "gain_at_r1": (self.gains(np.array([1.0]))[:, 0]
                               / self.gains(np.array([0.0]))[:, 0]).round(4).tolist()}

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
        return cls(arrs["shading_centre"], coeffs, sensor_size(arrs["shading_size"]))

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
    out = np.empty((h, w), dtype=np.float32)
    for y in range(ph):
        for x in range(pw):
            out[y::ph, x::pw] = field.plane(v[y::ph], u[x::pw], y * pw + x)
    out.flags.writeable = False
    return out


def gain_map(field: GainField, shape: tuple[int, int], period: tuple[int, int]) -> np.ndarray:
    """The field's per-pixel gains on a full raw of ``shape`` (float32 (H, W), read-only;
    computed once per field and size). ``period`` is the CFA's, its phase that of the
    table (position ``p = (y % ph) * pw + x % pw``)."""
    return _cached_map(field.key(), (field,), (int(shape[0]), int(shape[1])),
                       (int(period[0]), int(period[1])))


def gains_at(field: Any, ys: np.ndarray, xs: np.ndarray, shape: tuple[int, int],
             period: tuple[int, int]) -> np.ndarray:
    """The field's gains (float64, broadcast shape of ``ys``, ``xs``) at the pixels
    ``(ys, xs)`` of a full raw of ``shape``: the values of :func:`gain_map` there
    (position ``p = (y % ph) * pw + x % pw``), for callers that need a few pixels'
    gains or their own layout of the map."""
    ys, xs = np.broadcast_arrays(np.asarray(ys, np.int64), np.asarray(xs, np.int64))
    half = 0.5 * float(np.hypot(*shape))
    v = (ys + 0.5 - 0.5 * shape[0]) / half
    u = (xs + 0.5 - 0.5 * shape[1]) / half
    ph, pw = period
    return field.values(v, u, (ys % ph) * pw + xs % pw)


def field_from_arrays(arrs: dict[str, np.ndarray], n_positions: int) -> Any:
    """The gain field stored in a table's arrays (a radial :class:`GainField` or a
    :class:`~l3cli.lens.grid.SplineField`, by ``shading_rule``), or None."""
    rule = arrs.get("shading_rule")
    if rule is not None and rule.dtype.kind == "U" and rule.ndim == 0 \
            and str(rule) == SPLINE_RULE:
        return SplineField.from_arrays(arrs, n_positions)
    return GainField.from_arrays(arrs, n_positions)


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
