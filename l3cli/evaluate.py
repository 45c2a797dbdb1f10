"""Evaluate rendered images against references: S-CIELAB, PSNR, Macbeth ΔE, MTF50.

The library core of ``l3 evaluate`` (it knows nothing of click).

Inputs
------
* Rendered images and reference images given as files, paired in order; or
* a reference ``simulate`` folder (``manifest.json``), with the renders given as
  a folder or as files, matched to the captures by stem (``RENDER_DIR/STEM.exr``,
  ``.tif``, ``.tiff``, ``.png``, ``.jpg``, ``.jpeg``). The manifest then gives the
  chart geometry and ideal patch XYZ, the slanted-edge region, and the pixel pitch.

Images to CIE XYZ
-----------------
:func:`l3cli.io.image.read_image` returns each image with its colour space:

* TIFF/PNG/JPEG are display sRGB: decoded with the sRGB transfer function and
  converted to XYZ (D65) times 100, so the display white is (95.047, 100, 108.883)
  (the sRGB display model of ISETCam and METRICS.md);
* EXR holds linear values in the space named by its ``l3:space`` attribute, which
  ``l3 render``/``l3 simulate`` write (``xyz``, ``linear-srgb``, ``srgb`` or ``lab``);
  an EXR without the attribute is linear sRGB (the reader's rule), except a
  ``simulate`` target, which the manifest declares (``target.space``, ``xyz``).

Scale and white point
---------------------
The reference decides the white point used for CIELAB and S-CIELAB:

* a display-encoded reference: the display white (95.047, 100, 108.883);
* a linear reference from a ``simulate`` folder (targets on an arbitrary fixed
  photometric scale): the capture's ``white_xyz`` if the manifest gives one; else
  the chart's ideal white patch (``chart.reference_xyz[white_index]``, as the
  Macbeth ΔE uses); else the illuminant's chromaticity (manifest ``illuminant``
  if colour-science knows it, else D65) with Y = the 99th percentile of the
  reference's Y;
* another linear reference: D65 with Y = 1 (l3's linear convention: a display
  white has Y = 1).

A display-encoded render compared with a linear reference is taken as relative
to the reference's white (its XYZ is scaled by white Y / 100); a linear render
compared with a display-encoded reference is taken on l3's linear scale (display
white Y = 1, so its XYZ is scaled by 100). XYZ is clipped to
[0, white] before the S-CIELAB filtering, as ISETCam does.

PSNR is computed on the encoded values (data range 1) when both images are
display-encoded, and on linear XYZ with the white's Y as data range otherwise.

``align`` registers each reference on its render first (:func:`align_reference`):
a camera JPEG or raw-converter output is often a crop of the raw's area (and
may be mirrored or rotated), while ``l3 render`` writes the raw's full area.
The render is then cut to the reference's area and brought to its
orientation, so chart corners and edge regions are in the reference's pixels.

``exclude_border`` removes a margin of N pixels on every side from both images
before S-CIELAB and PSNR (some camera ISPs corrupt the outer pixels); chart
patches and edge regions keep their full-image coordinates.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.errors import ConfigError, InputError
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
    DEFAULT_OPPONENT,
    SRGB_WHITE_XYZ,
    SCIELABResult,
    samples_per_degree,
    scielab,
)

__all__ = [
    "IMAGE_SUFFIXES",
    "EvalItem",
    "ImageReport",
    "find_items",
    "load_xyz",
    "align_reference",
    "evaluate_item",
    "evaluate",
    "summarise",
    "report_dict",
    "write_report",
    "format_table",
]

log = logging.getLogger(__name__)

#: Suffixes of rendered images looked for in a render folder, in order of preference.
IMAGE_SUFFIXES = (".exr", ".tif", ".tiff", ".png", ".jpg", ".jpeg")

#: Fraction of each manifest patch box (per side) averaged for the Macbeth ΔE.
PATCH_FRACTION = 0.5

#: Keys of the JSON contract, per image and in the summary (in this order).
CONTRACT_IMAGE_KEYS = (
    "scielab_mean", "scielab_median", "scielab_p90", "psnr_db", "macbeth_de_mean", "mtf50_cy_per_mm",
)
SUMMARY_KEYS = (
    "scielab_mean", "scielab_median", "scielab_p90", "scielab_de2000_mean", "psnr_db",
    "macbeth_de_mean", "macbeth_de2000_mean", "mtf50_cy_per_px", "mtf50_cy_per_mm",
)


@dataclass(frozen=True)
class EvalItem:
    """One (rendered, reference) pair to evaluate.

    Attributes
    ----------
    name
        Name in the report (the capture stem, or the rendered file name).
    rendered, reference
        Image paths.
    capture
        The manifest's capture record when the reference is a simulation.
    camera
        The manifest's camera record when the reference is a simulation.
    reference_space
        Colour space of the reference declared by the manifest (or None: from the file).
    """

    name: str
    rendered: Path
    reference: Path
    capture: dict | None = None
    camera: dict | None = None
    reference_space: str | None = None


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
    chart_boxes: list | None = None
    edge_roi: tuple | None = None


# ----------------------------------------------------------------------------- inputs


def _read_manifest(folder: Path) -> dict:
    mpath = folder / "manifest.json"
    try:
        manifest = json.loads(mpath.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{mpath}: cannot read the simulation manifest ({exc})") from exc
    if not isinstance(manifest, dict) or manifest.get("format") != "l3-simulation":
        raise InputError(f"{mpath}: not an l3 simulation manifest (format must be 'l3-simulation')")
    if not isinstance(manifest.get("captures"), list):
        raise InputError(f"{mpath}: 'captures' must be a list")
    return manifest


def _stem(path: Path) -> str:
    return path.name[: -len(path.suffix)] if path.suffix else path.name


def _images_in(folder: Path) -> list[Path]:
    return sorted(
        p for p in folder.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES
    )


def _render_for(folder: Path, stem: str) -> Path | None:
    for suf in IMAGE_SUFFIXES:
        for cand in (folder / f"{stem}{suf}", folder / f"{stem}{suf.upper()}"):
            if cand.is_file():
                return cand
    return None


def find_items(
    rendered: Sequence[str | os.PathLike], references: Sequence[str | os.PathLike]
) -> list[EvalItem]:
    """Pair rendered images with references.

    Parameters
    ----------
    rendered
        Rendered image files, or one folder of them.
    references
        Reference image files (one per rendered file, same order), one folder of
        images (matched by stem), or one ``simulate`` folder (matched to the
        captures by stem).

    Returns
    -------
    list of EvalItem

    Raises
    ------
    InputError
        Missing paths, unequal counts, or a render that matches no capture.
    """
    rendered = [Path(p) for p in rendered]
    references = [Path(p) for p in references]
    if not rendered:
        raise InputError("no rendered image given")
    if not references:
        raise InputError("no reference given (--reference)")
    for p in (*rendered, *references):
        if not p.exists():
            raise InputError(f"{p}: no such file or folder")

    if len(references) == 1 and references[0].is_dir():
        ref_dir = references[0]
        if (ref_dir / "manifest.json").exists():
            return _simulation_items(rendered, ref_dir)
        ref_images = {_stem(p): p for p in _images_in(ref_dir)}
        renders = _expand_renders(rendered)
        items = []
        for r in renders:
            ref = ref_images.get(_stem(r))
            if ref is None:
                raise InputError(f"{r}: no reference image {_stem(r)}.* in {ref_dir}")
            items.append(EvalItem(_stem(r), r, ref))
        return items

    for p in references:
        if p.is_dir():
            raise InputError(f"{p}: give one reference folder, or reference files only")
    renders = _expand_renders(rendered)
    if len(renders) != len(references):
        raise InputError(
            f"{len(renders)} rendered image(s) but {len(references)} reference(s); "
            "give one reference per rendered image, in the same order"
        )
    return [EvalItem(r.name, r, ref) for r, ref in zip(renders, references, strict=True)]


def _expand_renders(rendered: list[Path]) -> list[Path]:
    out: list[Path] = []
    for p in rendered:
        if p.is_dir():
            found = _images_in(p)
            if not found:
                raise InputError(f"{p}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
            out.extend(found)
        else:
            out.append(p)
    return out


def _simulation_items(rendered: list[Path], sim_dir: Path) -> list[EvalItem]:
    manifest = _read_manifest(sim_dir)
    camera = manifest.get("camera") or {}
    space = (manifest.get("target") or {}).get("space", "xyz")
    captures = {}
    for i, cap in enumerate(manifest["captures"]):
        if not isinstance(cap, dict) or "stem" not in cap or "target" not in cap:
            raise InputError(f"{sim_dir / 'manifest.json'}: capture {i} lacks 'stem' or 'target'")
        captures[str(cap["stem"])] = cap
    items = []
    if len(rendered) == 1 and rendered[0].is_dir():
        folder = rendered[0]
        for stem, cap in captures.items():
            r = _render_for(folder, stem)
            if r is None:
                log.info("%s: no render of capture %s; skipped", folder, stem)
                continue
            items.append(EvalItem(stem, r, sim_dir / cap["target"], cap, camera, space))
        if not items:
            raise InputError(
                f"{folder}: no render matches a capture of {sim_dir} "
                f"(expected files like {next(iter(captures), 'STEM')}.exr)"
            )
        return items
    for r in _expand_renders(rendered):
        stem = _stem(r)
        cap = captures.get(stem)
        if cap is None:
            raise InputError(
                f"{r}: its stem {stem!r} is not a capture of {sim_dir} "
                f"(captures: {', '.join(sorted(captures)[:5])}{', ...' if len(captures) > 5 else ''})"
            )
        items.append(EvalItem(stem, r, sim_dir / cap["target"], cap, camera, space))
    return items


def load_xyz(path: str | os.PathLike, *, space: str | None = None) -> tuple[np.ndarray, str]:
    """Read an image as float64 (H, W, 3) CIE XYZ.

    Parameters
    ----------
    path
        Image file (EXR, TIFF, PNG, JPEG).
    space
        Colour space of the file's values; None takes it from the file
        (EXR ``l3:space`` attribute; display sRGB for the others).

    Returns
    -------
    xyz, space
        XYZ (display-encoded images on the 100 scale: white Y = 100) and the
        space the values were in.

    Raises
    ------
    InputError
        Unreadable file, an unknown colour space (encoding), or not 3 channels.
    """
    xyz, space, _ = _load(path, space)
    return xyz, space


def _load(path: str | os.PathLike, space: str | None) -> tuple[np.ndarray, str, np.ndarray]:
    from l3cli.colourspace import check_space, convert
    from l3cli.io.image import read_image

    img, file_space = read_image(path)
    name = space or file_space
    try:
        space = check_space(name)
    except ConfigError:
        raise InputError(
            f"{path}: unknown encoding / colour space {name!r}; allowed: xyz, linear-srgb, srgb, lab"
        ) from None
    if img.shape[2] == 4:
        img = img[:, :, :3]
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    if img.shape[2] != 3:
        raise InputError(f"{path}: has {img.shape[2]} channels; evaluation needs 3 (or 1)")
    if not np.all(np.isfinite(img)):
        raise InputError(f"{path}: holds NaN or infinite values")
    xyz = np.asarray(convert(img, space, "xyz"), dtype=np.float64)
    if space == "srgb":
        xyz *= 100.0
    return xyz, space, img


# ----------------------------------------------------------------------------- white


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


def evaluate_item(
    item: EvalItem,
    *,
    dpi: float = 96.0,
    distance: float = 1.0,
    filters: str = "distribution",
    opponent: str = DEFAULT_OPPONENT,
    chart_corners: Sequence[float] | None = None,
    edge_roi: Sequence[int] | None = None,
    pixel_pitch_um: float | None = None,
    exclude_border: int = 0,
    keep_images: bool = False,
    align: bool = False,
) -> ImageReport:
    """Compute every applicable metric for one pair.

    Parameters
    ----------
    item
        The pair (see :func:`find_items`).
    dpi, distance
        Display resolution and viewing distance (metres) for S-CIELAB.
    filters
        S-CIELAB filter version (``distribution`` or ``original``).
    opponent
        S-CIELAB XYZ -> opponent matrix: ``xyz10`` (default, ISETCam's), ``xyz2`` or ``hpe``.
    chart_corners
        Eight numbers, the chart's outer corners (TL, TR, BR, BL) in the image,
        for a chart in real images; the reference image's patches are the ideal.
    edge_roi
        ``(x0, y0, x1, y1)`` of a slanted edge in real images.
    pixel_pitch_um
        Pixel pitch (micrometres) for cycles/mm; default from the manifest.
    exclude_border
        Pixels removed on each side before S-CIELAB and PSNR.
    keep_images
        Keep the XYZ images in the report (for plots).
    align
        Register the reference on the render and cut the render to it
        (:func:`align_reference`), for references that are a crop of the raw's
        area; chart corners and edge regions are then in the reference's pixels.

    Returns
    -------
    ImageReport
    """
    if exclude_border < 0:
        raise ConfigError(f"exclude_border must be >= 0, got {exclude_border}")
    rend, rend_space, rend_values = _load(item.rendered, None)
    ref, ref_space, ref_values = _load(item.reference, item.reference_space)
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
        rend = rend * (white[1] / 100.0)
    elif ref_space == "srgb" and rend_space != "srgb":
        rend = rend * 100.0  # linear l3 images: a display white has Y = 1

    values: dict[str, float | None] = {}
    sc = scielab(
        _crop(ref, exclude_border), _crop(rend, exclude_border),
        white_point=white, samples_per_deg=samples_per_degree(dpi, distance), version=filters,
        opponent=opponent,
    )
    values.update(sc.summary())

    if rend_space == "srgb" and ref_space == "srgb":
        p = psnr(_crop(ref_values, exclude_border), _crop(rend_values, exclude_border), data_range=1.0)
    else:
        p = psnr(_crop(ref, exclude_border), _crop(rend, exclude_border), data_range=float(white[1]))
    values["psnr_db"] = p

    report = ImageReport(item.name, values, scielab=sc, white_xyz=white)

    # Macbeth chart
    chart = _chart_from_capture(item.capture)
    if chart_corners is not None:
        boxes = chart_patches_from_corners(chart_corners, image_shape=rend.shape, fraction=PATCH_FRACTION)
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
    roi = tuple(int(v) for v in edge_roi) if edge_roi is not None else None
    if roi is None and isinstance(edge, dict) and edge.get("roi") is not None:
        roi = tuple(int(v) for v in edge["roi"])
    if roi is not None:
        pitch = pixel_pitch_um
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

    if keep_images:
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
    *,
    dpi: float = 96.0,
    distance: float = 1.0,
    filters: str = "distribution",
    opponent: str = DEFAULT_OPPONENT,
    chart_corners: Sequence[float] | None = None,
    edge_roi: Sequence[int] | None = None,
    pixel_pitch_um: float | None = None,
    exclude_border: int = 0,
    keep_images: bool = False,
    align: bool = False,
) -> tuple[list[ImageReport], dict[str, float]]:
    """Evaluate every pair; returns the per-image reports and the summary.

    See :func:`find_items` for the inputs and :func:`evaluate_item` for the options.
    """
    samples_per_degree(dpi, distance)  # validate early
    items = find_items(rendered, references)
    reports = []
    for item in items:
        log.info("evaluating %s against %s", item.rendered, item.reference)
        reports.append(
            evaluate_item(
                item, dpi=dpi, distance=distance, filters=filters, opponent=opponent,
                chart_corners=chart_corners,
                edge_roi=edge_roi, pixel_pitch_um=pixel_pitch_um, exclude_border=exclude_border,
                keep_images=keep_images, align=align,
            )
        )
    return reports, summarise(reports)


# ----------------------------------------------------------------------------- output


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
