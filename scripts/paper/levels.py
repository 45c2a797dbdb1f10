#!/usr/bin/env python3
"""Experiment 4: accuracy vs the number of response levels, log vs linear spacing.

``levels.py BUILD`` trains L3 tables for the Bayer camera of experiment 2
(``BUILD/sim/bayer/train``) with ``--levels N --spacing log|linear`` for each N
in :data:`LEVELS` (tables as trained, no smoothing: the spline prior would
blur the level structure under test), renders the held-out Macbeth captures
and writes ``BUILD/sections/levels.md``, ``BUILD/levels.json`` and
docs/figures/levels.png.

Published (Jiang et al. 2017): log spacing helps when there are few levels;
beyond about 12–15 levels the spacing makes no difference.
"""

from __future__ import annotations

import os
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from common import by_scene, md_table, pyplot, save_figure, train_render_eval, write_outputs

LEVELS = (3, 6, 12, 24)
#: runs side by side (each is a chain of l3 processes); $PAPER_JOBS
JOBS = int(os.environ.get("PAPER_JOBS", "2"))
SPACINGS = ("log", "linear")


def main(build: Path) -> None:
    test_sim = build / "sim" / "bayer" / "test"
    def one(sp_n: tuple[str, int]) -> dict[float, float]:
        sp, n = sp_n
        res = train_render_eval(build, f"levels_{sp}_{n:02d}", "bayer", smooth=False,
                                train_opts=("--levels", n, "--spacing", sp), scenes=("macbeth",))
        return by_scene(res["report"], test_sim, "macbeth", "macbeth_de_mean")

    runs = [(sp, n) for sp in SPACINGS for n in LEVELS]
    with ThreadPoolExecutor(max_workers=JOBS) as pool:
        results = list(pool.map(one, runs))
    de: dict[str, dict[int, dict[float, float]]] = {s: {} for s in SPACINGS}
    for (sp, n), r in zip(runs, results, strict=True):
        de[sp][n] = r
    luxes = sorted(de["log"][LEVELS[0]])
    mean = {sp: {n: float(np.mean(list(de[sp][n].values()))) for n in LEVELS} for sp in SPACINGS}

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.0))
    for sp, m in zip(SPACINGS, ("o-", "s--"), strict=True):
        axes[0].plot(LEVELS, [mean[sp][n] for n in LEVELS], m, label=f"{sp} spacing")
    axes[0].set_xlabel("number of response levels")
    axes[0].set_title("Macbeth mean ΔE*ab, mean over test levels")
    axes[0].legend(fontsize=7)
    for x in luxes:
        axes[1].plot(LEVELS, [de["linear"][n][x] / de["log"][n][x] for n in LEVELS], "o-", label=f"{x:g} lux")
    axes[1].axhline(1.0, color="k", lw=0.8)
    axes[1].set_xlabel("number of response levels")
    axes[1].set_title("ΔE ratio linear / log, per test light level")
    axes[1].legend(fontsize=6)
    fig.tight_layout()
    fig_link = save_figure(fig, "levels")

    rows = []
    for n in LEVELS:
        rows.append([n, mean["log"][n], mean["linear"][n]]
                    + [f"{de['log'][n][x]:.2f} / {de['linear'][n][x]:.2f}" for x in luxes])
    table = md_table(["levels", "log: mean ΔE", "linear: mean ΔE"]
                     + [f"{x:g} lux (log / lin)" for x in luxes], rows)
    few, many = LEVELS[0], LEVELS[-1]
    gain_few = mean["linear"][few] - mean["log"][few]
    gain_many = mean["linear"][many] - mean["log"][many]
    md = f"""## 4. Number of response levels, log vs linear spacing

The Bayer camera of experiment 2, trained with `l3 train --levels N --spacing
log|linear` (tables as trained: `l3 smooth`'s spline over levels would hide
the effect) and tested on the held-out Macbeth captures at {len(luxes)} light
levels; mean Macbeth ΔE*ab over the test levels, and per level (log / linear).

{table}

![ΔE vs number of levels]({fig_link})

Published: log spacing helps when there are few levels; beyond about 12–15
levels the spacing makes no difference. Ours: with {few} levels, linear
spacing is {'worse' if gain_few > 0 else 'better'} by {abs(gain_few):.2f} ΔE
(mean over test levels); with {many} levels the difference is
{gain_many:+.2f}. {'This agrees with the published finding.' if gain_few > 0 and abs(gain_many) < abs(gain_few) else 'This does not reproduce the published finding plainly; see the per-level columns.'}
Linear spacing puts almost all cut points above the darkest test levels, so
the dark captures share one or two classes with very different noise, which
is where log spacing helps; l3's level classes also carry a contrast bin and
a saturation pattern, so even few levels are not as coarse as in the paper.
"""
    write_outputs(build, "levels", md, {"levels": list(LEVELS), "mean": mean,
                                        "per_lux": {sp: {str(n): {str(k): v for k, v in de[sp][n].items()}
                                                         for n in LEVELS} for sp in SPACINGS}})


if __name__ == "__main__":
    main(Path(sys.argv[1]))
