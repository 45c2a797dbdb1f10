#!/usr/bin/env python3
"""Experiment 3: RGB-NIR vs NIR pixel blacked out vs NIR replaced by G, and the
weight L3 gives the NIR pixel at each response level.

``rgbnir.py BUILD`` reads ``BUILD/eval/{rgbnir,rgbnir-black,rgbnir-g}.json``
(held-out Macbeth captures) and the RGB-NIR tables ``BUILD/tables/rgbnir.raw.npz``
(as trained) and ``rgbnir.npz`` (smoothed), and writes
``BUILD/sections/rgbnir.md``, ``BUILD/rgbnir.json`` and docs/figures/rgbnir_*.png.

Published (Jiang et al. 2017, RGB-NIR section): median ΔE 2.87 (RGB-NIR),
3.08 (NIR blacked out), 2.69 (NIR replaced by G); the NIR weights are large at
low response levels and near zero at high ones.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from common import (
    build_arg,
    captures,
    linear_colour_floor,
    md_table,
    plain_log,
    pyplot,
    report,
    save_figure,
    write_outputs,
)

PUBLISHED = {"rgbnir": 2.87, "rgbnir-black": 3.08, "rgbnir-g": 2.69}
RUNS = [("rgbnir", "RGB-NIR"), ("rgbnir-black", "NIR blacked out"), ("rgbnir-g", "NIR → G")]


def patch_des(build: Path, run: str) -> dict[float, np.ndarray]:
    """``{lux: per-patch ΔE*ab (24,)}`` of the held-out Macbeth captures."""
    rep = report(build / "eval" / f"{run}.json")
    out = {}
    for stem, cap in captures(build / "sim" / run / "test").items():
        if cap["scene"] == "macbeth":
            out[float(cap["lux"])] = np.asarray(rep[stem]["macbeth_patches"]["de_ab"], float)
    return dict(sorted(out.items()))


def nir_share(table_path: Path, *, trained_only: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per level: (level value, NIR share of Σ|w|, NIR share of Σw), output Y.

    The first share counts how much of the kernel sits on NIR pixels at all;
    the second is the NIR pixels' net contribution to the kernel's gain (its
    response to a flat field), which is what adds signal.

    Unsaturated classes only, averaged over position groups and contrast bins
    weighted by training samples (at least 1, so that classes filled by
    ``l3 smooth`` count). NaN where no class is used.
    """
    from l3cli.plots_table import level_values
    from l3cli.table import load_table

    t = load_table(table_path)
    d = t.definition
    ng, ns, nl, nc = d.shape
    nir = d.cfa.channels.index("NIR")
    s = d.patch
    share = np.full(nl, np.nan)
    signed = np.full(nl, np.nan)
    for lev in range(nl):
        num = den = sig = sig_all = 0.0
        for g in range(ng):
            p = int(np.flatnonzero(d.position_group == g)[0])
            is_nir = (d.cfa.neighbourhood(p, s) == nir).ravel()
            for c in range(nc):
                k = int(d.class_index(g, 0, lev, c))
                if trained_only and t.empty[k]:
                    continue
                w = float(max(t.counts[k], 1))
                ky = np.abs(t.kernels[k, :-1, 1])
                num += w * ky[is_nir].sum()
                den += w * ky.sum()
                sig += w * t.kernels[k, :-1, 1][is_nir].sum()
                sig_all += w * t.kernels[k, :-1, 1].sum()
        if den > 0:
            share[lev] = num / den
            signed[lev] = sig / sig_all
    return level_values(t), share, signed


def main(build: Path) -> None:
    des = {r: patch_des(build, r) for r, _ in RUNS}
    luxes = list(des["rgbnir"])
    med_all = {r: float(np.median(np.concatenate(list(des[r].values())))) for r, _ in RUNS}
    med = {r: {x: float(np.median(des[r][x])) for x in luxes} for r, _ in RUNS}
    mean = {r: {x: float(np.mean(des[r][x])) for x in luxes} for r, _ in RUNS}

    lv, share_raw, signed_raw = nir_share(build / "tables" / "rgbnir.raw.npz", trained_only=True)
    _, share_s, signed_s = nir_share(build / "tables" / "rgbnir.npz", trained_only=False)

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.0))
    for r, lab in RUNS:
        axes[0].plot(luxes, [med[r][x] for x in luxes], "o-", label=lab)
    plain_log(axes[0], x=True)
    axes[0].set_xlabel("scene illuminance (lux), exposure fixed")
    axes[0].set_title("median Macbeth patch ΔE*ab")
    axes[0].legend(fontsize=7)
    axes[1].plot(lv, signed_raw, "o", color="C0", label="net share Σw, as trained")
    axes[1].plot(lv, signed_s, "-", color="C0", label="net share Σw, smoothed")
    axes[1].plot(lv, share_raw, "s", color="C1", ms=3, label="share of Σ|w|, as trained")
    axes[1].plot(lv, share_s, "--", color="C1", label="share of Σ|w|, smoothed")
    axes[1].axhline(0, color="k", lw=0.6)
    plain_log(axes[1], x=True, y=False)
    axes[1].set_xlabel("response level (normalised raw)")
    axes[1].set_title("NIR pixels' weight for output Y")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig_link = save_figure(fig, "rgbnir")

    rows = [[f"{x:g}"] + [med[r][x] for r, _ in RUNS] for x in luxes]
    rows.append(["all levels pooled"] + [med_all[r] for r, _ in RUNS])
    floor = {r: linear_colour_floor(build / "sim" / r / "test")[0] for r, _ in RUNS}
    rows.append(["one linear map, noise-free (mean ΔE; not a bound, see exp. 2)"] + [floor[r] for r, _ in RUNS])
    rows.append(["published"] + [PUBLISHED[r] for r, _ in RUNS])
    table = md_table(["lux"] + [lab for _, lab in RUNS], rows)
    ok = np.isfinite(signed_raw)
    white = 1.0 / 959.0  # one DN above black (10-bit ADC, black level 64)
    dark = ok & (lv < white)
    lit = ok & (lv >= white)
    net_dark = float(np.mean(np.abs(signed_raw[dark]))) if dark.any() else float("nan")
    net_lit = float(np.mean(np.abs(signed_raw[lit]))) if lit.any() else float("nan")
    abs_dark = float(np.mean(share_raw[dark])) if dark.any() else float("nan")
    abs_lit = float(np.mean(share_raw[lit])) if lit.any() else float("nan")
    order = sorted(med_all, key=med_all.get)
    pub_order = sorted(PUBLISHED, key=PUBLISHED.get)
    names = dict(RUNS)
    md = f"""## 3. RGB-NIR

Cameras (`scripts/paper/cameras.py`): `sample_configs/rgbnir.toml` (R G / NIR B,
2 µm pixels, f/2.8, ISETCam `cfaRGBNearIR` filters: IR-blocked R, G, B and an
IR-pass NIR pixel, no IR-cut filter on the lens, daylight simulator 380–1060
nm), the same camera with the NIR pixel blacked out (zero quantum efficiency:
it records dark current and noise only) and with the NIR pixel replaced by G
(an RGGB Bayer camera). Training and test sets as in experiment 2. Values:
median of the 24 Macbeth patch ΔE*ab per test level, and pooled over all
patches and levels.

{table}

![RGB-NIR ΔE and NIR weights]({fig_link})

- **Ranking.** Published: NIR→G best (2.69), RGB-NIR next (2.87), NIR blacked
  out worst (3.08). Ours: {' < '.join(f'{names[r]} {med_all[r]:.2f}' for r in order)}
  ({'the same order' if order == pub_order else 'a different order'}). Per
  level, RGB-NIR beats the blacked-out camera at
  {', '.join(f'{x:g}' for x in luxes if med['rgbnir'][x] < med['rgbnir-black'][x]) or 'no'} lux
  and loses at {', '.join(f'{x:g}' for x in luxes if med['rgbnir'][x] >= med['rgbnir-black'][x]) or 'no'} lux,
  and beats NIR→G at {', '.join(f'{x:g}' for x in luxes if med['rgbnir'][x] < med['rgbnir-g'][x]) or 'no'} lux.
  Our pooled medians include the darkest test level, where all three
  cameras are far above the published values; the published numbers come
  from ISETCam scenes at one light level, so only the ranking and the gaps
  are comparable. As in experiment 2, the best single linear map of these
  sensors on noise-free patch means (last-but-one row; a per-level map can
  do better, so it does not bound L3) is near or above the published values.
- **NIR weights vs response level.** Published: large at low levels, near
  zero at high ones. Ours (output Y, unsaturated classes as trained): the
  NIR taps' net share of the kernel's gain (Σ of the NIR taps / Σ of all
  taps) averages {net_dark:.2f} in absolute value over the levels below one
  DN and {net_lit:.3f} over all levels above; the sub-DN levels are
  noise, not a trend. Our NIR pixel (ISETCam's `irPassFilter` × silicon) has
  no response below 650 nm, so it carries no information about the visible
  XYZ target except through scene correlations, and the regression gives it
  almost no net weight at any usable level: l3 does not reproduce the
  published trend with this filter set. The NIR taps' share of the
  *absolute* weights is {abs_dark:.2f} (sub-DN levels) and {abs_lit:.2f}
  (above): positive/negative pairs that cancel on flat areas. That the
  RGB-NIR camera still beats the blacked-out one at some levels (ranking
  above) suggests these zero-sum taps carry useful information (edges,
  material contrast between the visible and the NIR), not extra signal.
"""
    write_outputs(build, "rgbnir", md, {
        "median_pooled": med_all, "linear_colour_floor": floor, "median_per_lux": {r: {str(k): v for k, v in med[r].items()} for r, _ in RUNS},
        "mean_per_lux": {r: {str(k): v for k, v in mean[r].items()} for r, _ in RUNS},
        "nir_share_levels": lv.tolist(), "nir_share_raw": share_raw.tolist(),
        "nir_share_smooth": share_s.tolist(), "nir_net_share_raw": signed_raw.tolist(), "nir_net_share_smooth": signed_s.tolist(),
        "published": PUBLISHED})


if __name__ == "__main__":
    main(build_arg(__doc__))
