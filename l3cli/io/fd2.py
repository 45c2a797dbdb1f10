"""Capture what C libraries print on file descriptor 2, from many threads at once.

LibRaw reports data errors by writing to the process's stderr (fd 2), e.g.
``cut.dng: Unexpected end of file``; l3 folds them into its one-line error.
fd 2 is process-wide, so a capture redirects it for every thread. Captures
share one redirection: the first to start points fd 2 at a temporary file,
the last to end points it back, and each keeps the lines written while it ran
that carry its tag (LibRaw prefixes its messages with the file name) or no
other capture's tag. Decodes of several files therefore run at the same time.

Text that must reach the real stderr (a progress bar, log records: see
:class:`Handler`) is written inside :data:`STDERR_LOCK`, which waits until no
capture is running and holds new captures off meanwhile. A thread must not
log or draw inside its own capture.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile
import threading
from collections.abc import Iterator
from typing import IO, Any

__all__ = ["STDERR_LOCK", "Handler", "captured"]


class _Fd2:
    """State of the one shared redirection (guarded by ``cond``)."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.users = 0  # captures running
        self.writing: int | None = None  # the thread writing to the real stderr
        self.depth = 0  # how many times it holds the lock
        self.waiting = 0  # threads waiting to write to the real stderr
        self.saved: int | None = None  # the real fd 2 while redirected
        self.sink: IO[bytes] | None = None
        self.tags: set[str] = set()  # tags of this redirection's captures

    def _start(self) -> None:
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError, AttributeError):  # no usable fd 2: nothing to capture
            return
        try:
            sink = tempfile.TemporaryFile()
            os.dup2(sink.fileno(), 2)
        except BaseException:
            os.close(saved)
            raise
        self.saved, self.sink = saved, sink

    def _stop(self) -> None:
        if self.saved is not None:
            os.dup2(self.saved, 2)
            os.close(self.saved)
        if self.sink is not None:
            self.sink.close()
        self.saved, self.sink = None, None
        self.tags.clear()

    def _end(self) -> int:
        # read by position (pread/fstat): seeking would move the offset fd 2 writes at
        return os.fstat(self.sink.fileno()).st_size if self.sink is not None else 0


_STATE = _Fd2()


def _mine(line: str, tag: str, others: set[str]) -> bool:
    if line.startswith(f"{tag}: "):
        return True
    return not any(line.startswith(f"{t}: ") for t in others)


@contextlib.contextmanager
def captured(tag: str) -> Iterator[list[str]]:
    """Capture fd 2 while the block runs; yield a list filled with its lines at the end.

    Parameters
    ----------
    tag
        The prefix (before ``": "``) of this block's messages, e.g. the file
        name LibRaw was given. Lines with another running capture's tag are
        left to that capture; untagged lines go to every capture that saw them.
    """
    s = _STATE
    lines: list[str] = []
    with s.cond:
        while s.writing is not None or s.waiting:
            s.cond.wait()
        if s.users == 0:
            s._start()
        s.users += 1
        s.tags.add(tag)
        start = s._end()
    try:
        yield lines
    finally:
        with s.cond:
            end = s._end()
            data = os.pread(s.sink.fileno(), end - start, start) if end > start else b""
            others = s.tags - {tag}
            s.users -= 1
            if s.users == 0:
                s._stop()
                s.cond.notify_all()
        text = data.decode("utf-8", "replace")
        lines.extend(ln.strip() for ln in text.splitlines()
                     if ln.strip() and _mine(ln.strip(), tag, others))


class _RealStderr:
    """Context manager: the real stderr, with no capture running (re-entrant per thread)."""

    def __enter__(self) -> None:
        s = _STATE
        me = threading.get_ident()
        with s.cond:
            if s.writing == me:
                s.depth += 1
                return
            s.waiting += 1
            try:
                while s.users or s.writing is not None:
                    s.cond.wait()
            finally:
                s.waiting -= 1
            s.writing, s.depth = me, 1

    def __exit__(self, *exc: Any) -> None:
        s = _STATE
        with s.cond:
            s.depth -= 1
            if s.depth == 0:
                s.writing = None
                s.cond.notify_all()


#: Held while writing to the real stderr from a thread while others may decode
#: (a progress bar, log lines): it waits for running captures to end.
STDERR_LOCK = _RealStderr()


class Handler(logging.StreamHandler):
    """A logging handler whose records reach the real stderr, never a capture."""

    def emit(self, record: logging.LogRecord) -> None:
        with STDERR_LOCK:
            super().emit(record)
