#!/usr/bin/env python3
"""Experiment 7: the learned RGBW transforms at low, mid, high and saturated levels.

``kernels.py BUILD`` reads the smoothed RGBW table of experiment 2
(``BUILD/tables/rgbw.npz``), draws the kernels for the output Y (luminance)
of a W-centred and a G-centred position at the Low / Mid / High levels
(:func:`l3cli.plots_table.default_levels`) and at the best-sampled level whose
patches have saturated W pixels ("Saturate"), plus the summed weight per
input channel, and writes ``BUILD/sections/kernels.md``, ``BUILD/kernels.json``
and docs/figures/kernels_*.png. The full set of kernel images of every position
group (``l3 inspect --plots``) lands in ``BUILD/kernels_full/``.

Published (Jiang et al. 2017, Fig. RGBW kernels): at low levels the weights
spread over the patch, at high levels they concentrate at the centre, and
when W saturates the weights move from W to the R, G, B pixels.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from common import build_arg, md_table, pyplot, run_l3, save_figure, write_outputs


def analyse(build: Path, camera: str, title: str) -> tuple:
    """Figure and channel shares of one RGBW table: (figure link, labels, chosen, shares)."""
    from l3cli.plots_table import default_levels, level_values
    from l3cli.table import load_table

    path = build / "tables" / f"{camera}.npz"
    run_l3("inspect", path, "--plots", build / "kernels_full" / camera)
    t = load_table(path)
    d = t.definition
    ng, ns, nl, nc = d.shape
    chans = d.cfa.channels
    w_bit = 1 << chans.index("W")
    s = d.patch
    lvals = level_values(t)
    counts = t.counts.reshape(ng, ns, nl, nc)
    # Low / mid / high: trained unsaturated levels at least 2 DN above black
    # (the lowest bins hold sub-DN noise), the middle one by index.
    ro = json.loads((build / "sim" / camera / "train" / "manifest.json").read_text())["camera"]["readout"]
    two_dn = 2.0 / (ro["white_level_dn"] - ro["black_level_dn"])
    trained = np.flatnonzero((~t.empty.reshape(ng, ns, nl, nc)[:, 0, :, 0]).any(axis=0) & (lvals >= two_dn))
    if trained.size:
        chosen = {"low": (0, int(trained[0])), "mid": (0, int(trained[trained.size // 2])),
                  "high": (0, int(trained[-1]))}
    else:
        chosen = {k: v for k, v in default_levels(t).items() if k != "saturated"}
    sat_lv = int(np.argmax(counts[:, w_bit].sum(axis=(0, 2))))
    if counts[:, w_bit, sat_lv].sum() > 0:
        chosen["saturate (W)"] = (w_bit, sat_lv)
    labels = list(chosen)

    # one W-centred and one G-centred position group
    groups = {}
    for g in range(ng):
        p = int(np.flatnonzero(d.position_group == g)[0])
        c = chans[d.cfa.neighbourhood(p, s)[s // 2, s // 2]]
        groups.setdefault(c, (g, p))
    show = [groups[c] for c in ("W", "G") if c in groups]

    plt = pyplot()
    fig, axes = plt.subplots(len(show) + 1, len(labels), figsize=(2.1 * len(labels), 2.1 * (len(show) + 1)),
                             squeeze=False)
    sums = {}
    for j, lab in enumerate(labels):
        sat, lev = chosen[lab]
        for i, (g, p) in enumerate(show):
            cls = int(d.class_index(g, sat, lev, 0))
            img = t.kernels[cls, :-1, 1].reshape(s, s)
            lay = d.cfa.neighbourhood(p, s)
            vmax = float(np.abs(img).max()) or 1.0
            ax = axes[i, j]
            ax.imshow(img, cmap="RdBu_r", vmin=-vmax, vmax=vmax)
            for yy in range(s):
                for xx in range(s):
                    ax.text(xx, yy, chans[lay[yy, xx]], ha="center", va="center", fontsize=6, color="0.2")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.grid(False)
            st = "filled" if t.empty[cls] else f"n={t.counts[cls]}"
            ax.set_title(f"{lab}, level {lev} (~{lvals[lev]:.2g})\n{chans[lay[s // 2, s // 2]]}-centred, {st}",
                         fontsize=7)
            if i == 0:
                # channel sums over all groups (sample-weighted), output Y
                tot = {c: 0.0 for c in chans}
                wsum = 0.0
                for gg in range(ng):
                    pp = int(np.flatnonzero(d.position_group == gg)[0])
                    lay2 = d.cfa.neighbourhood(pp, s).ravel()
                    k = int(d.class_index(gg, sat, lev, 0))
                    w = float(max(t.counts[k], 1))
                    for ci, c in enumerate(chans):
                        tot[c] += w * float(np.abs(t.kernels[k, :-1, 1][lay2 == ci]).sum())
                    wsum += w
                allw = sum(tot.values())
                sums[lab] = {c: tot[c] / allw for c in chans}
        ax = axes[-1, j]
        ax.bar(range(len(chans)), [sums[lab][c] for c in chans], color=[{"W": "0.6", "R": "r", "G": "g", "B": "b"}.get(c, "0.3") for c in chans])
        ax.set_xticks(range(len(chans)), chans)
        ax.set_ylim(0, 1)
        ax.set_title("share of Σ|w| per channel (Y)", fontsize=7)
    fig.suptitle(f"{title}: L3 kernels for output Y (smoothed table)", fontsize=9)
    fig.tight_layout()
    n_sat = (int(counts[:, w_bit, sat_lv].sum()), int(counts[:, 0, sat_lv].sum()))
    return save_figure(fig, f"kernels_{camera}"), labels, chosen, sums, lvals, chans, n_sat


def main(build: Path) -> None:
    fig_link, labels, chosen, sums, lvals, chans, n_sat = analyse(build, "rgbw", "RGBW")
    fig2, labels2, chosen2, sums2, lvals2, _, n_sat2 = analyse(build, "rgbw-ircut", "RGBW + IR-cut filter")

    def shift(ws: list[float], labs: list[str], n: tuple[int, int]) -> str:
        if "saturate (W)" not in labs or "high" not in labs:
            return "No trained class has saturated W pixels, so the shift at saturation cannot be seen."
        hi, sat = ws[labs.index("high")], ws[labs.index("saturate (W)")]
        verdict = (f"down by {100 * (1 - sat / hi):.0f} %: the published shift from W to R, G, B"
                   if sat < 0.8 * hi else "no clear shift, unlike the published kernels")
        return (f"From the unsaturated to the saturated-W class of the same level bin W's share goes from "
                f"{hi:.2f} to {sat:.2f} ({verdict}; training patches in that bin: {n[0]} with saturated W, "
                f"{n[1]} without).")

    rows = [[lab, chosen[lab][1], f"{lvals[chosen[lab][1]]:.3g}"] + [sums[lab][c] for c in chans] for lab in labels]
    table = md_table(["class", "level bin", "level (norm. raw)"] + [f"{c} share" for c in chans], rows)
    wshare = [sums[lab]["W"] for lab in labels]
    rows2 = [[lab, chosen2[lab][1], f"{lvals2[chosen2[lab][1]]:.3g}"] + [sums2[lab][c] for c in chans]
             for lab in labels2]
    table2 = md_table(["class", "level bin", "level (norm. raw)"] + [f"{c} share" for c in chans], rows2)
    wshare2 = [sums2[lab]["W"] for lab in labels2]
    md = f"""## 7. The transforms

Kernels of the smoothed RGBW table of experiment 2 for the output Y, at the
lowest (at least 2 DN above black), middle and highest trained unsaturated
levels (flat contrast bin) and at the best-sampled
level whose patches contain saturated W pixels. Top rows:
the weight images of a W-centred and a G-centred position (letters: the CFA
channel of each tap); bottom: each input channel's share of the summed
absolute weights, over all positions. Every position group and output
channel: `l3 inspect {build.name}/tables/rgbw.npz --plots DIR`.

![RGBW kernels]({fig_link})

{table}

Published: weights spread over the patch at low levels (denoising),
concentrate at the centre at high levels, and move from W to R, G, B when W
saturates. Ours: the W share of the weights is
{', '.join(f'{lab} {v:.2f}' for lab, v in zip(labels, wshare, strict=True))}.
In the dark the kernels lean on W, whose extra photons matter most there;
above it W's share drops: our W pixel (clear silicon and no IR-cut filter, as
in `sample_configs/rgbw.toml`) responds out to 1060 nm, and its
infrared-contaminated signal predicts the visible XYZ target worse than R, G
and B do. {shift(wshare, labels, n_sat)}

**The same camera behind an IR-cut filter** (`rgbw-ircut`, ISETCam's
`ircf_public`; trained and tested like the others, see experiment 2): W
share {', '.join(f'{lab} {v:.2f}' for lab, v in zip(labels2, wshare2, strict=True))}.
With W limited to the visible, W keeps more of the weight at high levels.
{shift(wshare2, labels2, n_sat2)}

![RGBW + IR-cut kernels]({fig2})

{table2}
"""
    write_outputs(build, "kernels", md, {
        "classes": {lab: {"saturation": chosen[lab][0], "level": chosen[lab][1],
                          "level_value": float(lvals[chosen[lab][1]]), "channel_share": sums[lab]} for lab in labels},
        "classes_ircut": {lab: {"saturation": chosen2[lab][0], "level": chosen2[lab][1],
                                "level_value": float(lvals2[chosen2[lab][1]]), "channel_share": sums2[lab]}
                          for lab in labels2}})


if __name__ == "__main__":
    main(build_arg(__doc__))
