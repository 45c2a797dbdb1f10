#!/usr/bin/env python3
"""Experiment 1: approximating a real camera pipeline (the real-camera issue).

The work is done by ``scripts/real_camera.sh`` (owned by the real-camera
helper): train on the Infinite-ISP ``frames/`` pairs, render and score the two
``holdout/`` frames (never used for training or tuning), and learn LibRaw's
AHD rendering of a Blackmagic Pocket 4K DNG on its left half, scored on the
right half. Its ``l3 evaluate`` reports land in ``BUILD/real/eval_*.json``.

``real.py BUILD --collect`` gathers them into ``BUILD/real/summary.json``;
``real.py BUILD`` writes ``BUILD/sections/real.md`` and ``BUILD/real.json``.

Published (Jiang et al. 2017): Nikon D200 pipeline approximated at mean
S-CIELAB ΔE*ab 1.74 and PSNR 40.4 dB on held-out images; DxO rendering 1.46.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
from common import ROOT, md_table, write_outputs

PUBLISHED = {"nikon_scielab": 1.74, "nikon_psnr": 40.4, "dxo_scielab": 1.46}


def train_opts() -> str:
    """The default ``l3 train`` options of scripts/real_camera.sh."""
    text = (ROOT / "scripts" / "real_camera.sh").read_text()
    m = re.search(r"TRAIN_OPTS=\$\{L3_TRAIN_OPTS:-(.*)\}", text)
    if not m:
        return "`l3 train` (options: see the script)"
    opts = m.group(1).strip()
    return f"`l3 train {opts}`" if opts else "`l3 train` with no options (its defaults)"


def collect(build: Path) -> None:
    from l3cli.io.atomic import atomic_path

    images = []
    for p in sorted((build / "real").glob("eval_*.json")):
        for im in json.loads(p.read_text())["images"]:
            images.append({"report": p.name, **{k: v for k, v in im.items() if not isinstance(v, (dict, list))}})
    if not images:
        raise SystemExit(f"no eval_*.json in {build / 'real'}: did scripts/real_camera.sh run?")
    with atomic_path(build / "real" / "summary.json") as tmp:
        tmp.write_text(json.dumps({"images": images}, indent=1) + "\n")


def main(build: Path) -> None:
    images = json.loads((build / "real" / "summary.json").read_text())["images"]
    iisp = [im for im in images if "bmpcc" not in im["report"]]
    bm = [im for im in images if "bmpcc" in im["report"] and "bmpcc_wb" not in im["report"]]
    wb = [im for im in images if "bmpcc_wb" in im["report"]]
    rows = [[im["name"], im["scielab_mean"], im["psnr_db"], im.get("macbeth_de_mean")] for im in iisp]
    i_sc = float(np.mean([im["scielab_mean"] for im in iisp])) if iisp else None
    i_ps = float(np.mean([im["psnr_db"] for im in iisp])) if iisp else None
    rows.append(["**Infinite-ISP holdout, mean**", i_sc, i_ps,
                 float(np.mean([im["macbeth_de_mean"] for im in iisp if im.get("macbeth_de_mean") is not None]))
                 if any(im.get("macbeth_de_mean") is not None for im in iisp) else None])
    rows += [[f"{im['name']} (Blackmagic vs LibRaw AHD, right half)", im["scielab_mean"], im["psnr_db"],
              im.get("macbeth_de_mean")] for im in bm]
    rows += [[f"{im['name']} (Blackmagic DNG crops, white balance per shot, LibRaw AHD)",
              im["scielab_mean"], im["psnr_db"], im.get("macbeth_de_mean")] for im in wb]
    b_sc = float(np.mean([im["scielab_mean"] for im in bm])) if bm else None
    w_sc = float(np.mean([im["scielab_mean"] for im in wb])) if wb else None
    table = md_table(["held-out image", "S-CIELAB mean ΔE*ab", "PSNR dB", "ColorChecker ΔE*ab"], rows)
    fmt = lambda v: "–" if v is None else f"{v:.2f}"  # noqa: E731
    md = f"""## 1. Approximating a real pipeline

Run by `scripts/real_camera.sh` (tutorial: docs/real-camera.md): an L3 table
({train_opts()}) trained on the three Infinite-ISP `frames/` pairs
(raw + the ISP's PNG) and scored on the two `holdout/` frames, which are
never used for training or tuning; and LibRaw's AHD rendering of a
Blackmagic Pocket 4K DNG learned on the left half, scored on the right half.
S-CIELAB at 96 dpi and 1 m, 4-pixel border excluded. Since the learned
tone curve (docs/training.md, sections 4 and 7) the Infinite-ISP table trains
in the ISP's own linear space (held out 1.09 before it, with the same
scripts); the Blackmagic cases keep the plain linear target, because the curve
does not beat the sRGB decoding there (`l3 train` checks this on held-out
blocks), and their small changes (0.21 / 0.23 → 0.22 / 0.25 for the
per-shot crops) come from the re-derived layout (24 levels, contrast bins at
0.2).

| pipeline approximated | published | ours |
|---|---|---|
| camera ISP, mean S-CIELAB ΔE*ab (held out) | 1.74 (Nikon D200) | {fmt(i_sc)} (Infinite-ISP) |
| camera ISP, PSNR dB | 40.4 (Nikon D200) | {fmt(i_ps)} (Infinite-ISP) |
| raw converter, mean S-CIELAB ΔE*ab | 1.46 (DxO) | {fmt(b_sc)} (LibRaw AHD, Blackmagic DNG) |
| raw converter, white balance per shot (issue 15) | – | {fmt(w_sc)} (LibRaw AHD, 2 held-out Blackmagic DNG crops) |

{table}

The data differ from the paper's: we have no Nikon D200 or DxO renders to
redistribute, so the camera pipeline is Infinite-ISP (an open ISP with one
fixed setting, 8-bit GRBG sensor, five scenes) and the raw converter is
LibRaw/AHD on one Blackmagic frame; the paper used many more Nikon D200
images. The comparison is of the same claim (a learned table reproduces a
fixed pipeline to within about 1.5–2 S-CIELAB ΔE), not of the same images.
{'' if i_sc is None or i_sc <= PUBLISHED['nikon_scielab'] else 'On the camera ISP, l3 falls short of the published 1.74 S-CIELAB ΔE.'}
{'' if i_ps is None or i_ps >= PUBLISHED['nikon_psnr'] else f'PSNR falls short of the published 40.4 dB ({i_ps:.1f} dB): the Infinite-ISP raws are 8-bit (coarse quantisation and more noise than a D200 NEF) and the ISP applies spatially varying steps (denoising, sharpening, tone mapping) that a per-class affine kernel reproduces only on average; PSNR, unlike S-CIELAB, counts every such pixel-level difference.'}
The ColorChecker ΔE*ab has no published counterpart; it is larger than the
S-CIELAB mean because it weighs the 24 chart colours (many of them
saturated) equally, while the frame-wide S-CIELAB mean is dominated by
large, low-chroma areas.
{'' if b_sc is None or b_sc <= PUBLISHED['dxo_scielab'] else 'On the raw converter, l3 falls short of the published 1.46.'}
"""
    write_outputs(build, "real", md, {"published": PUBLISHED, "infinite_isp_scielab": i_sc,
                                      "infinite_isp_psnr": i_ps, "blackmagic_scielab": b_sc,
                                      "blackmagic_wb_scielab": w_sc, "images": images})


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[2] == "--collect":
        collect(Path(sys.argv[1]))
    elif len(sys.argv) == 2 and not sys.argv[1].startswith("-"):
        main(Path(sys.argv[1]))
    else:
        raise SystemExit(__doc__)
