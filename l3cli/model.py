"""A trained table as the library's user holds it: :class:`Table`, :func:`load_table`.

``l3cli.load_table(path)`` and ``l3cli.train(...)`` return a :class:`Table`:
a :class:`~l3cli.table.TransformTable` (every function that takes a table
takes it) that also renders a raw (:meth:`Table.render`), saves itself and
tells its self-tuning record.
"""

from __future__ import annotations

import copy
import os
from pathlib import Path

import numpy as np

from l3cli.table import TransformTable, save_table
from l3cli.table import load_table as _load

__all__ = ["Table", "load_table"]


class Table(TransformTable):
    """A transform table that renders (:meth:`render`) and saves (:meth:`save`) itself."""

    @classmethod
    def of(cls, table: TransformTable) -> Table:
        """``table`` as a :class:`Table` (a shallow copy sharing its arrays)."""
        if isinstance(table, cls):
            return table
        out = copy.copy(table)
        out.__class__ = cls
        return out

    def render(self, raw, *, white_balance=None) -> np.ndarray:
        """Render a raw: a file path (read as ``l3 render`` reads it) or a
        :class:`l3cli.io.raw.RawImage` (not changed).

        The float render ``l3 render`` writes to EXR: float32 (H, W, n_out) in
        :attr:`output_space` (linear; a display white has Y = 1), with the table's
        lens shading, white balance, condition bins, tone curve and multi-scale
        stage applied. ``white_balance`` (gains ``r, g, b``) replaces the raw's own.

        Raises
        ------
        InputError, TableError
            An unreadable raw, or one the table does not fit (CFA, white balance).
        """
        from l3cli.prepared import render_raw

        if isinstance(raw, str | os.PathLike):
            from l3cli.io.raw import read_raw

            raw = read_raw(raw)
        gains = None if white_balance is None else np.asarray(white_balance, np.float64)
        return render_raw(self, raw, white_balance=gains)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the table (atomically, NPZ) to ``path``; returns the path."""
        return save_table(path, self)

    @property
    def tuning(self) -> dict | None:
        """The self-tuning record (candidates, scores, folds, rule, choice), or None
        when the table was not tuned (``l3 inspect`` prints it)."""
        return self.provenance.get("tune")


def load_table(path: str | os.PathLike) -> Table:
    """Read and validate a table file (:func:`l3cli.table.load_table`) as a :class:`Table`.

    Raises
    ------
    TableError
        Not a valid l3 table (the message names the file).
    """
    return Table.of(_load(path))
