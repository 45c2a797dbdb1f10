"""The options of an evaluation: one object instead of ten threaded keywords."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from l3cli import defaults
from l3cli.errors import ConfigError

__all__ = ["EvalOptions"]


@dataclass(frozen=True)
class EvalOptions:
    """How to evaluate (see ``l3 evaluate --help`` and ``docs/evaluation.md``).

    Attributes
    ----------
    dpi, distance
        Display resolution (dots per inch) and viewing distance (metres) for
        S-CIELAB.
    filters
        S-CIELAB filter version (``distribution`` or ``original``).
    opponent
        S-CIELAB XYZ -> opponent matrix: ``xyz10`` (default, ISETCam's),
        ``xyz2`` or ``hpe``.
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
        Keep the XYZ images in the reports (for plots).
    align
        Register the reference on the render and cut the render to it
        (:func:`l3cli.evaluate.align_reference`), for references that are a
        crop of the raw's area; chart corners and edge regions are then in the
        reference's pixels.

    Examples
    --------
    >>> EvalOptions(dpi=300).settings()["samples_per_degree"]
    206
    >>> EvalOptions(exclude_border=-1)
    Traceback (most recent call last):
    ...
    l3cli.errors.ConfigError: exclude_border must be >= 0, got -1
    """

    dpi: float = defaults.DPI
    distance: float = defaults.VIEWING_DISTANCE_M
    filters: str = defaults.SCIELAB_FILTERS
    opponent: str = defaults.SCIELAB_OPPONENT
    chart_corners: Sequence[float] | None = None
    edge_roi: Sequence[int] | None = None
    pixel_pitch_um: float | None = None
    exclude_border: int = 0
    keep_images: bool = False
    align: bool = False

    def __post_init__(self) -> None:
        from l3cli.metrics.scielab import samples_per_degree

        if self.exclude_border < 0:
            raise ConfigError(f"exclude_border must be >= 0, got {self.exclude_border}")
        samples_per_degree(self.dpi, self.distance)  # validates both

    def settings(self) -> dict[str, Any]:
        """The settings recorded in the JSON report."""
        from l3cli.metrics.scielab import samples_per_degree

        return {
            "dpi": self.dpi, "distance_m": self.distance,
            "samples_per_degree": samples_per_degree(self.dpi, self.distance),
            "filters": self.filters, "opponent": self.opponent,
            "exclude_border": self.exclude_border, "align": self.align,
            "delta_e": "CIE 1976 (extra: CIE 2000)",
        }
