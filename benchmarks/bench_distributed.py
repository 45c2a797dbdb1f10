"""Distributed training: 2 local dask workers vs 1, overhead vs in process, memory.

Usage::

    .venv/bin/python benchmarks/bench_distributed.py [--size 1280x960] [--repeat 3]
        [--memory-size 192x128]

1. Simulates 16 captures of ``sample_configs/bayer.toml`` (macbeth,
   slanted-edge, coffee, astronaut x 4 light levels, ``--size``) once into a
   temporary folder (on a 2-worker local cluster: ``run_simulation(scheduler=...)``).
2. Times ``l3cli.train.train`` (both passes: histogram + statistics, one task
   per capture, then the solve; the path of ``l3 train``) best of
   ``--repeat`` after one warm-up run:

   * in process (``workers=None``: the plain path, numba on every core);
   * on a local cluster of 1 worker and of 2 workers (one task thread per
     worker, numba threads = cores / workers, as ``l3 train --workers N``
     starts), reached with ``scheduler=ADDRESS`` like ``l3 train --scheduler``.

   The cluster start-up time is reported separately, and every table is
   checked to be identical to the in-process one.
3. Peak memory (VmHWM of a child process running ``l3 train`` in process) on
   20 and on 200 small captures (``--memory-size``; the 200 are the 20
   simulated ones, each hard-linked under 10 names in a second simulation
   folder, so every capture is read and accumulated anew): flat in the number
   of images, since statistics are folded as each capture finishes.

Prints Markdown tables.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

SCENES16 = ["macbeth", "slanted-edge", "natural:coffee", "natural:astronaut"]
LUX16 = [20.0, 80.0, 320.0, 1280.0]
SCENES_MEM = ["macbeth", "slanted-edge", "natural:coffee", "natural:astronaut",
              "natural:chelsea"]
LUX20 = [10.0, 60.0, 300.0, 1500.0]  # 5 scenes x 4 levels = 20 captures


def link_copies(src: Path, dst: Path, copies: int) -> int:
    """A simulation folder listing every capture of ``src`` ``copies`` times
    (hard links under new stems). Returns the number of captures."""
    import json

    m = json.loads((src / "manifest.json").read_text())
    dst.mkdir()
    caps = []
    for k in range(copies):
        for c in m["captures"]:
            stem = f"{c['stem']}_{k:02d}"
            raw, target = f"{stem}.dng", f"{stem}.target.exr"
            os.link(src / c["raw"], dst / raw)
            os.link(src / c["target"], dst / target)
            caps.append({**c, "stem": stem, "raw": raw, "target": target})
            caps[-1].pop("noise_free", None)
    (dst / "manifest.json").write_text(json.dumps({**m, "captures": caps}))
    return len(caps)


def _vmhwm_kb() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1])
    import resource

    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


def memory_child(sim: str, out: str) -> None:
    """Run ``l3 -q train SIM -o OUT`` in this process; print VmHWM (kB)."""
    from l3cli.cli.main import cli

    cli(["-q", "train", sim, "-o", out], standalone_mode=False)
    print(_vmhwm_kb())


def _cpu(client) -> float:
    """Process CPU seconds of this process and of every worker of ``client``."""
    own = time.process_time()
    if client is None:
        return own
    return own + sum(client.run(time.process_time).values())


def _best(fn, repeat: int, client=None) -> tuple[float, float, object]:
    """Best wall seconds, the CPU seconds of that run (client + workers), the result."""
    fn()  # warm-up: worker imports, numba cache, page cache
    best, cpu, result = float("inf"), 0.0, None
    for _ in range(repeat):
        c0 = _cpu(client)
        t0 = time.perf_counter()
        result = fn()
        dt = time.perf_counter() - t0
        if dt < best:
            best, cpu = dt, _cpu(client) - c0
    return best, cpu, result


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True)
               for k in ("kernels", "counts", "lambdas", "empty", "source_class"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1280x960")
    ap.add_argument("--memory-size", default="192x128")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        memory_child(*a.child)
        return
    import subprocess

    import numba

    from l3cli.camera import load_camera
    from l3cli.parallel import _cpu_count, dask_client
    from l3cli.simulate.run import run_simulation
    from l3cli.train import TrainOptions, find_pairs, train

    w, h = (int(v) for v in a.size.split("x"))
    mw, mh = (int(v) for v in a.memory_size.split("x"))
    cam = load_camera(REPO / "sample_configs" / "bayer.toml")
    tmp = Path(tempfile.mkdtemp(prefix="l3bench-dist-"))
    try:
        opts = TrainOptions()
        timings: dict[str, float] = {}
        cpus: dict[str, float] = {}
        starts: dict[int, float] = {}
        tables = {}
        # 2 workers: simulate the inputs, then time training
        t0 = time.perf_counter()
        with dask_client(workers=2) as client:
            starts[2] = time.perf_counter() - t0
            addr = client.scheduler.address
            t0 = time.perf_counter()
            run_simulation(cam, tmp / "s16", scenes=SCENES16, lux=LUX16, size=(w, h), seed=1,
                           scheduler=addr)
            t_sim16 = time.perf_counter() - t0
            run_simulation(cam, tmp / "s20", scenes=SCENES_MEM, lux=LUX20, size=(mw, mh),
                           seed=1, scheduler=addr)
            pairs = find_pairs([tmp / "s16"])
            timings["2 workers"], cpus["2 workers"], tables[2] = _best(
                lambda: train(pairs, opts, scheduler=addr), a.repeat, client)
        link_copies(tmp / "s20", tmp / "s200", 10)
        t0 = time.perf_counter()
        with dask_client(workers=1) as client:
            starts[1] = time.perf_counter() - t0
            addr = client.scheduler.address
            timings["1 worker"], cpus["1 worker"], tables[1] = _best(
                lambda: train(pairs, opts, scheduler=addr), a.repeat, client)
        timings["in process"], cpus["in process"], local = _best(lambda: train(pairs, opts),
                                                                 a.repeat)
        npx = sum(p.stat().st_size for p in (tmp / "s16").glob("*.dng"))
        load = os.getloadavg()[0]
        print(f"Distributed training benchmark: 16 simulated {w}x{h} Bayer captures "
              f"({len(pairs) * w * h / 1e6:.1f} MP in all, {npx / 1e6:.0f} MB of DNG; "
              f"simulated in {t_sim16:.1f} s on 2 workers), `l3 train` defaults (5x5 "
              f"patches, 24 levels x 2 contrasts, both passes + solve), best of {a.repeat} "
              f"after a warm-up; {_cpu_count()} cpus, in-process numba threads "
              f"{numba.get_num_threads()}, load average {load:.1f}\n")
        print("| path | wall s | speed-up vs 1 worker | vs in process | CPU s (client + "
              "workers) | cluster start-up s | table identical to in process |")
        print("|---|---|---|---|---|---|---|")
        t1 = timings["1 worker"]
        tl = timings["in process"]
        for name, n in (("in process", None), ("1 worker", 1), ("2 workers", 2)):
            t = timings[name]
            same = "yes" if n is None or _same(tables[n], local) else "NO"
            st = f"{starts[n]:.1f}" if n else "-"
            print(f"| {name} | {t:.2f} | {t1 / t:.2f}x | {tl / t:.2f}x | {cpus[name]:.2f} | "
                  f"{st} | {same} |")
        print(f"\nOverhead of the distributed path with 1 worker vs in process: "
              f"{t1 - tl:+.2f} s ({100 * (t1 / tl - 1):+.0f} %) on a warm cluster, plus "
              f"{starts[1]:.1f} s to start it (`--workers 1`).")

        # peak memory of `l3 train` (in process), 20 vs 200 captures
        print(f"\nPeak memory (VmHWM) of `l3 train` in one process, {mw}x{mh} captures:\n")
        print("| captures | wall s | peak memory MB |")
        print("|---|---|---|")
        for name in ("s20", "s200"):
            n = len(find_pairs([tmp / name]))
            t0 = time.perf_counter()
            res = subprocess.run([sys.executable, __file__, "--child", str(tmp / name),
                                  str(tmp / f"{name}.npz")], capture_output=True, text=True,
                                 check=True, cwd=REPO)
            dt = time.perf_counter() - t0
            kb = int(res.stdout.strip().splitlines()[-1])
            print(f"| {n} | {dt:.1f} | {kb / 1024:.0f} |")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
