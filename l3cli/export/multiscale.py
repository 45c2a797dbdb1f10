"""The multi-scale stage (:mod:`l3cli.multiscale.stage`, rule ``gauss-bands-v2``) as ONNX nodes.

:func:`stage` takes the rendered float image (N, C, H, W) in the table's output
space and returns the stage's output, as :func:`l3cli.multiscale.stage.apply_stage`
computes it: the sRGB coding from the same table (its bucket found by exact
comparisons with powers of two, :func:`coding`), the pyramid of 2 x 2 block means
(``AveragePool`` with ``ceil_mode``: cut-short blocks average their own pixels),
the Gaussians with scipy's ``"reflect"`` borders (``Gather`` of reflected indices
computed from the input's shape, then a per-channel ``Conv``), the bilinear
upsampling (columns, then rows), the band energy, the coarse classes (counts of
the cuts a value reaches) and the blend (``Gather`` of each pixel's class's
matrices, ``Einsum``). Sums run in ONNX Runtime's order, so values agree within
float32 rounding; a class can differ only where a level or energy lies within
that rounding of a cut.
"""

from __future__ import annotations

import numpy as np
from onnx import TensorProto

from l3cli.export.graph import Graph

__all__ = ["coding", "stage"]

F32, I64 = TensorProto.FLOAT, TensorProto.INT64


def _scalar_dim(g: Graph, x: str, axis: int) -> str:
    """int64 scalar: ``x.shape[axis]``."""
    d = g.slice(g.op("Shape", x), [axis], [axis + 1], [0])
    return g.op("Squeeze", d, g.const([0], np.int64))


def _reflect_indices(g: Graph, n: str, r: int) -> str:
    """int64 (n + 2r,): scipy's ``"reflect"`` index of ``-r .. n + r - 1`` (any distance out)."""
    i64 = np.int64
    i = g.op("Range", g.const(-r, i64), g.op("Add", n, g.const(r, i64)), g.const(1, i64))
    p = g.op("Mul", n, g.const(2, i64))
    m = g.op("Mod", i, p, fmod=0)  # in [0, 2n)
    return g.op("Where", g.op("Less", m, n), m,
                g.op("Sub", g.op("Sub", p, g.const(1, i64)), m))


def _gauss(g: Graph, x: str, sigma: float, channels: int) -> str:
    """:func:`l3cli.multiscale.stage.lowpass` of (N, C, H, W) ``x``: along H, then along W."""
    from l3cli.multiscale.stage import gauss_taps

    half = gauss_taps(sigma).astype(np.float32)
    r = half.size - 1
    full = np.concatenate([half[:0:-1], half]).astype(np.float32)
    for axis in (2, 3):
        idx = _reflect_indices(g, _scalar_dim(g, x, axis), r)
        padded = g.op("Gather", x, idx, axis=axis)
        shape = (channels, 1, full.size, 1) if axis == 2 else (channels, 1, 1, full.size)
        w = g.const(np.broadcast_to(full.reshape(shape[2:]), shape).copy(), hint="gauss")
        x = g.op("Conv", padded, w, group=channels)
    return x


def _upsample(g: Graph, lo: str, like: str, f: int, axis: int) -> str:
    """Bilinear upsampling of ``lo`` by ``f`` along ``axis`` to ``like``'s size there: the
    place ``s = (2 x + 1 - f) / (2 f)``, the samples on either side (clamped), weights
    ``1 - t`` and ``t`` (:func:`l3cli.multiscale._loops.upsample_cols`)."""
    n = _scalar_dim(g, like, axis)
    top = g.cast(g.op("Sub", _scalar_dim(g, lo, axis), g.const(1, np.int64)), F32)
    x = g.cast(g.op("Range", g.const(0, np.int64), n, g.const(1, np.int64)), F32)
    s = g.op("Div", g.op("Add", g.op("Mul", x, g.const(np.float32(2.0))),
                         g.const(np.float32(1 - f))), g.const(np.float32(2 * f)))
    i0 = g.op("Floor", s)
    t = g.op("Sub", s, i0)
    zero = g.const(np.float32(0.0))
    a = g.cast(g.op("Min", g.op("Max", i0, zero), top), I64)
    b = g.cast(g.op("Min", g.op("Max", g.op("Add", i0, g.const(np.float32(1.0))), zero), top),
               I64)
    if axis == 2:
        t = g.op("Unsqueeze", t, g.const([1], np.int64))  # (H, 1): broadcast along W
    t0 = g.op("Sub", g.const(np.float32(1.0)), t)
    return g.op("Add", g.op("Mul", t0, g.op("Gather", lo, a, axis=axis)),
                g.op("Mul", t, g.op("Gather", lo, b, axis=axis)))


def coding(g: Graph, x: str, inverse: bool) -> str:
    """:func:`l3cli.multiscale.stage.encode` (``inverse``: ``decode``) of ``x``: the linear
    segment, the table (its bucket: the octave by comparisons with powers of two, the
    place in it exactly), the formula beyond the table; odd."""
    from l3cli.multiscale.stage import CODE_SHIFT, code_table

    base, slope, first, last = code_table(inverse)
    per_octave = 1 << (23 - CODE_SHIFT)
    a = g.op("Abs", x)
    e_lo = (first >> (23 - CODE_SHIFT)) - 127  # the table's first and last octaves
    e_hi = (last >> (23 - CODE_SHIFT)) - 127
    powers = np.float32(2.0) ** np.arange(e_lo + 1, e_hi + 1, dtype=np.float32)
    ge = g.cast(g.op("GreaterOrEqual", g.op("Unsqueeze", a, g.const([-1], np.int64)),
                     g.const(powers)), I64)
    e = g.op("Add", g.op("ReduceSum", ge, g.const([-1], np.int64), keepdims=0),
             g.const(e_lo, np.int64))  # floor(log2 a) within the table's octaves
    octave = g.op("Gather", g.const(np.float32(2.0) ** np.arange(e_lo, e_hi + 1,
                                                                 dtype=np.float32)),
                  g.op("Sub", e, g.const(e_lo, np.int64)), axis=0)
    m = g.op("Div", a, octave)  # in [1, 2) inside the table
    idx = g.op("Floor", g.op("Mul", g.op("Sub", m, g.const(np.float32(1.0))),
                             g.const(np.float32(per_octave))))
    start = g.op("Mul", octave, g.op("Add", g.const(np.float32(1.0)),
                                     g.op("Div", idx, g.const(np.float32(per_octave)))))
    k = g.op("Add", g.op("Mul", g.op("Add", e, g.const(127, np.int64)),
                         g.const(per_octave, np.int64)), g.cast(idx, I64))
    k = g.op("Min", g.op("Max", g.op("Sub", k, g.const(first, np.int64)),
                         g.const(0, np.int64)), g.const(last - first, np.int64))
    table = g.op("Add", g.op("Gather", g.const(base), k, axis=0),
                 g.op("Mul", g.op("Gather", g.const(slope), k, axis=0), g.op("Sub", a, start)))
    if inverse:
        lin = g.op("Div", a, g.const(np.float32(12.92)))
        edge = np.float32(0.04045)
        formula = g.op("Pow", g.op("Div", g.op("Add", a, g.const(np.float32(0.055))),
                                   g.const(np.float32(1.055))), g.const(np.float32(2.4)))
    else:
        lin = g.op("Mul", g.const(np.float32(12.92)), a)
        edge = np.float32(0.0031308)
        formula = g.op("Sub", g.op("Mul", g.const(np.float32(1.055)),
                                   g.op("Pow", a, g.const(np.float32(1 / 2.4)))),
                       g.const(np.float32(0.055)))
    top = np.uint32((last + 1) << CODE_SHIFT).view(np.float32)  # the first value past it
    out = g.op("Where", g.op("LessOrEqual", a, g.const(edge)), lin,
               g.op("Where", g.op("Less", a, g.const(np.float32(top))), table, formula))
    return g.op("Mul", g.op("Sign", x), out)


def stage(g: Graph, img: str, ms) -> str:
    """The stage ``ms`` (:class:`l3cli.multiscale.stage.Multiscale`) on (N, C, H, W) ``img``."""
    from l3cli.multiscale.stage import factor, low_sigma

    c = ms.n_out
    coded = ms.transfer == "srgb"
    u = coding(g, img, False) if coded else img
    pyramid = {1: u}
    lps = []
    for s in ms.sigmas:
        f = factor(s)
        if f == 1:
            lps.append(_gauss(g, u, float(s), c))
            continue
        k = 2
        while k <= f:
            if k not in pyramid:
                pyramid[k] = g.op("AveragePool", pyramid[k // 2], kernel_shape=[2, 2],
                                  strides=[2, 2], ceil_mode=1)
            k *= 2
        lo = _gauss(g, pyramid[f], low_sigma(s, f), c)
        lps.append(_upsample(g, _upsample(g, lo, u, f, 3), u, f, 2))  # columns, then rows
    coarse = lps[-1]
    bands = [g.op("Sub", u if j == 0 else lps[j - 1], lps[j]) for j in range(len(lps))]
    d = g.op("Sub", u, coarse)
    e = g.op("ReduceMean", g.op("Mul", d, d), axes=[1], keepdims=1)  # (N, 1, H, W)
    e = _gauss(g, e, float(ms.sigmas[0]), 1)
    en = g.op("Sqrt", g.op("Max", e, g.const(np.float32(0.0))))
    lev = g.op("ReduceMean", coarse, axes=[1], keepdims=1)
    cuts = ms.level_cuts.astype(np.float32).reshape(1, -1, 1, 1)
    if not cuts.size:  # one level: bin 0 everywhere
        cuts = np.full((1, 1, 1, 1), np.inf, np.float32)
    lb = g.op("ReduceSum", g.cast(g.op("GreaterOrEqual", lev, g.const(cuts)), I64),
              g.const([1], np.int64), keepdims=0)
    ne = ms.energy_cuts.shape[1]
    cls = g.op("Mul", lb, g.const(ne + 1, np.int64))  # (N, H, W)
    if ne:
        ecuts = g.op("Gather", g.const(ms.energy_cuts.astype(np.float32)), lb, axis=0)
        env = g.op("Unsqueeze", g.op("Squeeze", en, g.const([1], np.int64)),
                   g.const([-1], np.int64))
        eb = g.op("ReduceSum", g.cast(g.op("GreaterOrEqual", env, ecuts), I64),
                  g.const([-1], np.int64), keepdims=0)
        cls = g.op("Add", cls, eb)
    a = g.op("Gather", g.const(ms.blend, hint="blend"), cls, axis=0)  # (N, H, W, R, C)
    stack = g.op("Concat", *bands, axis=1)  # (N, R, H, W): band j, channel c at j C + c
    out = g.op("Add", coarse, g.op("Einsum", stack, a, equation="nrhw,nhwrc->nchw"))
    return coding(g, out, True) if coded else out
