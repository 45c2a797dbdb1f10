"""The stages around the classifier as ONNX nodes.

White-balance gains on the mosaic, the per-class affine kernels (one
``Gather`` of each tap's coefficients by class, then a multiply-add with the
shifted patch), condition-bin kernel interpolation, the learned tone curve's
look-up, the white-balance adaptation matrix, and the display encoding. Each
follows the function ``l3 render`` calls (named in its docstring); they
agree within float32 rounding of a different summation order.
"""

from __future__ import annotations

import numpy as np
from onnx import TensorProto

from l3cli.export.graph import Graph

__all__ = ["apply_gains", "adaptation", "affine", "condition_kernels", "display", "tone_curve"]

F32, F64, I64 = TensorProto.FLOAT, TensorProto.DOUBLE, TensorProto.INT64
_RGB = ("R", "G", "B")


def apply_gains(g: Graph, mosaic: str, gains: str, cfa, saturation: float) -> str:
    """:func:`l3cli.whitebalance.apply_gains`: each pixel times its channel's gain (``gains``
    float32 (N, 3), green = 1); a pixel saturated in the raw stays at or above its value."""
    ph, pw = cfa.period
    which = np.array([[_RGB.index(cfa.channel_at(y, x)) for x in range(pw)] for y in range(ph)])
    idx = g.op("Squeeze", g.periodic(which, mosaic, dtype=np.int64), g.const([0], np.int64))
    gmap = g.op("Gather", gains, idx, axis=1)  # (N, 1, H, W)
    out = g.op("Mul", mosaic, gmap)
    sat = g.op("GreaterOrEqual", mosaic, g.const(np.float32(saturation)))
    return g.op("Where", sat, g.op("Max", out, mosaic), out)


def condition_kernels(g: Graph, table, value: str) -> str:
    """float32 (q, n_out, n_classes): :func:`l3cli.conditions.kernels_for` of the float64
    (1,) ``value``; the pooled kernels where it is not a positive number (unknown)."""
    cond = table.conditions
    pooled = np.asarray(table.kernels, dtype=np.float64)
    bins = np.stack([np.where(cond.own[b][:, None, None], cond.kernels[b], table.kernels)
                     for b in range(cond.values.size)]).astype(np.float64)
    bins = bins.transpose(0, 2, 3, 1)  # (n_bins, q, n_out, n_classes)
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
    k = g.op("Where", known, k, g.const(pooled.transpose(1, 2, 0), hint="pooled"))
    return g.cast(k, F32)


def affine(g: Graph, padded: str, classes: str, kernels: str | np.ndarray, patch: int,
           n_out: int) -> str:
    """The affine kernel of each pixel's class on its patch: float32 (N, n_out, H, W).

    ``kernels``: float32 (q, n_out, n_classes), a constant array or a graph tensor.
    The taps run in a ``Loop`` (one tap per iteration: the coefficients of the
    pixels' classes by ``Gather``, times the patch value, added to the sum), so
    only one tap's temporaries are alive at a time; as separate nodes, ONNX
    Runtime schedules every tap's product before the first addition and holds
    them all (~600 bytes per pixel more for a 7x7 patch).
    """
    from onnx import helper

    if isinstance(kernels, np.ndarray):
        kernels = g.const(np.ascontiguousarray(kernels), hint="kernels")
    q = patch * patch
    i64 = np.int64
    cls = g.op("Squeeze", classes, g.const([1], i64))  # (N, H, W)
    hw = g.slice(g.op("Shape", cls), [1], [3], [0])  # (H, W)
    bias = g.op("Gather", kernels, g.const(q, i64), axis=0)  # (n_out, n_classes)
    acc0 = g.op("Gather", bias, cls, axis=1)  # the constant term: (n_out, N, H, W)

    b = Graph(prefix="tap_")
    t = b.add_input("tap_t", TensorProto.INT64, [])
    b.add_input("tap_cond", TensorProto.BOOL, [])
    acc = b.add_input("tap_acc", TensorProto.FLOAT, ["n_out", "N", "H", "W"])
    s = b.const(patch, i64)
    start = b.op("Concat", b.op("Unsqueeze", b.op("Div", t, s), b.const([0], i64)),
                 b.op("Unsqueeze", b.op("Mod", t, s), b.const([0], i64)), axis=0)  # (dy, dx)
    window = b.op("Slice", padded, start, b.op("Add", start, hw), b.const([2, 3], i64))
    p = b.op("Squeeze", window, b.const([1], i64))  # (N, H, W)
    w = b.op("Gather", b.op("Gather", kernels, t, axis=0), cls, axis=1)  # (n_out, N, H, W)
    out = b.op("Add", acc, b.op("Mul", w, p))
    b.outputs.append(helper.make_tensor_value_info("tap_cond_out", TensorProto.BOOL, []))
    b.nodes.append(helper.make_node("Identity", ["tap_cond"], ["tap_cond_out"]))
    b.add_output(out, "tap_acc_out", TensorProto.FLOAT, ["n_out", "N", "H", "W"])
    total = g.op("Loop", g.const(q, i64), "", acc0, body=b.subgraph("taps"))
    return g.op("Transpose", total, perm=[1, 0, 2, 3])


def tone_curve(g: Graph, x: str, lut: np.ndarray, lo_hi: np.ndarray) -> str:
    """:func:`l3cli.tonecurve.curve_row` on (N, C, H, W) ``x``: per channel, linear
    interpolation in the look-up table, the end entries outside its range."""
    from l3cli.tonecurve import curve_arrays

    base, slope, lo, step_inv = curve_arrays(lut, lo_hi)
    n_out, n1 = base.shape
    col = (1, n_out, 1, 1)
    t = g.op("Mul", g.op("Sub", x, g.const(lo.reshape(col))), g.const(step_inv.reshape(col)))
    top = np.float32(n1 - 1) - np.float32(1e-3)
    t = g.op("Clip", t, g.const(np.float32(0.0)), g.const(top))
    i = g.op("Floor", t)
    flat = g.op("Add", g.cast(i, I64),
                g.const((np.arange(n_out, dtype=np.int64) * n1).reshape(col)))
    b = g.op("Gather", g.const(base.reshape(-1), hint="curve_base"), flat, axis=0)
    s = g.op("Gather", g.const(slope.reshape(-1), hint="curve_slope"), flat, axis=0)
    return g.op("Add", b, g.op("Mul", g.op("Sub", t, i), s))


def adaptation(g: Graph, img: str, gains: str, model) -> str:
    """:func:`l3cli.whitebalance.adapt_image` with ``model.matrix(gains)`` per image
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
