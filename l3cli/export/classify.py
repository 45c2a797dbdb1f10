"""The classification rule as ONNX nodes: padding, patch statistics, class index.

The graph computes what the tile kernel (:mod:`l3cli.classify.kernel`)
computes, in the same float32 operations in the same order, so every pixel
gets the same class bit for bit: per channel, the mask of the channel times
the padded mosaic, its square, their S-tap horizontal sums added left to
right, then the S-row vertical sums top to bottom (rows without the channel
add zeros, which changes no sum), the channel mean and variance, the
response level and the relative contrast. That is why the box sums are
chains of ``Add`` over shifted ``Slice`` views and not ``Conv`` nodes: a
convolution sums in the runtime's own order, and a last-bit difference in a
level or contrast moves pixels near a cut point into the neighbouring class.
Sums of 0/1 indicators (saturated pixels per patch) are exact in any order and
use ``Conv``; whether a patch holds a saturated pixel of a channel is a
``MaxPool`` along the rows then down the columns, skipped (an ``If``) in a
band without a saturated pixel.

Bins: the level bin is the number of level cuts at or below the level
(one broadcast comparison with every float32 cut, summed, which equals the
kernel's bucket lookup), the contrast bin the number of the
level's contrast thresholds at or below the contrast.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from onnx import TensorProto

from l3cli.classify import ClassDefinition
from l3cli.classify.features import orientation_centres
from l3cli.classify.layout import kernel_tables
from l3cli.export.graph import Graph

__all__ = ["Classes", "Patterns", "band_classes", "classify_nodes", "context_guide"]

F32, F64, I64 = TensorProto.FLOAT, TensorProto.DOUBLE, TensorProto.INT64


class Classes(NamedTuple):
    """Names of the classification's results in the graph."""

    #: float32 (N, 1, H + 2r, W + 2r): the padded mosaic (what the kernels weight).
    padded: str
    #: int64 (N, 1, H, W): the flat class index of every pixel.
    index: str


def _search(g: Graph, value: str, cuts: np.ndarray) -> str:
    """int64: how many of the increasing float32 ``cuts`` are <= ``value`` (N, 1, h, w):
    one broadcast comparison with every cut, its 0/1 values summed in float32 (exact:
    small whole numbers), which costs about half of a binary search's ``Gather`` steps."""
    hit = g.op("LessOrEqual", g.const(np.asarray(cuts, np.float32).reshape(-1, 1, 1, 1, 1)),
               g.op("Unsqueeze", value, g.const([0], np.int64)))  # (n, N, 1, h, w)
    count = g.op("ReduceSum", g.cast(hit, F32), g.const([0], np.int64), keepdims=0)
    return g.cast(count, I64)


def _saturation(g: Graph, saturated_f: str, masks: list[str], s: int, like: str) -> str:
    """int64 (N, 1, h, w): bit ``c`` set where the patch holds a saturated channel-``c``
    pixel (``saturated_f`` the padded band's 0/1 saturated pixels, ``masks`` each
    channel's 0/1 positions). Each channel's patch maximum is a ``MaxPool`` along the
    rows then down the columns (a maximum is exact in any order); a band without a
    saturated pixel skips them (an ``If``: zeros of the shape of ``like``)."""
    def pooled(b: Graph) -> str:
        sat = None
        for c, mask in enumerate(masks):
            hit = b.op("Mul", saturated_f, mask)
            anyc = b.op("MaxPool", b.op("MaxPool", hit, kernel_shape=[1, s]),
                        kernel_shape=[s, 1])
            bit = b.op("Mul", b.cast(anyc, I64), b.const(1 << c, np.int64))
            sat = bit if sat is None else b.op("Add", sat, bit)
        return sat

    def none(b: Graph) -> str:
        return b.op("Expand", b.const(np.int64(0)), b.op("Shape", like))

    any_sat = g.op("Greater", g.op("ReduceMax", saturated_f, keepdims=0),
                   g.const(np.float32(0.0)))
    return g.if_else(any_sat, pooled, none, I64)


def _orientation(g: Graph, d: ClassDefinition, padded: str) -> str:
    """int64 (N, 1, H, W) orientation bin (0 = isotropic), as the tile kernel finds it."""
    t = kernel_tables(d)
    ph, pw = d.cfa.period
    s = d.patch
    # quads of padded rows k - ph and k, columns xx and xx + pw
    top = g.window(padded, 0, ph + 1, 2)  # row k - ph
    bot = g.window(padded, ph, ph + 1, 2)  # row k
    a, b = g.window(top, 0, pw + 1, 3), g.window(top, pw, pw + 1, 3)
    c, e = g.window(bot, 0, pw + 1, 3), g.window(bot, pw, pw + 1, 3)
    gx = g.op("Add", g.op("Sub", b, a), g.op("Sub", e, c))
    gy = g.op("Add", g.op("Sub", c, a), g.op("Sub", e, b))
    sums = []
    for prod in (g.op("Mul", gx, gx), g.op("Mul", gy, gy), g.op("Mul", gx, gy)):
        hs = g.chain_sum(prod, s - pw, 3)  # width W + 2r - pw - (s - pw - 1) = W
        # padded quad row k (>= ph) is index k - ph here; rows dy = ph .. S-1 of the patch
        sums.append(g.chain_sum(hs, s - ph, 2))
    jxx, jyy, jxy = sums
    u = g.op("Sub", jxx, jyy)
    v = g.op("Mul", g.const(np.float32(2.0)), jxy)
    tt = g.op("Add", jxx, jyy)
    coh = g.op("Sub", g.op("Add", g.op("Mul", u, u), g.op("Mul", v, v)),
               g.op("Mul", g.const(t.coh2), g.op("Mul", tt, tt)))
    oc, os_ = orientation_centres(d.orientation_bins)
    best = g.op("Add", g.op("Mul", u, g.const(oc[0])), g.op("Mul", v, g.const(os_[0])))
    bin_ = g.const(1, np.int64)  # bin 1 (angle 0) until a later centre is nearer
    for j in range(1, oc.size):
        pr = g.op("Add", g.op("Mul", u, g.const(oc[j])), g.op("Mul", v, g.const(os_[j])))
        take = g.op("Greater", pr, best)
        best = g.op("Where", take, pr, best)
        bin_ = g.op("Where", take, g.const(j + 1, np.int64), bin_)
    return g.op("Where", g.op("Greater", coh, g.const(np.float32(0.0))), bin_,
                g.const(0, np.int64))


def _axis_weights(g: Graph, n: str, nb: str, block: int) -> tuple[str, str, str]:
    """Lower and upper block index and float32 weight of each pixel along one axis
    (:func:`l3cli.classify.features._interp_weights`, in float64 as there)."""
    f64 = np.float64
    k = g.op("Range", g.const(0.0), g.cast(n, F64), g.const(1.0))
    f = g.op("Sub", g.op("Div", g.op("Add", k, g.const(0.5)), g.const(f64(block))),
             g.const(0.5))
    last = g.op("Sub", nb, g.const(1, np.int64))
    f = g.op("Clip", f, g.const(0.0), g.cast(last, F64))
    i0f = g.op("Floor", f)
    i0 = g.cast(i0f, I64)
    i1 = g.op("Min", g.op("Add", i0, g.const(1, np.int64)), last)
    return i0, i1, g.cast(g.op("Sub", f, i0f), F32)


def context_guide(g: Graph, d: ClassDefinition, mosaic: str) -> str:
    """float32 (N, 1, H, W): the context guide of :func:`l3cli.classify.features.context_map`
    over the whole (N, 1, H, W) ``mosaic`` (block means in float64, bilinear in float32)."""
    t = kernel_tables(d)
    blk = d.context_block
    i64 = np.int64
    hw = g.dims(mosaic)
    h = g.op("Squeeze", g.slice(hw, [0], [1], [0]), g.const([0], i64))
    w = g.op("Squeeze", g.slice(hw, [1], [2], [0]), g.const([0], i64))
    b = g.const(blk, i64)
    nby, nbx = (g.op("Div", g.op("Add", v, g.const(blk - 1, i64)), b) for v in (h, w))
    pad_y, pad_x = (g.op("Sub", g.op("Mul", nb, b), v) for nb, v in ((nby, h), (nbx, w)))
    zero = g.const([0], i64)
    pads = g.op("Concat", zero, zero, zero, zero, zero, zero,
                *(g.op("Unsqueeze", v, zero) for v in (pad_y, pad_x)), axis=0)
    shape = g.op("Concat", g.const([0, 1, -1, blk], i64), g.op("Unsqueeze", nbx, zero),
                 g.const([blk], i64), axis=0)  # (N, 1, nby, B, nbx, B)

    def blocks(x: str) -> str:
        return g.op("ReduceSum", g.op("Reshape", g.op("Pad", x, pads), shape),
                    g.const([3, 5], i64), keepdims=0)

    x64 = g.cast(mosaic, F64)
    total = present = None
    for c in range(d.cfa.n_channels):
        mask = g.periodic((t.idx_pattern == c).astype(np.float64), mosaic, dtype=np.float64)
        sums, counts = blocks(g.op("Mul", x64, mask)), blocks(mask)
        mean = g.op("Div", sums, g.op("Max", counts, g.const(1.0)))
        has = g.cast(g.op("Greater", counts, g.const(0.0)), F64)
        total = mean if total is None else g.op("Add", total, mean)
        present = has if present is None else g.op("Add", present, has)
    grid = g.cast(g.op("Div", total, g.op("Max", present, g.const(1.0))), F32)
    r0, r1, wy = _axis_weights(g, h, nby, blk)
    c0, c1, wx = _axis_weights(g, w, nbx, blk)
    one = g.const(np.float32(1.0))
    wy = g.op("Unsqueeze", wy, g.const([1], i64))  # (H, 1)
    rows = g.op("Add", g.op("Mul", g.op("Gather", grid, r0, axis=2), g.op("Sub", one, wy)),
                g.op("Mul", g.op("Gather", grid, r1, axis=2), wy))
    return g.op("Add", g.op("Mul", g.op("Gather", rows, c0, axis=3), g.op("Sub", one, wx)),
                g.op("Mul", g.op("Gather", rows, c1, axis=3), wx))


def _context_bins(g: Graph, d: ClassDefinition, guide: str, lev: str) -> str:
    """int64 context bin of every pixel: the guide's, or the level over it (``ratio``)."""
    t = kernel_tables(d)
    if d.context_rule == "ratio":
        zero32 = g.const(np.float32(0.0))
        guide = g.op("Div", g.op("Max", lev, zero32),
                     g.op("Add", g.op("Max", guide, zero32), g.const(t.ctx_eps)))
    out = None
    for cut in t.xcuts:
        hit = g.cast(g.op("GreaterOrEqual", guide, g.const(np.float32(cut))), I64)
        out = hit if out is None else g.op("Add", out, hit)
    return out


class Patterns:
    """CFA-periodic maps (the pattern tiled from a band's origin) of the size of a band's
    output (``out_hw``) or of its padded input (``pad_hw``), built once in ``outer`` (the
    graph around a band loop, so that its iterations do not rebuild them)."""

    def __init__(self, outer: Graph, out_hw: str, pad_hw: str) -> None:
        self._g, self._hw, self._made = outer, {False: out_hw, True: pad_hw}, {}

    def __call__(self, pattern: np.ndarray, *, padded: bool = False, dtype=np.float32) -> str:
        arr = np.asarray(pattern, dtype=dtype)
        key = (padded, arr.dtype.str, arr.shape, arr.tobytes())
        if key not in self._made:
            self._made[key] = self._g.tile(arr, self._hw[padded], arr.dtype)
        return self._made[key]


def classify_nodes(g: Graph, d: ClassDefinition, mosaic: str) -> Classes:
    """Add the classification of the whole (N, 1, H, W) float32 ``mosaic`` to ``g``."""
    padded = g.pad_mirror(mosaic, d.patch // 2, d.cfa.period)
    maps = Patterns(g, g.dims(mosaic), g.dims(padded))
    guide = context_guide(g, d, mosaic) if d.context_block else None
    return Classes(padded, band_classes(g, d, padded, maps, guide))


def band_classes(g: Graph, d: ClassDefinition, padded: str, maps: Patterns,
                 guide: str | None = None) -> str:
    """int64 (N, 1, h, w): the class of every pixel of a band of rows, from the band's
    padded mosaic (N, 1, h + 2r, w + 2r), whose first row has the CFA phase of the
    padded frame's; ``maps`` tiles patterns to the band's sizes, ``guide`` is the band's
    rows of :func:`context_guide` (tables with context bins)."""
    t = kernel_tables(d)
    s, r = d.patch, d.patch // 2
    ph, pw = d.cfa.period
    nch = d.cfa.n_channels
    # padded-image channel of every pixel: the pattern shifted by r (phase kept)
    shifted = np.roll(t.idx_pattern, (r % ph, r % pw), axis=(0, 1))
    positions = np.arange(ph * pw).reshape(ph, pw)
    f32 = np.float32
    lev = spr = None
    saturated = g.op("GreaterOrEqual", padded, g.const(t.sat_thr))
    saturated_f = g.cast(saturated, F32)
    masks = []
    for c in range(nch):
        mask = maps((shifted == c).astype(f32), padded=True)
        u = g.op("Mul", padded, mask)
        q = g.op("Mul", u, padded)
        va = g.chain_sum(g.chain_sum(u, s, 3), s, 2)
        vq = g.chain_sum(g.chain_sum(q, s, 3), s, 2)
        ci = maps(t.cnt_inv[positions, c])
        wc = maps(t.wc[positions, c])
        m = g.op("Mul", va, ci)
        var = g.op("Sub", g.op("Mul", vq, ci), g.op("Mul", m, m))
        dl = g.op("Mul", m, wc)
        ds = g.op("Mul", g.op("Sqrt", g.op("Max", var, g.const(f32(0.0)))), wc)
        lev = dl if lev is None else g.op("Add", lev, dl)
        spr = ds if spr is None else g.op("Add", spr, ds)
        masks.append(mask)
    sat = _saturation(g, saturated_f, masks, s, lev)
    contrast = g.op("Div", spr, g.op("Add", g.op("Max", lev, g.const(f32(0.0))),
                                     g.const(t.eps)))
    lbin = _search(g, lev, d.level_cuts.astype(f32))
    ncc = d.n_contrast - 1
    cbin = None
    for j in range(ncc):
        cut = t.ccuts[:, j]
        if np.all(cut == cut[0]):  # the same threshold at every level (the defaults')
            th = g.const(np.float32(cut[0]))
        else:
            th = g.op("Gather", g.const(cut.copy()), lbin, axis=0)
        hit = g.cast(g.op("GreaterOrEqual", contrast, th), I64)
        cbin = hit if cbin is None else g.op("Add", cbin, hit)
    group = maps(d.position_group[positions], dtype=np.int64)
    idx = g.op("Add", g.op("Mul", group, g.const(d.n_saturation, np.int64)), sat)
    idx = g.op("Add", g.op("Mul", idx, g.const(d.n_levels, np.int64)), lbin)
    idx = g.op("Mul", idx, g.const(d.n_contrast, np.int64))
    if cbin is not None:
        idx = g.op("Add", idx, cbin)
    n_ext = d.n_orientation * d.n_context * d.n_highlight
    if n_ext > 1:
        ext = _orientation(g, d, padded) if d.orientation_bins else g.const(0, np.int64)
        if d.context_block:
            ext = g.op("Add", g.op("Mul", ext, g.const(d.n_context, np.int64)),
                       _context_bins(g, d, guide, lev))
        if d.highlight_bins:
            ones = g.const(np.ones((1, 1, s, s), f32))
            count = g.op("Conv", saturated_f, ones)  # 0/1 sums: exact
            hl = g.cast(g.op("GreaterOrEqual", count, g.const(t.hl_cnt)), I64)
            ext = g.op("Add", g.op("Mul", ext, g.const(d.n_highlight, np.int64)), hl)
        idx = g.op("Add", g.op("Mul", idx, g.const(n_ext, np.int64)), ext)
    return idx
