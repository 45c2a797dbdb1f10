"""ONNX Runtime (CPU) running an ``l3 export`` model vs l3's own render kernel, same frame.

Usage::

    .venv/bin/python benchmarks/bench_export.py [--size 4000x3000] [--repeat 2]

A table with the layout ``l3 train`` gives pairs folders by default (RGGB,
patch 7, 24 levels x 3 contrast bins, merged positions, a learned tone curve;
random kernels: speed does not depend on the values) renders a synthetic
12 MP mosaic to float32 linear sRGB, once with
:func:`l3cli.render.render_mosaic` and once with its exported model in ONNX
Runtime's CPU provider: one ``sess.run`` of the frame (all cores, default
session options), and :func:`l3cli.export.runner.run_strips` (a strip per
core on single-threaded sessions in parallel threads). Each renderer
runs in a child process of its own (warm-up run, then best of ``--repeat``),
which reports its wall time, its CPU time (user + system, all threads: the
fairer measure on a machine shared with other jobs) and its peak resident
memory (``resource.getrusage``: the whole process, inputs and Python
included); the two outputs are checked to agree (max difference printed).
Prints a Markdown table with the ratios. Skips (exit 0, one line) when
onnx/onnxruntime are not installed (``pip install 'l3cli[export]'``).
"""

from __future__ import annotations

import argparse
import json
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


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def child(which: str, size: str, repeat: int, out: str, threads: int | None = None) -> dict:
    """One renderer's run in this (child) process: times, peak RSS; output saved to ``out``."""
    from bench_render import synthetic_mosaic

    w, h = (int(v) for v in size.split("x"))
    mosaic = synthetic_mosaic(h, w)
    table = pairs_default_table()
    info: dict = {}
    if which == "l3":
        from l3cli.render import render_mosaic

        img = render_mosaic(table, mosaic)  # warm-up (numba compile / cache load)

        def run():
            render_mosaic(table, mosaic, out=img)
    else:  # "onnx": one sess.run of the frame; "strips": l3cli.export.runner.run_strips
        import onnxruntime as ort

        from l3cli.export import build_model

        t0 = time.perf_counter()
        model = build_model(table).SerializeToString()
        info["build_s"] = time.perf_counter() - t0
        info["model_mb"] = len(model) / 1e6
        info["ort"] = ort.__version__
        t0 = time.perf_counter()
        if which == "strips":
            from l3cli.export.runner import run_strips, strip_session

            sess = strip_session(model)
        else:
            so = ort.SessionOptions()
            if threads:
                so.intra_op_num_threads = threads
            sess = ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])
        info["session_s"] = time.perf_counter() - t0
        feed = {"mosaic": mosaic[None, None]}

        def run():
            if which == "strips":
                return run_strips(sess, mosaic[None, None], threads=threads)
            return sess.run(None, feed)[0]
        img = run()  # warm-up
    best_wall = best_cpu = float("inf")
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), _cpu()
        run()
        best_wall = min(best_wall, time.perf_counter() - t0)
        best_cpu = min(best_cpu, _cpu() - c0)
    np.save(out, img if which == "l3" else np.asarray(img)[0].transpose(1, 2, 0))
    info.update(wall_s=best_wall, cpu_s=best_cpu,
                peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    return info


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="4000x3000")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--threads", type=int, default=None,
                    help="threads of every renderer (l3: NUMBA_NUM_THREADS; ONNX Runtime: "
                         "intra-op threads of the one session, strips of run_strips); "
                         "default: l3's and ONNX Runtime's defaults, a strip per core")
    ap.add_argument("--child", choices=("l3", "onnx", "strips"), help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.size, args.repeat, args.out, args.threads)))
        return 0
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        print("bench_export: skipped (onnxruntime is not installed: pip install 'l3cli[export]')")
        return 0
    res = {}
    with tempfile.TemporaryDirectory() as tmp:
        for which in ("l3", "onnx", "strips"):
            out = os.path.join(tmp, f"{which}.npy")
            cmd = [sys.executable, __file__, "--child", which, "--size", args.size,
                   "--repeat", str(args.repeat), "--out", out]
            env = dict(os.environ)
            if args.threads:
                cmd += ["--threads", str(args.threads)]
                env["NUMBA_NUM_THREADS"] = str(args.threads)
            proc = subprocess.run(cmd, capture_output=True, text=True, check=True, env=env)
            res[which] = json.loads(proc.stdout.strip().splitlines()[-1])
        want = np.load(os.path.join(tmp, "l3.npy"))
        diff = max(float(np.abs(np.load(os.path.join(tmp, f"{k}.npy")) - want).max())
                   for k in ("onnx", "strips"))
    w, h = (int(v) for v in args.size.split("x"))
    mp = h * w / 1e6
    o, l3 = res["onnx"], res["l3"]
    print(f"{w}x{h} ({mp:.1f} MP) RGGB mosaic, patch 7, 2304 classes, tone curve; onnxruntime "
          f"{o['ort']}; model {o['model_mb']:.1f} MB (built in {o['build_s']:.2f} s, session "
          f"made in {o['session_s']:.2f} s); best of {args.repeat}; {os.cpu_count()} cores, "
          f"threads {args.threads or 'default'}, "
          f"load average {os.getloadavg()[0]:.1f}")
    print()
    print("| renderer (own process) | wall s | CPU s | MP/s | peak RSS MB | wall vs l3 | CPU vs l3 |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, r in (("l3 render_mosaic (numba tile kernel)", l3),
                    ("ONNX Runtime CPU, exported model, one sess.run", o),
                    (f"ONNX Runtime CPU, run_strips ({args.threads or os.cpu_count()} threads)",
                     res["strips"])):
        print(f"| {name} | {r['wall_s']:.2f} | {r['cpu_s']:.2f} | {mp / r['wall_s']:.1f} | "
              f"{r['peak_rss_mb']:.0f} | {r['wall_s'] / l3['wall_s']:.1f}x | "
              f"{r['cpu_s'] / l3['cpu_s']:.1f}x |")
    print()
    print(f"max |ONNX - l3| = {diff:.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
