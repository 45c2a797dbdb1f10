"""The frame rendered in bands of rows by an ONNX ``Loop``, as the tile kernel renders tiles.

A whole-frame graph holds every intermediate of the classifier and the
kernels at the frame's size at once (per pixel, 49 tap products of a 7x7
patch or the row of 150 coefficients gathered for it): gigabytes for a 12 MP
frame, and operators that stream through memory rather than cache. So the
graph pads the frame once (the CFA-phase mirror of ``l3 render``), then a
``Loop`` renders one band of :data:`BAND_ROWS` rows per iteration from the
padded rows it needs (the band and ``patch // 2`` rows on either side:
every band's classes and outputs are those of the whole frame, bit for bit
for the classes) and returns it as a scan output; the bands are joined and
the rows past the frame's last dropped. The band's size is fixed (the padded
frame is extended at the bottom with zero rows to a whole number of bands),
so the CFA-periodic maps the classifier needs are built once, before the loop.

Inside a band, the classes are found for the whole band, then an inner
``Loop`` applies the kernels one output row at a time (:data:`RowBody`): a
row's gathered coefficients and patches (600 bytes a pixel at patch 7, 3
outputs: 2.4 MB for 4000 pixels) stay in the cache from one node to the
next, where a band's (38 MB) would stream through memory. The per-pixel
stages after the kernels (:data:`PixelBody`: the tone curve, ...) then run
on the band's rows together.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from onnx import TensorProto

from l3cli.classify import ClassDefinition
from l3cli.export.classify import Patterns, band_classes
from l3cli.export.graph import Graph

__all__ = ["BAND_ROWS", "render_bands"]

#: Rows per iteration of the band loop (rounded up to whole CFA periods). More rows
#: recompute fewer of the patches' margin rows (6 at patch 7) in the classifier and pay
#: its ~250 nodes' overhead less often; 16 and 32 measured alike, 8 slower
#: (``docs/export.md``, Speed).
BAND_ROWS = 16

#: ``row_body(graph, padded_rows, classes) -> image``: builds one output row's image
#: (N, C, 1, w) in the inner loop's body graph from its padded mosaic rows
#: (N, 1, patch, w + 2r) and its int64 classes (N, 1, 1, w).
RowBody = Callable[[Graph, str, str], str]
#: ``pixel_body(graph, image) -> image``: the per-pixel stages on a band's image
#: (N, C, h, w), in the band loop's body graph.
PixelBody = Callable[[Graph, str], str]


def _pad_bottom(g: Graph, x: str, rows: str) -> str:
    """(N, 1, H, W) ``x`` with ``rows`` (int64 scalar) zero rows added at the bottom."""
    i64 = np.int64
    pads = g.op("Concat", g.const([0, 0, 0, 0, 0, 0], i64),
                g.op("Unsqueeze", rows, g.const([0], i64)), g.const([0], i64), axis=0)
    return g.op("Pad", x, pads)


def _body_graph(prefix: str) -> tuple[Graph, str, str]:
    """A ``Loop`` body graph with its iteration number and condition inputs."""
    b = Graph(prefix=prefix)
    i = b.add_input(b._name("i"), TensorProto.INT64, [])
    cond = b.add_input(b._name("cond"), TensorProto.BOOL, [])
    return b, i, cond


def _rows(g: Graph, x: str, first: str, n: int) -> str:
    """Rows ``first`` (int64 (1,)) to ``first + n`` of the (N, C, H, W) ``x``."""
    return g.op("Slice", x, first, g.op("Add", first, g.const([n], np.int64)),
                g.const([2], np.int64))


def render_bands(g: Graph, d: ClassDefinition, mosaic: str, row_body: RowBody,
                 pixel_body: PixelBody, *, n_out: int,
                 elem_type: int = TensorProto.FLOAT, guide: str | None = None,
                 rows: int = BAND_ROWS) -> str:
    """(N, ``n_out``, H, W): ``pixel_body`` of ``row_body``'s image of every row of the
    (N, 1, H, W) ``mosaic``, band by band (``elem_type``: ``pixel_body``'s output type).

    ``guide`` (N, 1, H, W): the context guide of the whole frame
    (:func:`l3cli.export.classify.context_guide`), cut into the bands' rows.
    """
    i64 = np.int64
    r = d.patch // 2
    ph, pw = d.cfa.period
    band = -(-rows // ph) * ph  # the band's first row keeps the frame's CFA phase
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

    b, i, cond = _body_graph("band_")
    y0 = b.op("Unsqueeze", b.op("Mul", i, b.const(band, i64)), b.const([0], i64))
    part = _rows(b, padded, y0, band + 2 * r)
    part_guide = None if guide is None else _rows(b, guide, y0, band)
    classes = band_classes(b, d, part, maps, part_guide)

    c, j, c_cond = _body_graph(f"{b._name('rows')}_")
    y = c.op("Unsqueeze", j, c.const([0], i64))
    c.add_output(c_cond, c._name("cond_out"), TensorProto.BOOL, [])
    c.add_output(row_body(c, _rows(c, part, y, d.patch), _rows(c, classes, y, 1)),
                 c._name("img"), TensorProto.FLOAT, ["N", n_out, 1, "W"])
    img = b.op("Loop", b.const(band, i64), "", body=c.subgraph("rows"))  # (band, N, C, 1, W)
    img = b.op("Squeeze", b.op("Transpose", img, perm=[1, 2, 0, 3, 4]), b.const([3], i64))
    b.add_output(cond, "band_cond_out", TensorProto.BOOL, [])
    b.add_output(pixel_body(b, img), "band_img", elem_type, ["N", n_out, band, "W"])
    scan = g.op("Loop", n_bands, "", body=b.subgraph("bands"))  # (n_bands, N, C, band, W)
    joined = g.op("Transpose", scan, perm=[1, 2, 0, 3, 4])
    shape = g.op("Concat", g.slice(g.op("Shape", mosaic), [0], [1], [0]),
                 g.const([n_out, -1], i64), w, axis=0)
    joined = g.op("Reshape", joined, shape)
    return g.op("Slice", joined, g.const([0], i64), g.op("Unsqueeze", h, g.const([0], i64)),
                g.const([2], i64))
