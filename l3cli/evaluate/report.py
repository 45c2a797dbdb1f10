"""The report of an evaluation: the JSON document and the text table."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from l3cli.evaluate.metrics import ImageReport

__all__ = ["CONTRACT_IMAGE_KEYS", "report_dict", "write_report", "format_table"]

#: Keys of the JSON contract, per image and in the summary (in this order).
CONTRACT_IMAGE_KEYS = (
    "scielab_mean", "scielab_median", "scielab_p90", "psnr_db", "macbeth_de_mean", "mtf50_cy_per_mm",
)


def _json_value(v: Any) -> Any:
    if v is None:
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def report_dict(
    reports: Sequence[ImageReport], summary: dict[str, float], *, settings: dict | None = None
) -> dict:
    """The JSON report: ``images`` (contract keys first, then extras) and ``summary``.

    Each image also carries ``macbeth_patches`` (per-patch ΔE*ab and CIEDE2000 in
    reading order, and the white scale) where a chart is known, and ``mtf_curve``
    (frequencies in cycles/pixel, MTF, edge angle and region) where an edge is.
    Non-finite values (PSNR of identical images) are written as null.
    """
    images = []
    for r in reports:
        d: dict[str, Any] = {"name": r.name}
        for k in CONTRACT_IMAGE_KEYS:
            if k in r.values:
                d[k] = _json_value(r.values[k])
        for k, v in r.values.items():
            if k not in d:
                d[k] = _json_value(v)
        if r.psnr_domain is not None:
            d["psnr_domain"] = r.psnr_domain
        if r.macbeth is not None:
            d["macbeth_patches"] = {
                "de_ab": [round(float(v), 4) for v in r.macbeth.delta_e_ab],
                "de2000": [round(float(v), 4) for v in r.macbeth.delta_e_2000],
                "white_scale": float(r.macbeth.white_scale),
            }
        if r.mtf is not None:
            d["mtf_curve"] = {
                "cy_per_px": [round(float(v), 5) for v in r.mtf.frequencies],
                "mtf": [round(float(v), 5) for v in r.mtf.mtf],
                "angle_deg": float(r.mtf.angle_deg),
                "roi": list(r.edge_roi) if r.edge_roi is not None else None,
            }
        images.append(d)
    out: dict[str, Any] = {"images": images, "summary": {k: _json_value(v) for k, v in summary.items()}}
    if settings:
        out["settings"] = settings
    return out


def write_report(path: str | os.PathLike, report: dict) -> Path:
    """Write the JSON report atomically."""
    from l3cli.io.atomic import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
    return path


def format_table(reports: Sequence[ImageReport], summary: dict[str, float]) -> str:
    """A plain-text table of the main metrics, one row per image and a mean row."""
    cols = [
        ("S-CIELAB mean", "scielab_mean", "{:.3f}"),
        ("median", "scielab_median", "{:.3f}"),
        ("p90", "scielab_p90", "{:.3f}"),
        ("ΔE2000 mean", "scielab_de2000_mean", "{:.3f}"),
        ("PSNR dB", "psnr_db", "{:.2f}"),
        ("Macbeth ΔE", "macbeth_de_mean", "{:.3f}"),
        ("MTF50 cy/px", "mtf50_cy_per_px", "{:.4f}"),
        ("MTF50 cy/mm", "mtf50_cy_per_mm", "{:.1f}"),
    ]
    present = [c for c in cols if any(c[1] in r.values for r in reports)]

    def fmt(vals: dict, key: str, spec: str) -> str:
        v = vals.get(key)
        if v is None:
            return "-"
        if not math.isfinite(v):
            return "inf" if v > 0 else "-"
        return spec.format(v)

    domains = {r.psnr_domain for r in reports if r.psnr_domain}
    if len(domains) == 1:  # say which values PSNR compares
        label = {"srgb-encoded": "PSNR dB (sRGB codes)", "linear-xyz": "PSNR dB (linear XYZ)"}
        present = [(label.get(next(iter(domains)), c[0]), *c[1:]) if c[1] == "psnr_db" else c
                   for c in present]
    rows = [["image"] + [c[0] for c in present]]
    for r in reports:
        rows.append([r.name] + [fmt(r.values, k, s) for _, k, s in present])
    if len(reports) > 1:
        rows.append(["mean"] + [fmt(summary, k, s) for _, k, s in present])
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = []
    for j, row in enumerate(rows):
        cells = [row[0].ljust(widths[0])] + [c.rjust(w) for c, w in zip(row[1:], widths[1:], strict=True)]
        lines.append("  ".join(cells))
        if j == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)

