"""A small ONNX graph builder: named constants, nodes, and the shape-dependent helpers.

Every tensor is a name; :class:`Graph` makes node outputs unique. The
helpers that depend on the input's height and width (:meth:`Graph.periodic`,
:meth:`Graph.mirror_indices`) build their index arithmetic from the input's
``Shape``, so one exported model takes mosaics of any size.
"""

from __future__ import annotations

import numpy as np

#: ONNX operator set the exported graphs use (standard ``ai.onnx`` ops only).
OPSET = 17
#: IR version written (what ONNX Runtime 1.14 and later read).
IR_VERSION = 8
#: Slice end meaning "to the end".
_END = np.iinfo(np.int64).max


class Graph:
    """Nodes, initialisers, inputs and outputs of one ONNX graph under construction."""

    def __init__(self, prefix: str = "") -> None:
        from onnx import helper, numpy_helper

        self._prefix = prefix  # subgraphs (a Loop's body) name their tensors apart

        self._helper = helper
        self._numpy_helper = numpy_helper
        self.nodes: list = []
        self.initializers: list = []
        self.inputs: list = []
        self.outputs: list = []
        self._count = 0
        self._consts: dict = {}

    # ------------------------------------------------------------- basics
    def _name(self, hint: str) -> str:
        self._count += 1
        return f"{self._prefix}{hint}_{self._count}"

    def const(self, value, dtype=None, hint: str = "c") -> str:
        """An initialiser holding ``value`` (small scalars and index lists are shared)."""
        arr = np.asarray(value, dtype=dtype)
        key = None
        if arr.size <= 16:
            key = (arr.dtype.str, arr.shape, arr.tobytes())
            if key in self._consts:
                return self._consts[key]
        name = self._name(hint)
        self.initializers.append(self._numpy_helper.from_array(np.array(arr, order="C"), name))
        if key is not None:
            self._consts[key] = name
        return name

    def op(self, op_type: str, *inputs: str, hint: str | None = None, n_out: int = 1,
           **attrs) -> str:
        """Add one node; returns its output name (the first, with ``n_out`` > 1 all)."""
        outs = [self._name(hint or op_type.lower()) for _ in range(n_out)]
        self.nodes.append(self._helper.make_node(op_type, list(inputs), outs, name=outs[0],
                                                 **attrs))  # named: profiles say which
        return outs[0] if n_out == 1 else outs

    def add_input(self, name: str, elem_type: int, shape: list) -> str:
        self.inputs.append(self._helper.make_tensor_value_info(name, elem_type, shape))
        return name

    def add_output(self, source: str, name: str, elem_type: int, shape: list) -> str:
        self.nodes.append(self._helper.make_node("Identity", [source], [name]))
        self.outputs.append(self._helper.make_tensor_value_info(name, elem_type, shape))
        return name

    def subgraph(self, name: str):
        """This graph as a ``GraphProto`` (a Loop's body: no opset, no check of its own)."""
        return self._helper.make_graph(self.nodes, name, self.inputs, self.outputs,
                                       initializer=self.initializers)

    def model(self, *, doc: str, metadata: dict[str, str]):
        """The finished, checked ``onnx.ModelProto``."""
        import onnx

        h = self._helper
        graph = h.make_graph(self.nodes, "l3_pipeline", self.inputs, self.outputs,
                             initializer=self.initializers, doc_string=doc)
        model = h.make_model(graph, opset_imports=[h.make_opsetid("", OPSET)],
                             producer_name="l3", doc_string=doc)
        model.ir_version = IR_VERSION
        h.set_model_props(model, metadata)
        onnx.checker.check_model(model)
        return model

    def if_else(self, cond: str, build_then, build_else, elem_type: int) -> str:
        """An ``If`` node on the bool scalar ``cond``: ``build_then(branch)`` and
        ``build_else(branch)`` add their nodes to a branch graph of their own (which may
        use this graph's tensors) and return the name of its result, of ``elem_type``."""
        branches = {}
        for tag, build in (("then", build_then), ("else", build_else)):
            b = Graph(prefix=f"{self._name(tag)}_")
            b.add_output(build(b), b._name("out"), elem_type, None)
            branches[tag] = b.subgraph(tag)
        return self.op("If", cond, then_branch=branches["then"], else_branch=branches["else"])

    # ------------------------------------------------------------- shortcuts
    def slice(self, x: str, starts, ends, axes) -> str:
        return self.op("Slice", x, self.const(starts, np.int64), self.const(ends, np.int64),
                       self.const(axes, np.int64))

    def window(self, x: str, offset: int, span: int, axis: int) -> str:
        """``x`` along ``axis`` from ``offset`` to ``offset - span + 1`` from the end:
        the values ``offset`` taps into a ``span``-tap window."""
        end = offset - (span - 1)
        return self.slice(x, [offset], [end if end < 0 else _END], [axis])

    def chain_sum(self, x: str, span: int, axis: int, first: int = 0) -> str:
        """``x[k + first] + x[k + first + 1] + ... + x[k + span - 1]`` along ``axis``, added
        left to right (the tile kernel's order, so float32 sums are the same bits)."""
        acc = self.window(x, first, span, axis)
        for d in range(first + 1, span):
            acc = self.op("Add", acc, self.window(x, d, span, axis))
        return acc

    def cast(self, x: str, to: int) -> str:
        return self.op("Cast", x, to=to)

    # ------------------------------------------------- shape-dependent helpers
    def dims(self, x: str) -> str:
        """int64 (2,): the last two dimensions (H, W) of ``x``."""
        return self.slice(self.op("Shape", x), [2], [4], [0])

    def periodic(self, pattern: np.ndarray, like: str, dtype=np.float32) -> str:
        """``pattern`` (ph, pw) tiled from the origin to the (H, W) of ``like``: (1, 1, H, W)."""
        return self.tile(pattern, self.dims(like), dtype)

    def tile(self, pattern: np.ndarray, hw: str, dtype=np.float32) -> str:
        """``pattern`` (ph, pw) tiled from the origin to the int64 (2,) size ``hw``:
        (1, 1, H, W)."""
        pattern = np.asarray(pattern, dtype=dtype)
        ph, pw = pattern.shape
        period = self.const([ph, pw], np.int64)
        reps = self.op("Div", self.op("Sub", self.op("Add", hw, period),
                                      self.const([1, 1], np.int64)), period)
        reps = self.op("Concat", self.const([1, 1], np.int64), reps, axis=0)
        tiled = self.op("Tile", self.const(pattern[None, None]), reps)
        return self.op("Slice", tiled, self.const([0, 0], np.int64), hw,
                       self.const([2, 3], np.int64))

    def mirror_indices(self, n: str, r: int, period: int) -> str:
        """int64 (n + 2r,): :func:`l3cli.classify.padding.mirror_indices` of a size held in
        the int64 scalar tensor ``n`` (the same arithmetic, with the loop that folds tiny
        images in closed form)."""
        i64 = np.int64
        p = self.const(period, i64)
        zero, one, two = (self.const(v, i64) for v in (0, 1, 2))
        i = self.op("Range", self.const(-r, i64), self.op("Add", n, self.const(r, i64)), one)
        # below the start: j = -i, moved inwards onto the phase of i
        j = self.op("Neg", i)
        lo = self.op("Add", j, self.op("Mod", self.op("Sub", i, j), p, fmod=0))
        # past the end: j = 2 (n - 1) - i, moved inwards
        j = self.op("Sub", self.op("Mul", two, self.op("Sub", n, one)), i)
        hi = self.op("Sub", j, self.op("Mod", self.op("Sub", j, i), p, fmod=0))
        out = self.op("Where", self.op("Less", i, zero), lo,
                      self.op("Where", self.op("GreaterOrEqual", i, n), hi, i))
        # images smaller than the reflection: whole periods back into range
        over = self.op("Div", self.op("Add", self.op("Sub", out, n), p), p)  # >= 1 where out >= n
        out = self.op("Where", self.op("GreaterOrEqual", out, n),
                      self.op("Sub", out, self.op("Mul", over, p)), out)
        under = self.op("Div", self.op("Sub", p, self.op("Add", out, one)), p)  # >= 1 where < 0
        return self.op("Where", self.op("Less", out, zero),
                       self.op("Add", out, self.op("Mul", under, p)), out)

    def pad_mirror(self, x: str, r: int, period: tuple[int, int]) -> str:
        """CFA-phase mirror padding of (N, 1, H, W) ``x`` by ``r``: (N, 1, H + 2r, W + 2r)."""
        if r == 0:
            return x
        hw = self.dims(x)
        h = self.op("Squeeze", self.slice(hw, [0], [1], [0]), self.const([0], np.int64))
        w = self.op("Squeeze", self.slice(hw, [1], [2], [0]), self.const([0], np.int64))
        rows = self.op("Gather", x, self.mirror_indices(h, r, period[0]), axis=2)
        # the columns: only the 2r outside the frame gathered (a Gather along the last axis
        # copies value by value), the frame's own joined to them
        cols = self.mirror_indices(w, r, period[1])
        left = self.op("Gather", rows, self.slice(cols, [0], [r], [0]), axis=3)
        right = self.op("Gather", rows, self.slice(cols, [-r], [_END], [0]), axis=3)
        return self.op("Concat", left, rows, right, axis=3)
