"""Evaluate rendered images against references: S-CIELAB, PSNR, Macbeth ΔE, MTF50.

The package is callable: ``l3cli.evaluate(image, reference)`` is
:func:`~l3cli.evaluate.metrics.evaluate_images` (one image, a file or an array).

The library core of ``l3 evaluate`` (it knows nothing of click), one module a
concern: :mod:`~l3cli.evaluate.inputs` (pairing, images read as XYZ),
:mod:`~l3cli.evaluate.options` (:class:`EvalOptions`),
:mod:`~l3cli.evaluate.metrics` (white point, registration, the metrics of
each pair), :mod:`~l3cli.evaluate.report` (JSON and text) and
:mod:`~l3cli.evaluate.plots` (figures, matplotlib imported lazily).

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

One white scale for every format: a display code value of 1 is linear Y = 1,
the rule ``l3 render`` encodes with. So a display-encoded render compared with a
linear reference is decoded to XYZ on l3's linear scale (its XYZ on the 100 scale
divided by 100), and a linear render compared with a display-encoded reference
is multiplied by 100. EXR, 16-bit TIFF, PNG and JPEG renders of one table then
score alike against a ``simulate`` folder, up to the quantisation of the format
(``tests/evaluate/test_evaluate_truth.py`` states and tests the bounds). XYZ is clipped
to [0, white] before the S-CIELAB filtering, as ISETCam does.

PSNR is computed in the reference's domain, whatever the render's format: sRGB
code values (data range 1) against a display-encoded reference, the render
encoded as ``l3 render`` encodes it; linear XYZ with the white's Y as data range
against a linear reference. The JSON names it (``psnr_domain``), the table's
column header too.

A reference folder is searched for rendered images only: a TIFF or PNG with a
raw sidecar (``X.tif.toml``) is a raw mosaic and never a reference, and two
images of one stem (``X.png``, ``X.jpg``) are refused as ambiguous. A reference
whose structure hardly correlates with the render's (band-pass correlation of
luminance below :data:`~l3cli.evaluate.metrics.MIN_CORRESPONDENCE`) is reported
with a warning: probably another shot or another file.

``align`` registers each reference on its render first (:func:`align_reference`):
a camera JPEG or raw-converter output is often a crop of the raw's area (and
may be mirrored or rotated), while ``l3 render`` writes the raw's full area.
The render is then cut to the reference's area and brought to its
orientation, so chart corners and edge regions are in the reference's pixels.

``exclude_border`` removes a margin of N pixels on every side from both images
before S-CIELAB and PSNR (some camera ISPs corrupt the outer pixels); chart
patches and edge regions keep their full-image coordinates.
"""

import sys
import types

from l3cli.evaluate.inputs import IMAGE_SUFFIXES, EvalItem, find_items, load_xyz
from l3cli.evaluate.metrics import (
    ImageReport,
    align_reference,
    evaluate,
    evaluate_images,
    evaluate_item,
    summarise,
    white_point_for,
)
from l3cli.evaluate.options import EvalOptions
from l3cli.evaluate.report import format_table, report_dict, write_report

__all__ = [
    "IMAGE_SUFFIXES",
    "EvalItem",
    "EvalOptions",
    "ImageReport",
    "find_items",
    "load_xyz",
    "align_reference",
    "white_point_for",
    "evaluate_item",
    "evaluate",
    "evaluate_images",
    "summarise",
    "report_dict",
    "write_report",
    "format_table",
]


class _CallableEvaluate(types.ModuleType):
    """The package's type: calling it evaluates one image (:func:`evaluate_images`)."""

    def __call__(self, image, reference, **options):
        return evaluate_images(image, reference, **options)


sys.modules[__name__].__class__ = _CallableEvaluate
