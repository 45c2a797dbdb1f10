"""``l3 export``: a transform table as a standard ONNX graph (``docs/export.md``).

:func:`build_model` turns a :class:`~l3cli.table.TransformTable` into an
``onnx.ModelProto`` of standard ``ai.onnx`` operators (opset
:data:`~l3cli.export.graph.OPSET`) that renders a normalised mosaic as
``l3 render`` does: the classifier (:mod:`l3cli.export.classify`, bit for
bit the tile kernel's classes, context bins included), the per-class affine kernels, the learned
tone curve, the white-balance gains and adaptation, condition-bin kernels,
and optionally the display encoding (:mod:`l3cli.export.stages`). Borders
are padded by the CFA-phase mirror of :func:`l3cli.classify.mirror_indices`,
computed in the graph from the input's size, so one model takes mosaics of
any height and width (at least one patch and one CFA period).

Graph inputs (names are part of the format, :data:`INPUTS`):

``mosaic``
    float32 (N, 1, H, W): ``(raw - black) / (white - black)``, CFA phase as
    the table's (``l3.cfa`` in the metadata) at the top-left pixel.
``wb_gains``
    float32 (N, 3): the raw's as-shot white-balance multipliers ``[r, g, b]``
    with green = 1 (tables trained with ``--as-shot-wb`` only).
``condition``
    float64 (1,): the shot's ISO, exposure time or white b/r (tables trained
    with ``--by``; 0 or NaN = unknown: the pooled kernels), shared by the batch.
``frame``
    int64 (4,) (tables with a lens shading gain field): where the mosaic lies
    on the sensor's full raw, ``(full height, full width, top, left)``; zeros
    mean the mosaic is the whole raw.

DNG ``GainMap`` opcodes are the caller's, as black level is: the mosaic is
fed with them applied (``l3cli.lens.gainmaps.apply_dng_gains(read_raw(path))``).

Output ``image``: float32 (N, C, H, W) in the table's output space, or with
``output="display"`` uint8/uint16 display values (sRGB for 3-channel tables).

A feature the graph cannot express is refused by name with a one-line
:class:`~l3cli.errors.ConfigError` (:func:`check_exportable`).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from l3cli.errors import ConfigError, InputError
from l3cli.table import TransformTable

__all__ = ["FORMAT", "INPUTS", "OUTPUTS", "build_model", "check_exportable", "export_table",
           "model_metadata", "require_onnx"]

#: ``l3.format`` of the models l3 writes.
FORMAT = "l3-onnx-pipeline-v1"
#: Graph inputs a model may have (``mosaic`` always; the others when the table needs them).
INPUTS = ("mosaic", "wb_gains", "condition", "frame")
#: What ``output`` may be.
OUTPUTS = ("linear", "display")


def require_onnx() -> None:
    """Raise a one-line :class:`ConfigError` when the ``onnx`` package is missing."""
    try:
        import onnx  # noqa: F401
    except ImportError:
        raise ConfigError("exporting needs the onnx package: pip install 'l3cli[export]'") \
            from None


def check_exportable(table: TransformTable, output: str = "linear") -> None:
    """Raise :class:`ConfigError` naming the first table feature the export cannot express."""
    if output not in OUTPUTS:
        raise ConfigError(f"output {output!r} is not known; use one of {', '.join(OUTPUTS)}")
    for name in _unknown_features(table):
        raise ConfigError(f"the table's {_NAMES.get(name, name)} cannot be exported yet")
    if table.white_balance is not None:
        from l3cli.whitebalance.model import ADAPT_SPACE, WhiteBalanceModel

        model = WhiteBalanceModel.from_dict(table.white_balance)
        if model.space != table.output_space or ADAPT_SPACE[table.output_space] != model.space:
            raise ConfigError(
                f"the table's white-balance adaptation acts in {model.space} but it renders "
                f"{table.output_space}; only tables whose output space is the adaptation's "
                "(xyz, linear-srgb) can be exported")
        if table.n_out != 3:
            raise ConfigError("white-balance adaptation needs 3 output channels")
    if output == "display" and table.n_out == 3 and table.output_space == "lab":
        raise ConfigError("display output of a lab table cannot be exported (its conversion is "
                          "colour-science's); export --output linear")


#: Table and class-definition fields the export knows how to build (or refuses above).
_KNOWN_TABLE = {"definition", "kernels", "counts", "lambdas", "empty", "source_class",
                "output_space", "provenance", "format", "version", "white_balance",
                "conditions", "tone_lut", "shading", "multiscale"}
_KNOWN_DEFINITION = {"cfa", "patch", "level_cuts", "level_spacing", "contrast_cuts",
                     "saturation_threshold", "position_group", "contrast_eps", "contrast_rule",
                     "saturation_rule", "orientation_bins", "coherence_threshold",
                     "orientation_rule", "context_block", "context_cuts", "context_rule",
                     "highlight_bins", "highlight_fraction", "_tables"}
#: How refusals name the stages that tables may hold beyond those.
_NAMES = {"multiscale": "multiscale stage", "shading": "lens shading correction"}


def _unknown_features(table: TransformTable) -> list[str]:
    """Fields of the table (and its class definition) in use that this export does not know:
    a stage added to l3 after the export is refused rather than silently left out."""
    import dataclasses

    out = [f.name for f in dataclasses.fields(table)
           if f.name not in _KNOWN_TABLE and getattr(table, f.name) is not None]
    d = table.definition
    for f in dataclasses.fields(d):
        if f.name in _KNOWN_DEFINITION:
            continue
        default = (f.default_factory() if f.default_factory is not dataclasses.MISSING
                   else f.default)
        value = getattr(d, f.name)
        if default is dataclasses.MISSING or not np.array_equal(np.asarray(value, dtype=object),
                                                                np.asarray(default, dtype=object)):
            out.append(f.name)
    return out


def model_metadata(table: TransformTable, *, table_name: str, table_sha256: str, output: str,
                   bits: int) -> dict[str, str]:
    """The ``metadata_props`` of an exported model (all strings; ``l3 inspect`` reads them)."""
    from l3cli import __version__

    d = table.definition
    ph, pw = d.cfa.period
    min_h, min_w = max(ph, d.patch // 2 + 1), max(pw, d.patch // 2 + 1)
    inputs = {"mosaic": "float32 (N, 1, H, W): (raw - black) / (white - black), per-position "
                        f"black level; CFA {d.cfa.spec} at the top-left pixel; "
                        f"H >= {min_h}, W >= {min_w}; not clipped"}
    if table.white_balance is not None:
        inputs["wb_gains"] = "float32 (N, 3): as-shot white-balance multipliers r, g, b, green = 1"
    if table.conditions is not None:
        inputs["condition"] = (f"float64 (1,): the shot's {table.conditions.by} (0 or NaN: "
                               "unknown, pooled kernels), one value for the batch")
    if table.shading is not None:
        inputs["frame"] = ("int64 (4,): full raw height, width, top, left of the mosaic on "
                           "it (lens shading); zeros: the mosaic is the whole raw")
    out_desc = (f"float32 (N, {table.n_out}, H, W) in {table.output_space}" if output == "linear"
                else f"uint{bits} (N, {table.n_out}, H, W) display values")
    return {
        "l3.format": FORMAT,
        "l3.version": __version__,
        "l3.table": table_name,
        "l3.table_sha256": table_sha256,
        "l3.cfa": d.cfa.spec,
        "l3.patch": str(d.patch),
        "l3.classes": str(d.n_classes),
        "l3.output": output,
        "l3.output_space": table.output_space,
        "l3.bits": str(bits) if output == "display" else "",
        "l3.inputs": json.dumps(inputs),
        "l3.output_image": out_desc,
        "l3.black_white": "subtract each CFA position's black level and divide by "
                          "(white - black) before the graph; values above 1 and below 0 are "
                          "kept; a DNG's GainMap opcodes are applied before the graph too",
        "l3.borders": "CFA-phase mirror padding, as l3 render",
        "l3.features": json.dumps(_features(table)),
        "l3.provenance": json.dumps(table.provenance, sort_keys=True, default=str),
    }


def _features(table: TransformTable) -> list[str]:
    from l3cli.features import table_features

    d = table.definition
    return [f"levels {d.n_levels}", f"contrast bins {d.n_contrast}", "saturation",
            *(f.describe(table) for f in table_features(table))]


def build_model(table: TransformTable, *, output: str = "linear", bits: int = 8,
                table_name: str = "table", table_sha256: str = ""):
    """The ONNX model of ``table`` (see the module docstring for its inputs and output)."""
    require_onnx()
    check_exportable(table, output)
    if bits not in (8, 16):
        raise ConfigError(f"bits {bits} is not allowed; use 8 or 16")
    from onnx import TensorProto

    from l3cli.export import stages
    from l3cli.export.bands import render_bands
    from l3cli.export.classify import context_guide
    from l3cli.export.graph import Graph

    g = Graph()
    mosaic = g.add_input("mosaic", TensorProto.FLOAT, ["N", 1, "H", "W"])
    d = table.definition
    if table.shading is not None:  # first, as l3cli.lens.field.corrected
        frame = g.add_input("frame", TensorProto.INT64, [4])
        mosaic = stages.shading(g, mosaic, table.shading, d.cfa.period,
                                d.saturation_threshold, frame)
    gains = None
    if table.white_balance is not None:
        gains = g.add_input("wb_gains", TensorProto.FLOAT, ["N", 3])
        mosaic = stages.apply_gains(g, mosaic, gains, d.cfa, d.saturation_threshold)
    if table.conditions is not None:
        value = g.add_input("condition", TensorProto.DOUBLE, [1])
        kernels = stages.condition_kernels(g, table, value)
    else:
        kernels = table.kernels
    rows = stages.kernel_rows(g, kernels, d.patch, table.n_out)
    post = _post_stages(table, output, bits, gains)
    n_pixel = next((k for k, (per_pixel, _) in enumerate(post) if not per_pixel), len(post))

    ones = stages.ones_row(g, mosaic)

    def row(b, padded, classes):  # the kernels on one output row
        return stages.affine(b, padded, classes, rows, ones, d.patch, table.n_out)

    def pixels(b, img):  # the per-pixel stages of one band
        for _, stage in post[:n_pixel]:
            img = stage(b, img)
        return img

    display_in_band = output == "display" and n_pixel == len(post)
    elem = TensorProto.FLOAT
    if output == "display":
        elem = TensorProto.UINT8 if bits == 8 else TensorProto.UINT16
    img = render_bands(g, d, mosaic, row, pixels, n_out=table.n_out,
                       elem_type=elem if display_in_band else TensorProto.FLOAT,
                       guide=context_guide(g, d, mosaic) if d.context_block else None)
    for _, stage in post[n_pixel:]:  # stages that need the whole image
        img = stage(g, img)
    g.add_output(img, "image", elem, ["N", table.n_out, "H", "W"])
    meta = model_metadata(table, table_name=table_name, table_sha256=table_sha256,
                          output=output, bits=bits)
    doc = (f"l3 pipeline from {table_name}: {d.cfa.spec} mosaic -> {meta['l3.output_image']}")
    return g.model(doc=doc, metadata=meta)


def _post_stages(table: TransformTable, output: str, bits: int, gains: str | None) -> list:
    """The stages after the kernels, in ``l3 render``'s order: ``(per_pixel, build)`` with
    ``build(graph, image) -> image``. The leading per-pixel stages run in the band loop
    (:mod:`l3cli.export.bands`); a stage that needs the whole image (a filter) and every
    stage after it run on the joined frame."""
    from l3cli.export import stages

    out: list = []
    if table.tone_lut is not None:
        lut, lo_hi = table.tone_lut
        out.append((True, lambda g, img: stages.tone_curve(g, img, lut, lo_hi)))
    if gains is not None:
        from l3cli.whitebalance.model import WhiteBalanceModel

        model = WhiteBalanceModel.from_dict(table.white_balance)
        out.append((True, lambda g, img: stages.adaptation(g, img, gains, model)))
    if table.multiscale is not None:  # noise reduction beyond the patch: the whole image
        from l3cli.export.multiscale import stage

        out.append((False, lambda g, img: stage(g, img, table.multiscale)))
    if output == "display":
        out.append((True, lambda g, img: stages.display(g, img, table.output_space,
                                                        table.n_out, bits)))
    return out


def export_table(table_path: str | os.PathLike, out_path: str | os.PathLike, *,
                 output: str = "linear", bits: int = 8) -> Path:
    """Load a table, build its model and write it to ``out_path`` atomically."""
    from l3cli.io.atomic import atomic_path
    from l3cli.table import load_table

    require_onnx()
    table_path, out_path = Path(table_path), Path(out_path)
    table = load_table(table_path)
    if out_path.suffix.lower() != ".onnx":
        raise InputError(f"{out_path}: the output must be a .onnx file")
    sha = hashlib.sha256(table_path.read_bytes()).hexdigest()
    model = build_model(table, output=output, bits=bits, table_name=table_path.name,
                        table_sha256=sha)
    with atomic_path(out_path) as tmp, open(tmp, "wb") as fh:
        fh.write(model.SerializeToString())
    return out_path
