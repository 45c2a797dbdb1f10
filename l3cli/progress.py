"""Progress reporting on stderr, hidden when quiet or not a terminal."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

__all__ = ["progress"]


def progress(items: Iterable[T], *, label: str, length: int | None = None,
             enabled: bool | None = None) -> Iterator[T]:
    """Iterate over ``items`` with a progress bar on stderr.

    The bar is shown only when ``enabled`` (default: stderr is a TTY). Library
    code calls this; the CLI decides ``enabled`` from ``-q``.
    """
    import click

    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled:
        yield from items
        return
    with click.progressbar(items, label=label, length=length, file=sys.stderr) as bar:
        yield from bar
