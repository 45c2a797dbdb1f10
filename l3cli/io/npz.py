"""NPZ members checked before they are read: a header may not claim more than the file holds.

An NPZ is a zip of ``.npy`` files, each a header (dtype, shape) and the values.
``numpy.load`` allocates what the header claims before it reads a byte of the
values, so a header of a few bytes claiming 2**40 values ends in "out of
memory" naming nothing. :func:`check_members` reads every member's header (a
few hundred bytes each) and refuses one whose values would need more bytes
than the member holds, naming the file and the key; :func:`read_members` then
reads them, naming the key of any that still cannot be held in memory.
"""

from __future__ import annotations

import math
import os
import zipfile
from typing import IO

import numpy as np

__all__ = ["check_members", "read_members"]


def _header(fh: IO[bytes]) -> tuple[tuple[int, ...], np.dtype]:
    fmt = np.lib.format
    version = fmt.read_magic(fh)
    if version == (1, 0):
        shape, _, dtype = fmt.read_array_header_1_0(fh)
    elif version == (2, 0):
        shape, _, dtype = fmt.read_array_header_2_0(fh)
    else:  # 3.0 (utf-8 field names): no public reader; numpy's own, else no check
        reader = getattr(fmt, "_read_array_header", None)
        if reader is None:
            raise ValueError(f".npy format version {version} is not checked here")
        shape, _, dtype = reader(fh, version)
    return tuple(int(n) for n in shape), np.dtype(dtype)


def check_members(path: str | os.PathLike, error: type[Exception]) -> None:
    """Refuse an NPZ whose member's header claims more values than the member holds.

    Raises
    ------
    error
        ``FILE: key 'K' claims N values of DTYPE (B bytes), the file holds M``. A
        file that is not a readable zip passes (``numpy.load`` reports it).
    """
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError):
        return
    with zf:
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            key = info.filename[:-4]
            try:
                with zf.open(info) as fh:
                    shape, dtype = _header(fh)
                    held = info.file_size - fh.tell()
            except Exception:  # noqa: BLE001 - numpy.load names a damaged header itself
                continue
            if dtype.hasobject:
                continue  # refused as pickled objects by numpy.load(allow_pickle=False)
            n = math.prod(shape)
            need = n * dtype.itemsize
            if need > held:
                raise error(f"{path}: key {key!r} claims {n} values of {dtype} ({need} bytes), "
                            f"the file holds {max(held, 0)} bytes for it (damaged table)")


def read_members(npz: np.lib.npyio.NpzFile, path: str | os.PathLike,
                 error: type[Exception]) -> dict[str, np.ndarray]:
    """Every array of an open NPZ; a member too large for this machine's memory is an
    ``error`` naming the file and its key (not "out of memory" naming nothing)."""
    out: dict[str, np.ndarray] = {}
    for k in npz.files:
        try:
            out[k] = npz[k]
        except MemoryError:
            raise error(f"{path}: key {k!r} does not fit in memory") from None
    return out
