"""Inputs are never overwritten: find outputs that are (or alias) an input.

An output aliases an input when both name the same file: the same path, a
path through a symbolic link, a hard link (same device and inode), or a
name inside an output folder that is also an input's name there.
:func:`refuse_overwrite` checks every planned output against every input
before any work starts.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from l3cli.errors import OutputError

__all__ = ["check_name_length", "input_files", "refuse_overwrite", "same_file"]


def _key(path: Path) -> tuple[str, tuple[int, int] | None]:
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
        ident = (st.st_dev, st.st_ino)
    except (OSError, ValueError):  # missing, unreadable, or not a valid path
        ident = None
    return real, ident


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when ``a`` and ``b`` name one file (same path, symlink or hard link)."""
    ra, ia = _key(Path(a))
    rb, ib = _key(Path(b))
    return ra == rb or (ia is not None and ia == ib)


def input_files(inputs: Iterable[str | os.PathLike]) -> list[Path]:
    """The files that ``inputs`` stand for.

    A file stands for itself and its sidecar (``NAME.toml``, if present); a
    folder (a ``simulate`` or pairs folder, a folder of renders) for the files
    directly in it.
    """
    out: list[Path] = []
    for inp in inputs:
        p = Path(inp)
        if "\0" in str(p):
            continue
        if p.is_dir():
            try:
                out.extend(q for q in p.iterdir() if q.is_file())
            except OSError:
                continue
        else:
            out.append(p)
            side = p.with_name(p.name + ".toml")
            if side.exists():
                out.append(side)
    return out


def check_name_length(path: str | os.PathLike, what: str = "output") -> None:
    """Refuse an output path the filesystem cannot hold: a name (any component)
    longer than its folder's filesystem allows, or a path beyond ``PATH_MAX``.

    Raises
    ------
    OutputError
        One line naming the option and the limit.
    """
    p = Path(path)
    raw = os.fsencode(p)
    try:
        path_max = os.pathconf(".", "PC_PATH_MAX")
    except (OSError, ValueError):
        path_max = 4096
    if len(raw) >= path_max:
        raise OutputError(f"{str(p)[:60]}...: {what} path is {len(raw)} bytes long, more than "
                          f"the {path_max} this system allows")
    folder = p.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        name_max = os.pathconf(folder if str(folder) else ".", "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255
    for part in p.parts:
        n = len(os.fsencode(part))
        if n > name_max:
            raise OutputError(f"{part[:40]}...: {what} name is {n} bytes long, more than the "
                              f"{name_max} the filesystem allows; choose a shorter name")


def refuse_overwrite(outputs: Iterable[tuple[str | os.PathLike, str]],
                     inputs: Iterable[str | os.PathLike]) -> None:
    """Raise when an output would replace an input, or two outputs are one file.

    Parameters
    ----------
    outputs
        ``(path, what)`` pairs, ``what`` naming the option (``"-o"``, ``"--json"``).
    inputs
        Input files and folders (folders stand for the files in them,
        :func:`input_files`).

    Raises
    ------
    OutputError
        Naming the output, the option and the input it would overwrite.
    """
    by_real: dict[str, Path] = {}
    by_ident: dict[tuple[int, int], Path] = {}
    for f in input_files(inputs):
        real, ident = _key(f)
        by_real.setdefault(real, f)
        if ident is not None:
            by_ident.setdefault(ident, f)
    seen: dict[str, tuple[Path, str]] = {}
    for out, what in outputs:
        if "\0" in str(out):
            raise OutputError(f"{str(out)!r}: {what} is not a valid path (NUL character)")
        out = Path(out)
        check_name_length(out, what)
        real, ident = _key(out)
        hit = by_real.get(real) or (by_ident.get(ident) if ident is not None else None)
        if hit is not None:
            raise OutputError(f"{out}: {what} would overwrite the input {hit}; "
                              "choose another output")
        if real in seen:
            other, other_what = seen[real]
            raise OutputError(f"{out}: {what} and {other_what} would both write this file")
        seen[real] = (out, what)
