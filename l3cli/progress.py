"""Progress reporting on stderr, hidden when quiet or not a terminal.

The library core does not depend on click: it reports progress through
:func:`progress`, which draws a bar only when a front end has installed one
with :func:`set_bar_factory` (the ``l3`` command line installs click's
progress bar). Without a factory, or when disabled, it just iterates.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import AbstractContextManager
from typing import Any, TypeVar

T = TypeVar("T")

__all__ = ["progress", "set_bar_factory"]

#: ``factory(items, label=..., length=...)`` -> a context manager yielding an
#: iterable over ``items`` that draws the bar; installed by the front end.
BarFactory = Callable[..., AbstractContextManager[Iterable[Any]]]

_bar_factory: BarFactory | None = None


def set_bar_factory(factory: BarFactory | None) -> BarFactory | None:
    """Install the progress-bar factory (None: no bars). Returns the previous one."""
    global _bar_factory
    previous, _bar_factory = _bar_factory, factory
    return previous


def progress(items: Iterable[T], *, label: str, length: int | None = None,
             enabled: bool | None = None) -> Iterator[T]:
    """Iterate over ``items`` with a progress bar on stderr.

    The bar is shown only when ``enabled`` (default: stderr is a TTY) and a
    bar factory is installed. Library code calls this; the CLI decides
    ``enabled`` from ``-q``.
    """
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled or _bar_factory is None:
        yield from items
        return
    with _bar_factory(items, label=label, length=length) as bar:
        yield from bar
