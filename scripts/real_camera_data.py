#!/usr/bin/env python3
"""Helpers of scripts/real_camera.sh (approximating real pipelines, issue 7).

``blackmagic DNG OUTDIR``
    Renders the Blackmagic Pocket 4K DNG with LibRaw (rawpy ``postprocess``:
    AHD demosaic, camera white balance, sRGB primaries, sRGB transfer curve,
    16-bit, no auto-brightening) and splits raw and render at the middle
    column (even, so both halves keep the RGGB phase):
    ``OUTDIR/train/bmpcc_left.{raw,raw.toml,tif}`` (a pairs folder),
    ``OUTDIR/test/bmpcc_right.{raw,raw.toml}`` and ``OUTDIR/ref/bmpcc_right.tif``.
``bmpcc-wb DNG OUTDIR``
    Real raws whose white balance differs per shot (issue 15): five 1024x1024
    crops of the Blackmagic DNG (linearised by LibRaw, black 512), each
    written as a DNG with its own AsShotNeutral (as an auto white balance
    would choose; :data:`BMPCC_NEUTRALS`), rendered by LibRaw honouring it
    (the settings of ``blackmagic``): ``OUTDIR/train/`` shots 0-2 and
    ``OUTDIR/test/`` shots 3-4 as pairs folders (DNG + 16-bit TIFF).
``chart STEM [CHARTS_JSON]``
    Prints the ``l3 evaluate --chart`` value of an Infinite-ISP frame from
    CHARTS_JSON (default: the bundled
    ``l3cli/data/charts/infinite_isp_charts.json`` of the full frames; the
    compact set's crops have theirs in ``examples/infinite_isp/charts.json``).
``summary JSON...``
    Prints one Markdown table row per report (S-CIELAB mean, PSNR, Macbeth ΔE).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

#: LibRaw settings of the reference rendering (documented in docs/results.md).
LIBRAW_SETTINGS = dict(demosaic="AHD", use_camera_wb=True, output_color="sRGB",
                       gamma="(2.4, 12.92) = sRGB curve", output_bps=16, no_auto_bright=True)


def blackmagic(dng: str, outdir: str) -> None:
    import rawpy

    from l3cli.io.image import write_image
    from l3cli.io.raw import read_raw

    out = Path(outdir)
    for sub in ("train", "test", "ref"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    raw = read_raw(dng)
    with rawpy.imread(dng) as rp:
        dn = np.array(rp.raw_image_visible, dtype=np.uint16)
        rgb = rp.postprocess(demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD,
                             use_camera_wb=True, output_color=rawpy.ColorSpace.sRGB,
                             gamma=(2.4, 12.92), output_bps=16, no_auto_bright=True)
    if rgb.shape[:2] != dn.shape:
        raise SystemExit(f"LibRaw output {rgb.shape} differs from the raw {dn.shape}")
    h, w = dn.shape
    split = (w // 2) & ~1  # even: the right half keeps the RGGB phase
    black = float(raw.black_level[0])
    if np.ptp(raw.black_level):
        raise SystemExit("per-position black levels are not handled here")
    enc = rgb.astype(np.float32) / 65535.0
    for name, sl, folder in (("bmpcc_left", np.s_[:, :split], "train"),
                             ("bmpcc_right", np.s_[:, split:], "test")):
        part = np.ascontiguousarray(dn[sl])
        part.astype("<u2").tofile(out / folder / f"{name}.raw")
        (out / folder / f"{name}.raw.toml").write_text(
            f"width = {part.shape[1]}\nheight = {part.shape[0]}\ndtype = \"uint16\"\n"
            f"cfa = \"{raw.cfa.spec.replace('/', '')}\"\nblack_level = {black:g}\n"
            f"white_level = {raw.white_level:g}\n"
            "description = \"Blackmagic Pocket Cinema Camera 4K DNG (linearised by LibRaw), "
            f"columns {'0' if folder == 'train' else split}-{split - 1 if folder == 'train' else w - 1}\"\n"
        )
        write_image(out / ("train" if folder == "train" else "ref") / f"{name}.tif",
                    enc[sl], space="srgb")
    print(f"split {w}x{h} at column {split}; LibRaw settings: {LIBRAW_SETTINGS}")


#: Camera neutrals (AsShotNeutral, R G B) of the five bmpcc-wb shots: the DNG's own
#: (0.4533, 1, 0.53) and four others in the range daylight to tungsten.
BMPCC_NEUTRALS = ((0.4533, 1.0, 0.53), (0.60, 1.0, 0.40), (0.38, 1.0, 0.66),
                  (0.52, 1.0, 0.46), (0.42, 1.0, 0.60))


def bmpcc_wb(dng: str, outdir: str) -> None:
    import rawpy
    import tifffile

    from l3cli.io.image import write_image
    from l3cli.io.raw import write_raw

    out = Path(outdir)
    with rawpy.imread(dng) as rp:
        dn = np.array(rp.raw_image_visible, dtype=np.uint16)
        black = float(rp.black_level_per_channel[0])
    with tifffile.TiffFile(dng) as tf:
        v = tf.pages[0].tags["ColorMatrix1"].value
    cm = (np.array(v[0::2], float) / np.array(v[1::2], float)).reshape(3, 3)
    size = 1024
    for i, neutral in enumerate(BMPCC_NEUTRALS):
        y0, x0 = (200 + (i % 2) * 900) & ~1, (100 + i * 800) & ~1
        crop = dn[y0:y0 + size, x0:x0 + size]
        folder = out / ("train" if i < 3 else "test")
        folder.mkdir(parents=True, exist_ok=True)
        p = write_raw(folder / f"shot{i}.dng", crop, "RGGB", black_level=black,
                      white_level=65535, color_matrix=cm, as_shot_neutral=np.array(neutral),
                      make="Blackmagic", model="Pocket Cinema Camera 4K")
        with rawpy.imread(str(p)) as rp:
            rgb = rp.postprocess(demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD,
                                 use_camera_wb=True, output_color=rawpy.ColorSpace.sRGB,
                                 gamma=(2.4, 12.92), output_bps=16, no_auto_bright=True)
        write_image(folder / f"shot{i}.tif", rgb.astype(np.float32) / 65535.0, space="srgb")
        print(f"shot{i}: crop x={x0} y={y0}, AsShotNeutral {neutral}")


def chart(stem: str, charts: str | None = None) -> None:
    from importlib.resources import files

    src = Path(charts) if charts else files("l3cli") / "data/charts/infinite_isp_charts.json"
    data = json.loads(src.read_text())
    print(data["frames"][stem]["chart_option"])


def summary(paths: list[str]) -> None:
    for p in paths:
        rep = json.loads(Path(p).read_text())
        for im in rep["images"]:
            mac = im.get("macbeth_de_mean")
            print(f"| {im['name']} | {im['scielab_mean']:.3f} | {im['psnr_db']:.2f} | "
                  f"{'-' if mac is None else f'{mac:.2f}'} |")


if __name__ == "__main__":
    cmd, *args = sys.argv[1:] or ["help"]
    if cmd == "blackmagic" and len(args) == 2:
        blackmagic(*args)
    elif cmd == "bmpcc-wb" and len(args) == 2:
        bmpcc_wb(*args)
    elif cmd == "chart" and len(args) in (1, 2):
        chart(*args)
    elif cmd == "summary" and args:
        summary(args)
    else:
        raise SystemExit(__doc__)
