"""The stages around the classifier as ONNX nodes.

Lens shading and white-balance gains on the mosaic, the per-class affine
kernels (one ``Gather`` of each pixel's coefficients by class, then a
``MatMul`` with its patch), condition-bin kernel interpolation, the learned tone curve's
look-up, the white-balance adaptation matrix, and the display encoding. Each
follows the function ``l3 render`` calls (named in its docstring); they
agree within float32 rounding of a different summation order.
"""

from __future__ import annotations

import numpy as np
from onnx import TensorProto

from l3cli.export.graph import Graph

__all__ = ["apply_gains", "adaptation", "affine", "condition_kernels", "display",
           "kernel_rows", "shading", "tone_curve"]

F32, F64, I64 = TensorProto.FLOAT, TensorProto.DOUBLE, TensorProto.INT64
_RGB = ("R", "G", "B")


def apply_gains(g: Graph, mosaic: str, gains: str, cfa, saturation: float) -> str:
    """:func:`l3cli.whitebalance.model.apply_gains`: each pixel times its channel's gain (``gains``
    float32 (N, 3), green = 1); a pixel saturated in the raw stays at or above its value."""
    ph, pw = cfa.period
    which = np.array([[_RGB.index(cfa.channel_at(y, x)) for x in range(pw)] for y in range(ph)])
    idx = g.op("Squeeze", g.periodic(which, mosaic, dtype=np.int64), g.const([0], np.int64))
    gmap = g.op("Gather", gains, idx, axis=1)  # (N, 1, H, W)
    out = g.op("Mul", mosaic, gmap)
    sat = g.op("GreaterOrEqual", mosaic, g.const(np.float32(saturation)))
    return g.op("Where", sat, g.op("Max", out, mosaic), out)


def condition_kernels(g: Graph, table, value: str) -> str:
    """float32 (n_classes, q, n_out): :func:`l3cli.conditions.kernels_for` of the float64
    (1,) ``value``; the pooled kernels where it is not a positive number (unknown)."""
    cond = table.conditions
    pooled = np.asarray(table.kernels, dtype=np.float64)
    bins = np.stack([np.where(cond.own[b][:, None, None], cond.kernels[b], table.kernels)
                     for b in range(cond.values.size)]).astype(np.float64)
    logs = np.log(cond.values)
    v = g.op("Squeeze", value, g.const([0], np.int64))  # scalar
    known = g.op("Greater", v, g.const(0.0))  # False for NaN too
    safe = g.op("Where", known, v, g.const(1.0))
    x = g.op("Clip", g.op("Log", safe), g.const(logs[0]), g.const(logs[-1]))
    j = g.op("ReduceSum", g.cast(g.op("LessOrEqual", g.const(logs), x), I64), keepdims=0)
    i = g.op("Max", g.op("Sub", j, g.const(1, np.int64)), g.const(0, np.int64))
    j = g.op("Min", j, g.const(logs.size - 1, np.int64))
    li, lj = (g.op("Gather", g.const(logs), k, axis=0) for k in (i, j))
    tt = g.op("Div", g.op("Sub", x, li), g.op("Sub", lj, li))
    tt = g.op("Where", g.op("Equal", i, j), g.const(0.0), tt)
    table_b = g.const(bins, hint="cond_kernels")
    ki, kj = (g.op("Gather", table_b, k, axis=0) for k in (i, j))
    k = g.op("Add", g.op("Mul", g.op("Sub", g.const(1.0), tt), ki), g.op("Mul", tt, kj))
    k = g.op("Where", known, k, g.const(pooled, hint="pooled"))
    return g.cast(k, F32)


def kernel_rows(g: Graph, kernels: str | np.ndarray, patch: int, n_out: int) -> str:
    """The per-class kernels (n_classes, q + 1, n_out), a table's array or a graph tensor,
    as the rows :func:`affine` gathers: (n_classes, n_out * (q + 1)), each output's taps
    column by column (``dx`` major, ``dy`` minor: the order in which :func:`affine` lays
    out a patch) followed by its constant term."""
    s, q = patch, patch * patch
    if isinstance(kernels, np.ndarray):
        n = kernels.shape[0]
        taps = kernels[:, :q, :].reshape(n, s, s, n_out).transpose(0, 3, 2, 1).reshape(n, n_out, q)
        rows = np.concatenate([taps, kernels[:, q, :, None]], axis=2)
        return g.const(np.ascontiguousarray(rows).reshape(n, n_out * (q + 1)), hint="kernel_rows")
    i64 = np.int64
    taps = g.op("Reshape", g.slice(kernels, [0], [q], [1]), g.const([0, s, s, n_out], i64))
    taps = g.op("Reshape", g.op("Transpose", taps, perm=[0, 3, 2, 1]),
                g.const([0, n_out, q], i64))
    bias = g.op("Transpose", g.slice(kernels, [q], [q + 1], [1]), perm=[0, 2, 1])
    return g.op("Reshape", g.op("Concat", taps, bias, axis=2),
                g.const([0, n_out * (q + 1)], i64))


def ones_row(g: Graph, like: str) -> str:
    """float32 (N, 1, 1, W) ones for the (N, C, H, W) ``like`` (:func:`affine`'s constant
    terms' plane)."""
    shape = g.op("Concat", g.op("Shape", like, end=1), g.const([1, 1], np.int64),
                 g.op("Shape", like, start=3), axis=0)
    return g.op("Expand", g.const(np.ones((1, 1, 1, 1), np.float32)), shape)


def affine(g: Graph, rows: str, classes: str, kernels: str, ones: str, patch: int,
           n_out: int) -> str:
    """The affine kernel of each pixel's class on its patch, for one output row: float32
    (N, n_out, 1, w).

    ``rows`` (N, 1, S, w + 2r): the padded rows of the patches of the row's (N, 1, 1, w)
    int64 ``classes``; ``kernels``: :func:`kernel_rows`; ``ones``: :func:`ones_row`. The
    row's patches are laid out plane by plane first: S ``Slice`` nodes cut the rows at
    each column offset, and joined with the plane of ones (the constant term's) they
    make (N, 1, q + 1, w); one ``Transpose`` turns that into a row per pixel. Each
    pixel's row of coefficients is one ``Gather`` (a contiguous row), and their products
    one batched ``MatMul`` of (n_out, q + 1) by (q + 1, 1) per pixel. A row at a time,
    the 600 bytes a pixel of coefficients and patch (patch 7, 3 outputs) stay in the
    cache between the nodes (:mod:`l3cli.export.bands`).
    """
    i64 = np.int64
    s, q = patch, patch * patch
    planes = [g.window(rows, dx, s, 3) for dx in range(s)]  # (N, 1, S, w) each
    pat = g.op("Reshape", g.op("Concat", *planes, ones, axis=2), g.const([0, q + 1, -1], i64))
    pat = g.op("Unsqueeze", g.op("Transpose", pat, perm=[0, 2, 1]),
               g.const([3], i64))  # (N, w, q + 1, 1)
    cls = g.op("Reshape", classes, g.const([0, -1], i64))  # (N, w)
    coef = g.op("Reshape", g.op("Gather", kernels, cls, axis=0),
                g.const([0, 0, n_out, q + 1], i64))  # (N, w, n_out, q + 1)
    out = g.op("Reshape", g.op("MatMul", coef, pat), g.const([0, 0, n_out], i64))  # (N, w, C)
    return g.op("Unsqueeze", g.op("Transpose", out, perm=[0, 2, 1]), g.const([2], i64))


def tone_curve(g: Graph, x: str, lut: np.ndarray, lo_hi: np.ndarray) -> str:
    """:func:`l3cli.tone.curve.curve_row` on (N, C, H, W) ``x``: per channel, linear
    interpolation in the look-up table, the end entries outside its range. The entries
    are looked up by ``GatherElements`` on the flattened indices (a ``Gather`` copies each
    scalar with a call of its own: several times slower in ONNX Runtime)."""
    from l3cli.tone.curve import curve_arrays

    base, slope, lo, step_inv = curve_arrays(lut, lo_hi)
    n_out, n1 = base.shape
    col = (1, n_out, 1, 1)
    t = g.op("Mul", g.op("Sub", x, g.const(lo.reshape(col))), g.const(step_inv.reshape(col)))
    top = np.float32(n1 - 1) - np.float32(1e-3)
    t = g.op("Clip", t, g.const(np.float32(0.0)), g.const(top))
    i = g.op("Floor", t)
    flat = g.op("Add", g.cast(i, I64),
                g.const((np.arange(n_out, dtype=np.int64) * n1).reshape(col)))
    flat = g.op("Reshape", flat, g.const([1, -1], np.int64))
    shape = g.op("Shape", x)
    b, s = (g.op("Reshape", g.op("GatherElements", g.const(v.reshape(1, -1), hint=hint), flat,
                                 axis=1), shape)
            for v, hint in ((base, "curve_base"), (slope, "curve_slope")))
    return g.op("Add", b, g.op("Mul", g.op("Sub", t, i), s))


def adaptation(g: Graph, img: str, gains: str, model) -> str:
    """:func:`l3cli.whitebalance.model.adapt_image` with ``model.matrix(gains)`` per image
    (the table's output space is the model's, so no conversion): (N, 3, H, W)."""
    nf = model.center.size
    coef = model.coef
    if nf:
        logs = g.op("Log", g.cast(gains, F64))  # (N, 3)
        feats = np.array([[-1.0, -1.0], [0.0, 2.0], [1.0, -1.0]])[:, :nf]  # b-r, 2g-r-b
        f = g.op("Sub", g.op("MatMul", logs, g.const(feats)), g.const(model.center))
        vec = g.op("Add", g.op("MatMul", f, g.const(coef[1:])), g.const(coef[0]))  # (N, 9)
    else:
        zero = g.op("Mul", g.op("ReduceSum", g.cast(gains, F64), g.const([1], np.int64),
                                keepdims=1), g.const(0.0))  # (N, 1)
        vec = g.op("Add", zero, g.const(coef[0]))
    m = g.op("Reshape", g.cast(vec, F32), g.const([-1, 3, 3], np.int64))
    return g.op("Einsum", m, img, equation="nij,njhw->nihw")


def display(g: Graph, img: str, space: str, n_out: int, bits: int) -> str:
    """:func:`l3cli.io.encode.display_encode`'s recipe: to linear sRGB (``xyz``), clip,
    the sRGB transfer function in float64, ``round(v * (2**bits - 1))``: uint8/uint16."""
    from l3cli.colourspace import XYZ_TO_LINEAR_SRGB

    encode = n_out == 3 and space in ("xyz", "linear-srgb")
    v = img
    if encode and space == "xyz":
        m = np.asarray(XYZ_TO_LINEAR_SRGB, dtype=np.float64)
        v = g.cast(g.op("Einsum", g.const(m), g.cast(v, F64), equation="ij,njhw->nihw"), F32)
    zero, one = g.const(np.float32(0.0)), g.const(np.float32(1.0))
    v = g.op("Clip", v, zero, one)
    if encode:
        d = g.cast(v, F64)
        power = g.op("Sub", g.op("Mul", g.const(1.055), g.op("Pow", d, g.const(1 / 2.4))),
                     g.const(0.055))
        d = g.op("Where", g.op("LessOrEqual", d, g.const(0.0031308)),
                 g.op("Mul", d, g.const(12.92)), power)
        v = g.op("Clip", g.cast(d, F32), zero, one)
    q = g.op("Round", g.op("Mul", v, g.const(np.float32((1 << bits) - 1))))
    return g.cast(q, TensorProto.UINT8 if bits == 8 else TensorProto.UINT16)


def shading(g: Graph, mosaic: str, field, period: tuple[int, int], saturation: float,
            frame: str) -> str:
    """:func:`l3cli.lens.field.correct_mosaic` of (N, 1, H, W) ``mosaic`` by the table's gain
    field, evaluated in the graph (float64, as :func:`l3cli.lens.field.gain_map`) on the raw
    that int64 (4,) ``frame`` places the mosaic on: ``(full height, full width, top,
    left)``, or zeros for the mosaic itself (the table's CFA positions are the full raw's).
    A radial field (:class:`l3cli.lens.field.GainField`) is its polynomial in r² by Horner, a
    spline grid (:class:`l3cli.lens.grid.SplineField`) its tensor B-spline
    (:func:`_spline_gain`)."""
    i64 = np.int64
    ph, pw = period
    hw = g.dims(mosaic)
    full = g.slice(frame, [0], [2], [0])
    full = g.op("Where", g.op("Greater", full, g.const([0, 0], i64)), full, hw)
    origin = g.slice(frame, [2], [4], [0])
    size = g.cast(full, F64)
    half = g.op("Mul", g.const(0.5), g.op("Sqrt", g.op("ReduceSum", g.op("Mul", size, size),
                                                      keepdims=0)))
    coords, phase = [], []  # per axis: normalised coordinates and CFA phases (full raw's)
    for axis, p in enumerate((ph, pw)):
        first = g.op("Squeeze", g.slice(origin, [axis], [axis + 1], [0]), g.const([0], i64))
        n = g.op("Squeeze", g.slice(hw, [axis], [axis + 1], [0]), g.const([0], i64))
        k = g.op("Range", first, g.op("Add", first, n), g.const(1, i64))  # full-raw index
        edge = g.op("Mul", g.const(0.5), g.op("Squeeze", g.slice(size, [axis], [axis + 1], [0]),
                                              g.const([0], i64)))
        coords.append(g.op("Div", g.op("Sub", g.op("Add", g.cast(k, F64), g.const(0.5)), edge),
                           half))  # l3cli.lens.field.normalised_coords
        phase.append(g.op("Mod", k, g.const(p, i64)))
    if field.radial:
        gain = _radial_gain(g, field, coords, phase, pw)
    else:
        gain = _spline_gain(g, field, coords, phase, period)
    gain = g.op("Unsqueeze", g.cast(gain, F32), g.const([0, 1], i64))  # (1, 1, H, W)
    one = g.const(np.float32(1.0))
    prod = g.op("Mul", mosaic, gain)
    brighten = g.op("Min", prod, g.op("Max", mosaic, one))  # every gain >= 1: clip at white
    keep = g.op("Or", g.op("Less", mosaic, g.const(np.float32(saturation))),
                g.op("GreaterOrEqual", gain, one))
    mixed = g.op("Where", keep, prod, mosaic)  # a gain below one spares saturated pixels
    up = g.op("GreaterOrEqual", g.op("ReduceMin", gain, keepdims=0), one)
    return g.op("Where", up, brighten, mixed)


def _radial_gain(g: Graph, field, coords: list[str], phase: list[str], pw: int) -> str:
    """float64 (H, W): :meth:`l3cli.lens.field.GainField.plane` of each pixel's position."""
    i64 = np.int64
    cy, cx = (float(v) for v in field.centre)
    sq, ph_ = [], []
    for axis, (v, c) in enumerate(zip(coords, (cy, cx), strict=True)):
        shape = [-1, 1] if axis == 0 else [1, -1]
        d = g.op("Sub", v, g.const(c))
        sq.append(g.op("Reshape", g.op("Mul", d, d), g.const(shape, i64)))
        ph_.append(g.op("Reshape", phase[axis], g.const(shape, i64)))
    r2 = g.op("Add", *sq)  # float64 (H, W)
    pos = g.op("Add", g.op("Mul", ph_[0], g.const(pw, i64)), ph_[1])  # (H, W)
    coeffs = field.coeffs
    gain = None
    for j in range(coeffs.shape[1] - 1, -1, -1):  # Horner, as GainField.gains
        c = g.op("Gather", g.const(coeffs[:, j].copy()), pos, axis=0)
        gain = c if gain is None else g.op("Add", g.op("Mul", gain, r2), c)
    return gain


def _bspline_matrix(g: Graph, x: str, lo: float, hi: float, n: int) -> str:
    """float64 (len, n + 3): :func:`l3cli.lens.grid.bspline_matrix` of the float64 (len,)
    ``x`` (each row's four weights put in place by comparisons: the other entries are
    exact zeros)."""
    i64 = np.int64
    s = g.op("Mul", g.op("Div", g.op("Sub", g.op("Clip", x, g.const(lo), g.const(hi)),
                                     g.const(lo)), g.const(hi - lo)), g.const(float(n)))
    i = g.op("Min", g.cast(g.op("Floor", s), I64), g.const(n - 1, i64))
    f = g.op("Sub", s, g.cast(i, F64))
    f2 = g.op("Mul", f, f)
    f3 = g.op("Mul", f2, f)
    e = g.op("Sub", g.const(1.0), f)
    c = g.const
    w = [g.op("Mul", g.op("Mul", e, e), e),  # (1 - f)^3, ...
         g.op("Add", g.op("Sub", g.op("Mul", c(3.0), f3), g.op("Mul", c(6.0), f2)), c(4.0)),
         g.op("Add", g.op("Add", g.op("Add", g.op("Mul", c(-3.0), f3), g.op("Mul", c(3.0), f2)),
                             g.op("Mul", c(3.0), f)), c(1.0)),
         f3]
    w = g.op("Div", g.op("Concat", *(g.op("Unsqueeze", v, c([1], i64)) for v in w), axis=1),
             c(6.0))  # (len, 4)
    first = g.op("Add", g.op("Unsqueeze", i, c([1], i64)), c(np.arange(4, dtype=i64)))
    hit = g.op("Equal", g.op("Unsqueeze", first, c([2], i64)),
               c(np.arange(n + 3, dtype=i64).reshape(1, 1, -1)))  # (len, 4, n + 3)
    placed = g.op("Where", hit, g.op("Unsqueeze", w, c([2], i64)), c(0.0))
    return g.op("ReduceSum", placed, c([1], i64), keepdims=0)


def _spline_gain(g: Graph, field, coords: list[str], phase: list[str],
                 period: tuple[int, int]) -> str:
    """float64 (H, W): :meth:`l3cli.lens.grid.SplineField.plane` of each pixel's
    position, as two ``MatMul``s: the rows' basis (zero outside the row's CFA phase) times
    the control values of every position side by side, then times the columns' basis
    (zero outside the column's phase). Each pixel's sums hold the terms of its own
    position and exact zeros, in l3's association (rows first)."""
    from l3cli.lens.grid import frame_extent

    i64 = np.int64
    ph, pw = period
    ny, nx = field.intervals
    ext = frame_extent(*field.size)
    grid = field.grid.reshape(ph, pw, ny + 3, nx + 3).transpose(0, 2, 1, 3)
    masked = []
    for axis, (p, n) in enumerate(((ph, ny), (pw, nx))):
        basis = _bspline_matrix(g, coords[axis], -ext[axis], ext[axis], n)  # (len, n + 3)
        tiled = g.op("Tile", basis, g.const([1, p], i64))  # (len, p (n + 3))
        own = g.op("Equal", g.op("Unsqueeze", phase[axis], g.const([1], i64)),
                   g.const(np.repeat(np.arange(p, dtype=i64), n + 3)[None]))
        masked.append(g.op("Where", own, tiled, g.const(0.0)))
    rows = g.op("MatMul", masked[0],
                g.const(np.ascontiguousarray(grid.reshape(ph * (ny + 3), pw * (nx + 3))),
                        hint="shading_grid"))  # (H, pw (nx + 3))
    return g.op("MatMul", rows, g.op("Transpose", masked[1], perm=[1, 0]))
