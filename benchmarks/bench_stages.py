"""Per-stage CPU seconds of one raw file's render, on one core: where a file's time goes.

Usage::

    NUMBA_NUM_THREADS=1 taskset -c 0 .venv/bin/python benchmarks/bench_stages.py [--dng PATH]
        [--repeat 5]

For one real 9-MP DNG (default: the Blackmagic Pocket 4K frame of the shared
data set) and tables of the two default layouts with random kernels (speed
does not depend on the values): pairs (patch 7, 36 levels x 3 contrasts,
linear sRGB out) and simulate (patch 5, 24 levels x 2 contrasts, XYZ out),
the process CPU seconds (user + system, best of ``--repeat``) of

* decode (:func:`l3cli.io.raw.read_raw`);
* classify only (:func:`l3cli.classify.classify`);
* the float render (:func:`l3cli.render.render_mosaic`, what EXR gets);
* the display render, 8 and 16 bits (:func:`l3cli.render.render_display`,
  what JPEG/PNG and TIFF get: for 8 bits render and display encoding fused in
  the kernel), beside the whole-image two-step path (float render, then
  :func:`l3cli.io.encode.display_encode`) with a check that both give the same
  integers;
* writing JPEG (quality 95, 4:4:4) and uncompressed 16-bit TIFF
  (:func:`l3cli.io.image.write_image`).

Run it on one core with one tile thread for per-stage numbers (the machine
may be shared: CPU time, not wall time). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

DEFAULT_DNG = REPO.parent / "shared" / "data" / "raw" / "misc" / "blackmagic_pocket4k_rggb.dng"


def layout_table(cfa: str, patch: int, levels: int, contrasts: int, space: str):
    """A table of a default layout (level cuts log-spaced) with random kernels."""
    from l3cli.classify import ClassDefinition, level_cuts_between
    from l3cli.table import TransformTable

    cuts = np.linspace(0.05, 0.3, contrasts - 1) if contrasts > 2 else 0.05
    d = ClassDefinition.build(cfa, patch=patch, level_cuts=level_cuts_between(1e-3, 0.9, levels),
                              contrast_cuts=cuts)
    nc, q = d.n_classes, patch * patch + 1
    k = (0.04 * np.random.default_rng(1).standard_normal((nc, q, 3))).astype(np.float32)
    k[:, q // 2, :] += 1.0
    return TransformTable(definition=d, kernels=k, counts=np.full(nc, 1000),
                          lambdas=np.zeros((nc, 3)), empty=np.zeros(nc, bool),
                          source_class=np.arange(nc), output_space=space,
                          provenance={"benchmark": True})


def cpu_best(fn, repeat: int) -> float:
    """Best process CPU seconds (user + system) of ``repeat`` calls."""
    best = float("inf")
    for _ in range(repeat):
        t = time.process_time()
        fn()
        best = min(best, time.process_time() - t)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dng", type=Path, default=DEFAULT_DNG)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    if not a.dng.exists():
        print(f"(skipped: {a.dng} is not here; it is in the shared data set)")
        return
    from l3cli.classify import classify
    from l3cli.io.encode import display_encode
    from l3cli.io.image import write_image
    from l3cli.io.raw import read_raw
    from l3cli.render import render_display, render_mosaic
    from l3cli.threads import tile_threads

    raw = read_raw(a.dng)
    m = raw.mosaic
    h, w = m.shape
    rows = [("decode (read_raw: LibRaw, or l3 for lossy DNGs; normalise)", cpu_best(lambda: read_raw(a.dng), a.repeat), "")]
    tmp = Path(tempfile.mkdtemp(prefix="l3stages-"))
    layouts = {"pairs (patch 7, linear sRGB)": (7, 36, 3, "linear-srgb"),
               "simulate (patch 5, XYZ)": (5, 24, 2, "xyz")}
    img = np.empty((h, w, 3), np.float32)
    for name, (patch, levels, contrasts, space) in layouts.items():
        t = layout_table(raw.cfa.spec, patch, levels, contrasts, space)
        small = m[:64, :64]
        render_mosaic(t, small)
        render_display(t, small, 8)
        display_encode(render_mosaic(t, small), space, 8)
        rows.append((f"{name}: classify", cpu_best(lambda t=t: classify(m, t.definition),
                                                   a.repeat), ""))
        rows.append((f"{name}: float render", cpu_best(
            lambda t=t: render_mosaic(t, m, out=img), a.repeat), ""))
        for bits in (8, 16):
            fused = cpu_best(lambda t=t, b=bits: render_display(t, m, b), a.repeat)
            two = cpu_best(lambda t=t, b=bits, s=space: display_encode(
                render_mosaic(t, m, out=img), s, b), a.repeat)
            same = np.array_equal(render_display(t, m, bits),
                                  display_encode(render_mosaic(t, m), space, bits))
            rows.append((f"{name}: display render {bits}-bit", fused,
                         "same integers as two-step" if same else "DIFFERS from two-step"))
            rows.append((f"{name}: render, then display_encode {bits}-bit", two, ""))
    t = layout_table(raw.cfa.spec, 7, 36, 3, "linear-srgb")
    out8, out16 = render_display(t, m, 8), render_display(t, m, 16)
    rows.append(("write JPEG q95 4:4:4", cpu_best(
        lambda: write_image(tmp / "a.jpg", out8, space="srgb", quality=95), a.repeat), ""))
    rows.append(("write TIFF 16-bit, uncompressed", cpu_best(
        lambda: write_image(tmp / "a.tif", out16, space="srgb", compression="none"),
        a.repeat), ""))
    print(f"Per-stage CPU of one {w}x{h} ({w * h / 1e6:.1f} MP) raw ({a.dng.name}), "
          f"tile threads {tile_threads()}, load average {os.getloadavg()[0]:.1f}, "
          f"best of {a.repeat}\n")
    print("| stage | CPU s | note |")
    print("|---|---|---|")
    for name, sec, note in rows:
        print(f"| {name} | {sec:.3f} | {note} |")


if __name__ == "__main__":
    main()
