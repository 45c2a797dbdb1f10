"""ONNX Runtime (CPU) running an ``l3 export`` model vs l3's own render kernel, same run.

Usage::

    .venv/bin/python benchmarks/bench_export.py [--size 4000x3000] [--repeat 2]

A table with the layout ``l3 train`` gives pairs folders by default (RGGB,
patch 7, 24 levels x 3 contrast bins, merged positions, a learned tone curve;
random kernels: speed does not depend on the values) renders a synthetic
12 MP mosaic to float32 linear sRGB with :func:`l3cli.render.render_mosaic`
and with its exported model in ONNX Runtime's CPU provider (all cores,
default graph optimisations), interleaved, best of ``--repeat``; the two
outputs are checked to agree (max difference printed). Prints a Markdown
table with the ratio. Skips (exit 0, one line) when onnx/onnxruntime are not
installed (``pip install 'l3cli[export]'``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def pairs_default_table():
    """Random kernels in the layout of ``l3 train``'s pairs-folder defaults."""
    from l3cli.classify import ClassDefinition, level_cuts_between
    from l3cli.table import TransformTable

    d = ClassDefinition.build("RGGB", patch=7, level_cuts=level_cuts_between(2e-3, 0.9, 24),
                              contrast_cuts=[0.2, 0.4])
    nc, q = d.n_classes, d.n_coeffs
    rng = np.random.default_rng(1)
    k = (0.02 * rng.standard_normal((nc, q, 3))).astype(np.float32)
    k[:, q // 2, :] += 1.0
    x = np.linspace(0.0, 1.0, 1024)
    lut = np.stack([x ** 2.2] * 3, axis=1).astype(np.float32)
    return TransformTable(definition=d, kernels=k, counts=np.full(nc, 1000),
                          lambdas=np.zeros((nc, 3)), empty=np.zeros(nc, bool),
                          source_class=np.arange(nc), output_space="linear-srgb",
                          provenance={"benchmark": True},
                          tone_lut=(lut, np.array([[0.0] * 3, [1.0] * 3], np.float32)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="4000x3000")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    try:
        import onnxruntime as ort
    except ImportError:
        print("bench_export: skipped (onnxruntime is not installed: pip install 'l3cli[export]')")
        return 0
    from bench_render import synthetic_mosaic
    from common import peak_rss_mb

    from l3cli.export import build_model
    from l3cli.render import render_mosaic

    w, h = (int(v) for v in args.size.split("x"))
    mosaic = synthetic_mosaic(h, w)
    table = pairs_default_table()
    t0 = time.perf_counter()
    model = build_model(table).SerializeToString()
    t_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    sess = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
    t_load = time.perf_counter() - t0
    feed = {"mosaic": mosaic[None, None]}
    want = render_mosaic(table, mosaic)  # warm-up (numba compile / cache load)
    got = sess.run(None, feed)[0]
    diff = float(np.abs(got[0].transpose(1, 2, 0) - want).max())
    del got
    best_l3 = best_ort = float("inf")
    for _ in range(args.repeat):  # interleaved
        t0 = time.perf_counter()
        render_mosaic(table, mosaic, out=want)
        best_l3 = min(best_l3, time.perf_counter() - t0)
        t0 = time.perf_counter()
        sess.run(None, feed)
        best_ort = min(best_ort, time.perf_counter() - t0)
    mp = h * w / 1e6
    print(f"{w}x{h} ({mp:.1f} MP) RGGB mosaic, patch 7, {table.definition.n_classes} classes, "
          f"tone curve; onnxruntime {ort.__version__}; model {len(model) / 1e6:.1f} MB "
          f"(built in {t_build:.2f} s, session made in {t_load:.2f} s); best of {args.repeat}")
    print()
    print("| renderer | seconds | MP/s | vs l3 |")
    print("|---|---:|---:|---:|")
    print(f"| l3 render_mosaic (numba tile kernel) | {best_l3:.3f} | {mp / best_l3:.1f} | 1.00 |")
    print(f"| ONNX Runtime CPU, exported model | {best_ort:.3f} | {mp / best_ort:.1f} | "
          f"{best_ort / best_l3:.1f}x slower |")
    print()
    print(f"max |ONNX - l3| = {diff:.2e}; peak RSS {peak_rss_mb():.0f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
