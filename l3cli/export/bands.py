"""The frame rendered in bands of rows by an ONNX ``Loop``, as the tile kernel renders tiles.

A whole-frame graph holds every intermediate of the classifier and the
kernels at the frame's size at once (per pixel, 49 tap products of a 7x7
patch or the row of 147 coefficients gathered for it): gigabytes for a 12 MP
frame, and operators that stream through memory rather than cache. So the
graph pads the frame once (the CFA-phase mirror of ``l3 render``), then a
``Loop`` renders one band of :data:`BAND_ROWS` rows per iteration from the
padded rows it needs (the band and ``patch // 2`` rows on either side:
every band's classes and outputs are those of the whole frame, bit for bit
for the classes) and returns it as a scan output; the bands are joined and
the rows past the frame's last dropped. The band's size is fixed (the padded
frame is extended at the bottom with zero rows to a whole number of bands),
so the CFA-periodic maps the classifier needs are built once, before the loop.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from onnx import TensorProto, helper

from l3cli.classify import ClassDefinition
from l3cli.export.classify import Patterns, band_classes
from l3cli.export.graph import Graph

__all__ = ["BAND_ROWS", "SUB_ROWS", "render_bands"]

#: Rows per iteration of the band loop (rounded up to whole CFA periods): a 4000-pixel-wide
#: band of 16 rows holds about 38 MB of gathered coefficients at patch 7, 3 outputs. Fewer
#: rows stream less through memory but recompute more of the patches' margin rows (6 at
#: patch 7) and pay the ~260 nodes' overhead more often: 16 was the fastest of 8, 16 and 32
#: (``docs/export.md``, Speed).
BAND_ROWS = 16
#: Rows of a band the kernels render at a time (an inner ``Loop``; a divisor of the band):
#: their temporaries (588 bytes a pixel of gathered coefficients at patch 7, 3 outputs)
#: stay in the cache.
SUB_ROWS = 1

#: ``body(graph, padded_band, classes) -> image``: builds one band's image (N, C, h, w)
#: in the loop's body graph from its padded mosaic (N, 1, h + 2r, w + 2r) and its
#: int64 classes (N, 1, h, w).
Body = Callable[[Graph, str, str], str]


def _pad_bottom(g: Graph, x: str, rows: str) -> str:
    """(N, 1, H, W) ``x`` with ``rows`` (int64 scalar) zero rows added at the bottom."""
    i64 = np.int64
    pads = g.op("Concat", g.const([0, 0, 0, 0, 0, 0], i64),
                g.op("Unsqueeze", rows, g.const([0], i64)), g.const([0], i64), axis=0)
    return g.op("Pad", x, pads)


def render_bands(g: Graph, d: ClassDefinition, mosaic: str, body: Body, *, n_out: int,
                 elem_type: int = TensorProto.FLOAT, guide: str | None = None,
                 rows: int = BAND_ROWS, sub_rows: int = SUB_ROWS) -> str:
    """(N, ``n_out``, H, W): ``body``'s image of every band of the (N, 1, H, W) ``mosaic``.

    ``guide`` (N, 1, H, W): the context guide of the whole frame
    (:func:`l3cli.export.classify.context_guide`), cut into the bands' rows.
    """
    i64 = np.int64
    r = d.patch // 2
    ph, pw = d.cfa.period
    step = np.lcm(ph, sub_rows)  # the band's first row keeps the frame's CFA phase
    band = int(-(-rows // step) * step)
    padded = g.pad_mirror(mosaic, r, (ph, pw))
    hw = g.dims(mosaic)
    h = g.op("Squeeze", g.slice(hw, [0], [1], [0]), g.const([0], i64))
    w = g.slice(hw, [1], [2], [0])  # (1,)
    n_bands = g.op("Div", g.op("Add", h, g.const(band - 1, i64)), g.const(band, i64))
    extra = g.op("Sub", g.op("Mul", n_bands, g.const(band, i64)), h)
    padded = _pad_bottom(g, padded, extra)
    if guide is not None:
        guide = _pad_bottom(g, guide, extra)
    out_hw = g.op("Concat", g.const([band], i64), w, axis=0)
    maps = Patterns(g, out_hw, g.op("Add", out_hw, g.const([2 * r, 2 * r], i64)))

    b = Graph(prefix="band_")
    i = b.add_input("band_i", TensorProto.INT64, [])
    b.add_input("band_cond", TensorProto.BOOL, [])
    y0 = b.op("Unsqueeze", b.op("Mul", i, b.const(band, i64)), b.const([0], i64))
    part = b.op("Slice", padded, y0, b.op("Add", y0, b.const([band + 2 * r], i64)),
                b.const([2], i64))
    part_guide = None
    if guide is not None:
        part_guide = b.op("Slice", guide, y0, b.op("Add", y0, b.const([band], i64)),
                          b.const([2], i64))
    img = _sub_bands(b, part, band_classes(b, d, part, maps, part_guide), body,
                     band=band, r=r, sub=sub_rows, n_out=n_out, elem_type=elem_type)
    b.outputs.append(helper.make_tensor_value_info("band_cond_out", TensorProto.BOOL, []))
    b.nodes.append(helper.make_node("Identity", ["band_cond"], ["band_cond_out"]))
    b.add_output(img, "band_img", elem_type, [band // sub_rows, "N", n_out, sub_rows, "W"])
    scan = g.op("Loop", n_bands, "", body=b.subgraph("bands"))  # (n_bands, n_sub, N, C, sub, W)
    joined = g.op("Transpose", scan, perm=[2, 3, 0, 1, 4, 5])
    shape = g.op("Concat", g.slice(g.op("Shape", mosaic), [0], [1], [0]),
                 g.const([n_out, -1], i64), w, axis=0)
    joined = g.op("Reshape", joined, shape)
    return g.op("Slice", joined, g.const([0], i64), g.op("Unsqueeze", h, g.const([0], i64)),
                g.const([2], i64))


def _sub_bands(b: Graph, part: str, classes: str, body: Body, *, band: int, r: int, sub: int,
               n_out: int, elem_type: int) -> str:
    """(band // sub, N, n_out, sub, W): ``body``'s image of a band, ``sub`` rows at a time
    (an inner ``Loop``), from the band's padded mosaic ``part`` and its ``classes``."""
    i64 = np.int64
    c = Graph(prefix=f"{b._name('rows')}_")
    j = c.add_input(c._name("j"), TensorProto.INT64, [])
    cond = c.add_input(c._name("cond"), TensorProto.BOOL, [])
    y0 = c.op("Unsqueeze", c.op("Mul", j, c.const(sub, i64)), c.const([0], i64))
    rows = c.op("Slice", part, y0, c.op("Add", y0, c.const([sub + 2 * r], i64)),
                c.const([2], i64))
    cls = c.op("Slice", classes, y0, c.op("Add", y0, c.const([sub], i64)), c.const([2], i64))
    img = body(c, rows, cls)
    c.add_output(cond, c._name("cond_out"), TensorProto.BOOL, [])
    c.add_output(img, c._name("img"), elem_type, ["N", n_out, sub, "W"])
    return b.op("Loop", b.const(band // sub, i64), "", body=c.subgraph("rows"))
