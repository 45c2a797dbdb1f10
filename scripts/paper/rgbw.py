#!/usr/bin/env python3
"""Experiment 2: the 2x2 RGBW camera vs the same camera with W replaced by G
(an RGGB Bayer), and both vs a conventional pipeline, across light levels,
each camera with its own auto exposure.

``rgbw.py BUILD`` reads the ``l3 evaluate`` reports ``BUILD/eval/{rgbw,bayer,
rgbw-lab,bayer-lab,rgbw-ircut,bayer-baseline}.json`` of the held-out Macbeth
captures and writes ``BUILD/sections/rgbw.md``, ``BUILD/rgbw.json`` and
docs/figures/rgbw_*.png.

Published (Jiang et al. 2017, RGBW section): mean Macbeth ΔE*ab 1.70 for the
RGBW camera (one R, G, B and W per 2x2 repeat) and 1.65 for the same camera
with W replaced by G (a Bayer).
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

PUBLISHED = {"rgbw": 1.70, "bayer": 1.65}
MAIN = [("rgbw", "L3, RGBW"), ("bayer", "L3, Bayer (RGBW with W→G)"),
        ("rgbw-ircut", "L3, RGBW + IR-cut"),
        ("bayer-baseline", "Menon demosaic + 3x3 matrix, Bayer")]
# training variants: CIELAB target; the chart left out of training
VARIANTS = [("rgbw-lab", "RGBW, Lab target"), ("bayer-lab", "Bayer, Lab target"),
            ("rgbw-nochart", "RGBW, chart not in training"), ("bayer-nochart", "Bayer, chart not in training"),
            ("rgbw-esser", "RGBW, + Esser chart"), ("bayer-esser", "Bayer, + Esser chart"),
            ("rgbw-wide", "RGBW, patch 5, 12 levels, 1 contrast bin"), ("bayer-wide", "Bayer, patch 5, 12 levels, 1 contrast bin")]
RUNS = MAIN + VARIANTS
SIMS = {"rgbw-lab": "rgbw", "bayer-lab": "bayer", "rgbw-nochart": "rgbw", "bayer-nochart": "bayer",
        "rgbw-esser": "rgbw", "bayer-esser": "bayer", "rgbw-wide": "rgbw", "bayer-wide": "bayer",
        "bayer-baseline": "bayer"}
CAMERAS = [("rgbw", "RGBW"), ("bayer", "Bayer"), ("rgbw-ircut", "RGBW + IR-cut")]
PATCHES = ("dark skin", "light skin", "blue sky", "foliage", "blue flower", "bluish green",
           "orange", "purplish blue", "moderate red", "purple", "yellow green", "orange yellow",
           "blue", "green", "red", "yellow", "magenta", "cyan", "white", "neutral 8",
           "neutral 6.5", "neutral 5", "neutral 3.5", "black")
# the class layout of this experiment's main tables (validation's pick, below)
TRAIN_LAYOUT = "patch 7, 24 response levels, 2 contrast bins"
# Camera and recipe choices, measured once on a validation split of the
# TRAINING light levels (never on the test levels): trained on 10, 120, 1600
# and 5000 lux, validated on Macbeth captures at 35 and 450 lux (seed 7,
# 320x240), mean Macbeth ΔE*ab of the two (35 lux, 450 lux in brackets);
# criterion: the worse of the two cameras. Rows 1-3 compare exposure models
# (patch 5, 24 levels, 2 contrast bins), the others recipes on the camera of
# row 3. Reproduced by scripts/paper/rgbw_validation.sh.
VALIDATION = [  # (camera / recipe, RGBW, Bayer, (RGBW@35, RGBW@450, Bayer@35, Bayer@450))
    ("time cap 0.5 s, no gain (the previous camera)", 3.84, 3.57, (5.22, 2.45, 4.48, 2.66)),
    ("+ auto gain up to 16x", 3.20, 2.97, (3.41, 3.00, 3.22, 2.72)),
    ("+ auto gain, + black clamp (this camera), patch 5", 2.70, 3.01, (2.63, 2.78, 3.21, 2.80)),
    ("patch 7 (validation's pick)", 2.37, 2.74, (2.37, 2.37, 2.76, 2.73)),
    ("patch 9", 2.54, 2.75, (2.57, 2.50, 2.78, 2.73)),
    ("patch 7, 36 levels", 3.37, 2.75, (3.32, 3.41, 2.78, 2.71)),
    ("patch 5, 12 levels, 1 contrast bin", 4.12, 3.30, (4.04, 4.20, 3.25, 3.35)),
    ("patch 5, + Esser chart", 2.44, 3.37, (2.44, 2.43, 3.42, 3.32)),
    ("patch 7, + Esser chart", 2.36, 3.38, (2.40, 2.33, 3.45, 3.31)),
]
# Diagnosis of the previous camera's dark levels (time cap 0.5 s, no gain,
# patch-5 tables of the previous build; noise-free captures: `l3 simulate
# --no-noise`, same seed, rendered through the same tables). Mean Macbeth
# ΔE*ab: (camera, lux, noisy, noise-free).
DIAG_NOISE = [("RGBW", 20, 6.49, 6.90), ("RGBW", 70, 2.53, 2.89),
              ("Bayer", 20, 4.66, 5.94), ("Bayer", 70, 3.69, 3.92)]
# The same after auto gain (up to 16x) without the black clamp, and with the
# dark current set to 0 (test levels; patch 5): (camera, mean, at 20 lux,
# noise-free at 20 lux, mean with no dark current, 20 lux with none).
DIAG_DARK = [("RGBW", 2.78, 4.10, 3.49, 2.51, 2.97), ("Bayer", 3.13, 4.56, 4.61, 2.76, 3.45)]
# ISETCam's auto exposure as it is (no time cap, no gain, no black clamp), patch 7,
# test levels: RGBW mean, Bayer mean, RGBW at 20 lux, Bayer at 20 lux
NOCAP = (2.60, 3.75, 3.37, 4.62)
# Validation split, tables NOT smoothed (`l3 train` output rendered as is):
# (recipe, RGBW, Bayer) with the chart in training, then with the chart left
# out of training (the photos only; same validation captures) smoothed / not.
UNSMOOTHED = [("patch 7, log levels", 1.93, 2.72), ("patch 7, linear levels", 1.65, 2.24),
              ("patch 5, linear levels", 2.14, 2.12)]
UNSMOOTHED_NOCHART = {"patch 7, log": ((7.02, 7.19), (3.83, 3.83)),
                      "patch 7, linear": ((6.75, 6.76), (3.97, 4.20))}  # (smoothed, not) RGBW, Bayer
# Noise-free Macbeth captures at 20 lux (seed 2, `l3 simulate --no-noise`)
# through this build's main tables: mean Macbeth ΔE*ab
DIAG_NOW = {"RGBW": 2.24, "Bayer": 2.73}
# `l3 baseline` (Bayer) with its matrix fitted on the training captures at
# 120 lux and above only (the manifest cut to those), mean over the test levels
BASELINE_BRIGHT_ONLY = 5.76
# the bar: RGBW within 15 % of the Bayer, both at most 3.0 (goal 2.0)
BAR_RATIO, BAR_DE, GOAL_DE = 0.15, 3.0, 2.0
MAX_GAIN_TOL = 0.999  # a capture at (almost) the camera's largest gain is under-exposed


def _exposures(sim: Path) -> dict[float, tuple[float, float]]:
    """``{lux: (exposure time in s, analog gain)}`` of the Macbeth captures of a simulation folder."""
    return {float(c["lux"]): (float(c["exposure_s"]), float(c.get("analog_gain", 1.0)))
            for c in captures(sim).values() if c["scene"] == "macbeth"}


def main(build: Path) -> None:
    from common import patch_electrons

    sims = {r: build / "sim" / SIMS.get(r, r) / "test" for r, _ in RUNS}
    de, sc, patches = {}, {}, {}
    for run, _ in RUNS:
        rep = report(build / "eval" / f"{run}.json")
        de[run] = by_scene(rep, sims[run], "macbeth", "macbeth_de_mean")
        sc[run] = by_scene(rep, sims[run], "macbeth", "scielab_mean")
        caps = captures(sims[run])
        patches[run] = {float(c["lux"]): rep[s]["macbeth_patches"]["de_ab"] for s, c in caps.items()
                        if c["scene"] == "macbeth" and s in rep and rep[s].get("macbeth_patches")}
    luxes = sorted(de["rgbw"])
    train_lux = sorted({c["lux"] for c in captures(build / "sim" / "rgbw" / "train").values()})
    mean = {r: float(np.mean([de[r][x] for x in luxes])) for r, _ in RUNS}
    lit = luxes[1:]
    mean_lit = {r: float(np.mean([de[r][x] for x in lit])) for r, _ in RUNS}
    expo = {c: _exposures(build / "sim" / c / "test") for c, _ in CAMERAS}
    cam_ex = json_camera(build / "sim" / "rgbw" / "test")["exposure"]
    max_t, max_g = float(cam_ex["max_time_s"]), float(cam_ex.get("max_analog_gain", 1.0))
    clamp = bool(json_camera(build / "sim" / "rgbw" / "test")["readout"].get("black_clamp", False))
    gained = {c: [x for x in luxes if expo[c][x][1] > 1.0] for c, _ in CAMERAS}
    under = {c: [x for x in luxes if expo[c][x][0] >= max_t * 0.999 and expo[c][x][1] >= max_g * MAX_GAIN_TOL]
             for c, _ in CAMERAS}
    floor = {r: linear_colour_floor(sims[r])[0] for r, _ in MAIN}
    floor3 = {r: linear_colour_floor(sims[r], pieces=3)[0] for r, _ in MAIN}
    ratio = mean["rgbw"] / mean["bayer"]
    bar = {"ratio": ratio, "not_worse_by_15_percent": ratio <= 1 + BAR_RATIO,
           "within_15_percent": abs(ratio - 1) <= BAR_RATIO,
           "both_at_most_3": max(mean["rgbw"], mean["bayer"]) <= BAR_DE,
           "both_at_most_2": max(mean["rgbw"], mean["bayer"]) <= GOAL_DE}
    # photo-electrons on the white patch at the lowest and highest test levels
    stems = {c: {float(v["lux"]): k for k, v in captures(build / "sim" / c / "test").items()
                 if v["scene"] == "macbeth"} for c in ("rgbw", "bayer")}
    chans = {"rgbw": ("R", "G", "W", "B"), "bayer": ("R", "G", "G", "B")}
    white_e = {}
    for c in ("rgbw", "bayer"):
        from l3cli.cfa import CFA
        cfa = CFA.from_spec(json_camera(build / "sim" / c / "test")["cfa_pattern"])
        for x in (luxes[0], luxes[-1]):
            e = patch_electrons(build / "sim" / c / "test", stems[c][x])[18]
            white_e[(c, x)] = {ch: float(e[cfa.channels.index(ch)]) for ch in dict.fromkeys(chans[c])}

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.0))
    for run, label in MAIN:
        axes[0].plot(luxes, [de[run][x] for x in luxes], "o-", label=label)
        axes[1].plot(luxes, [sc[run][x] for x in luxes], "o-", label=label)
    for ax, t in zip(axes, ("Macbeth mean ΔE*ab", "S-CIELAB mean ΔE*ab (Macbeth capture)"), strict=True):
        plain_log(ax, x=True)
        ax.set_xlabel("scene illuminance (lux), auto exposure + gain")
        ax.set_title(t)
    axes[0].axhline(PUBLISHED["rgbw"], color="k", lw=0.8, ls="--", label="published RGBW (1.70)")
    axes[0].legend(fontsize=6)
    fig.tight_layout()
    fig_link = save_figure(fig, "rgbw_vs_light")

    rows = [[f"{x:g}"] + [de[r][x] for r, _ in MAIN] for x in luxes]
    rows.append(["mean, all levels"] + [mean[r] for r, _ in MAIN])
    rows.append([f"mean, {lit[0]:g}–{lit[-1]:g} lux"] + [mean_lit[r] for r, _ in MAIN])
    rows.append(["one linear map, noise-free (not a bound on L3)"] + [floor[r] for r, _ in MAIN])
    rows.append(["3 linear maps by response level, noise-free, in sample"] + [floor3[r] for r, _ in MAIN])
    rows.append(["published"] + [PUBLISHED.get(r) for r, _ in MAIN])
    table = md_table(["lux"] + [lab for _, lab in MAIN], rows)
    v_rows = [[f"{x:g}"] + [de[r][x] for r, _ in VARIANTS] for x in luxes]
    v_rows.append(["mean, all levels"] + [mean[r] for r, _ in VARIANTS])
    v_rows.append([f"mean, {lit[0]:g}–{lit[-1]:g} lux"] + [mean_lit[r] for r, _ in VARIANTS])
    v_table = md_table(["lux"] + [lab for _, lab in VARIANTS], v_rows)
    val_table = "\n".join("  " + ln for ln in md_table(
        ["camera / recipe (validation)", "RGBW", "Bayer", "worse of the two", "RGBW 35 / 450 lux",
         "Bayer 35 / 450 lux"],
        [[r, a, b, max(a, b), f"{v[0]:.2f} / {v[1]:.2f}", f"{v[2]:.2f} / {v[3]:.2f}"]
         for r, a, b, v in VALIDATION]).splitlines())
    diag_table = "\n".join("  " + ln for ln in md_table(
        ["camera", "lux", "noisy", "noise-free"], [[c, f"{x:g}", a, b] for c, x, a, b in DIAG_NOISE]).splitlines())
    dark_table = "\n".join("  " + ln for ln in md_table(
        ["camera", "mean", "20 lux", "20 lux noise-free", "mean, no dark current", "20 lux, no dark current"],
        [list(r) for r in DIAG_DARK]).splitlines())
    sc_rows = [[f"{x:g}"] + [sc[r][x] for r, _ in MAIN] for x in luxes]
    sc_table = md_table(["lux"] + [lab for _, lab in MAIN], sc_rows)
    ex_rows = [[f"{x:g}"] + [f"{expo[c][x][0] * 1000:.0f} ms × {expo[c][x][1]:.2g}" for c, _ in CAMERAS]
               for x in luxes]
    ex_table = md_table(["lux"] + [f"{lab}: time × gain" for _, lab in CAMERAS], ex_rows)
    lo, hi = luxes[0], luxes[-1]
    worst = sorted(range(24), key=lambda i: -patches["bayer"][lo][i])[:4]
    worst_txt = ", ".join(f"{PATCHES[i]} {patches['bayer'][lo][i]:.1f}" for i in worst)
    n_better = sum(de["rgbw"][x] < de["bayer"][x] for x in luxes)
    best_val = min(VALIDATION[3:], key=lambda r: max(r[1], r[2]))

    below = {c: [x for x in luxes if de[c][x] < floor[c]] for c in ("rgbw", "bayer")}
    below_txt = "; L3 itself is below it at " + "; ".join(
        f"{', '.join(f'{x:g}' for x in below[c])} lux ({lab})"
        for c, lab in (("rgbw", "RGBW"), ("bayer", "Bayer")) if below[c]) if any(below.values()) else ""

    def levels_txt(xs: list[float]) -> str:
        return ", ".join(f"{x:g}" for x in xs) or "none"

    def versus(a: str, b: str, metric: dict) -> str:
        better = [x for x in luxes if metric[a][x] < metric[b][x]]
        worse = [x for x in luxes if metric[a][x] >= metric[b][x]]
        txt = f"better at {', '.join(f'{x:g}' for x in better) or 'no'} lux"
        if worse:
            txt += f", worse at {', '.join(f'{x:g}' for x in worse)} lux"
        return txt

    def e_txt(c: str, x: float) -> str:
        return ", ".join(f"{ch} {v:.0f}" for ch, v in white_e[(c, x)].items())

    def yes(flag: bool) -> str:
        return "met" if flag else "**not met**"

    pct = (1 - ratio) * 100
    unsm_txt = "; ".join(f"{r}: {a:.2f} / {b:.2f}" for r, a, b in UNSMOOTHED)
    nochart_txt = "; ".join(f"{r}: {v[0][0]:.2f} vs {v[0][1]:.2f} / {v[1][0]:.2f} vs {v[1][1]:.2f}"
                            for r, v in UNSMOOTHED_NOCHART.items())
    under_txt = (f"it reaches its {max_g:g}x limit, so under-exposes, at "
                 f"{levels_txt(under['rgbw'])} lux (RGBW) and {levels_txt(under['bayer'])} lux (Bayer)"
                 if under["rgbw"] or under["bayer"] else
                 f"it stays below its {max_g:g}x limit at every test level (the training "
                 "captures at 10 lux reach it: the Bayer's is under-exposed there)")
    md = f"""## 2. RGBW vs Bayer, and both vs a conventional pipeline

Cameras (`scripts/paper/cameras.py`): the L3 RGBW camera
(`sample_configs/rgbw.toml`: 1.4 µm pixels, f/4, ISETCam's interleaved RGBW
filter curves, no IR-cut filter, and — as in the paper — exactly one R, G, B
and W in each 2x2 repeat, R G / W B), and the same camera with its W pixel
replaced by G, which makes it an RGGB Bayer with the same pixel, optics and
R, G, B filters (the paper's comparison camera; `l3 baseline`, a Bayer-only
conventional pipeline: Menon 2007 demosaicking + a 3x3 matrix fitted by
least squares on the same training data, can render it too). A 4x4 RGBW
layout with R and B on 2 of 16 pixels is kept as `sample_configs/rgbw-4x4.toml`
but not used here. Each L3 table is trained (`l3 train`, XYZ target unless
the column says Lab; {TRAIN_LAYOUT})
on the Macbeth chart and the four bundled natural photos at {len(train_lux)}
light levels ({', '.join(f'{x:g}' for x in train_lux)} lux), smoothed
(`l3 smooth`), and tested on Macbeth captures at light levels *not* used in
training.

**Exposure.** Every camera uses its own auto exposure (its TOML's
`[exposure]`): ISETCam's default rule (`autoExposure`, method `luminance`:
the brightest pixel at 95 % of the voltage swing), which has no time limit;
our cameras stop at {max_t * 1000:.0f} ms and then raise the analog gain, as a
camera's auto ISO does, up to {max_g:g}x (`max_analog_gain`; ISO {100 * max_g:.0f}
at a base ISO of 100). Gain restores the response level but not the
electrons: shot and read noise stay those of the capped time. The sensor
{'clamps its black level on the mean dark signal (`black_clamp`, as optical-black rows do)' if clamp else 'keeps the dark current in the raw, as ISETCam does'}.
Exposure times and gains of the test captures:

{ex_table}

Auto gain is at work at {levels_txt(gained['rgbw'])} lux (RGBW) and
{levels_txt(gained['bayer'])} lux (Bayer); {under_txt}.
{'Every' if not (under['rgbw'] or under['bayer']) else 'Every other'} test capture reaches the exposure target, so its raw
response is that of the training captures at the target, and the test level differs from the training ones in its
noise: the unseen light levels test noise, not response level. Because W, which
sees about four times the light of G, reaches the target first, the RGBW
camera's R, G and B pixels collect fewer electrons than the Bayer's at the
same light level (white patch, noise-free photo-electrons at {hi:g} lux: RGBW
{e_txt('rgbw', hi)}; Bayer {e_txt('bayer', hi)}; at {lo:g} lux: RGBW
{e_txt('rgbw', lo)}; Bayer {e_txt('bayer', lo)}).

Mean Macbeth ΔE*ab over the 24 patches (white-normalised, as ISETCam's
`macbethColorError`):

{table}

The same cameras trained differently (mean Macbeth ΔE*ab; test captures as
above): in CIELAB (`l3 train --target lab`), on the natural photos
alone (the chart not in training, so its colours are out of sample too),
with the Esser chart added to training (113 reflectances measured to 1068 nm,
ISETCam, bundled as `l3cli/data/spectral/reflectance_esser.csv`, tiled at
three patch sizes by `scripts/paper/esser.py`, at the same light levels), and
with fewer, wider classes (patch 5, 12 levels, one contrast bin):

{v_table}

S-CIELAB mean ΔE*ab of the same Macbeth captures (96 dpi, 1 m):

{sc_table}

![Macbeth ΔE vs light level]({fig_link})

- **RGBW vs W→G (a Bayer).** Published: RGBW 1.70 vs Bayer 1.65 (RGBW 3 %
  worse). Ours, mean over the {len(luxes)} test levels: {mean['rgbw']:.2f} vs
  {mean['bayer']:.2f} (RGBW/Bayer = {ratio:.2f}, RGBW {abs(pct):.0f} % {'better' if pct > 0 else 'worse'};
  RGBW better at {n_better} of {len(luxes)} levels). The issue's bar: RGBW no more
  than 15 % worse than the Bayer — {yes(bar['not_worse_by_15_percent'])}{'' if bar['within_15_percent'] else ' (read as "within ±15 %" it is not: the RGBW camera is the better one by more than 15 %)'};
  both at most {BAR_DE:.1f} — {yes(bar['both_at_most_3'])}; goal both at most
  {GOAL_DE:.1f} — {yes(bar['both_at_most_2'])}. Why RGBW comes out ahead, unlike
  in the paper: its four channels fit XYZ better than three where there is
  light (at {hi:g} lux {de['rgbw'][hi]:.2f} vs {de['bayer'][hi]:.2f}, against
  single-map floors of {floor['rgbw']:.2f} and {floor['bayer']:.2f}), and W gathers more
  light where there is little.
- **What limited the dark levels before (diagnosis).** With the previous
  camera (time cap 0.5 s, no gain) both cameras were capped at 20 lux (the
  Bayer at 70 lux too) and gave 6.49 (RGBW) and 4.66 / 3.69 (Bayer) there. That
  was bias, not noise: the noise-free captures at the same levels, rendered
  through the same tables, were as bad or worse (mean Macbeth ΔE*ab;
  `scripts/paper/rgbw_diagnose.py` gives the per-patch ΔL*, ΔC*ab and
  training classes):

{diag_table}

  The errors were colour, not lightness: at 20 lux (RGBW, noise-free) the 18
  coloured patches averaged 8.1 and the six greys 3.2, with a mean |ΔL*| of
  0.8 and mean ΔC*ab of −4.1 on the coloured patches (foliage 19.8, yellow
  17.4, blue 17.3, cyan 13.5, green 13.1: chroma lost, cyan's hue turned); the
  Bayer's errors went both ways (orange yellow ΔC*ab +15.9, orange +9.3, cyan
  a hue error). The cause is how L3's classes meet the auto exposure: at every
  light level where the exposure reaches its target the chart's raw response
  is the same, so training saw the chart at only three response levels (the
  10, 35 and ≥ 120 lux captures: 0.20, 0.71 and 1.0 of the target response
  for RGBW). At 20 lux every patch sat at 0.40 and fell into response-level
  classes whose training samples came from other chart colours and from the
  four photos (yellow, for example, into a level bin where, at the exposure
  target, training had the chart only as its blue sky and cyan patches). There the kernels are
  in effect those learnt from the photos, whose near infrared is a linear
  function of RGB: the chart-free tables give the same size of error
  (columns "chart not in training"). W at 20 lux still held 2300 e⁻ on the
  white patch (40 % of the target); the 70 lux capture, uncapped for RGBW,
  lands on the training captures' response levels and is nearly in sample.
- **The fix: auto gain, as cameras do, and a black clamp.** With gain, a
  capped capture returns to the target response, so the chart's patches fall
  into the classes that were trained on them. Gain alone left the 20-lux
  captures biased by the dark current: 10 e⁻/s × 0.5 s = 5 e⁻ per pixel,
  times the gain (10x for the Bayer at 20 lux) is an offset of 50 e⁻ that
  changes from capture to capture, which the classes cannot see and the dark
  patches (under 100 e⁻ in R and B) cannot hide (test levels, patch 5):

{dark_table}

  A sensor's optical-black clamp takes the mean dark signal out before the
  ADC (its shot noise and the DSNU remain); the cameras now do that
  (`black_clamp = true`). ISETCam itself has neither gain nor clamp and no
  time cap. Its rule as it is (no cap, no gain, no clamp; patch 7; test
  levels) gives {NOCAP[0]:.2f} (RGBW) and {NOCAP[1]:.2f} (Bayer), {NOCAP[2]:.2f} and
  {NOCAP[3]:.2f} at {lo:g} lux: the Bayer's exposures grow to 5 s at 20 lux and 10 s
  at 10 lux, whose dark current (50–100 e⁻) again shifts the dark patches by
  an amount the classes cannot see, in training as in the test.
- **Choices, made on a validation split of the training light levels.**
  Tables trained at 10, 120, 1600 and 5000 lux, scored on new Macbeth
  captures at 35 lux (gained for both cameras) and 450 lux (at the target),
  mean ΔE*ab of the two; criterion: the worse of the two cameras, as in the
  bar (`scripts/paper/rgbw_validation.sh`). The exposure model first (patch
  5), then recipes on the chosen camera:

{val_table}

  Each step of the exposure model helped the worse camera (3.84 → 3.20 →
  3.01), and 7x7 patches gave the lowest worse-camera error
  ({best_val[0].split(' (')[0]}: {max(best_val[1], best_val[2]):.2f}); the main tables use them. Noisy,
  gained training captures share the classes of the clean ones at the same
  response level, and a larger patch averages more pixels per class. The
  Esser chart (measured near infrared) helps the RGBW camera and hurts the
  Bayer at both validation levels, so it stays a variant. Conditioning the
  kernels on ISO (`l3 train --by iso`, one kernel set per gain) was tried on the
  Bayer and failed (10.3 at the gained test levels): each gain bin then holds
  one training light level and too few colours per class.
- **Not adopted: dropping the smoothing.** On the same validation split the
  tables as trained, without `l3 smooth`, score much lower ({unsm_txt}; the
  spline over levels is the prior that costs, not symmetry or uniformity).
  But with the chart left out of training, the same split shows no such gain
  (smoothed vs not, RGBW / Bayer: {nochart_txt}): the unsmoothed kernels fit the
  chart's own colours in the level bins where training put them, which is an
  in-sample gain on a test that shares the chart with training, not better
  colour. The main tables stay smoothed, as the paper's were.
- **What limits the dark level now.** At {lo:g} lux RGBW gives {de['rgbw'][lo]:.2f}
  and the Bayer {de['bayer'][lo]:.2f} (gains {expo['rgbw'][lo][1]:.2g}x and
  {expo['bayer'][lo][1]:.2g}x); the Bayer's worst patches there: {worst_txt}. The
  noise-free captures at {lo:g} lux through the same tables give
  {DIAG_NOW['RGBW']:.2f} (RGBW) and {DIAG_NOW['Bayer']:.2f} (Bayer), as at the bright
  levels: what the Bayer loses at {lo:g} lux is noise (its R and B pixels hold
  about {white_e[('bayer', lo)]['R']:.0f} and {white_e[('bayer', lo)]['B']:.0f} e⁻ on the white
  patch), where the RGBW camera's W pixels, with four times the light, keep it
  away.
- **What limits the bright levels.** Where auto exposure reaches its target
  the error is close to the row "one linear map": the mean ΔE of the best
  single linear map from the camera's channels to XYZ on noise-free,
  dark-subtracted, perfectly demosaicked patch means (least squares over the
  24 patches, no offset, `common.linear_colour_floor`): {floor['rgbw']:.2f} for RGBW,
  {floor['bayer']:.2f} for the Bayer. Our simulated sensors (ISETCam's filter
  curves under the daylight simulator, no IR-cut filter) are that far from
  the Luther condition. This is *not* a bound on L3: L3 fits one map per
  response level (and contrast class), and a piecewise-linear map can go
  below the single-map floor — three maps over dark / mid / bright patches
  reach {floor3['rgbw']:.2f} (RGBW) and {floor3['bayer']:.2f} (Bayer) on the same noise-free
  patches (in sample, so an optimistic figure){below_txt}.
- **The chart in training.** Under auto exposure the bright test captures of
  the chart have the same response as its bright training captures (only the
  noise differs), so the main table is close to in-sample for the chart's
  colours. Trained on the four natural photos alone, the mean over all
  levels is {mean['rgbw-nochart']:.2f} (RGBW) and {mean['bayer-nochart']:.2f} (Bayer) instead of
  {mean['rgbw']:.2f} and {mean['bayer']:.2f}. The natural photos are RGB images given spectra
  by a smooth three-function basis (Mallett & Yuksel 2019) whose near-infrared
  part is a linear function of r, g, b (`l3cli.simulate.scenes`): they teach
  a relation between visible colour and near-infrared light that the chart's
  measured reflectances do not follow, and the camera whose W and R see the
  near infrared suffers most. This, more than noise, is what keeps our
  out-of-sample numbers above the published ones: the paper trained on many
  ISETCam scenes with measured spectra.
- **Training target.** Training in CIELAB (`l3 train --target lab`, which
  makes the ridge loss roughly a ΔE loss, as the paper suggests) is worse,
  not better: {mean['rgbw-lab']:.2f} (RGBW) and {mean['bayer-lab']:.2f} (Bayer) over
  all levels. Lab is a non-linear function of the raw values within a class
  (cube root of Y, ratios for a*, b*), and one affine kernel per class fits it
  worse than it fits XYZ, which is linear in the raw values for a fixed
  spectrum. XYZ stays the target.
- **IR.** The RGBW camera has no IR-cut filter, so W and R integrate
  700–1060 nm light that the XYZ target does not see; the same camera behind
  an IR-cut filter gives {mean['rgbw-ircut']:.2f} (mean over levels;
  {versus('rgbw-ircut', 'rgbw', de)} than without). See experiment 7 for what
  this does to the kernels.
- **L3 vs the conventional pipeline (Bayer camera).** Macbeth ΔE: L3 is
  {versus('bayer', 'bayer-baseline', de)}; S-CIELAB: L3 is
  {versus('bayer', 'bayer-baseline', sc)}. RGBW L3 vs the Bayer baseline:
  Macbeth ΔE {versus('rgbw', 'bayer-baseline', de)}. The paper reports L3
  ahead of the conventional pipeline{', as here' if all(de['bayer'][x] < de['bayer-baseline'][x] for x in luxes) else '; here it is not at every level'}.
  The baseline's one 3x3 matrix is fitted by least squares on every training
  capture, and the gained dim ones (16x at 10 lux) now enter it at full
  response with their noise, which pulls the matrix toward grey (errors in
  the variables): fitted on the captures at 120 lux and above only it gives
  {BASELINE_BRIGHT_ONLY:.2f} over the test levels, as before auto gain (5.79).
- **Why the published values are lower.** The paper's 1.70 / 1.65 come from
  ISETCam simulations of many more training scenes with measured spectra;
  ours from five scenes at 320x240 pixels (four of them RGB photos with
  synthetic spectra), with the chart also seen in training (other levels,
  other noise). Our means are {mean['rgbw'] - PUBLISHED['rgbw']:+.2f} (RGBW) and
  {mean['bayer'] - PUBLISHED['bayer']:+.2f} (Bayer) from the published values; the Bayer's
  distance is mostly its single-map floor ({floor['bayer']:.2f}) and the noise of
  its gained dark levels.
"""
    write_outputs(build, "rgbw", md, {"macbeth_de": {r: {str(k): v for k, v in de[r].items()} for r, _ in RUNS},
                                      "scielab": {r: {str(k): v for k, v in sc[r].items()} for r, _ in RUNS},
                                      "exposure_s": {c: {str(k): v[0] for k, v in expo[c].items()}
                                                     for c, _ in CAMERAS},
                                      "analog_gain": {c: {str(k): v[1] for k, v in expo[c].items()}
                                                      for c, _ in CAMERAS},
                                      "under_exposed_levels": under, "gained_levels": gained,
                                      "mean": mean, "linear_colour_floor": floor,
                                      "linear_colour_floor_3_pieces": floor3,
                                      "mean_lit_levels": mean_lit, "lit_levels": lit,
                                      "white_patch_electrons": {f"{c}@{x:g}": v for (c, x), v in white_e.items()},
                                      "bar": bar, "published": PUBLISHED,
                                      "validation": [list(r[:3]) for r in VALIDATION]})


def json_camera(sim: Path) -> dict:
    """The camera record of a simulation folder's manifest."""
    import json

    return json.loads((sim / "manifest.json").read_text())["camera"]


if __name__ == "__main__":
    main(build_arg(__doc__))
