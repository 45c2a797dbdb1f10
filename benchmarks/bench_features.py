"""Render speed with the optional class features (orientation, context) on and off.

Usage::

    .venv/bin/python benchmarks/bench_features.py [--size 4000x3000] [--repeat 5] [--patch 7]

Times :func:`l3cli.render.render_mosaic` on the synthetic mosaic of
``bench_render.py`` for tables of the same level/contrast layout with no
extra feature, orientation bins, a context dimension, and both; the runs
are interleaved (one of each per round) and the best of ``--repeat`` rounds
is reported, with the ratio to the table without features. Prints a
Markdown table.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from bench_render import synthetic_mosaic  # noqa: E402

VARIANTS = {
    "no extra feature": {},
    "orientation 4": {"orientation_bins": 4},
    "orientation 8": {"orientation_bins": 8},
    "context 64 px, 3 bins (ratio)": {"context_block": 64, "context_cuts": [0.8, 1.25],
                                      "context_rule": "ratio"},
    "orientation 4 + context": {"orientation_bins": 4, "context_block": 64,
                                "context_cuts": [0.8, 1.25], "context_rule": "ratio"},
    "no extra feature (again, last in each round)": {},
}


def table(patch: int, levels: int = 24, **features):
    from l3cli.classify import ClassDefinition, level_cuts_between
    from l3cli.table import TransformTable

    d = ClassDefinition.build("RGGB", patch=patch,
                              level_cuts=level_cuts_between(1e-3, 0.9, levels),
                              contrast_cuts=0.05, **features)
    nc, q = d.n_classes, d.n_coeffs
    rng = np.random.default_rng(1)
    k = (0.04 * rng.standard_normal((nc, q, 3))).astype(np.float32)
    k[:, q // 2, :] += 1.0
    return TransformTable(definition=d, kernels=k, counts=np.full(nc, 1000),
                          lambdas=np.zeros((nc, 3)), empty=np.zeros(nc, bool),
                          source_class=np.arange(nc), provenance={"benchmark": True})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="4000x3000")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--patch", type=int, default=7)
    args = ap.parse_args()
    from l3cli.render import render_mosaic

    w, h = (int(v) for v in args.size.split("x"))
    m = synthetic_mosaic(h, w)
    tables = {name: table(args.patch, **kw) for name, kw in VARIANTS.items()}
    out = np.empty((h, w, 3), dtype=np.float32)
    for t in tables.values():  # compile and warm up
        render_mosaic(t, m[:64, :64].copy())
    best = {name: np.inf for name in tables}
    for _ in range(args.repeat):
        for name, t in tables.items():
            t0 = time.perf_counter()
            render_mosaic(t, m, out=out)
            best[name] = min(best[name], time.perf_counter() - t0)
    ref = best["no extra feature"]
    print(f"render {w}x{h}, patch {args.patch}, best of {args.repeat} interleaved rounds\n")
    print("| table | classes | s | MP/s | vs no feature |")
    print("|---|---:|---:|---:|---:|")
    for name, t in tables.items():
        print(f"| {name} | {t.definition.n_classes} | {best[name]:.3f} | "
              f"{w * h / best[name] / 1e6:.1f} | {best[name] / ref:.2f}x |")


if __name__ == "__main__":
    main()
