#!/usr/bin/env python3
"""Experiment 6: resolution of the L3 RGBW pipeline (MTF50).

``mtf.py BUILD``

1. reads the slanted-edge results of experiment 2 (``BUILD/eval/rgbw.json``:
   RGBW camera, f/4, 1.4 µm, auto exposure, several light levels): MTF50 of
   the L3 render and of the ideal target vs response level, next to the
   diffraction bound;
2. runs a grid over f-number × pixel pitch (:data:`F_NUMBERS` ×
   :data:`PITCHES_UM`): for each, a camera ``mtf-fF-pP`` (scripts/paper/
   cameras.py), training captures (Macbeth + natural photos) and one
   slanted-edge test capture, all auto-exposed (brightest pixel at 95 % of
   saturation) so that every grid point has the same signal level; train,
   smooth, render the edge, measure MTF50 (``l3 evaluate``);
3. writes ``BUILD/sections/mtf.md``, ``BUILD/mtf.json`` and docs/figures/mtf_*.png.

Published (Jiang et al. 2017): MTF50 of the L3 RGBW render at f/4, 1.4 µm is
154.8 cy/mm against a diffraction bound of 186.7 cy/mm; an MTF50 surface over
f-number 2–14 and pixel size 1.2–6 µm; MTF50 vs response level.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from common import (
    ROOT,
    build_arg,
    captures,
    md_table,
    plain_log,
    pyplot,
    report,
    run_l3,
    save_figure,
    train_render_eval,
    write_outputs,
)

PUBLISHED = {"l3": 154.8, "diffraction": 186.7}
F_NUMBERS = (2.0, 4.0, 8.0, 14.0)
PITCHES_UM = (1.2, 2.4, 6.0)
GRID_SIZE = "256x192"
GRID_LUX = 1000.0
#: grid points run side by side (each is a chain of l3 processes); $PAPER_JOBS
JOBS = int(os.environ.get("PAPER_JOBS", "2"))


def diffraction_mtf50(f_number: float, *, pitch_um: float | None = None) -> float:
    """MTF50 (cy/mm) of a diffraction-limited lens, polychromatic.

    The Airy (circular pupil) OTF per wavelength, averaged with weights
    ȳ(λ)·D65(λ) over 400–700 nm (luminance of a white edge under daylight);
    times the pixel aperture ``sinc(ν p)`` when ``pitch_um`` is given.

    References
    ----------
    Goodman, J. W. (2005). Introduction to Fourier Optics, 3rd ed., eq. 6-32.
    """
    import colour
    from scipy.optimize import brentq

    shape = colour.SpectralShape(400, 700, 5)
    wl = np.arange(400, 701, 5, dtype=float)
    cmf = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    w = cmf.values[:, 1] * d65.values
    w = w / w.sum()

    def mtf(nu: float) -> float:
        x = np.clip(nu * wl * 1e-6 * f_number, 0.0, 1.0)
        m = float((w * 2 / np.pi * (np.arccos(x) - x * np.sqrt(1 - x * x))).sum())
        if pitch_um is not None:
            m *= float(np.sinc(nu * pitch_um * 1e-3))
        return m - 0.5

    return float(brentq(mtf, 1e-3, 1e6 / (400 * f_number)))


def edge_levels(sim: Path) -> dict[float, float]:
    """``{lux: mean noise-free response}`` of the slanted-edge captures."""
    from l3cli.io.image import read_image

    out = {}
    for _stem, cap in captures(sim).items():
        if cap["scene"] == "slanted-edge":
            img, _ = read_image(sim / cap["noise_free"])
            out[float(cap["lux"])] = float(np.mean(img))
    return dict(sorted(out.items()))


def grid_point(build: Path, f: float, p: float) -> dict:
    name = f"mtf-f{f:g}-p{p:g}"
    cam = build / "cameras" / f"{name}.toml"
    subprocess.run([sys.executable, str(ROOT / "scripts" / "paper" / "cameras.py"), name, str(cam)],
                   check=True)
    tr, te = build / "sim" / name / "train", build / "sim" / name / "test"
    for d, scenes, seed in ((tr, ("macbeth", "natural"), 1), (te, ("slanted-edge",), 2)):
        if not (d / "manifest.json").exists():
            d.parent.mkdir(parents=True, exist_ok=True)
            run_l3("simulate", cam.resolve(), "-o", d, *[a for s in scenes for a in ("--scene", s)],
                   "--lux", GRID_LUX, "--size", GRID_SIZE, "--seed", seed)
    res = train_render_eval(build, name, name, train_sim=tr, test_sim=te)
    ims = [v for v in res["report"].values() if v.get("mtf50_cy_per_mm") is not None]
    if not ims:  # l3 evaluate found no edge in the render (reported in docs/results.md)
        print(f"warning: no MTF50 for {name}", file=sys.stderr)
    return {"f_number": f, "pitch_um": p, "l3": ims[0]["mtf50_cy_per_mm"] if ims else None,
            "target": ims[0]["mtf50_reference_cy_per_px"] * 1000.0 / p if ims else None,
            "diffraction": diffraction_mtf50(f), "nyquist": 1000.0 / (2 * p)}


def main(build: Path) -> None:
    # 1. f/4, 1.4 um, from experiment 2
    sim = build / "sim" / "rgbw" / "test"
    pitch = json.loads((sim / "manifest.json").read_text())["camera"]["pixel_pitch_um"]
    rep = report(build / "eval" / "rgbw.json")
    caps = captures(sim)
    l3_lux, tgt_lux = {}, {}
    for stem, cap in caps.items():
        if cap["scene"] == "slanted-edge":
            l3_lux[float(cap["lux"])] = rep[stem]["mtf50_cy_per_mm"]
            tgt_lux[float(cap["lux"])] = rep[stem]["mtf50_reference_cy_per_px"] * 1000.0 / pitch
    luxes = sorted(l3_lux)
    levels = edge_levels(sim)
    diff4 = diffraction_mtf50(4.0)
    diff4_px = diffraction_mtf50(4.0, pitch_um=pitch)
    target = float(np.median(list(tgt_lux.values())))

    # 2. grid
    with ThreadPoolExecutor(max_workers=JOBS) as pool:
        grid = list(pool.map(lambda fp: grid_point(build, *fp),
                             [(f, p) for p in PITCHES_UM for f in F_NUMBERS]))

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.0))
    lv = [levels[x] for x in luxes]
    axes[0].plot(lv, [l3_lux[x] for x in luxes], "o-", label="L3 render")
    axes[0].plot(lv, [tgt_lux[x] for x in luxes], "s--", label="ideal target (optics + pixel)")
    axes[0].axhline(diff4, color="k", lw=0.8, ls=":", label=f"diffraction bound ({diff4:.0f})")
    axes[0].axhline(PUBLISHED["l3"], color="C3", lw=0.8, ls="--", label="published L3 (154.8)")
    plain_log(axes[0], x=True, y=False)
    axes[0].set_xlabel("mean noise-free response of the edge capture")
    axes[0].set_ylabel("MTF50 (cy/mm)")
    axes[0].set_title("RGBW f/4, 1.4 µm: MTF50 vs response level")
    axes[0].legend(fontsize=6)
    for p in PITCHES_UM:
        pts = [g for g in grid if g["pitch_um"] == p and g["l3"] is not None]
        (ln,) = axes[1].plot([g["f_number"] for g in pts], [g["l3"] for g in pts], "o-", label=f"L3, {p:g} µm")
        axes[1].plot([g["f_number"] for g in pts], [g["target"] for g in pts], "--", color=ln.get_color(), lw=0.8)
    axes[1].plot(F_NUMBERS, [diffraction_mtf50(f) for f in F_NUMBERS], "k:", label="diffraction")
    plain_log(axes[1], x=True)
    axes[1].set_xticks(F_NUMBERS, [f"{f:g}" for f in F_NUMBERS])
    axes[1].set_xlabel("f-number")
    axes[1].set_title("MTF50 (cy/mm); dashed: ideal target")
    axes[1].legend(fontsize=6)
    fig.tight_layout()
    fig_link = save_figure(fig, "mtf")

    rows1 = [[f"{x:g}", levels[x], l3_lux[x], tgt_lux[x]] for x in luxes]
    if l3_lux[luxes[0]] < 0.95 * max(l3_lux.values()):
        blur_txt = (f"MTF50 goes from {l3_lux[luxes[0]]:.0f} cy/mm at the lowest level to "
                    f"{max(l3_lux.values()):.0f} at the best: at low levels the kernels average over the "
                    "patch to suppress noise (a blur), at high levels they concentrate at the centre.")
    elif levels[luxes[0]] >= 0.9 * levels[luxes[-1]]:
        blur_txt = (f"MTF50 changes little with the light level ({min(l3_lux.values()):.0f}–"
                    f"{max(l3_lux.values()):.0f} cy/mm): auto exposure, and below its time cap auto gain, "
                    f"give the edge capture the same response at every test level (mean "
                    f"{levels[luxes[-1]]:.2f}); the gained {luxes[0]:g}-lux capture is noisier, yet its "
                    "kernels do not blur the edge measurably. The paper's published loss of resolution "
                    "in the dark needs darker captures than these.")
    else:
        blur_txt = (f"MTF50 changes little with the light level ({min(l3_lux.values()):.0f}–"
                    f"{max(l3_lux.values()):.0f} cy/mm): under auto exposure the edge capture has nearly "
                    f"the same response at every level where the exposure is not capped (mean "
                    f"{levels[luxes[-1]]:.2f}), and even at the lowest level (mean {levels[luxes[0]]:.2f}) "
                    "the kernels that suppress noise do not blur the edge measurably. The paper's "
                    "published loss of resolution in the dark needs darker captures than these.")
    t1 = md_table(["lux", "mean response", "L3 MTF50 cy/mm", "ideal target MTF50 cy/mm"], rows1)
    header = ["pixel µm \\ f-number"] + [f"f/{f:g}" for f in F_NUMBERS]
    rows2 = []
    for p in PITCHES_UM:
        pts = {g["f_number"]: g for g in grid if g["pitch_um"] == p}
        rows2.append([f"{p:g} (Nyquist {1000 / (2 * p):.0f})"]
                     + [f"{pts[f]['l3']:.0f} / {pts[f]['target']:.0f}" if pts[f]["l3"] else "no edge found"
                        for f in F_NUMBERS])
    rows2.append(["diffraction bound"] + [f"{diffraction_mtf50(f):.0f}" for f in F_NUMBERS])
    t2 = md_table(header, rows2)
    ok = [g for g in grid if g["l3"] is not None]
    worst = min(ok, key=lambda g: g["l3"] / g["target"]) if ok else {"l3": 0, "target": 0, "f_number": 0,
                                                                      "pitch_um": 0}
    bright = [x for x in luxes if levels[x] < 0.5] or luxes
    best = max(bright, key=lambda x: l3_lux[x])
    over_txt = (", and can even exceed the ideal target's MTF50: a render MTF50 above the target's means "
                "overshoot (the learned kernels sharpen, and part of the RGBW mosaic's aliasing lands in the "
                "edge-spread function), not more real detail."
                if any(l3_lux[x] > tgt_lux[x] for x in luxes) or any(
                    g["l3"] is not None and g["l3"] > g["target"] for g in grid)
                else f" (and below the ideal target's {target:.1f}).")
    md = f"""## 6. Resolution (MTF50)

MTF50 by ISO 12233 slanted edge (`l3 evaluate`, Burns' method on the
luminance of the linear render) of the RGBW camera's L3 renders. The
diffraction bound is the MTF50 of a diffraction-limited f/4 lens alone
(Airy OTF averaged over 400–700 nm with weights ȳ·D65, computed in
`scripts/paper/mtf.py`): **{diff4:.1f} cy/mm** (183.6 at 550 nm alone);
adding the 1.4 µm pixel aperture (sinc) gives {diff4_px:.1f} cy/mm, and the
simulator's ideal target — the best any pipeline can do against it — measures
{target:.1f} cy/mm.

| quantity | published | ours |
|---|---|---|
| L3 RGBW MTF50, f/4, 1.4 µm | 154.8 | {l3_lux[best]:.1f} (at {best:g} lux; {min(l3_lux.values()):.1f}–{max(l3_lux.values()):.1f} over the test levels) |
| diffraction bound | 186.7 | {diff4:.1f} |

Our bound is {abs(diff4 - PUBLISHED['diffraction']):.1f} cy/mm {'below' if diff4 < PUBLISHED['diffraction'] else 'above'} the
published one: 186.7 cy/mm is the Airy MTF50 of f/4 at a single wavelength
of about 541 nm, ours averages the Airy OTF over the visible spectrum. Our L3
MTF50 at the brighter levels is {'above' if l3_lux[best] > PUBLISHED['l3'] else 'below'} the published 154.8{over_txt}

**MTF50 vs response level** (the test edges of experiment 2; levels are
the mean noise-free raw response of the edge capture):

{t1}

{blur_txt}

**MTF50 over f-number × pixel pitch** (L3 render / ideal target, cy/mm;
auto exposure at {GRID_LUX:g} lux, {GRID_SIZE} captures, electrical
parameters of the 1.4 µm pixel at every pitch):

{t2}

![MTF50]({fig_link})

Small pixels are diffraction-limited at large f-numbers (MTF50 follows the
bound); large pixels are limited by the pixel aperture and sampling
(MTF50 stays below the Nyquist frequency whatever the f-number). Where the
lens passes detail well beyond the sampling (small f-numbers, large pixels)
the L3 render falls far below the ideal target ({worst['l3']:.0f} vs
{worst['target']:.0f} cy/mm at f/{worst['f_number']:g}, {worst['pitch_um']:g} µm): the sparse
R, G, B sites of the RGBW mosaic (one of each per 2x2) alias, and a per-class linear kernel
cannot undo aliasing. The paper shows this surface on a finer grid; ours
has {len(F_NUMBERS)} x {len(PITCHES_UM)} points to fit `make paper`'s time budget.
"""
    write_outputs(build, "mtf", md, {
        "published": PUBLISHED, "diffraction_f4": diff4, "diffraction_f4_with_pixel": diff4_px,
        "target_f4_p1.4": target, "l3_per_lux": {str(k): v for k, v in l3_lux.items()},
        "target_per_lux": {str(k): v for k, v in tgt_lux.items()},
        "edge_level_per_lux": {str(k): v for k, v in levels.items()}, "grid": grid})


if __name__ == "__main__":
    main(build_arg(__doc__))
