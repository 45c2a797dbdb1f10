"""How the multi-scale stage runs its compiled loops (:mod:`l3cli.multiscale._loops`):
their stored machine code (:mod:`l3cli.kernel_store`) on l3's threads
(:func:`l3cli.threads.run_split`), without importing numba."""

from __future__ import annotations

import functools
from pathlib import Path

__all__ = ["KERNEL_SOURCES", "split", "stored"]

#: The source files the stage's machine code comes from (:mod:`l3cli.kernel_store`).
_HERE = Path(__file__).resolve().parent
KERNEL_SOURCES = tuple(str(p) for p in (
    _HERE / "_loops.py", _HERE / "_layout.py", _HERE.parent / "io" / "encode_rows.py"))


@functools.cache
def stored(name: str):
    """The stage's loop ``name`` (:mod:`l3cli.multiscale._loops`): its stored machine code
    when there is some for the arguments' types, else numba's, then stored."""
    from l3cli.kernel_store import Stored

    def dispatcher():
        from l3cli.multiscale import _loops

        return getattr(_loops, name)

    return Stored(f"multiscale-{name.replace('_', '-')}", KERNEL_SOURCES, dispatcher)


def split(name: str, args: tuple, n: int) -> None:
    """The loop ``name`` on ``args`` over rows (or bands) ``0..n``, shared by l3's threads
    (:func:`l3cli.threads.run_split`)."""
    if n <= 0:
        return
    from l3cli.threads import run_split

    run_split(stored(name).function(*args, 0, n), args, n)
