"""Image-quality metrics: S-CIELAB, Macbeth ΔE, slanted-edge MTF, PSNR.

One module per method; colour conversions and ΔE formulas come from
colour-science. Conventions follow ISETCam (see ``docs/evaluation.md``):

- :mod:`l3cli.metrics.scielab` — :func:`~l3cli.metrics.scielab.scielab`
  (Zhang & Wandell 1997), filters and samples per degree;
- :mod:`l3cli.metrics.macbeth` — :func:`~l3cli.metrics.macbeth.macbeth_delta_e`
  (ISETCam ``macbethColorError``) and chart geometry;
- :mod:`l3cli.metrics.mtf` — :func:`~l3cli.metrics.mtf.slanted_edge_mtf`
  (ISO 12233, after Burns' sfrmat);
- :mod:`l3cli.metrics.psnr` — :func:`~l3cli.metrics.psnr.psnr`.

The functions named like their modules (``scielab``, ``psnr``) are not
re-exported here, so that ``import l3cli.metrics.scielab`` always gives the module.
"""

from l3cli.metrics.macbeth import (
    MacbethResult,
    chart_patches_from_corners,
    macbeth_delta_e,
    patch_means,
)
from l3cli.metrics.mtf import MTFResult, mtf50, slanted_edge_mtf
from l3cli.metrics.psnr import data_range_for
from l3cli.metrics.scielab import (
    SCIELAB_FILTER_PARAMETERS,
    SCIELABResult,
    samples_per_degree,
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
    "SCIELAB_FILTER_PARAMETERS",
    "SCIELABResult",
    "samples_per_degree",
    "scielab_filters",
]
