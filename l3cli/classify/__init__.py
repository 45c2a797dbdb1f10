"""The L3 patch classifier, shared by training and rendering.

Every pixel of a raw mosaic is assigned a *class* from the patch of
``patch`` x ``patch`` raw values centred on it. The class is the tuple

``(position group, saturation pattern, response level, contrast)``

* **position group** -- the pixel's position in the CFA repeat,
  ``p = (y % ph) * pw + (x % pw)``; positions whose patch layouts coincide
  (:meth:`l3cli.cfa.CFA.equivalent_positions`) may share a group
  (``merge_positions``).
* **saturation pattern** -- a bit mask over the CFA channels: bit ``c`` is set
  when at least one pixel of channel ``c`` in the patch is at or above the
  saturation threshold. Pattern 0 is "nothing saturated"; every other pattern
  has its own classes.
* **response level** -- the mean of the per-channel means of the patch,
  ``L = (1/C') sum_c mean{x_k : channel(k) = c}`` over the ``C'`` channels
  present in the patch, binned by ``n_levels - 1`` cut points (log-spaced by
  default, linear optionally). Bin 0 is below the first cut (at the noise
  floor), the last bin above the last cut (near saturation).
* **contrast** -- the relative within-channel spread
  ``K = [(1/C') sum_c sd_c] / (max(L, 0) + eps)`` where ``sd_c`` is the
  standard deviation of the channel-``c`` pixels of the patch about their own
  mean (so colour differences between channels never count as texture), and
  the division by the level makes the rule the same at every exposure. ``K``
  is binned per level by ``n_contrast - 1`` thresholds; by default the
  thresholds are quantiles of the training data's contrast at that level (the
  median for two bins, flat vs textured), so both bins of every level are
  populated whatever the noise. The standard deviation (not a median-based
  spread) is used because it follows from separable box sums of ``x`` and
  ``x²``, which keeps classification a few operations per pixel; clipped
  outliers are taken out by the saturation classes.

The class index is ``((group * n_sat + sat) * n_levels + level) * n_contrast +
contrast`` with ``n_sat = 2 ** n_channels``.

The numba tile kernel (:func:`run_tiles`) is the only implementation of
the rule; render and train both call it. Per tile of pixels it computes S-tap
horizontal then vertical sums of each channel's ``x`` and ``x²`` and an OR of
the saturated-channel bits, then level, contrast and class per pixel.

Modules: :mod:`~l3cli.classify.definition` (:class:`ClassDefinition`, which
validates itself), :mod:`~l3cli.classify.levels` (cut points and the float32
level lookup), :mod:`~l3cli.classify.padding` (CFA-phase mirror padding),
:mod:`~l3cli.classify.kernel` (the numba tile kernel, :func:`classify`,
:func:`patch_features`) and :mod:`~l3cli.classify.histograms` (the feature
histogram that places the cut points in training). The render loops the
kernel calls live beside the renderer, in :mod:`l3cli.render_rows`.

Precision: the features are computed in float32 in a fixed order (no
fast-math), so a pixel's class depends on its patch only. The level is exact
to a few float32 ulps; the contrast to about 1e-4 (``E[x²] - m²`` cancels
where a channel is nearly flat, so a perfectly flat patch has a contrast
between 0 and ~5e-4 rather than 0). Real raw data always carry more relative
noise than that (quantisation alone gives ~1e-4 at 12 bits), and the
comparisons with the cut points are made in float32: a cut point ``c`` acts
as ``float32(c)``.

References
----------
The L3 method's classes: Tian et al., Proc. SPIE 9023 (2014), and Jiang et
al., IEEE Trans. Image Processing 26(10) (2017); full citations in
``docs/training.md``.
"""

from l3cli.classify.definition import (
    CONTRAST_RULE,
    DEFAULT_CONTRAST_EPS,
    SATURATION_RULE,
    ClassDefinition,
    check_patch,
    describe_difference,
    position_groups,
)
from l3cli.classify.histograms import ContrastHistogram
from l3cli.classify.kernel import (
    MODE_CLASSES,
    MODE_DISPLAY,
    MODE_FEATURES,
    MODE_RENDER,
    KernelTables,
    band_rows,
    check_mosaic,
    classify,
    kernel_tables,
    patch_features,
    run_tiles,
)
from l3cli.classify.levels import SPACINGS, LevelLookup, level_cuts_between, level_lookup
from l3cli.classify.padding import mirror_indices, pad_mosaic

__all__ = [
    "CONTRAST_RULE",
    "DEFAULT_CONTRAST_EPS",
    "MODE_CLASSES",
    "MODE_DISPLAY",
    "MODE_FEATURES",
    "MODE_RENDER",
    "SATURATION_RULE",
    "SPACINGS",
    "ClassDefinition",
    "ContrastHistogram",
    "KernelTables",
    "LevelLookup",
    "band_rows",
    "check_mosaic",
    "check_patch",
    "classify",
    "describe_difference",
    "kernel_tables",
    "level_cuts_between",
    "level_lookup",
    "mirror_indices",
    "pad_mosaic",
    "patch_features",
    "position_groups",
    "run_tiles",
]
