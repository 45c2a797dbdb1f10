"""Interleaved A/B timing of whole commands (for comparing two versions of l3).

Usage::

    .venv/bin/python benchmarks/ab.py N 'COMMAND A' 'COMMAND B' [...]

Runs the commands one after another, N rounds (so load changes hit every
command alike), each through the shell as a fresh process, and prints per
command the best and median wall seconds and CPU seconds (user + system of
the child, from ``wait4``). Not part of ``make bench``: it is the tool the
notes in ``docs/performance.md`` cite for before/after comparisons, e.g.
a checkout of the previous commit with its own venv against this one.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time


def main(argv: list[str]) -> None:
    if len(argv) < 2 or not argv[0].isdigit():
        sys.exit(__doc__)
    rounds, cmds = int(argv[0]), argv[1:]
    res: dict[str, list[tuple[float, float]]] = {c: [] for c in cmds}
    for _ in range(rounds):
        for c in cmds:
            t0 = time.perf_counter()
            p = subprocess.Popen(c, shell=True, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL)
            _, status, ru = os.wait4(p.pid, 0)
            if os.waitstatus_to_exitcode(status) != 0:
                sys.exit(f"failed: {c}")
            res[c].append((time.perf_counter() - t0, ru.ru_utime + ru.ru_stime))
    for c, v in res.items():
        wall, cpu = [x[0] for x in v], [x[1] for x in v]
        print(f"wall min {min(wall):.3f} median {statistics.median(wall):.3f} s, "
              f"CPU min {min(cpu):.2f} median {statistics.median(cpu):.2f} s | {c}")


if __name__ == "__main__":
    main(sys.argv[1:])
