"""Benchmark: one 12-megapixel capture of `l3 simulate` (issue 3's performance figure).

Simulates a 4000x3000 capture of the bundled natural scene ``coffee`` with
``sample_configs/bayer.toml`` (RGGB, 71 wavelengths, 380-730 nm in 5 nm steps)
and, separately, ``sample_configs/rgbw-4x4.toml`` (4x4 interleaved RGBW, 69
wavelengths, 380-1060 nm in 10 nm steps): scene → Airy optics → noise chain →
DN, plus the XYZ target and the noise-free response (in memory; file writing
is not timed). Reports wall time and peak resident memory of a fresh
process per case, limited to 2 FFT/BLAS threads.

Run standalone::

    .venv/bin/python benchmarks/bench_simulate.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_CHILD = r"""
import json, os, resource, sys, time
import numpy as np
from l3cli.camera import load_camera
from l3cli.simulate import make_scene, prepare_camera, simulate_capture
cfg, w, h = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
cam = load_camera(cfg)
t0 = time.perf_counter()
model = prepare_camera(cam)
scene = make_scene("natural:coffee", h, w, model.wavelengths)
t1 = time.perf_counter()
cap = simulate_capture(model, scene, illuminant=cam.exposure.illuminant, lux=100.0, seed=1,
                       workers=2)
t2 = time.perf_counter()
ru = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"scene_s": t1 - t0, "capture_s": t2 - t1, "total_s": t2 - t0,
                  "cpu_s": ru.ru_utime + ru.ru_stime,
                  "n_wavelengths": int(model.wavelengths.size),
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                  "shape": list(cap.dn.shape)}))
"""


def measure(config: str, width: int = 4000, height: int = 3000) -> dict:
    """Run one capture in a fresh 2-thread process; return its timings and peak memory."""
    env = dict(os.environ, OMP_NUM_THREADS="2", OPENBLAS_NUM_THREADS="2", MKL_NUM_THREADS="2",
               NUMBA_NUM_THREADS="2")
    out = subprocess.run([sys.executable, "-c", _CHILD, str(ROOT / config), str(width), str(height)],
                         capture_output=True, text=True, env=env, cwd=ROOT, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(report=print) -> list[dict]:
    """Measure the 12 MP cases and report one line each (``report`` receives strings)."""
    rows = []
    for cfg in ("sample_configs/bayer.toml", "sample_configs/rgbw-4x4.toml"):
        r = measure(cfg)
        r["config"] = cfg
        rows.append(r)
        report(f"simulate 4000x3000 {Path(cfg).stem}: {r['n_wavelengths']} wavelengths, "
               f"{r['total_s']:.1f} s (scene {r['scene_s']:.1f} s + capture {r['capture_s']:.1f} s), "
               f"peak RSS {r['peak_rss_mb']:.0f} MB, process CPU {r['cpu_s']:.1f} s, "
               f"load average {os.getloadavg()[0]:.1f}")
    return rows


if __name__ == "__main__":
    run()
