"""Atomic output: write to a temporary file in the same folder, then rename.

A reader never sees a half-written output and a failed write leaves nothing
behind.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from l3cli.errors import OutputError

__all__ = ["atomic_path", "check_writable_dir"]


def check_writable_dir(folder: str | os.PathLike) -> Path:
    """Return ``folder`` as a Path after checking it exists and is writable.

    Raises
    ------
    OutputError
        If the folder does not exist, is not a folder, or cannot be written.
    """
    folder = Path(folder)
    if not folder.exists():
        raise OutputError(f"{folder}: output folder does not exist")
    if not folder.is_dir():
        raise OutputError(f"{folder}: not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"{folder}: output folder is not writable")
    return folder


def _umask() -> int:
    """The process umask (read from /proc where possible: setting it is not thread-safe)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    Parameters
    ----------
    path
        The final output path.
    suffix
        Suffix for the temporary file (defaults to ``path``'s own suffix, so
        writers that choose a format by extension still work).

    Notes
    -----
    On any exception the temporary file is removed and ``path`` is untouched.
    The file gets the permissions of a newly created file (``0666 & ~umask``).
    """
    path = Path(path)
    folder = check_writable_dir(path.parent if str(path.parent) else Path("."))
    suffix = path.suffix if suffix is None else suffix
    fd, tmp = tempfile.mkstemp(prefix=f".l3-tmp-{path.stem}-", suffix=suffix, dir=folder)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if not tmp_path.exists() or tmp_path.stat().st_size == 0:
            raise OutputError(f"{path}: nothing was written")
        # mkstemp makes the file private (0600); give it the mode a plain open() would.
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise
