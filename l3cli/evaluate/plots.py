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

from l3cli.io.atomic import atomic_path, check_writable_dir

if TYPE_CHECKING:
    from l3cli.evaluate.metrics import ImageReport

__all__ = ["plot_report", "xyz_to_display"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


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


def plot_report(report: ImageReport, out_dir: str | os.PathLike) -> list[Path]:
    """Write the figures of one :class:`l3cli.evaluate.ImageReport` into ``out_dir``.

    Returns
    -------
    list of Path
        The PNG files written (``NAME_scielab.png``, ``NAME_mtf.png``,
        ``NAME_macbeth.png``, ``NAME_crops.png`` where applicable).
    """
    plt = _pyplot()
    out_dir = check_writable_dir(out_dir)
    name = _safe(report.name)
    written: list[Path] = []

    if report.scielab is not None:
        de = report.scielab.delta_e_ab
        fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [1.3, 1]})
        vmax = max(float(np.percentile(de, 99.5)), 1e-6)
        im = ax0.imshow(de, cmap="inferno", vmin=0, vmax=vmax, interpolation="nearest")
        fig.colorbar(im, ax=ax0, label="S-CIELAB ΔE*ab")
        ax0.set_title(f"{report.name}: S-CIELAB ΔE*ab map")
        ax0.set_axis_off()
        ax1.hist(de.ravel(), bins=100, range=(0, max(vmax, float(de.max()))), color="0.3")
        ax1.axvline(report.scielab.mean, color="C3", label=f"mean {report.scielab.mean:.2f}")
        ax1.axvline(report.scielab.p90, color="C0", ls="--", label=f"p90 {report.scielab.p90:.2f}")
        ax1.set_xlabel("ΔE*ab")
        ax1.set_ylabel("pixels")
        ax1.legend()
        ax1.set_title(f"{report.scielab.samples_per_deg} samples/deg, {report.scielab.version}")
        written.append(_save(fig, out_dir / f"{name}_scielab.png"))
        plt.close(fig)

    if report.mtf is not None:
        m = report.mtf
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.plot(m.frequencies, m.mtf, color="k", label="MTF")
        ax.axhline(0.5, color="0.6", lw=0.8)
        ax.axvline(m.mtf50_cy_per_px, color="C3", ls="--")
        label = f"MTF50 = {m.mtf50_cy_per_px:.4f} cy/px"
        if m.mtf50_cy_per_mm is not None:
            label += f" = {m.mtf50_cy_per_mm:.1f} cy/mm"
        ax.plot([m.mtf50_cy_per_px], [0.5], "o", color="C3", label=label)
        ax.axvline(0.5, color="0.8", lw=0.8, ls=":")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, max(1.05, float(np.max(m.mtf[m.frequencies <= 1])) * 1.05))
        ax.set_xlabel("frequency (cycles/pixel)")
        ax.set_ylabel("MTF")
        ax.set_title(f"{report.name}: slanted edge ({m.angle_deg:.1f}°)")
        ax.legend()
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
        ax.set_title(f"{report.name}: Macbeth (upper-left reference, lower-right rendered), "
                     f"mean ΔE*ab {mb.mean_ab:.2f}", fontsize=9)
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
        fig.suptitle(report.name)
        written.append(_save(fig, out_dir / f"{name}_crops.png"))
        plt.close(fig)
    return written
