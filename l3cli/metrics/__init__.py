"""Image-quality metrics: S-CIELAB, Macbeth ΔE, slanted-edge MTF, PSNR.

One module per method (``scielab``, ``macbeth``, ``mtf``, ``psnr``); colour
conversions and ΔE formulas come from colour-science. Conventions follow ISETCam
(see ``docs/evaluation.md``).
"""

from l3cli.metrics.macbeth import (
    MacbethResult,
    chart_patches_from_corners,
    macbeth_delta_e,
    patch_means,
)
from l3cli.metrics.mtf import MTFResult, mtf50, slanted_edge_mtf
from l3cli.metrics.psnr import data_range_for, psnr
from l3cli.metrics.scielab import (
    SCIELAB_FILTER_PARAMETERS,
    SCIELABResult,
    samples_per_degree,
    scielab,
    scielab_filters,
)

__all__ = [
    "MacbethResult",
    "chart_patches_from_corners",
    "macbeth_delta_e",
    "patch_means",
    "MTFResult",
    "mtf50",
    "slanted_edge_mtf",
    "data_range_for",
    "psnr",
    "SCIELAB_FILTER_PARAMETERS",
    "SCIELABResult",
    "samples_per_degree",
    "scielab",
    "scielab_filters",
]
