"""The metrics of one (rendered, reference) item, and of all: the orchestration.

White point, scale, registration (``--align``), then S-CIELAB, PSNR, the
Macbeth ΔE and the slanted-edge MTF50 from :mod:`l3cli.metrics`; see
:mod:`l3cli.evaluate` for the conventions.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from l3cli.errors import InputError, OptionError
from l3cli.evaluate.inputs import ArrayImage, EvalItem, find_items, load_image
from l3cli.evaluate.options import EvalOptions
from l3cli.metrics.macbeth import (
    MACBETH_WHITE_INDEX,
    MacbethResult,
    chart_patches_from_corners,
    macbeth_delta_e,
    patch_means,
)
from l3cli.metrics.mtf import LUMINANCE_WEIGHTS, MTFResult, slanted_edge_mtf
from l3cli.metrics.psnr import psnr
from l3cli.metrics.scielab import (
    SRGB_WHITE_XYZ,
    SCIELABResult,
    samples_per_degree,
    scielab,
)

__all__ = ["PATCH_FRACTION", "SUMMARY_KEYS", "ImageReport", "white_point_for", "align_reference",
           "evaluate_item", "summarise", "evaluate"]

log = logging.getLogger("l3cli.evaluate")

#: Fraction of each manifest patch box (per side) averaged for the Macbeth ΔE.
PATCH_FRACTION = 0.5

SUMMARY_KEYS = (
    "scielab_mean", "scielab_median", "scielab_p90", "scielab_de2000_mean", "psnr_db",
    "macbeth_de_mean", "macbeth_de2000_mean", "mtf50_cy_per_px", "mtf50_cy_per_mm",
)


@dataclass
class ImageReport:
    """Metrics of one image; ``values`` holds the JSON keys, the rest feeds plots."""

    name: str
    values: dict[str, float | None]
    scielab: SCIELABResult | None = None
    macbeth: MacbethResult | None = None
    mtf: MTFResult | None = None
    rendered_xyz: np.ndarray | None = field(default=None, repr=False)
    reference_xyz: np.ndarray | None = field(default=None, repr=False)
    white_xyz: np.ndarray | None = None
    psnr_domain: str | None = None
    chart_boxes: list | None = None
    edge_roi: tuple | None = None



def _illuminant_xy(name: Any) -> np.ndarray:
    import colour

    table = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]
    if isinstance(name, str):
        for key in (name, name.upper(), name.replace("CIE ", "")):
            if key in table:
                return np.asarray(table[key], dtype=np.float64)
    return np.asarray(table["D65"], dtype=np.float64)


def white_point_for(
    reference_xyz: np.ndarray, reference_space: str, capture: dict | None
) -> np.ndarray:
    """The white point (XYZ on the reference's scale); see the module notes."""
    if reference_space == "srgb":
        return np.asarray(SRGB_WHITE_XYZ, dtype=np.float64)
    if capture is None:
        return np.array([0.95047, 1.0, 1.08883])
    wx = capture.get("white_xyz")
    if wx is not None:
        w = np.asarray(wx, dtype=np.float64).reshape(3)
        if np.all(w > 0):
            return w
    chart = capture.get("chart")
    if chart and chart.get("reference_xyz") is not None:
        ref = np.asarray(chart["reference_xyz"], dtype=np.float64)
        w = ref[int(chart.get("white_index", MACBETH_WHITE_INDEX))]
        if np.all(w > 0):
            return w
    y = float(np.percentile(reference_xyz[..., 1], 99))
    if not y > 0:
        raise InputError("reference image is black: no white point can be derived")
    xy = _illuminant_xy(capture.get("illuminant"))
    return np.array([xy[0] / xy[1] * y, y, (1 - xy[0] - xy[1]) / xy[1] * y])


# ----------------------------------------------------------------------------- metrics


def _crop(img: np.ndarray, n: int) -> np.ndarray:
    if n <= 0:
        return img
    if img.shape[0] <= 2 * n or img.shape[1] <= 2 * n:
        raise InputError(
            f"--exclude-border {n} leaves nothing of a {img.shape[1]}x{img.shape[0]} image"
        )
    return img[n:-n, n:-n]


def _luminance_linear(xyz: np.ndarray) -> np.ndarray:
    from l3cli.colourspace import convert

    rgb = np.asarray(convert(xyz.astype(np.float32), "xyz", "linear-srgb"), dtype=np.float64)
    return rgb @ np.asarray(LUMINANCE_WEIGHTS)


def _chart_from_capture(capture: dict | None) -> dict | None:
    chart = (capture or {}).get("chart")
    return chart if isinstance(chart, dict) and chart.get("patches") else None


def _inverse_flip(flip: str) -> str:
    return {"transpose-horizontal": "transpose-vertical",
            "transpose-vertical": "transpose-horizontal"}.get(flip, flip)


def align_reference(
    rendered: np.ndarray, reference: np.ndarray, *, rendered_name: str = "rendered",
    reference_name: str = "reference",
) -> tuple[tuple[int, int, int, int], str]:
    """Where a reference image lies in a rendered image of the raw's full area.

    Parameters
    ----------
    rendered, reference
        (H, W, 3) and (h, w, 3) XYZ images on one scale; the reference is the
        rendered image's area or a crop of it, possibly mirrored or rotated by
        90 degrees.
    rendered_name, reference_name
        Names for messages.

    Returns
    -------
    window, flip
        ``(y0, x0, height, width)`` of the rendered pixels under the
        reference, and the flip (:data:`l3cli.align.FLIPS`) that brings that
        window to the reference's orientation.

    Raises
    ------
    InputError
        The reference is larger than the render, or does not align with it
        (:data:`l3cli.align.MIN_SCORE`, :data:`l3cli.align.MIN_SHARPNESS`).

    References
    ----------
    The registration of :mod:`l3cli.align` (phase correlation, band-pass check).
    """
    from l3cli.align import MIN_SCORE, MIN_SHARPNESS, register

    try:
        a = register(rendered[..., 1].astype(np.float32), reference[..., 1].astype(np.float32))
    except ValueError:
        raise InputError(
            f"reference {reference_name} ({reference.shape[1]}x{reference.shape[0]}) is larger "
            f"than rendered {rendered_name} ({rendered.shape[1]}x{rendered.shape[0]}) in every "
            "orientation; --align needs a reference of the render's area or a crop of it"
        ) from None
    if a.score < MIN_SCORE or a.sharpness < MIN_SHARPNESS:
        raise InputError(
            f"reference {reference_name} does not align with rendered {rendered_name}: best "
            f"match at offset ({a.dy}, {a.dx}) flip {a.flip} has structure correlation "
            f"{a.score:.2f} (need {MIN_SCORE:g}) and peak sharpness {a.sharpness:.0f} "
            f"(need {MIN_SHARPNESS:g}); is it a resized copy, or of another shot?"
        )
    h, w = reference.shape[:2]
    if a.flip.startswith("transpose"):
        h, w = w, h
    log.info("%s lies in %s at offset (dy=%d, dx=%d), flip %s (score %.3f)", reference_name,
             rendered_name, a.dy, a.dx, a.flip, a.score)
    return (a.dy, a.dx, h, w), _inverse_flip(a.flip)


#: Band-pass correlation of render and reference luminance below which the
#: reference is reported as probably not of the same shot (a renders of the same
#: scene, even noisy ones, score well above 0.5; unrelated images near 0).
MIN_CORRESPONDENCE = 0.3

#: The domain PSNR is computed in, by the reference's encoding (JSON ``psnr_domain``).
PSNR_DOMAINS = {"srgb": "srgb-encoded", "linear": "linear-xyz"}


def _check_correspondence(rend: np.ndarray, ref: np.ndarray, item: EvalItem) -> float | None:
    """Warn when the reference does not look like the render (another shot or file)."""
    from l3cli.align.common import match_score

    if rend.shape != ref.shape:
        return None
    score = match_score(rend[..., 1], ref[..., 1])
    if score < MIN_CORRESPONDENCE:
        log.warning(
            "%s: reference %s hardly resembles it (structure correlation %.2f < %g); is it the "
            "reference of the same shot?", item.rendered, item.reference, score, MIN_CORRESPONDENCE)
    return score


def _psnr(rend: np.ndarray, ref: np.ndarray, rend_codes: np.ndarray | None, ref_values: np.ndarray,
          ref_space: str, white: np.ndarray, exclude_border: int) -> float:
    """PSNR in the reference's domain, whatever the render's format.

    A display-encoded reference: both images as sRGB code values (data range 1),
    the render's own codes (``rend_codes``) or its XYZ encoded as l3 encodes it; a
    linear reference: linear XYZ with the white's Y as data range.
    """
    if ref_space == "srgb":
        from l3cli.colourspace import convert

        enc = rend_codes if rend_codes is not None else np.clip(np.asarray(convert((rend / 100.0).astype(np.float32), "xyz", "srgb"),
                                 dtype=np.float64), 0.0, 1.0)
        return psnr(_crop(ref_values, exclude_border), _crop(enc, exclude_border), data_range=1.0)
    return psnr(_crop(ref, exclude_border), _crop(rend, exclude_border), data_range=float(white[1]))


def evaluate_item(item: EvalItem, options: EvalOptions | None = None, *,
                  rendered_space: str | None = None) -> ImageReport:
    """Compute every applicable metric for one pair.

    Parameters
    ----------
    item
        The pair (see :func:`~l3cli.evaluate.inputs.find_items`).
    options
        How (:class:`~l3cli.evaluate.options.EvalOptions`; default: its defaults).
    rendered_space
        The render's colour space (None: the file's own).

    Returns
    -------
    ImageReport
    """
    o = options or EvalOptions()
    exclude_border, align = o.exclude_border, o.align
    rend, rend_space, rend_values = load_image(item.rendered, rendered_space)
    ref, ref_space, ref_values = load_image(item.reference, item.reference_space)
    if align:
        from l3cli.align import apply_flip

        (y0, x0, hh, ww), flip = align_reference(
            rend, ref, rendered_name=str(item.rendered), reference_name=str(item.reference))
        rend = np.ascontiguousarray(apply_flip(rend[y0:y0 + hh, x0:x0 + ww], flip))
        rend_values = np.ascontiguousarray(apply_flip(rend_values[y0:y0 + hh, x0:x0 + ww], flip))
    if rend.shape != ref.shape:
        raise InputError(
            f"rendered {item.rendered} is {rend.shape[1]}x{rend.shape[0]} but reference "
            f"{item.reference} is {ref.shape[1]}x{ref.shape[0]}; they must be the same size"
            + ("" if align or rend.shape[0] < ref.shape[0] or rend.shape[1] < ref.shape[1]
               else " (for a reference that is a crop of the render, use --align)")
        )
    white = white_point_for(ref, ref_space, item.capture)
    if rend_space == "srgb" and ref_space != "srgb":
        rend = rend / 100.0  # one white scale: a display white is Y = 1 on l3's linear scale
    elif ref_space == "srgb" and rend_space != "srgb":
        rend = rend * 100.0  # the same rule the other way: linear Y = 1 is the display white
    _check_correspondence(rend, ref, item)

    values: dict[str, float | None] = {}
    sc = scielab(
        _crop(ref, exclude_border), _crop(rend, exclude_border),
        white_point=white, samples_per_deg=samples_per_degree(o.dpi, o.distance), version=o.filters,
        opponent=o.opponent,
    )
    values.update(sc.summary())
    values["psnr_db"] = _psnr(rend, ref, rend_values if rend_space == "srgb" else None, ref_values,
                              ref_space, white, exclude_border)

    report = ImageReport(item.name, values, scielab=sc, white_xyz=white,
                         psnr_domain=PSNR_DOMAINS["srgb" if ref_space == "srgb" else "linear"])

    # Macbeth chart
    chart = _chart_from_capture(item.capture)
    if o.chart_corners is not None:
        boxes = chart_patches_from_corners(o.chart_corners, image_shape=rend.shape, fraction=PATCH_FRACTION)
        measured = patch_means(rend, boxes)
        ideal = patch_means(ref, boxes)
        white_index = MACBETH_WHITE_INDEX
        report.chart_boxes = boxes
    elif chart is not None:
        boxes = chart["patches"]
        measured = patch_means(rend, boxes, fraction=PATCH_FRACTION)
        if chart.get("reference_xyz") is not None:
            ideal = np.asarray(chart["reference_xyz"], dtype=np.float64)
        else:
            ideal = patch_means(ref, boxes, fraction=PATCH_FRACTION)
        white_index = int(chart.get("white_index", MACBETH_WHITE_INDEX))
        report.chart_boxes = [tuple(b) for b in boxes]
    else:
        measured = None
    if measured is not None:
        mb = macbeth_delta_e(measured, ideal, white_index=white_index)
        values["macbeth_de_mean"] = mb.mean_ab
        values["macbeth_de2000_mean"] = mb.mean_2000
        values["macbeth_de_max"] = float(np.max(mb.delta_e_ab))
        report.macbeth = mb

    # Slanted edge
    edge = (item.capture or {}).get("edge")
    roi = tuple(int(v) for v in o.edge_roi) if o.edge_roi is not None else None
    if roi is None and isinstance(edge, dict) and edge.get("roi") is not None:
        roi = tuple(int(v) for v in edge["roi"])
    if roi is not None:
        pitch = o.pixel_pitch_um
        if pitch is None and item.camera:
            pitch = item.camera.get("pixel_pitch_um")
        pitch = float(pitch) if pitch is not None else None
        res = slanted_edge_mtf(_luminance_linear(rend), roi=roi, pixel_pitch_um=pitch)
        values["mtf50_cy_per_px"] = res.mtf50_cy_per_px
        values["mtf50_cy_per_mm"] = res.mtf50_cy_per_mm
        try:
            ref_res = slanted_edge_mtf(_luminance_linear(ref), roi=roi, pixel_pitch_um=pitch)
            values["mtf50_reference_cy_per_px"] = ref_res.mtf50_cy_per_px
        except InputError as exc:  # an ideal target may be too sharp for MTF50 < 1 cy/px
            log.info("%s: reference MTF50 not measured (%s)", item.reference, exc)
        report.mtf = res
        report.edge_roi = roi

    if o.keep_images:
        report.rendered_xyz = rend
        report.reference_xyz = ref
    return report


def summarise(reports: Sequence[ImageReport]) -> dict[str, float]:
    """Mean of each key over the images that have it (``psnr_db``: finite values only)."""
    out: dict[str, float] = {}
    keys: list[str] = list(SUMMARY_KEYS)
    for r in reports:
        for k in r.values:
            if k not in keys:
                keys.append(k)
    for k in keys:
        vals = [r.values[k] for r in reports if r.values.get(k) is not None]
        vals = [float(v) for v in vals if math.isfinite(float(v))]
        if vals:
            out[k] = float(np.mean(vals))
    return out


def evaluate(
    rendered: Sequence[str | os.PathLike],
    references: Sequence[str | os.PathLike],
    options: EvalOptions | None = None,
) -> tuple[list[ImageReport], dict[str, float]]:
    """Evaluate every pair; returns the per-image reports and the summary.

    See :func:`~l3cli.evaluate.inputs.find_items` for the inputs and
    :class:`~l3cli.evaluate.options.EvalOptions` for the options.
    """
    options = options or EvalOptions()
    items = find_items(rendered, references)
    reports = []
    for item in items:
        log.info("evaluating %s against %s", item.rendered, item.reference)
        reports.append(evaluate_item(item, options))
    return reports, summarise(reports)


def evaluate_images(image, reference, *, space: str | None = None,
                    reference_space: str | None = None, **options) -> dict[str, float]:
    """The metrics of one image against its reference, as ``l3 evaluate`` computes them
    (``l3cli.evaluate(image, reference)``).

    Parameters
    ----------
    image, reference
        Image files (EXR, TIFF, PNG, JPEG), or float arrays (H, W, 3).
    space, reference_space
        The colour space of each (:data:`l3cli.colourspace.SPACES`): needed for an
        array (e.g. a table's render is in its ``output_space``, linear); a file's
        own by default.
    **options
        :class:`~l3cli.evaluate.options.EvalOptions` fields, e.g. ``exclude_border=4``.

    Returns
    -------
    dict
        Metric name -> value (``scielab_mean``, ``psnr_db``, ...; the keys of the
        JSON report's per-image ``metrics``).
    """
    import pathlib

    def source(x, sp, param, what):
        if isinstance(x, np.ndarray):
            if sp is None:
                raise OptionError(param, "{name} is needed with an array (its colour space: "
                                  "xyz, linear-srgb, srgb or lab)")
            return ArrayImage(x, sp, f"the {what} array")
        return pathlib.Path(x)

    rendered = source(image, space, "space", "image")
    ref = source(reference, reference_space, "reference_space", "reference")
    item = EvalItem(getattr(rendered, "stem", "image"), rendered, ref,
                    reference_space=reference_space)
    report = evaluate_item(item, EvalOptions(**options), rendered_space=space)
    return dict(report.values)
