"""Render cost of a learned tone curve (l3cli.tone.curve): 12 MP, with and without.

Usage::

    .venv/bin/python benchmarks/bench_tonecurve.py [--size 4000x3000] [--repeat 5] [--layout 7,36,3]

Times :func:`l3cli.render.render_mosaic` on the synthetic mosaic of
``bench_render.py`` with a table of the given layout (``--layout``), once as trained without a curve and once with a
1024-entry look-up table per channel, interleaved; reports the best wall
time and the process CPU seconds (user + sys, all threads) of each, and
their ratio. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import synthetic_mosaic  # noqa: E402


def layout_table(patch: int, levels: int, bins: int):
    """A table of the given layout (random kernels: speed does not depend on the values)."""
    from l3cli.classify import ClassDefinition, level_cuts_between
    from l3cli.table import TransformTable

    cuts = [0.1 * (k + 1) for k in range(bins - 1)] if bins > 1 else []
    d = ClassDefinition.build("RGGB", patch=patch, contrast_cuts=np.array([cuts] * levels),
                              level_cuts=level_cuts_between(1e-3, 0.9, levels))
    nc, q = d.n_classes, d.n_coeffs
    k = (0.04 * np.random.default_rng(1).standard_normal((nc, q, 3))).astype(np.float32)
    k[:, (q - 1) // 2, :] += 1.0
    return TransformTable(definition=d, kernels=k, counts=np.full(nc, 1000),
                          lambdas=np.zeros((nc, 3)), empty=np.zeros(nc, bool),
                          source_class=np.arange(nc), provenance={"benchmark": True})


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="4000x3000")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--layout", default="7,36,3",
                    help="PATCH,LEVELS,CONTRAST_BINS of the table (default: pairs folders' "
                         "defaults; bench_render.py uses 5,40,2)")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    from l3cli.render import render_mosaic
    from l3cli.tone.curve import ToneCurve

    mosaic = synthetic_mosaic(h, w)
    patch, levels, bins = (int(v) for v in args.layout.split(","))
    plain = layout_table(patch, levels, bins)
    curved = layout_table(patch, levels, bins)
    knots = np.stack([np.linspace(0, 1, 17) ** 2.2] * plain.n_out, axis=1)
    curved.tone_lut = ToneCurve(knots).lut("linear-srgb")
    out = np.empty((h, w, plain.n_out), dtype=np.float32)
    for t in (plain, curved):
        render_mosaic(t, mosaic[:64, :64])  # compile / load the cache
    res: dict[str, list[tuple[float, float]]] = {"without curve": [], "with curve": []}
    for _ in range(args.repeat):
        for name, t in (("without curve", plain), ("with curve", curved)):
            c0, w0 = _cpu(), time.perf_counter()
            render_mosaic(t, mosaic, out=out)
            res[name].append((time.perf_counter() - w0, _cpu() - c0))
    print(f"{w}x{h}, layout {args.layout}, best of {args.repeat}, "
          f"load average {os.getloadavg()[0]:.2f}\n")
    print("| render | wall s | CPU s |\n|---|---|---|")
    best = {k: (min(v[0] for v in r), min(v[1] for v in r)) for k, r in res.items()}
    for k, (wall, cpu) in best.items():
        print(f"| {k} | {wall:.3f} | {cpu:.3f} |")
    a, b = best["without curve"], best["with curve"]
    print(f"\nratio with/without: wall {b[0] / a[0]:.3f}, CPU {b[1] / a[1]:.3f}")


if __name__ == "__main__":
    main()
