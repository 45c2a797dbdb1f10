#!/usr/bin/env python3
"""Make the compact Infinite-ISP tutorial set in ``examples/infinite_isp/`` (issue 15, part 6).

    scripts/make_examples.py [SHARED_DATA_DIR] [OUT_DIR]

Crops a 1024x768 window around the ColorChecker of each of the five
Infinite-ISP frames (shared data ``raw/infinite_isp``, Apache-2.0) from the raw
and from the Infinite-ISP render alike, so the pairs stay pixel-aligned:

* the raw crop is written as an 8-bit deflate-compressed TIFF mosaic with a
  ``.tif.toml`` sidecar (same CFA, black and white levels as the full frame;
  the window starts on even rows and columns, so the GRBG phase is kept);
* the render crop is written as a PNG (lossless, the ISP's own 8-bit values);
* ``charts.json`` holds the ColorChecker corners of
  ``l3cli/data/charts/infinite_isp_charts.json`` shifted by the crop offset.

``frames/`` (Indoor1, Outdoor1, Outdoor2) is for training; ``holdout/``
(Outdoor3, Outdoor4) for evaluation only, as in the full set.
"""

from __future__ import annotations

import json
import sys
from importlib.resources import files
from pathlib import Path

import numpy as np

WIDTH, HEIGHT = 1024, 768
FULL_W, FULL_H = 2592, 1536


def crop_window(corners: np.ndarray) -> tuple[int, int]:
    """Top-left (x0, y0) of the crop centred on the chart, even, inside the frame."""
    cx, cy = corners.mean(axis=0)
    x0 = int(np.clip(round(cx - WIDTH / 2), 0, FULL_W - WIDTH)) & ~1
    y0 = int(np.clip(round(cy - HEIGHT / 2), 0, FULL_H - HEIGHT)) & ~1
    return x0, y0


def main(data: Path, out: Path) -> None:
    import tifffile
    from PIL import Image

    src = data / "raw" / "infinite_isp"
    charts = json.loads((files("l3cli") / "data/charts/infinite_isp_charts.json").read_text())
    frames_out = {}
    for stem, info in charts["frames"].items():
        folder = info["folder"]
        corners = np.array(info["corners"], dtype=float)
        x0, y0 = crop_window(corners)
        short = stem.split("_")[0] + "_crop"
        raw = np.fromfile(src / folder / f"{stem}.raw", np.uint8).reshape(FULL_H, FULL_W)
        render = np.array(Image.open(src / folder / f"{stem}.png"))
        if render.shape[:2] != raw.shape:
            raise SystemExit(f"{stem}: render {render.shape} differs from the raw {raw.shape}")
        side = (src / folder / f"{stem}.raw.toml").read_text()
        keep = [ln for ln in side.splitlines() if ln.split("=")[0].strip()
                in ("cfa", "black_level", "white_level")]
        dest = out / folder
        dest.mkdir(parents=True, exist_ok=True)
        win = np.s_[y0:y0 + HEIGHT, x0:x0 + WIDTH]
        tifffile.imwrite(dest / f"{short}.tif", np.ascontiguousarray(raw[win]),
                         compression="zlib", compressionargs={"level": 9})
        (dest / f"{short}.tif.toml").write_text(
            "\n".join(keep) + f"\nbit_depth = 8\ndescription = \"Infinite-ISP {stem}.raw, "
            f"{WIDTH}x{HEIGHT} crop at x={x0}, y={y0}\"\n")
        Image.fromarray(np.ascontiguousarray(render[win])).save(dest / f"{short}.png",
                                                                optimize=True)
        shifted = np.round(corners - [x0, y0], 1)
        frames_out[short] = {
            "folder": folder, "source": f"{stem}", "crop_xywh": [x0, y0, WIDTH, HEIGHT],
            "corners": shifted.tolist(),
            "chart_option": ",".join(f"{v:g}" for v in shifted.ravel()),
        }
        print(f"{short}: crop x={x0} y={y0}")
    meta = {k: charts[k] for k in ("format", "version", "chart", "corner_order")}
    meta["dataset"] = (f"{WIDTH}x{HEIGHT} crops of the Infinite-ISP reference frames "
                       "(Apache-2.0), made by scripts/make_examples.py")
    meta["method"] = "the corners of l3cli/data/charts/infinite_isp_charts.json minus the crop offset"
    meta["frames"] = frames_out
    (out / "charts.json").write_text(json.dumps(meta, indent=1) + "\n")
    for name in ("LICENSE-Apache-2.0.txt", "NOTICE.txt"):
        (out / name).write_bytes((src / name).read_bytes())


if __name__ == "__main__":
    here = Path(__file__).resolve().parent.parent
    args = sys.argv[1:]
    main(Path(args[0]) if args else here.parent / "shared" / "data",
         Path(args[1]) if len(args) > 1 else here / "examples" / "infinite_isp")
