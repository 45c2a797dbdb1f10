"""Shared helpers for l3 benchmarks: timing, peak memory, machine description."""

from __future__ import annotations

import os
import platform
import resource
import time
from collections.abc import Callable

import numpy as np

__all__ = ["best_of", "copy_bandwidth", "machine", "peak_rss_mb", "make_bayer_mosaic"]


def best_of(fn: Callable[[], object], *, repeat: int = 3, warmup: int = 1) -> float:
    """Best wall time in seconds over ``repeat`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def copy_bandwidth(nbytes: int, *, repeat: int = 5) -> float:
    """Memory bandwidth ceiling in GB/s: a numpy copy of ``nbytes`` (read + write)."""
    src = np.ones(nbytes // 4, dtype=np.float32)
    dst = np.empty_like(src)
    t = best_of(lambda: np.copyto(dst, src), repeat=repeat)
    return 2 * src.nbytes / t / 1e9


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, in MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def machine() -> str:
    """One line describing the machine the numbers come from."""
    try:
        import threadpoolctl

        blas = ", ".join(sorted({i.get("internal_api", "?") for i in threadpoolctl.threadpool_info()}))
    except Exception:  # noqa: BLE001 - informative only
        blas = "?"
    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
            f"Python {platform.python_version()}, numpy {np.__version__}, BLAS {blas}")


def make_bayer_mosaic(height: int, width: int, *, seed: int = 0) -> np.ndarray:
    """A natural-looking float32 Bayer (RGGB) mosaic: smooth colour field + edges + noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    base = 0.25 + 0.2 * np.sin(x / 97.0) * np.cos(y / 61.0)
    edges = 0.15 * ((x // 64 + y // 48) % 2)
    cfa_gain = np.tile(np.array([[0.6, 1.0], [1.0, 0.45]], np.float32),
                       (height // 2 + 1, width // 2 + 1))[:height, :width]
    m = (base + edges) * cfa_gain + rng.normal(0, 0.01, (height, width)).astype(np.float32)
    return np.clip(m, 0, 1).astype(np.float32)
