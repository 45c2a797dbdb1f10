#!/usr/bin/env python3
"""Experiment 5: patch size 5x5 vs 7x7 vs 9x9 — accuracy and cost.

``patch.py BUILD`` trains and smooths L3 tables for the RGBW camera
(``BUILD/sim/rgbw/train``) with ``--patch 5|7|9``, renders all held-out
captures, evaluates them, and writes ``BUILD/sections/patch.md``,
``BUILD/patch.json`` and docs/figures/patch.png. Cost is reported both as
kernel coefficients per output pixel (machine-independent) and as measured
wall-clock train and render times (on a shared machine: indicative only).

Published (Jiang et al. 2017): little gain beyond 5x5, while the cost
doubles (7x7) or triples (9x9).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from common import (
    build_arg,
    by_scene,
    md_table,
    plain_log,
    pyplot,
    raws_of,
    save_figure,
    train_render_eval,
    write_outputs,
)

PATCHES = (5, 7, 9)


def render_throughput(table_path: Path, raw_path: Path, *, megapixels: float = 4.0) -> float:
    """In-process render throughput (Mpixel/s, best of 5) of a table on a tiled raw.

    The raw is tiled (whole CFA repeats) to about ``megapixels``; a first call on
    a crop compiles the kernels, so process start-up and JIT are excluded.
    """
    import time

    from l3cli.io.raw import read_raw
    from l3cli.render import render_mosaic
    from l3cli.table import load_table

    table = load_table(table_path)
    mosaic = read_raw(raw_path).mosaic
    ph, pw = table.cfa.period
    h, w = (mosaic.shape[0] // ph) * ph, (mosaic.shape[1] // pw) * pw
    reps = max(1, int(round((megapixels * 1e6 / (h * w)) ** 0.5)))
    big = np.tile(mosaic[:h, :w], (reps, reps))
    render_mosaic(table, big[: 8 * ph, : 8 * pw])
    out = render_mosaic(table, big)  # also touches the output's pages once
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        render_mosaic(table, big, out=out)
        best = min(best, time.perf_counter() - t0)
    return big.size / best / 1e6


def main(build: Path) -> None:
    test_sim = build / "sim" / "rgbw" / "test"
    res = {}
    for p in PATCHES:
        r = train_render_eval(build, f"patch_{p}", "rgbw", train_opts=("--patch", p))
        res[p] = {
            "de": by_scene(r["report"], test_sim, "macbeth", "macbeth_de_mean"),
            "scielab": by_scene(r["report"], test_sim, "macbeth", "scielab_mean"),
            "mtf50": by_scene(r["report"], test_sim, "slanted-edge", "mtf50_cy_per_mm"),
            "train_s": r["train_s"], "smooth_s": r["smooth_s"], "render_s": r["render_s"],
            "coeffs": p * p + 1,
        }
        res[p]["mpix_per_s"] = render_throughput(r["table"], raws_of(test_sim, scene="macbeth")[-1])
    luxes = sorted(res[5]["de"])
    for p in PATCHES:
        res[p]["de_mean"] = float(np.mean(list(res[p]["de"].values())))
        res[p]["scielab_mean"] = float(np.mean(list(res[p]["scielab"].values())))
        res[p]["mtf50_mean"] = float(np.mean(list(res[p]["mtf50"].values())))

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.0))
    for p in PATCHES:
        axes[0].plot(luxes, [res[p]["de"][x] for x in luxes], "o-", label=f"{p}x{p}")
    plain_log(axes[0], x=True)
    axes[0].set_xlabel("scene illuminance (lux)")
    axes[0].set_title("RGBW Macbeth mean ΔE*ab")
    axes[0].legend(fontsize=7)
    x = np.arange(len(PATCHES))
    axes[1].bar(x - 0.2, [res[p]["coeffs"] / res[5]["coeffs"] for p in PATCHES], 0.4, label="coefficients")
    axes[1].bar(x + 0.2, [res[5]["mpix_per_s"] / res[p]["mpix_per_s"] for p in PATCHES], 0.4,
                label="render time (in-process)")
    axes[1].set_xticks(x, [f"{p}x{p}" for p in PATCHES])
    axes[1].set_title("cost relative to 5x5")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig_link = save_figure(fig, "patch")

    rows = [[f"{p}x{p}", res[p]["de_mean"], res[p]["scielab_mean"], res[p]["mtf50_mean"],
             res[p]["coeffs"], res[p]["train_s"], res[p]["mpix_per_s"]]
            for p in PATCHES]
    table = md_table(["patch", "Macbeth ΔE (mean over levels)", "S-CIELAB (Macbeth)",
                      "MTF50 cy/mm (mean)", "coefficients / output", "`l3 train` s",
                      "render Mpixel/s (in-process)"], rows)
    d7 = res[7]["de_mean"] - res[5]["de_mean"]
    d9 = res[9]["de_mean"] - res[5]["de_mean"]
    md = f"""## 5. Patch size

The RGBW camera of experiment 2 trained and smoothed with `--patch 5`, `7`
and `9`, tested on the same held-out captures (Macbeth: ΔE and S-CIELAB;
slanted edge: MTF50; all means over the {len(luxes)} test light levels). Time
columns are wall-clock on the machine that ran `make paper` (shared with
other jobs while these numbers were made: indicative only); the
coefficient count is the machine-independent cost of rendering one output
channel of one pixel.

{table}

![patch size]({fig_link})

Published: little gain beyond 5x5 while the cost doubles (7x7) or triples
(9x9). Ours: 7x7 changes the mean ΔE by {d7:+.2f} and 9x9 by {d9:+.2f}
relative to 5x5, at {res[7]['coeffs'] / res[5]['coeffs']:.1f}x and
{res[9]['coeffs'] / res[5]['coeffs']:.1f}x the coefficients
(render time {res[5]['mpix_per_s'] / res[7]['mpix_per_s']:.1f}x and
{res[5]['mpix_per_s'] / res[9]['mpix_per_s']:.1f}x, measured in-process on a
~4-megapixel tiling of a test raw; the `l3 train` times of these small
training sets are dominated by process start-up and, the first time a patch
size is used on a machine, by numba compiling its kernels, ~20 s, cached
afterwards).
{'l3 renders larger patches at much less than their coefficient ratio: classifying each pixel (which grows only with the side of the patch, not its area) costs as much as the multiply-adds at 5x5, so the published doubling/tripling of cost does not carry over.' if res[5]['mpix_per_s'] / res[9]['mpix_per_s'] < 0.7 * res[9]['coeffs'] / res[5]['coeffs'] else 'Render time grows roughly with the coefficient count, as published.'}
{'Unlike the published result, larger patches gain clearly here' if min(d7, d9) < -0.3 else 'As published, larger patches gain little'}: our RGBW
mosaic (one R, G, B and W per 2x2 repeat) puts 4–9 pixels of each channel in
a 5x5 patch; a 7x7 or 9x9 patch averages more of them against noise, but
needs more training data per class (more coefficients, so more classes fall
below `--min-samples` and are filled by the spline).
"""
    write_outputs(build, "patch", md, {str(p): {k: (v if not isinstance(v, dict) else {str(a): b for a, b in v.items()})
                                                for k, v in res[p].items()} for p in PATCHES})


if __name__ == "__main__":
    main(build_arg(__doc__))
