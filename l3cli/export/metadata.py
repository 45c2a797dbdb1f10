"""Reading an exported model back: its l3 metadata and graph interface (``l3 inspect``)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from l3cli.errors import InputError

__all__ = ["model_summary", "format_model_summary"]

_ELEM = {1: "float32", 2: "uint8", 4: "uint16", 7: "int64", 11: "float64"}


def _shape(value_info) -> str:
    dims = [d.dim_param or str(d.dim_value) for d in value_info.type.tensor_type.shape.dim]
    return f"{_ELEM.get(value_info.type.tensor_type.elem_type, '?')} ({', '.join(dims)})"


def model_summary(path: str | os.PathLike) -> dict[str, Any]:
    """The metadata, inputs and outputs of an ONNX model ``l3 export`` wrote.

    Raises
    ------
    InputError
        The file is missing, not an ONNX model, or not one l3 wrote.
    """
    from l3cli.export import FORMAT, require_onnx

    require_onnx()
    import onnx

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such model file")
    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # protobuf raises its own DecodeError, among others
        raise InputError(f"{path}: not an ONNX model ({type(exc).__name__})") from None
    meta = {p.key: p.value for p in model.metadata_props}
    if meta.get("l3.format") != FORMAT:
        raise InputError(f"{path}: not an l3 pipeline (no l3.format {FORMAT!r} in its metadata)")
    out: dict[str, Any] = {"model": str(path)}
    for key, value in meta.items():
        name = key.removeprefix("l3.")
        if name in ("inputs", "features", "provenance"):
            try:
                value = json.loads(value)
            except json.JSONDecodeError:
                pass
        out[name] = value
    out["graph_inputs"] = {v.name: _shape(v) for v in model.graph.input}
    out["graph_outputs"] = {v.name: _shape(v) for v in model.graph.output}
    out["opset"] = max((o.version for o in model.opset_import if o.domain in ("", "ai.onnx")),
                       default=0)
    out["nodes"] = len(model.graph.node)
    return out


def format_model_summary(summary: dict[str, Any]) -> str:
    """Readable lines of :func:`model_summary`."""
    s = summary
    lines = [
        f"model: {s['model']} (ONNX opset {s['opset']}, {s['nodes']} nodes; "
        f"{s.get('format')}, l3 {s.get('version')})",
        f"table: {s.get('table')} (sha256 {str(s.get('table_sha256'))[:16]}...)",
        f"CFA {s.get('cfa')}, patch {s.get('patch')}x{s.get('patch')}, {s.get('classes')} classes",
        f"features: {', '.join(s.get('features') or [])}",
        f"output: {s.get('output_image')}",
        "inputs:",
    ]
    for name, desc in (s.get("inputs") or {}).items():
        lines.append(f"  {name}: {desc}")
    lines += [f"before the graph: {s.get('black_white')}", f"borders: {s.get('borders')}"]
    prov = s.get("provenance")
    if prov:
        lines.append("table provenance: " + json.dumps(prov, sort_keys=True, default=str)[:400])
    return "\n".join(lines)
