#!/usr/bin/env python3
"""Experiment 4: accuracy vs the number of response levels, log vs linear spacing.

``levels.py BUILD`` trains L3 tables for the Bayer camera of experiment 2
(``BUILD/sim/bayer/train``) with ``--levels N --spacing log|linear`` for each N
in :data:`LEVELS`, renders the held-out Macbeth captures with the table as
trained and after ``l3 smooth``, and writes ``BUILD/sections/levels.md``,
``BUILD/levels.json`` and docs/figures/levels.png.

Published (Jiang et al. 2017): log spacing helps when there are few levels;
beyond about 12–15 levels the spacing makes no difference.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from common import (
    build_arg,
    by_scene,
    captures,
    md_table,
    pyplot,
    save_figure,
    train_render_eval,
    write_outputs,
)

#: numbers of levels (3 would be degenerate: its two cut points are the ends of
#: the level range whatever the spacing)
LEVELS = (4, 8, 12, 24)
SPACINGS = ("log", "linear")
#: runs side by side (each is a chain of l3 processes); $PAPER_JOBS
JOBS = int(os.environ.get("PAPER_JOBS", "2"))


def main(build: Path) -> None:
    test_sim = build / "sim" / "bayer" / "test"

    def one(sp_n: tuple[str, int]) -> tuple[dict, dict]:
        sp, n = sp_n
        res = train_render_eval(build, f"levels_{sp}_{n:02d}", "bayer", eval_raw=True,
                                train_opts=("--levels", n, "--spacing", sp), scenes=("macbeth",))
        return (by_scene(res["report_raw"], test_sim, "macbeth", "macbeth_de_mean"),
                by_scene(res["report"], test_sim, "macbeth", "macbeth_de_mean"))

    runs = [(sp, n) for sp in SPACINGS for n in LEVELS]
    with ThreadPoolExecutor(max_workers=JOBS) as pool:
        results = list(pool.map(one, runs))
    de = {kind: {sp: {} for sp in SPACINGS} for kind in ("raw", "smooth")}
    for (sp, n), (raw, smo) in zip(runs, results, strict=True):
        de["raw"][sp][n] = raw
        de["smooth"][sp][n] = smo
    luxes = sorted(de["raw"]["log"][LEVELS[0]])
    mean = {k: {sp: {n: float(np.mean(list(de[k][sp][n].values()))) for n in LEVELS} for sp in SPACINGS}
            for k in de}

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.0))
    for ax, kind in zip(axes, ("raw", "smooth"), strict=True):
        for sp, m in zip(SPACINGS, ("o-", "s--"), strict=True):
            ax.plot(LEVELS, [mean[kind][sp][n] for n in LEVELS], m, label=f"{sp} spacing")
        ax.set_xlabel("number of response levels")
        ax.set_title(f"Macbeth ΔE*ab, mean over test levels\n({'as trained' if kind == 'raw' else 'after l3 smooth'})")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig_link = save_figure(fig, "levels")

    def table(kind: str) -> str:
        rows = [[n, mean[kind]["log"][n], mean[kind]["linear"][n]]
                + [f"{de[kind]['log'][n][x]:.2f} / {de[kind]['linear'][n][x]:.2f}" for x in luxes]
                for n in LEVELS]
        return md_table(["levels", "log: mean ΔE", "linear: mean ΔE"]
                        + [f"{x:g} lux (log / lin)" for x in luxes], rows)

    few, many = LEVELS[0], LEVELS[-1]
    gap = {k: {n: mean[k]["linear"][n] - mean[k]["log"][n] for n in LEVELS} for k in mean}
    dark = luxes[0]
    train_lux = ", ".join(f"{x:g}" for x in sorted({c["lux"] for c in captures(build / "sim" / "bayer" / "train").values()}))
    train_lux += " lux"
    per = {x: de["raw"]["linear"][many][x] - de["raw"]["log"][many][x] for x in luxes}
    gap_txt = ", ".join(f"{x:g} lux {v:+.2f}" for x, v in per.items())
    rest = [abs(per[x]) for x in luxes[1:]]
    dark_decides = abs(per[dark]) > 2 * max(rest) if rest else True
    from l3cli.table import load_table

    n_below = {sp: int(np.sum(load_table(build / "runs" / f"levels_{sp}_{many:02d}" / "table.raw.npz")
                              .definition.level_cuts < 0.1) + 1) for sp in SPACINGS}
    if dark_decides:
        why = (f"The difference comes from the darkest test level ({dark:g} lux). Log spacing cuts the "
               "dark range into many narrow bins (a fraction of a DN to a few DN wide). They are not short "
               "of samples (thousands per class), but the patch mean that picks the bin is itself noisy at "
               "these levels, and each narrow bin's kernel is fitted to the particular mixture of training "
               f"light levels (here {train_lux}) that lands in it; a test level between them gets a "
               "different mixture. Linear spacing pools all dark pixels into one bin whose kernel is an "
               "average over levels, which generalises better to an unseen dark level.")
    else:
        why = ("The difference is spread over the test levels, not held by the darkest one: under auto "
               "exposure (with auto gain below its time cap) the chart's patches sit at the same response "
               "levels at every test level, from a few hundredths to about a third of white, and linear "
               "spacing puts more of its bins there, log spacing more into the dark range below them "
               f"({n_below['log']} of {many} log bins start below 0.1 of white, {n_below['linear']} linear ones).")
    md = f"""## 4. Number of response levels, log vs linear spacing

The Bayer camera of experiment 2, trained with `l3 train --levels N --spacing
log|linear` and tested on the held-out Macbeth captures at {len(luxes)} light
levels, with the tables as trained and after `l3 smooth` (whose spline over
levels also regularises sparsely sampled level bins); mean Macbeth ΔE*ab over
the test levels, and per level (log / linear).

As trained:

{table('raw')}

After `l3 smooth`:

{table('smooth')}

![ΔE vs number of levels]({fig_link})

Published: log spacing helps when there are few levels; beyond about 12–15
levels the spacing makes no difference. Ours (linear minus log, mean ΔE; positive =
log better): as trained {', '.join(f'{n} levels {gap["raw"][n]:+.2f}' for n in LEVELS)};
smoothed {', '.join(f'{n} levels {gap["smooth"][n]:+.2f}' for n in LEVELS)}.
{'Log spacing helps with few levels, as published.' if gap['raw'][few] > 0.1 else 'Log spacing does not help with few levels here: l3 falls short of the published finding.'}
{'With many levels the spacing matters little, as published.' if abs(gap['raw'][many]) < 0.3 else f'With {many} levels the spacing still matters (as trained), unlike the published result.'}
With {many} levels, as trained, linear minus log per test level: {gap_txt}.
{why}
Smoothing over levels (default strength) changes {many} log levels by
{mean['smooth']['log'][many] - mean['raw']['log'][many]:+.2f} and {many} linear levels by
{mean['smooth']['linear'][many] - mean['raw']['linear'][many]:+.2f} (the spline runs over ln(level), on
which linear bins crowd together at the bright end, so it pulls their kernels
together there). The paper's training set covered the light levels far
more densely.
"""
    write_outputs(build, "levels", md, {
        "levels": list(LEVELS), "mean": mean["raw"], "mean_smooth": mean["smooth"],
        "dark_level_decides": bool(dark_decides),
        "per_lux": {k: {sp: {str(n): {str(x): v for x, v in de[k][sp][n].items()} for n in LEVELS}
                        for sp in SPACINGS} for k in de}})


if __name__ == "__main__":
    main(build_arg(__doc__))
