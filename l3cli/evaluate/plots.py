"""Evaluation figures (matplotlib, Agg backend, imported lazily).

Per image: the S-CIELAB ΔE*ab map with its histogram (as the Nikon figure of the
L3 paper), the slanted-edge MTF with MTF50 marked, the Macbeth patches with the
reference and rendered colours as two halves of each patch, and side-by-side
crops of reference and rendered images.

References
----------
Q. Tian, S. Lansel, J. E. Farrell and B. A. Wandell, "Automating the design of
image processing pipelines for novel color filter arrays: Local, Linear, Learned
(L3) method", Proc. SPIE 9023, Digital Photography X (2014).
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from l3cli.figures import pyplot
from l3cli.io.atomic import atomic_path, check_writable_dir

if TYPE_CHECKING:
    from l3cli.evaluate.metrics import ImageReport

__all__ = ["plot_report", "xyz_to_display"]


def _safe(name: str) -> str:
    for suf in (".exr", ".tif", ".tiff", ".png", ".jpg", ".jpeg"):
        if name.lower().endswith(suf):
            name = name[: -len(suf)]
            break
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name) or "image"


def xyz_to_display(xyz: np.ndarray, white_xyz: np.ndarray) -> np.ndarray:
    """Display sRGB (clipped to [0, 1]) of XYZ relative to a white whose Y maps to 1."""
    from l3cli.colourspace import convert

    y = float(np.asarray(white_xyz).reshape(3)[1])
    return np.asarray(convert((np.asarray(xyz) / y).astype(np.float32), "xyz", "srgb"))


def _save(fig, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    return path


#: Words for the S-CIELAB filter sets (``--filters``).
FILTER_WORDS = {"distribution": "ISETCam's filters", "original": "the 1997 paper's filters"}


def scielab_title(samples_per_deg: float, dpi: float | None = None,
                  distance_m: float | None = None) -> str:
    """``"S-CIELAB ΔE*ab per pixel (96 dpi at 1.0 m: 66 samples/degree)"``."""
    view = f"{samples_per_deg:g} samples/degree"
    if dpi is not None and distance_m is not None:
        view = f"{dpi:g} dpi at {distance_m:g} m: {view}"
    return f"S-CIELAB ΔE*ab per pixel ({view})"


def plot_report(report: ImageReport, out_dir: str | os.PathLike, *, dpi: float | None = None,
                distance_m: float | None = None) -> list[Path]:
    """Write the figures of one :class:`l3cli.evaluate.ImageReport` into ``out_dir``.

    Parameters
    ----------
    report
        The image's report.
    out_dir
        Existing, writable folder.
    dpi, distance_m
        The display S-CIELAB was computed for (``--dpi``, ``--distance``),
        named in the figure's title with the samples per degree they give.

    Returns
    -------
    list of Path
        The PNG files written (``NAME_scielab.png``, ``NAME_mtf.png``,
        ``NAME_macbeth.png``, ``NAME_crops.png`` where applicable).
    """
    plt = pyplot()
    out_dir = check_writable_dir(out_dir)
    name = _safe(report.name)
    written: list[Path] = []

    if report.scielab is not None:
        de = report.scielab.delta_e_ab
        fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 4.6), layout="constrained",
                                       gridspec_kw={"width_ratios": [1.3, 1]})
        vmax = max(float(np.percentile(de, 99.5)), 1e-6)
        im = ax0.imshow(de, cmap="inferno", vmin=0, vmax=vmax, interpolation="nearest")
        fig.colorbar(im, ax=ax0, label="ΔE*ab (colour scale tops out at the 99.5th percentile)")
        ax0.set_title(f"{report.name}: S-CIELAB ΔE*ab map (brighter: larger difference)",
                      fontsize=10)
        ax0.set_axis_off()
        top = max(float(np.percentile(de, 99.9)), 1e-6)  # a long tail would squash the bars
        above = int(np.count_nonzero(de > top))
        counts, _, _ = ax1.hist(de.ravel(), bins=100, range=(0, top), color="0.3")
        ax1.set_ylim(0, 1.4 * max(float(counts.max()), 1.0))  # headroom for the legend
        ax1.axvline(report.scielab.mean, color="C3", label=f"mean {report.scielab.mean:.2f}")
        ax1.axvline(report.scielab.p90, color="C0", ls="--",
                    label=f"90th percentile {report.scielab.p90:.2f}")
        if above:
            ax1.plot([], [], " ", label=f"{above} pixels ({100.0 * above / de.size:.2g} %) "
                                        f"above {top:.3g} not shown")
        ax1.set_xlim(0, top)
        ax1.set_xlabel("S-CIELAB ΔE*ab")
        ax1.set_ylabel("pixels")
        ax1.legend(fontsize=8, loc="upper right")
        ax1.set_title(scielab_title(report.scielab.samples_per_deg, dpi, distance_m)
                      + f"\n{FILTER_WORDS.get(report.scielab.version, report.scielab.version)}",
                      fontsize=10)
        written.append(_save(fig, out_dir / f"{name}_scielab.png"))
        plt.close(fig)

    if report.mtf is not None:
        m = report.mtf
        fig, ax = plt.subplots(figsize=(6.4, 4.2), layout="constrained")
        ax.plot(m.frequencies, m.mtf, color="k", label="MTF")
        ax.axhline(0.5, color="0.6", lw=0.8)
        ax.axvline(m.mtf50_cy_per_px, color="C3", ls="--")
        label = f"MTF50 = {m.mtf50_cy_per_px:.4f} cycles/pixel"
        if m.mtf50_cy_per_mm is not None:
            label += f" = {m.mtf50_cy_per_mm:.1f} cycles/mm"
        ax.plot([m.mtf50_cy_per_px], [0.5], "o", color="C3", label=label)
        ax.axvline(0.5, color="0.6", lw=0.8, ls=":", label="Nyquist frequency (0.5 cycles/pixel)")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, max(1.05, float(np.max(m.mtf[m.frequencies <= 1])) * 1.05))
        ax.set_xlabel("spatial frequency (cycles/pixel)")
        ax.set_ylabel("MTF (contrast transferred)")
        ax.set_title(f"{report.name}: sharpness, ISO 12233 slanted edge at {m.angle_deg:.1f}°",
                     fontsize=10)
        ax.legend(fontsize=8)
        written.append(_save(fig, out_dir / f"{name}_mtf.png"))
        plt.close(fig)

    if report.macbeth is not None:
        mb = report.macbeth
        white = mb.ideal_xyz[np.argmax(mb.ideal_xyz[:, 1])]
        ideal_rgb = xyz_to_display(mb.ideal_xyz, white)
        meas_rgb = xyz_to_display(mb.measured_xyz, white)
        n = len(mb.ideal_xyz)
        cols = 6 if n % 6 == 0 else int(np.ceil(np.sqrt(n)))
        rows = int(np.ceil(n / cols))
        cell = 40
        img = np.ones((rows * cell, cols * cell, 3), dtype=np.float32)
        yy, xx = np.mgrid[0:cell, 0:cell]
        upper = xx + yy < cell  # upper-left triangle: reference; lower-right: rendered
        for i in range(n):
            r, c = divmod(i, cols)
            block = np.where(upper[..., None], ideal_rgb[i], meas_rgb[i])
            block[[0, -1], :] = 1.0
            block[:, [0, -1]] = 1.0
            img[r * cell:(r + 1) * cell, c * cell:(c + 1) * cell] = block
        fig, ax = plt.subplots(figsize=(cols * 1.1, rows * 1.1 + 0.6))
        ax.imshow(img, interpolation="nearest")
        for i in range(n):
            r, c = divmod(i, cols)
            ax.text(c * cell + cell - 3, r * cell + cell - 4, f"{mb.delta_e_ab[i]:.1f}",
                    ha="right", va="bottom", fontsize=7, color="w" if mb.ideal_lab[i, 0] < 55 else "k")
        ax.set_axis_off()
        ax.set_title(f"{report.name}: ColorChecker patches, mean ΔE*ab {mb.mean_ab:.2f}\n"
                     "upper-left triangle: reference, lower-right: rendered, number: ΔE*ab",
                     fontsize=9)
        written.append(_save(fig, out_dir / f"{name}_macbeth.png"))
        plt.close(fig)

    if report.rendered_xyz is not None and report.reference_xyz is not None:
        h, w = report.reference_xyz.shape[:2]
        s = min(256, h, w)
        y0, x0 = (h - s) // 2, (w - s) // 2
        crops = [("reference", report.reference_xyz), ("rendered", report.rendered_xyz)]
        fig, axes = plt.subplots(1, 2, figsize=(9, 4.8))
        for ax, (title, xyz) in zip(axes, crops, strict=True):
            ax.imshow(xyz_to_display(xyz[y0:y0 + s, x0:x0 + s], report.white_xyz), interpolation="nearest")
            ax.set_title(f"{title} (x {x0}-{x0 + s}, y {y0}-{y0 + s})")
            ax.set_axis_off()
        fig.suptitle(f"{report.name}: centre crops as display sRGB")
        written.append(_save(fig, out_dir / f"{name}_crops.png"))
        plt.close(fig)
    return written
