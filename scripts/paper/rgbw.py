#!/usr/bin/env python3
"""Experiment 2: RGBW vs the same camera with W replaced by G, and both vs a
conventional pipeline, across light levels.

``rgbw.py BUILD`` reads the ``l3 evaluate`` reports ``BUILD/eval/{rgbw,rgbw-g,
rgbw-ircut,bayer,bayer-baseline}.json`` of the held-out Macbeth captures and writes
``BUILD/sections/rgbw.md``, ``BUILD/rgbw.json`` and docs/figures/rgbw_*.png.

Published (Jiang et al. 2017, RGBW section): mean Macbeth ΔE*ab 1.70 for the
RGBW camera and 1.65 for the same camera with W replaced by G.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from common import (
    build_arg,
    by_scene,
    captures,
    linear_colour_floor,
    md_table,
    plain_log,
    pyplot,
    report,
    save_figure,
    write_outputs,
)

PUBLISHED = {"rgbw": 1.70, "rgbw-g": 1.65}
RUNS = [("rgbw", "L3, RGBW"), ("rgbw-g", "L3, RGBW with W→G"), ("rgbw-ircut", "L3, RGBW + IR-cut"),
        ("bayer", "L3, Bayer RGGB"),
        ("bayer-baseline", "Menon demosaic + 3x3 matrix, Bayer RGGB")]


def main(build: Path) -> None:
    sims = {r: r for r, _ in RUNS} | {"bayer-baseline": "bayer"}
    de, sc = {}, {}
    for run, _ in RUNS:
        rep = report(build / "eval" / f"{run}.json")
        sim = build / "sim" / sims[run] / "test"
        de[run] = by_scene(rep, sim, "macbeth", "macbeth_de_mean")
        sc[run] = by_scene(rep, sim, "macbeth", "scielab_mean")
    luxes = sorted(de["rgbw"])
    n_train = len({c["lux"] for c in captures(build / "sim" / "rgbw" / "train").values()})
    mean = {r: float(np.mean([de[r][x] for x in luxes])) for r, _ in RUNS}
    mid = luxes[1:-1]
    mean_mid = {r: float(np.mean([de[r][x] for x in mid])) for r, _ in RUNS}

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.0))
    for run, label in RUNS:
        axes[0].plot(luxes, [de[run][x] for x in luxes], "o-", label=label)
        axes[1].plot(luxes, [sc[run][x] for x in luxes], "o-", label=label)
    for ax, t in zip(axes, ("Macbeth mean ΔE*ab", "S-CIELAB mean ΔE*ab (Macbeth capture)"), strict=True):
        plain_log(ax, x=True)
        ax.set_xlabel("scene illuminance (lux), exposure fixed")
        ax.set_title(t)
    axes[0].axhline(PUBLISHED["rgbw"], color="k", lw=0.8, ls="--", label="published RGBW (1.70)")
    axes[0].legend(fontsize=6)
    fig.tight_layout()
    fig_link = save_figure(fig, "rgbw_vs_light")

    rows = [[f"{x:g}"] + [de[r][x] for r, _ in RUNS] for x in luxes]
    rows.append(["mean, all levels"] + [mean[r] for r, _ in RUNS])
    rows.append([f"mean, {mid[0]:g}–{mid[-1]:g} lux"] + [mean_mid[r] for r, _ in RUNS])
    floor = {r: linear_colour_floor(build / "sim" / sims[r] / "test")[0] for r, _ in RUNS}
    rows.append(["linear colour floor (noise-free)"] + [floor[r] for r, _ in RUNS])
    rows.append(["published"] + [PUBLISHED.get(r) for r, _ in RUNS])
    table = md_table(["lux"] + [lab for _, lab in RUNS], rows)
    sc_rows = [[f"{x:g}"] + [sc[r][x] for r, _ in RUNS] for x in luxes]
    sc_table = md_table(["lux"] + [lab for _, lab in RUNS], sc_rows)
    best = min(luxes, key=lambda x: de["rgbw"][x])
    diff = mean["rgbw"] - mean["rgbw-g"]
    n_better = sum(de["rgbw"][x] < de["rgbw-g"][x] for x in luxes)

    def versus(a: str, b: str, metric: dict) -> str:
        better = [x for x in luxes if metric[a][x] < metric[b][x]]
        worse = [x for x in luxes if metric[a][x] >= metric[b][x]]
        txt = f"better at {', '.join(f'{x:g}' for x in better) or 'no'} lux"
        if worse:
            txt += f", worse at {', '.join(f'{x:g}' for x in worse)} lux"
        return txt

    md = f"""## 2. RGBW vs Bayer, and both vs a conventional pipeline

Cameras (`scripts/paper/cameras.py`): the L3 RGBW camera
(`sample_configs/rgbw.toml`: 1.4 µm pixels, f/4, ISETCam's interleaved RGBW
filters, no IR-cut filter), the same camera with every W pixel replaced by G
(the paper's comparison; 12 of its 16 pixels are then G), and the same pixel
and filters in an RGGB Bayer mosaic, which `l3 baseline` (a Bayer-only
conventional pipeline: Menon 2007 demosaicking + a 3x3 matrix fitted by
least squares on the same training data) can also render. Each L3 table is
trained on the Macbeth chart and the four bundled natural photos at
{n_train} light levels, smoothed (`l3 smooth`), and tested on Macbeth captures at
light levels *not* used in training, with a fixed exposure so the light level
sets the response level (W saturates on the bright patches at the highest
level). Mean Macbeth ΔE*ab over the 24 patches (white-normalised, as
ISETCam's `macbethColorError`):

{table}

S-CIELAB mean ΔE*ab of the same Macbeth captures (96 dpi, 1 m):

{sc_table}

![Macbeth ΔE vs light level]({fig_link})

- **RGBW vs W→G.** Published: RGBW 1.70 vs W→G 1.65, a small loss for RGBW.
  Ours: {mean['rgbw']:.2f} vs {mean['rgbw-g']:.2f} averaged over the test
  levels (RGBW {'worse' if diff > 0 else 'better'} by {abs(diff):.2f}; better at
  {n_better} of {len(luxes)} levels). Our W→G camera keeps the RGBW layout, so
  R and B are only 2 of 16 pixels each; its colour suffers much more than the
  paper's comparison camera did. Absolute values: our best RGBW level
  ({best:g} lux) gives {de['rgbw'][best]:.2f}, {'above' if de['rgbw'][best] > PUBLISHED['rgbw'] else 'below'} the published
  1.70{' — l3 falls short of the published accuracy' if de['rgbw'][best] > PUBLISHED['rgbw'] else ''}. The published
  values come from ISETCam simulations of many more scenes; ours from five
  scenes at 320x240 pixels, so many classes are trained from few samples or
  filled by the spline prior. More important, the row "linear colour
  floor" is the mean ΔE of the *best* linear map from the camera's channels
  to XYZ on noise-free, perfectly demosaicked patch means (least squares over
  the 24 patches, `common.linear_colour_floor`): {floor['rgbw']:.2f} for RGBW
  and {floor['bayer']:.2f} for the Bayer camera. Our simulated sensors (ISETCam's
  filter curves under the daylight simulator) are that far from the Luther
  condition, so a pipeline that is linear at a given level — as L3 is within
  each class — is unlikely to reach 1.70 on them (the least-squares fit is
  not the ΔE-optimal linear map, but the gap is large). Either the published
  simulation's sensors, illuminant or scene set gave better-conditioned
  colour, or its ΔE was computed on a different basis; we could not pin
  this down.
- **IR.** Our RGBW camera (`sample_configs/rgbw.toml`) has no IR-cut filter,
  so W integrates 700–1060 nm light that the XYZ target does not see; the
  same camera behind an IR-cut filter gives {mean['rgbw-ircut']:.2f}
  (mean over levels; {versus('rgbw-ircut', 'rgbw', de)} than without). See
  experiment 7 for what this does to the kernels.
- **L3 vs the conventional pipeline (Bayer camera).** Macbeth ΔE: L3 is
  {versus('bayer', 'bayer-baseline', de)}; S-CIELAB: L3 is
  {versus('bayer', 'bayer-baseline', sc)}. RGBW L3 vs the Bayer baseline:
  Macbeth ΔE {versus('rgbw', 'bayer-baseline', de)}. L3 wins at mid and high
  levels (and with saturation, where the baseline's matrix has no answer);
  in the dark its Macbeth ΔE is worse than the baseline's although its
  S-CIELAB is similar: the errors concentrate on the saturated patches (red,
  yellow, magenta) while the greys stay low, the signature of colours pulled
  toward grey by the ridge regularisation that the noisy dark classes need.
  The paper reports L3 ahead of the conventional pipeline; on our data it
  is not, in the dark.
"""
    write_outputs(build, "rgbw", md, {"macbeth_de": {r: {str(k): v for k, v in de[r].items()} for r, _ in RUNS},
                                      "scielab": {r: {str(k): v for k, v in sc[r].items()} for r, _ in RUNS},
                                      "mean": mean, "linear_colour_floor": floor, "mean_mid_levels": mean_mid, "mid_levels": mid,
                                      "published": PUBLISHED})


if __name__ == "__main__":
    main(build_arg(__doc__))
