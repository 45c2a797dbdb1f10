"""Per-raw mosaic gains: a DNG's GainMap opcodes, the table's lens shading, white balance.

Three gains multiply a raw's mosaic before classification, in this order,
each with its own clipping rule:

1. a DNG's ``GainMap`` opcodes (the camera's lens-shading correction, parsed
   by :mod:`l3cli.io.dng_opcodes`, carried unapplied as
   ``RawImage.gain_maps``): each map's gain, bilinearly interpolated on its
   grid at the pixel centre, then the result clipped at 1, as the DNG SDK
   does (:func:`apply_maps`);
2. a table's learned gain field (:class:`l3cli.lens.field.GainField`,
   :func:`l3cli.lens.field.correct_mosaic`'s rule);
3. a white-balancing table's as-shot gains per CFA position
   (:func:`l3cli.whitebalance.model.multiply_gains`' rule).

:func:`apply_dng_gains` applies the first to a raw read by
:func:`l3cli.io.raw.read_raw`, for callers that want the corrected mosaic
(training, ``l3 info``, the baseline). A render does not make passes of
them over the mosaic: :func:`mosaic_gains` gathers all three into one
:class:`MosaicGains`, whose :meth:`~MosaicGains.kernel_args` the tile kernel
evaluates per pixel as it copies a tile's band from the mosaic
(:mod:`l3cli.classify.tile_kernel`):

* a DNG map as its grid (float64) with each column's grid cell and fraction
  and each row's: per tile the kernel interpolates the grid rows its band
  needs at the tile's columns (one gather per column and grid row), then a
  band row's gains are one linear interpolation between two of those rows,
  contiguous along the row (a vector loop); maps that touch different CFA
  positions (a phone's four, one per Bayer position) share a layer;
* a radial field as its polynomial in ``r² = a[y] + b[x]`` (float64, the same
  operations as :func:`l3cli.lens.field.gain_map`); any other field (a spline
  grid, :mod:`l3cli.lens.grid`) as its gain map, the float32 gains the
  pass multiplies by (:func:`l3cli.lens.field.gain_map`, computed once per field
  and raw size), read along each band row;
* the white balance as its (ph, pw) gains.

The fold covers maps whose pitch divides the CFA period and whose area is the
whole image (every phone and action camera writes these); any other map, and
tables with a context guide (its block means are taken from the corrected
mosaic), fall back to the passes over the mosaic (:meth:`MosaicGains.apply`),
with the same result.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["MosaicGains", "apply_dng_gains", "apply_maps", "colour_planes", "mosaic_gains",
           "NO_GAINS"]

log = logging.getLogger(__name__)

_F64 = np.float64


def apply_maps(mosaic: np.ndarray, maps: Sequence[Any],
               planes: np.ndarray | None = None) -> np.ndarray:
    """Apply DNG ``GainMap`` opcodes to a normalised mosaic in place, as the DNG SDK does.

    Each map (:class:`l3cli.io.dng_opcodes.GainMap`) scales the pixels of its
    area (``top``/``left``/``bottom``/``right``, every ``row_pitch``-th row and
    ``col_pitch``-th column from the area's corner) by its gain, bilinearly
    interpolated on the map's grid at the pixel centre's position relative to
    the whole image (``(row + 0.5) / height``; clamped at the map's edges), and
    clips the result at 1 (the white level). ``planes`` (int (H, W), or None
    for a one-plane mosaic) gives each pixel's plane: a map acts on the
    pixels of its ``plane .. plane + planes - 1`` with map plane
    ``min(plane, map_planes - 1)``.
    """
    from l3cli.startup import stop_if_interrupted

    h, w = mosaic.shape
    # the image's planes bound the loop over a map's planes, not the map's field
    n_planes = 1 if planes is None else int(np.max(planes, initial=-1)) + 1
    for gm in maps:
        stop_if_interrupted()
        top, left = max(gm.top, 0), max(gm.left, 0)
        bottom, right = min(gm.bottom, h), min(gm.right, w)
        if bottom <= top or right <= left:
            continue
        area = (slice(top, bottom, gm.row_pitch), slice(left, right, gm.col_pitch))
        view = mosaic[area]  # the map's pixels, written in place
        rows = np.arange(top, bottom, gm.row_pitch)
        cols = np.arange(left, right, gm.col_pitch)
        # the bilinear interpolation is separable: gains = Av @ grid @ Ahᵀ, each row of
        # Av and Ah holding a pixel's two weights on its axis (one matrix product per
        # plane rather than four gathers of the grid per pixel)
        av = _interp_matrix((rows + 0.5) / h, gm.origin_v, gm.spacing_v, gm.points_v)
        ah = _interp_matrix((cols + 0.5) / w, gm.origin_h, gm.spacing_h, gm.points_h)
        which = None if planes is None else np.asarray(planes)[area]
        for plane in range(gm.plane, min(gm.plane + gm.planes, n_planes)):
            stop_if_interrupted()
            sel = None if which is None else which == plane
            if sel is not None and not sel.any():
                continue
            g = ((av @ _grid(gm, plane)) @ ah.T).astype(np.float32)
            np.multiply(view, g, out=g)
            np.minimum(g, np.float32(1.0), out=g)
            np.copyto(view, g, where=True if sel is None else sel)
    return mosaic


def _grid(gm: Any, plane: int) -> np.ndarray:
    """The map's float64 grid of ``plane`` (a map of one point on an axis, constant
    along it, padded to two)."""
    grid = gm.gains[:, :, min(plane, gm.gains.shape[2] - 1)].astype(_F64)
    return np.pad(grid, ((0, grid.shape[0] == 1), (0, grid.shape[1] == 1)), mode="edge")


def _interp_matrix(pos: np.ndarray, origin: float, spacing: float, points: int) -> np.ndarray:
    """float64 (len(pos), max(points, 2)): each position's two bilinear weights on a map
    axis (:func:`_interp_weights`), as the rows of a matrix."""
    frac, idx = _interp_weights(pos, origin, spacing, points)
    m = np.zeros((pos.size, max(points, 2)), dtype=_F64)
    k = np.arange(pos.size)
    m[k, idx] = 1.0 - frac
    m[k, idx + 1] += frac
    return m


def _interp_weights(pos: np.ndarray, origin: float, spacing: float, points: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Lower grid index and fraction of ``pos`` on a map axis (clamped at its ends)."""
    if points < 2:
        return np.zeros(pos.size), np.zeros(pos.size, dtype=np.int64)
    # clamped before the integer cast: an extreme origin or spacing stays on the grid
    f = np.clip((pos - origin) / spacing, -1.0, float(points))
    idx = np.floor(f).astype(np.int64)
    frac = f - idx
    low = idx < 0
    idx[low], frac[low] = 0, 0.0
    high = idx >= points - 1
    idx[high], frac[high] = points - 2, 1.0
    return frac, idx


def colour_planes(cfa: Any, shape: tuple[int, int]) -> np.ndarray:
    """Each pixel's colour plane for OpcodeList3's maps: int (H, W), the index among the
    CFA's R, G, B in that order (-1 for other channels)."""
    chans = [c for c in ("R", "G", "B") if c in cfa.channels]
    cmap = np.asarray(cfa.channel_map(*shape))
    return np.array([chans.index(c) if c in chans else -1 for c in cfa.channels])[cmap]


def _apply_dng(mosaic: np.ndarray, dng: Any, cfa: Any) -> np.ndarray:
    apply_maps(mosaic, dng.list2)
    if dng.list3:
        apply_maps(mosaic, dng.list3, planes=colour_planes(cfa, mosaic.shape))
    return mosaic


def apply_dng_gains(raw: Any) -> Any:
    """Apply a raw's pending DNG GainMaps (``raw.gain_maps``) to its mosaic, in place.

    Returns ``raw``, its ``gain_maps`` now None (a raw is corrected once);
    a raw without pending maps is returned as it is.
    """
    dng = getattr(raw, "gain_maps", None)
    if dng is None:
        return raw
    _check_shape(dng, raw.mosaic.shape, raw.path)
    _apply_dng(raw.mosaic, dng, raw.cfa)
    raw.gain_maps = None
    log.debug("%s: applied %d + %d DNG GainMap opcodes", raw.path, len(dng.list2),
              len(dng.list3))
    return raw


def _check_shape(dng: Any, shape: tuple[int, ...], name: Any) -> None:
    if tuple(shape) != tuple(dng.shape):
        raise ValueError(f"{name}: the DNG gain maps are for a {dng.shape[1]}x{dng.shape[0]} "
                         f"mosaic, not {shape[1]}x{shape[0]}")


# ----------------------------------------------------------- the kernel's form
#: The tile kernel's gain arguments when there are none (the order of
#: :meth:`MosaicGains.kernel_args`). The gain map's stand-in is read-only as the gain map
#: is (:func:`l3cli.lens.field.gain_map`, cached): numba compiles a kernel apart for a
#: read-only array, so both kinds of table share one compile.
_NO_MAP = np.ones((1, 1), np.float32)
_NO_MAP.flags.writeable = False
NO_GAINS = (0, np.zeros((0, 1, 1), np.int64), np.zeros((0, 1, 1), _F64),
            np.zeros((0, 1, 1), np.float32), np.zeros((0, 1, 1, 1), _F64),
            np.zeros((0, 1, 1, 1), _F64), np.zeros((0, 1), np.int64), np.zeros((0, 1), _F64),
            np.zeros(1, _F64), np.zeros(1, _F64), np.zeros((1, 1, 1), _F64), False,
            np.ones((1, 1), np.float32), _NO_MAP, 0, 0)

#: ``kernel_args()[0]`` bits: DNG maps, the learned radial field, white balance, a
#: learned field as its gain map (a spline-grid field).
DNG, FIELD, WB, MAP = 1, 2, 4, 8


@dataclass(eq=False)
class MosaicGains:
    """One raw's gains before classification (see the module notes).

    Attributes
    ----------
    shape
        (H, W) of the mosaic the gains are for.
    cfa
        The raw's CFA (its phase is the mosaic's).
    dng
        The raw's pending DNG maps (:class:`l3cli.io.dng_opcodes.DngGainMaps`), or None.
    field, full_shape, origin
        The table's gain field (or None), and where the mosaic lies on its full raw.
    wb
        float32 (ph, pw) white-balance gains, or None.
    saturation
        The table's saturation threshold.
    foldable
        True when the tile kernel can evaluate every gain (:meth:`kernel_args`);
        else :meth:`apply` multiplies the mosaic.
    """

    shape: tuple[int, int]
    cfa: Any
    dng: Any = None
    field: Any = None
    full_shape: tuple[int, int] | None = None
    origin: tuple[int, int] = (0, 0)
    wb: np.ndarray | None = None
    saturation: float = 1.0
    foldable: bool = True
    name: Any = "raw"

    def apply(self, mosaic: np.ndarray) -> np.ndarray:
        """``mosaic`` (float32 (H, W)) multiplied by the gains in place, as passes over it:
        the DNG maps (:func:`apply_maps`), the field
        (:func:`l3cli.lens.field.correct_mosaic`), the white balance
        (:func:`l3cli.whitebalance.model.multiply_gains`). Returns ``mosaic``."""
        if tuple(mosaic.shape) != tuple(self.shape):
            raise ValueError(f"the gains are for a {self.shape} mosaic, not {mosaic.shape}")
        if self.dng is not None:
            _apply_dng(mosaic, self.dng, self.cfa)
        if self.field is not None:
            from l3cli.lens.field import correct_mosaic

            correct_mosaic(mosaic, self.field, self.cfa, self.saturation,
                           full_shape=self.full_shape, origin=self.origin, out=mosaic,
                           name=self.name)
        if self.wb is not None:
            from l3cli.whitebalance.model import multiply_gains

            multiply_gains(mosaic, self.wb, self.saturation)
        return mosaic

    def kernel_args(self) -> tuple:
        """The tile kernel's gain arguments: ``(mode, idx, frac, cap, grid, gdiff, iv, fv,
        a, b, coeffs, floor_one, wb)`` (:data:`NO_GAINS` for none), laid out so that the
        kernel reads each column's values contiguously along a band row.

        ``mode``: bits :data:`DNG`, :data:`FIELD`, :data:`WB`. DNG map layers, per
        row phase: ``grid`` float64 (layers, ph, rows, M) the grid of the map at each
        column phase (entry ``j * pw + px``: grid column ``j``, column phase ``px``;
        the last entry 1: no map), ``gdiff`` the differences to the next grid
        column (the last 0); ``idx`` int64, ``frac`` float64 and ``cap`` float32
        (layers, ph, W): per row phase and column, the entry of ``grid`` and the
        fraction to the next grid column, and the clip (1; infinity where the
        layer has no map); ``iv`` int64 and ``fv`` float64 (layers, H): per image
        row its grid row and the fraction to the next (the maps of a layer that
        share a row phase share their vertical grid). The field: ``a``
        (H,) and ``b`` (W,) float64 squared offsets from its centre, ``coeffs``
        float64 (ph, k, W) its polynomial per row phase and column,
        ``floor_one`` every field gain on the mosaic is at least 1 (its clipping
        rule). ``wb`` float32 (ph, W): the white-balance gain per row phase and
        column. ``gmap``, ``my``, ``mx``: a field that is not radial (mode bit
        :data:`MAP`) as its float32 gain map on the full raw and where the mosaic
        starts on it (``floor_one`` its rule, as the radial field's); the
        column. Built once per instance.
        """
        args = self.__dict__.get("_args")
        if args is None:
            if not self.foldable:
                raise ValueError("these gains are applied to the mosaic (MosaicGains.apply), "
                                 "not in the kernel")
            args = self.__dict__["_args"] = _kernel_args(self)
        return args


def _kernel_args(g: MosaicGains) -> tuple:
    mode = 0
    idx, frac, cap, grid, gdiff, iv, fv, a, b, coeffs, floor_one, wb, gmap, my, mx = (
        NO_GAINS[1:])
    ph, pw = g.cfa.period
    w = g.shape[1]
    if g.dng is not None:
        mode |= DNG
        idx, frac, cap, grid, gdiff, iv, fv = _build_layers(g.dng, g.cfa, g.shape)
    if g.field is not None and g.field.radial:
        mode |= FIELD
        a, b, coeffs, floor_one = _field_args(g)
    elif g.field is not None:
        mode |= MAP
        gmap, my, mx, floor_one = _map_args(g)
    if g.wb is not None:
        mode |= WB
        wb = np.empty((ph, w), np.float32)
        for py in range(ph):
            wb[py] = np.resize(np.asarray(g.wb, np.float32)[py], w)  # column phase x % pw
    return (mode, idx, frac, cap, grid, gdiff, iv, fv, a, b, coeffs, bool(floor_one), wb,
            gmap, int(my), int(mx))


def _pieces(dng: Any, cfa: Any) -> list[tuple[Any, dict[tuple[int, int], int]]] | None:
    """Each map with the grid plane it gives each CFA position it touches; None when a
    map's pixels are not whole CFA positions of the whole image."""
    ph, pw = cfa.period
    colour = colour_planes(cfa, (ph, pw))
    h, w = dng.shape
    from l3cli.startup import stop_if_interrupted

    out = []
    for maps, by_colour in ((dng.list2, False), (dng.list3, True)):
        for gm in maps:
            stop_if_interrupted()  # a render thread ends on a signal here too
            if (ph % gm.row_pitch or pw % gm.col_pitch or gm.top >= gm.row_pitch
                    or gm.left >= gm.col_pitch or gm.bottom < h or gm.right < w):
                return None
            at = {}
            for py in range(ph):
                for px in range(pw):
                    if (py - gm.top) % gm.row_pitch or (px - gm.left) % gm.col_pitch:
                        continue
                    plane = int(colour[py, px]) if by_colour else 0
                    if gm.plane <= plane < gm.plane + gm.planes:
                        at[(py, px)] = min(plane, gm.gains.shape[2] - 1)
            out.append((gm, at))
    return out


def foldable_maps(dng: Any, cfa: Any) -> bool:
    """True when the tile kernel can apply ``dng``'s maps (:func:`_pieces`)."""
    return _pieces(dng, cfa) is not None


def _build_layers(dng: Any, cfa: Any, shape: tuple[int, int]) -> tuple:
    ph, pw = cfa.period
    h, w = shape
    pieces = _pieces(dng, cfa)
    if pieces is None:
        raise ValueError("these DNG gain maps cannot be folded into the kernel")
    # a map goes into the first layer after every earlier map that touches one of its
    # positions (a pixel meets its maps in their order, each clipped at 1) and whose maps
    # on the row phases it touches have its vertical grid (a band row's grid rows and
    # fraction are one per layer and row phase)
    last: dict[tuple[int, int], int] = {}
    geometry: dict[tuple[int, int], tuple] = {}  # (layer, row phase) -> vertical grid
    layer_of = []
    for gm, at in pieces:
        geo = (gm.origin_v, gm.spacing_v, max(gm.points_v, 1))
        k = 1 + max((last.get(p, -1) for p in at), default=-1)
        while any(geometry.get((k, py), geo) != geo for py, _ in at):
            k += 1
        layer_of.append(k)
        for p in at:
            last[p] = k
            geometry[(k, p[0])] = geo
    n_layers = 1 + max(layer_of, default=-1)
    m = max(max(gm.points_h, 2) for gm, _ in pieces) * pw + 1  # + the no-map entry
    n_i = max(max(gm.points_v, 2) for gm, _ in pieces)
    idx = np.full((n_layers, ph, w), m - 1, np.int64)
    frac = np.zeros((n_layers, ph, w), _F64)
    cap = np.full((n_layers, ph, w), np.inf, np.float32)
    grid = np.ones((n_layers, ph, n_i, m), _F64)
    gdiff = np.zeros((n_layers, ph, n_i, m), _F64)
    iv = np.zeros((n_layers, h), np.int64)
    fv = np.zeros((n_layers, h), _F64)
    ys, xs = np.arange(h), np.arange(w)
    for (gm, at), k in zip(pieces, layer_of, strict=True):
        cf, ci = _interp_weights((xs + 0.5) / w, gm.origin_h, gm.spacing_h, gm.points_h)
        rf, ri = _interp_weights((ys + 0.5) / h, gm.origin_v, gm.spacing_v, gm.points_v)
        for (py, px), plane in at.items():
            g = _grid(gm, plane)  # (grid rows, grid columns)
            ni, n = g.shape
            grid[k, py, :ni, px:n * pw:pw] = g
            gdiff[k, py, :ni, px:(n - 1) * pw:pw] = g[:, 1:] - g[:, :-1]
            idx[k, py, px::pw] = ci[px::pw] * pw + px
            frac[k, py, px::pw] = cf[px::pw]
            cap[k, py, px::pw] = 1.0
            iv[k, py::ph] = ri[py::ph]
            fv[k, py::ph] = rf[py::ph]
    return idx, frac, cap, grid, gdiff, iv, fv


@functools.lru_cache(maxsize=8)
def _field_floor(key: bytes, field_ref: tuple, full: tuple[int, int], period: tuple[int, int],
                 box: tuple[int, int, int, int]) -> bool:
    """Every float32 gain of the field on the mosaic's window ``box`` of its full raw is at
    least 1 (:func:`l3cli.lens.field.correct_mosaic`'s test, on the values
    :func:`l3cli.lens.field.gain_map` computes), found in bands of rows without the map."""
    from l3cli.lens.field import normalised_coords

    field = field_ref[0]
    y0, x0, hh, ww = box
    ph, pw = period
    v, u = normalised_coords(*full)
    cy, cx = field.centre
    for py in range(ph):
        for px in range(pw):
            # the positions are the full raw's: rows y0 + y with (y0 + y) % ph == py
            rows = np.arange((py - y0) % ph, hh, ph) + y0
            cols = np.arange((px - x0) % pw, ww, pw) + x0
            if rows.size == 0 or cols.size == 0:
                continue
            a, b = (v[rows] - cy) ** 2, (u[cols] - cx) ** 2
            c = field.coeffs[py * pw + px]
            step = max(1, (1 << 20) // cols.size)
            for r0 in range(0, rows.size, step):
                r2 = a[r0:r0 + step, None] + b[None, :]
                g = np.zeros_like(r2)
                for k in range(c.size - 1, -1, -1):  # Horner, as GainField.gains
                    g *= r2
                    g += c[k]
                if float(g.astype(np.float32).min()) < 1.0:
                    return False
    return True


def _field_args(g: MosaicGains) -> tuple:
    from l3cli.lens.field import normalised_coords

    field = g.field
    h, w = g.shape
    full = tuple(g.full_shape) if g.full_shape is not None else (h, w)
    y0, x0 = g.origin
    ph, pw = g.cfa.period
    v, u = normalised_coords(*full)
    cy, cx = field.centre
    a = np.ascontiguousarray((v[y0:y0 + h] - cy) ** 2)
    b = np.ascontiguousarray((u[x0:x0 + w] - cx) ** 2)
    # the field's positions are the full raw's (l3cli.lens.field.gain_map): position of
    # the mosaic's (y, x) is that of (y0 + y, x0 + x)
    k = field.coeffs.shape[1]
    coeffs = np.empty((ph, k, w), _F64)
    for py in range(ph):
        for px in range(pw):
            pos = ((y0 + py) % ph) * pw + (x0 + px) % pw
            coeffs[py, :, px::pw] = field.coeffs[pos][:, None]
    floor_one = _field_floor(field.key(), (field,), full, (ph, pw), (y0, x0, h, w))
    return a, b, coeffs, floor_one


def _map_args(g: MosaicGains) -> tuple:
    """A field that is not radial (:mod:`l3cli.lens.grid`) as the gain map of its full
    raw (:func:`l3cli.lens.field.gain_map`: the float32 gains the pass multiplies by,
    computed once per field and size), where the mosaic starts on it, and whether every
    gain on the mosaic is at least 1 (:func:`l3cli.lens.field.correct_mosaic`'s test)."""
    from l3cli.lens.field import gain_map

    h, w = g.shape
    full = tuple(g.full_shape) if g.full_shape is not None else (h, w)
    y0, x0 = g.origin
    gmap = gain_map(g.field, full, g.cfa.period)
    floor_one = float(gmap[y0:y0 + h, x0:x0 + w].min()) >= 1.0
    return gmap, y0, x0, floor_one


def mosaic_gains(raw: Any, *, field: Any = None, wb: np.ndarray | None = None,
                 saturation: float = 1.0, fold: bool = True) -> MosaicGains | None:
    """The gains of ``raw``'s mosaic before classification: its pending DNG maps, the
    table's gain ``field`` (unless the raw is shading-corrected already) and the
    white-balance pattern ``wb`` (float32 (ph, pw)); None when there are none.

    ``fold`` False (a context guide reads the corrected mosaic) makes
    :meth:`MosaicGains.apply` the way they are applied.
    """
    dng = getattr(raw, "gain_maps", None)
    if field is not None and raw.metadata.get("shading_corrected"):
        field = None
    if dng is None and field is None and wb is None:
        return None
    shape = (int(raw.mosaic.shape[0]), int(raw.mosaic.shape[1]))
    if dng is not None:
        _check_shape(dng, shape, raw.path)
    full, origin = None, (0, 0)
    if field is not None:
        from l3cli.lens.field import _placement

        full_shape, y0, x0 = _placement(raw)
        full, origin = full_shape, (y0, x0)
        if tuple(full) != tuple(field.size) and fold:  # (else correct_mosaic says it)
            log.warning("%s: the raw is %dx%d, the table's shading gain field was learned on "
                        "%dx%d raws; applying it in coordinates relative to the frame",
                        raw.path or "raw", full[1], full[0], field.size[1], field.size[0])
    foldable = fold and (dng is None or foldable_maps(dng, raw.cfa))
    return MosaicGains(shape, raw.cfa, dng, field, full, origin,
                       None if wb is None else np.asarray(wb, np.float32), float(saturation),
                       foldable, raw.path or "raw")
