"""Render throughput on a 12 MP Bayer mosaic vs LibRaw (rawpy) in the same process.

Usage::

    .venv/bin/python benchmarks/bench_render.py [--size 4000x3000] [--repeat 3]
        [--memory-size 6000x4000]

Builds a synthetic 12 MP RGGB mosaic (smooth colour field + texture + noise),
a table with the issue's layout (4 positions x 40 levels x 2 contrasts; random
kernels: speed does not depend on the values), writes the mosaic as a 12-bit
DNG, then times, interleaved and best of ``--repeat``:

* ``l3 render`` core (:func:`l3cli.render.render_mosaic`, mosaic in memory,
  float32 XYZ out), and the same straight to 8-bit display sRGB
  (:func:`l3cli.render.render_display`, the display encoding fused into the
  kernel: what ``l3 render`` does for JPEG/PNG, and what LibRaw's
  ``postprocess`` returns);
* rawpy ``postprocess`` with AHD, PPG and LINEAR demosaicing (file already
  opened and unpacked, 8-bit sRGB out);
* colour-demosaicing's Malvar (2004) and Menon (2007) demosaicking of the
  same mosaic in memory (pure numpy/scipy; timed once each, they are slow);
* the memory-bandwidth ceiling: a numpy copy of the bytes render must touch
  (mosaic in, 3-channel float32 out).

Peak memory of a 24 MP render (read DNG, render, write EXR) is measured in a
child process (``ru_maxrss``). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def synthetic_mosaic(h: int, w: int, seed: int = 0) -> np.ndarray:
    """A 12-bit-like RGGB mosaic in [0, 1] with smooth colour and texture."""
    rng = np.random.default_rng(seed)
    y = np.linspace(0, 1, h, dtype=np.float32)[:, None]
    x = np.linspace(0, 1, w, dtype=np.float32)[None, :]
    base = 0.05 + 0.4 * (0.5 + 0.5 * np.sin(6 * x + 3 * y)) * (0.3 + 0.7 * y)
    tex = 0.1 * np.sin(200 * x) * np.sin(150 * y)
    m = base + tex
    m[0::2, 0::2] *= 0.7
    m[1::2, 1::2] *= 0.5
    m += rng.normal(0, 0.005, m.shape).astype(np.float32)
    return np.clip(m, 0, 1).astype(np.float32)


def bench_table(levels: int = 40):
    from l3cli.classify import ClassDefinition, level_cuts_between
    from l3cli.table import TransformTable

    d = ClassDefinition.build("RGGB", patch=5, level_cuts=level_cuts_between(1e-3, 0.9, levels),
                              contrast_cuts=0.05)
    nc = d.n_classes
    rng = np.random.default_rng(1)
    k = (0.04 * rng.standard_normal((nc, 26, 3))).astype(np.float32)
    k[:, 12, :] += 1.0
    return TransformTable(definition=d, kernels=k, counts=np.full(nc, 1000), lambdas=np.zeros((nc, 3)),
                          empty=np.zeros(nc, bool), source_class=np.arange(nc),
                          provenance={"benchmark": True})


def _best(fn, repeat):
    """Best (wall, process CPU) seconds of ``repeat`` runs."""
    times = []
    for _ in range(repeat):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0, time.process_time() - c0))
    return min(times)


def memory_child(dng: str, table: str, out: str) -> None:
    from l3cli.render import render_file
    from l3cli.table import load_table

    render_file(load_table(table), dng, out)
    # VmHWM (peak RSS of this address space; ru_maxrss would include the
    # parent's memory inherited through fork + exec)
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            print(int(line.split()[1]))
            return
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="4000x3000")
    ap.add_argument("--memory-size", default="6000x4000")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        memory_child(*a.child)
        return
    import rawpy

    from l3cli.io.raw import write_raw
    from l3cli.render import render_display, render_mosaic
    from l3cli.table import save_table
    from l3cli.threads import tile_threads

    w, h = (int(v) for v in a.size.split("x"))
    mosaic = synthetic_mosaic(h, w)
    table = bench_table()
    tmp = Path(tempfile.mkdtemp(prefix="l3bench-"))
    dng = write_raw(tmp / "bench.dng", np.round(mosaic * 4095).astype(np.uint16), "RGGB",
                    white_level=4095)
    out = np.empty((h, w, 3), np.float32)
    out8 = np.empty((h, w, 3), np.uint8)
    render_mosaic(table, mosaic[:64, :64])  # compile / load the cache
    render_display(table, mosaic[:64, :64], 8)
    rows = {}
    with rawpy.imread(str(dng)) as raw:
        _ = raw.raw_image_visible  # unpack once
        algs = {"LibRaw AHD": rawpy.DemosaicAlgorithm.AHD,
                "LibRaw PPG": rawpy.DemosaicAlgorithm.PPG,
                "LibRaw LINEAR": rawpy.DemosaicAlgorithm.LINEAR}
        timings = {k: [] for k in ["l3 render", "l3 render → 8-bit sRGB (fused)", *algs,
                                   "numpy copy (bandwidth)"]}
        src = np.empty(mosaic.nbytes + out.nbytes, np.uint8)
        dst = np.empty_like(src)
        for _ in range(a.repeat):
            timings["l3 render"].append(_best(lambda: render_mosaic(table, mosaic, out=out), 1))
            timings["l3 render → 8-bit sRGB (fused)"].append(
                _best(lambda: render_display(table, mosaic, 8, out=out8), 1))
            for name, alg in algs.items():
                timings[name].append(_best(lambda alg=alg: raw.postprocess(demosaic_algorithm=alg), 1))
            timings["numpy copy (bandwidth)"].append(_best(lambda: np.copyto(dst, src), 1))
    import colour_demosaicing as cd

    cd_mosaic = mosaic.astype(np.float64)
    for name, fn in (("colour-demosaicing Malvar 2004", cd.demosaicing_CFA_Bayer_Malvar2004),
                     ("colour-demosaicing Menon 2007", cd.demosaicing_CFA_Bayer_Menon2007)):
        timings[name] = [_best(lambda fn=fn, m=cd_mosaic: fn(m, "RGGB"), 1)]
    del cd_mosaic
    mp = h * w / 1e6
    for k, v in timings.items():
        rows[k] = min(v)
    t_l3 = rows["l3 render"][0]
    print(f"12 MP render benchmark: {w}x{h} RGGB, table 4 positions x 40 levels x 2 contrasts "
          f"x 8 saturation patterns, tile threads {tile_threads()}, "
          f"cpus {os.cpu_count()}, load average {os.getloadavg()[0]:.1f}\n")
    print("| method | wall s | MP/s | l3 speed-up (wall) | process CPU s |")
    print("|---|---|---|---|---|")
    for k, (t, cpu) in rows.items():
        print(f"| {k} | {t:.3f} | {mp / t:.1f} | {t / t_l3:.2f}x | {cpu:.3f} |")
    t_copy = rows["numpy copy (bandwidth)"][0]
    print(f"\nl3 render runs at {100 * t_copy / t_l3:.0f} % of the memory-bandwidth ceiling "
          f"(a copy of the {(mosaic.nbytes + out.nbytes) / 1e6:.0f} MB it reads and writes takes "
          f"{t_copy * 1e3:.0f} ms): it is compute-bound.")
    # peak memory of a 24 MP render in a child process
    mw, mh = (int(v) for v in a.memory_size.split("x"))
    big = synthetic_mosaic(mh, mw, seed=2)
    big_dng = write_raw(tmp / "big.dng", np.round(big * 4095).astype(np.uint16), "RGGB",
                        white_level=4095)
    del big
    tpath = save_table(tmp / "table.npz", table)
    res = subprocess.run([sys.executable, __file__, "--child", str(big_dng), str(tpath),
                          str(tmp / "big.exr")], capture_output=True, text=True, check=True)
    peak_mb = int(res.stdout.strip().splitlines()[-1]) / 1024
    print(f"\nPeak memory (VmHWM) of read DNG + render + write EXR, {mw}x{mh} "
          f"({mw * mh / 1e6:.0f} MP): {peak_mb:.0f} MB")


if __name__ == "__main__":
    main()
