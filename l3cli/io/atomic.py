"""Atomic output: write to a temporary file in the same folder, check, fsync, rename.

Every file l3 writes goes through :func:`atomic_path`. A reader never sees a
half-written output, a failed write (a full disk, an I/O error, an encoder that
reports a short write) leaves the previous file byte for byte, and no
temporary file stays behind.

Temporary names carry the writing process's id (``.l3-tmp-<pid>-...``); a
later run removes the temporaries of processes that no longer exist
(:func:`clean_stale`), so a killed run's leftovers do not pile up.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from l3cli.errors import OutputError

__all__ = ["atomic_path", "check_writable_dir", "check_free_space", "clean_stale",
           "forget_temporary", "make_temp_dir", "remove_live_temporaries", "write_error",
           "TMP_PREFIX"]

#: Prefix of every temporary file or folder l3 creates next to an output.
TMP_PREFIX = ".l3-tmp-"
_TMP_RE = re.compile(r"^\.l3-tmp-(\d+)-")
#: Temporaries from before names carried a process id are removed after this long.
_OLD_STYLE_AGE_S = 24 * 3600

#: errno values that mean "this output cannot be written" (not a bug).
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EFBIG, errno.EROFS,
                          errno.EACCES, errno.EPERM, errno.ENAMETOOLONG, errno.ENOTDIR,
                          errno.EISDIR, errno.ENOENT, errno.EEXIST, errno.ENOTEMPTY,
                          errno.EXDEV, errno.EMLINK, errno.ELOOP, errno.EBUSY})


def write_error(path: str | os.PathLike, exc: OSError) -> OutputError:
    """One-line :class:`OutputError` for an ``OSError`` met while writing ``path``."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        what = "no space left on the device (disk full or file size limit)"
    else:
        what = exc.strerror or str(exc)
    return OutputError(f"{path}: cannot write: {what}")


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


def check_free_space(path: str | os.PathLike, nbytes: int) -> None:
    """Refuse to start a write of about ``nbytes`` that cannot fit.

    For encoders that cannot report a failed write (libjpeg ends the process on
    a full disk): the free space of ``path``'s filesystem and the process's
    file-size limit must both leave room for ``nbytes``.

    Raises
    ------
    OutputError
        Not enough room.
    """
    import resource

    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    room = None
    with contextlib.suppress(OSError):
        st = os.statvfs(folder)
        room = st.f_bavail * st.f_frsize
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    if soft != resource.RLIM_INFINITY:
        room = soft if room is None else min(room, soft)
    if room is not None and room < nbytes:
        raise OutputError(f"{path}: cannot write: no space left on the device "
                          f"(needs up to {nbytes} bytes, {room} free)")


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


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, another user's
        return True
    return True


_CLEANED: set[str] = set()


def _clean_once(folder: str | os.PathLike) -> None:
    """:func:`clean_stale` on the first write into ``folder`` of this process."""
    key = os.path.realpath(folder)
    if key not in _CLEANED:
        _CLEANED.add(key)
        clean_stale(folder)


def clean_stale(folder: str | os.PathLike) -> list[Path]:
    """Remove l3's temporary files and folders left in ``folder`` by killed runs.

    Only names l3 itself creates (``.l3-tmp-<pid>-...``) whose process is gone
    are removed (and pid-less ones from older l3 versions after a day).
    Returns what was removed; errors are ignored (cleaning is best effort).
    """
    removed: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    now = time.time()
    for entry in entries:
        if not entry.name.startswith(TMP_PREFIX):
            continue
        m = _TMP_RE.match(entry.name)
        try:
            if m:
                if _alive(int(m.group(1))):
                    continue
            elif now - entry.stat(follow_symlinks=False).st_mtime < _OLD_STYLE_AGE_S:
                continue
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
            removed.append(Path(entry.path))
        except OSError:
            continue
    return removed


def _tmp_prefix(name: str) -> str:
    return f"{TMP_PREFIX}{os.getpid()}-{name[:40]}-"


#: This process's temporaries not yet renamed or removed: what an interrupted run
#: removes on its way out (:func:`remove_live_temporaries`) wherever the signal came.
_LIVE: set[str] = set()


def remove_live_temporaries() -> list[str]:
    """Remove this process's temporary files and folders that still exist (the CLI
    calls it when a run is interrupted). Returns what was removed."""
    removed = []
    for p in sorted(_LIVE, key=len, reverse=True):
        _LIVE.discard(p)
        try:
            if os.path.isdir(p) and not os.path.islink(p):
                shutil.rmtree(p)
            else:
                os.unlink(p)
            removed.append(p)
        except OSError:
            continue
    return removed


def forget_temporary(path: str | os.PathLike) -> None:
    """The temporary at ``path`` was renamed into place or removed."""
    _LIVE.discard(os.fspath(path))


def make_temp_dir(parent: str | os.PathLike, name: str) -> Path:
    """A new temporary folder in ``parent`` named for this process (stale ones cleaned).

    Recorded until :func:`forget_temporary`: an interrupted run removes it
    whenever the signal arrives (:func:`remove_live_temporaries`).
    """
    from l3cli.startup import signals_deferred, test_point

    _clean_once(parent)
    try:
        with signals_deferred():
            tmp = tempfile.mkdtemp(prefix=_tmp_prefix(name), dir=parent)
            _LIVE.add(tmp)
    except OSError as exc:
        raise write_error(Path(parent) / name, exc) from exc
    test_point("temporary")
    return Path(tmp)


def fsync_path(path: str | os.PathLike, *, folder: bool = False) -> None:
    """Flush a file (or a folder's entries) to the device."""
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if folder else 0))
    try:
        os.fsync(fd)
    except OSError as exc:
        if folder and exc.errno in (errno.EINVAL, errno.EBADF):  # not supported for folders
            return
        raise
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; check, fsync and rename it onto ``path``.

    Parameters
    ----------
    path
        The final output path.
    suffix
        Suffix for the temporary file (defaults to ``path``'s own suffix, so
        writers that choose a format by extension still work).

    Raises
    ------
    OutputError
        The folder is missing or not writable, nothing was written, or writing
        failed (``ENOSPC``, ``EIO``, ...); ``path`` is then untouched.

    Notes
    -----
    The caller writes the temporary file and raises on any encoder error. On
    any exception the temporary file is removed and ``path`` is untouched. The
    file gets the permissions of a newly created file (``0666 & ~umask``).
    """
    path = Path(path)
    folder = check_writable_dir(path.parent if str(path.parent) else Path("."))
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, expected an output file name")
    if path.exists() and not path.is_file():
        raise OutputError(f"{path}: exists and is not a regular file (a device or pipe); "
                          "choose another output")
    suffix = path.suffix if suffix is None else suffix
    _clean_once(folder)
    from l3cli.startup import signals_deferred, test_point

    try:
        with signals_deferred():
            fd, tmp = tempfile.mkstemp(prefix=_tmp_prefix(path.stem), suffix=suffix,
                                       dir=folder)
            _LIVE.add(tmp)
        os.close(fd)
    except OSError as exc:
        raise write_error(path, exc) from exc
    test_point("temporary")
    tmp_path = Path(tmp)
    try:
        try:
            yield tmp_path
            if not tmp_path.exists() or tmp_path.stat().st_size == 0:
                raise OutputError(f"{path}: nothing was written")
            fsync_path(tmp_path)
            # mkstemp makes the file private (0600); give it the mode a plain open() would.
            os.chmod(tmp_path, 0o666 & ~_umask())
            os.replace(tmp_path, path)
            _LIVE.discard(tmp)
        except OSError as exc:
            if exc.errno in WRITE_ERRNOS:
                raise write_error(path, exc) from exc
            raise
        with contextlib.suppress(OSError):
            fsync_path(folder, folder=True)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
            _LIVE.discard(tmp)
        raise
