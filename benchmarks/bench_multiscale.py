"""Cost of the multi-scale stage (``l3 train --multiscale``, :mod:`l3cli.multiscale.stage`).

Usage::

    .venv/bin/python benchmarks/bench_multiscale.py TABLE.npz [--size 4000x3000] [--repeat 3]
        [--copies 4]

``TABLE.npz`` is a table trained with ``--multiscale`` (its stage is timed; the same
table without the stage is the baseline). Prints seconds per megapixel:

* *stage alone*: :func:`l3cli.multiscale.stage.apply_stage` (float) and
  :func:`l3cli.multiscale.stage.apply_display` (8-bit) on a float render of the
  synthetic mosaic of ``bench_render.py`` (its parts too: the coding, the features);
* *render stage*: :func:`l3cli.kernelset.render_display` 8-bit without the stage
  against the float render + the stage display-encoded row by row (what ``l3
  render`` does for TIFF, PNG and JPEG);
* *whole process*: ``l3 render`` of ``--copies`` headerless raws to JPEG, with and
  without the stage, best of ``--repeat`` interleaved rounds.
"""

from __future__ import annotations

import argparse
import copy
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from common import best_of  # noqa: E402


def _mosaic(h: int, w: int) -> np.ndarray:
    from bench_render import synthetic_mosaic

    return synthetic_mosaic(h, w)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("table")
    ap.add_argument("--size", default="4000x3000")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--copies", type=int, default=4)
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    mp = w * h / 1e6

    from l3cli.kernelset import render_display, render_mosaic
    from l3cli.multiscale import stage as ms
    from l3cli.table import load_table, save_table

    table = load_table(args.table)
    if table.multiscale is None:
        raise SystemExit(f"{args.table}: no multiscale stage (train with --multiscale)")
    plain = copy.copy(table)
    plain.multiscale = None
    stage = table.multiscale
    mosaic = _mosaic(h, w)
    y = render_mosaic(plain, mosaic)
    rows = []

    def per_mp(label, fn):
        t = best_of(fn, repeat=args.repeat)
        rows.append((label, t / mp))

    per_mp("stage alone, float (apply_stage)", lambda: ms.apply_stage(stage, y))
    per_mp("stage alone, 8-bit display (apply_display)",
           lambda: ms.apply_display(stage, y, table.output_space, 8))
    per_mp("  sRGB coding", lambda: ms.encode(y, stage.transfer))
    u = ms.encode(y, stage.transfer)
    per_mp("  features (feature_maps: what training computes)",
           lambda: ms.feature_maps(u, stage.sigmas))
    per_mp("render float, no stage", lambda: render_mosaic(plain, mosaic))
    per_mp("render 8-bit display, no stage (fused)", lambda: render_display(plain, mosaic, 8))
    per_mp("render float + stage, 8-bit display (fused)",
           lambda: ms.apply_display(stage, render_mosaic(plain, mosaic), table.output_space, 8,
                                    inplace=True))

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        save_table(tmp / "plain.npz", plain)
        save_table(tmp / "ms.npz", table)
        raws = []
        from l3cli.io.raw import write_raw

        dn = np.round(np.clip(mosaic, 0, 1) * 65535).astype(np.uint16)
        for i in range(args.copies):
            raws.append(write_raw(tmp / f"r{i}.dng", dn, table.cfa.spec))
        best = {"plain": np.inf, "ms": np.inf}
        for _ in range(args.repeat):
            for name in best:
                out = tmp / f"out_{name}"
                t0 = time.perf_counter()
                subprocess.run([sys.executable, "-m", "l3cli.cli.main", "-q", "render",
                                str(tmp / f"{name}.npz"), *map(str, raws), "-o", str(out),
                                "--format", "jpg"], check=True)
                best[name] = min(best[name], time.perf_counter() - t0)
        rows.append(("whole process l3 render -> JPEG, no stage", best["plain"] / mp / len(raws)))
        rows.append(("whole process l3 render -> JPEG, with stage", best["ms"] / mp / len(raws)))
    print(f"| {args.size} ({mp:.1f} MP), table {Path(args.table).name} | s / MP |")
    print("|---|---|")
    for label, v in rows:
        print(f"| {label} | {v:.3f} |")


if __name__ == "__main__":
    main()
