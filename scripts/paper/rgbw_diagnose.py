#!/usr/bin/env python3
"""Per-patch diagnosis of experiment 2's Macbeth renders: bias or noise, which
patches, lightness or chroma, and which training data the patches' classes saw.

``rgbw_diagnose.py BUILD CAMERA TEST_SIM RENDER_DIR [TABLE]``

BUILD: the paper build folder (its ``sim/CAMERA/train`` and
``tables/TABLE.npz``, TABLE defaults to CAMERA); TEST_SIM: a simulation folder
of Macbeth captures (e.g. made with ``l3 simulate --no-noise`` to see the bias
alone); RENDER_DIR: their renders through the table. For every Macbeth
capture it prints, per patch: ΔE*ab, ΔL*, ΔC*ab (rendered − ideal, after the
white normalisation of ``l3 evaluate``), the ideal L* and C*ab, the patch's
median response level and level bin, and how many unsaturated training
samples that level bin held from the chart (per training light level) and
from the natural photos.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from l3cli.classify.kernel import patch_features
from l3cli.io.image import read_image
from l3cli.io.manifest import read_manifest
from l3cli.metrics.macbeth import macbeth_delta_e, patch_means
from l3cli.table import load_table

PATCHES = ("dark skin", "light skin", "blue sky", "foliage", "blue flower", "bluish green", "orange",
           "purplish blue", "moderate red", "purple", "yellow green", "orange yellow", "blue", "green",
           "red", "yellow", "magenta", "cyan", "white", "neutral 8", "neutral 6.5", "neutral 5",
           "neutral 3.5", "black")


def _mosaic(path: Path) -> np.ndarray:
    img, _ = read_image(path)
    return (img[..., 0] if img.ndim == 3 else img).astype(np.float32)


def level_bins(sim: Path, table) -> dict[str, np.ndarray]:
    """Unsaturated training samples per level bin: ``chart@LUX`` per light level and ``natural``."""
    d = table.definition
    out: dict[str, np.ndarray] = {}
    for c in read_manifest(sim)["captures"]:
        lev, _, sat = patch_features(_mosaic(sim / c["noise_free"]), d.cfa, patch=d.patch)
        h = np.bincount(np.searchsorted(d.level_cuts, lev[sat == 0], side="right"),
                        minlength=d.level_cuts.size + 1)
        key = f"chart@{c['lux']:g}" if c["scene"] == "macbeth" else "natural"
        out[key] = out.get(key, 0) + h
    return out


def main(build: Path, camera: str, test: Path, renders: Path, table_name: str) -> None:
    table = load_table(build / "tables" / f"{table_name}.npz")
    d = table.definition
    bins = level_bins(build / "sim" / camera / "train", table)
    charts = sorted((k for k in bins if k.startswith("chart@")), key=lambda k: float(k[6:]))
    for c in read_manifest(test)["captures"]:
        if c["scene"] != "macbeth":
            continue
        boxes = c["chart"]["patches"]
        rendered, _ = read_image(renders / f"{c['stem']}.exr")
        res = macbeth_delta_e(patch_means(rendered, boxes, fraction=0.5), np.array(c["chart"]["reference_xyz"]))
        lev, _, _ = patch_features(_mosaic(test / c["noise_free"]), d.cfa, patch=d.patch)
        chroma_m = np.hypot(res.measured_lab[:, 1], res.measured_lab[:, 2])
        chroma_i = np.hypot(res.ideal_lab[:, 1], res.ideal_lab[:, 2])
        d_l = res.measured_lab[:, 0] - res.ideal_lab[:, 0]
        d_c = chroma_m - chroma_i
        print(f"== {c['stem']}: {c['exposure_s'] * 1000:.0f} ms x gain {c.get('analog_gain', 1.0):.3g}, "
              f"mean ΔE*ab {res.delta_e_ab.mean():.2f} (colours {res.delta_e_ab[:18].mean():.2f}, "
              f"greys {res.delta_e_ab[18:].mean():.2f}); mean |ΔL*| {np.abs(d_l).mean():.2f}, "
              f"mean ΔC*ab of the colours {d_c[:18].mean():.2f}")
        print(f"  {'patch':13s}  ΔE*ab   ΔL*  ΔC*ab     L*   C*ab   level bin  natural  "
              + " ".join(charts))
        for i, (x0, y0, x1, y1) in enumerate(boxes):
            dx, dy = (x1 - x0) // 4, (y1 - y0) // 4
            lv = float(np.median(lev[y0 + dy:y1 - dy, x0 + dx:x1 - dx]))
            b = int(np.searchsorted(d.level_cuts, lv, side="right"))
            print(f"  {PATCHES[i]:13s} {res.delta_e_ab[i]:6.2f} {d_l[i]:5.2f} {d_c[i]:6.2f} "
                  f"{res.ideal_lab[i, 0]:6.1f} {chroma_i[i]:6.1f}  {lv:.4f} {b:3d}  {bins['natural'][b]:7d}  "
                  + " ".join(f"{bins[k][b]:{len(k)}d}" for k in charts))


if __name__ == "__main__":
    if len(sys.argv) not in (5, 6):
        raise SystemExit(__doc__)
    a = sys.argv[1:]
    main(Path(a[0]), a[1], Path(a[2]), Path(a[3]), a[4] if len(a) == 5 else a[1])
