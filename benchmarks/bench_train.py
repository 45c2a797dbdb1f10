"""Training throughput: sufficient-statistics accumulation in patches per second.

Usage::

    .venv/bin/python benchmarks/bench_train.py [--size 4000x3000] [--repeat 3]

Times :func:`l3cli.train.stats.accumulate` (classification, class-sorted
gather, per-class XᵀX / XᵀY / Σy² in float64) on a synthetic 12 MP RGGB
mosaic with a random 3-channel target, 5x5 patches, 24 levels x 2 contrasts,
and the ridge/GCV solve of all classes. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="4000x3000")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    import numba

    from benchmarks.bench_render import synthetic_mosaic
    from l3cli.classify import ClassDefinition, level_cuts_between
    from l3cli.train import ClassStats, TrainOptions, accumulate, table_from_stats

    w, h = (int(v) for v in a.size.split("x"))
    mosaic = synthetic_mosaic(h, w)
    target = np.random.default_rng(3).random((h, w, 3), dtype=np.float32)
    d = ClassDefinition.build("RGGB", patch=5, level_cuts=level_cuts_between(1e-3, 0.9, 24),
                              contrast_cuts=0.05)
    warm = ClassStats.zeros(d, 3)
    accumulate(warm, mosaic[:64, :64], target[:64, :64])
    times = []
    for _ in range(a.repeat):
        stats = ClassStats.zeros(d, 3)
        t0 = time.perf_counter()
        accumulate(stats, mosaic, target)
        times.append(time.perf_counter() - t0)
    t = min(times)
    t0 = time.perf_counter()
    table = table_from_stats(stats, TrainOptions(min_samples_factor=3))
    t_solve = time.perf_counter() - t0
    n = h * w
    print(f"Training benchmark: {w}x{h} RGGB, 5x5 patches, {d.n_classes} classes, numba threads "
          f"{numba.get_num_threads()}, cpus {os.cpu_count()}, load average "
          f"{os.getloadavg()[0]:.1f}\n")
    print("| step | seconds | throughput |")
    print("|---|---|---|")
    print(f"| accumulate statistics | {t:.3f} | {n / t / 1e6:.2f} M patches/s |")
    print(f"| ridge + GCV solve ({int((~table.empty).sum())} trained classes) | {t_solve:.3f} | "
          f"{(~table.empty).sum() / t_solve:.0f} classes/s |")


if __name__ == "__main__":
    main()
