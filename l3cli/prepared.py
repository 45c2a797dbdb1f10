"""One raw, prepared once, and the one render path from it to every output.

Every render of a raw by a table takes two steps:

1. :func:`prepare` (once per raw): the fit check (the table's CFA and patch
   against the raw's), the raw's kernel set
   (:func:`l3cli.kernelset.prepare_kernels`: condition bins interpolated,
   white-balance gains and adaptation, the table's lens shading and the DNG's
   GainMaps, all folded into the tile kernel's band copy) and the mosaic the
   kernel set renders. The result is a :class:`Prepared`.
2. :meth:`Prepared.render`: float32 in the table's output space (EXR, the
   library's renders, training's cross-validation) or display integers of
   8 or 16 bits (PNG, JPEG, TIFF), the multi-scale stage included.

``l3 render`` (:func:`l3cli.pipeline.render_one`), :meth:`l3cli.model.Table.render`,
:func:`render_raw`, the multi-scale stage's fit and the tuning's fold renders
(:func:`plain`, for mosaics that are already corrected) all render this way:
a feature folded into :func:`prepare` reaches every one of them.

Examples
--------
>>> import numpy as np
>>> from l3cli.classify import ClassDefinition
>>> from l3cli.io.raw import RawImage
>>> from l3cli.prepared import prepare
>>> from l3cli.table import TransformTable
>>> d = ClassDefinition.build("RGGB", patch=3, level_cuts=[0.1])
>>> n = d.n_classes
>>> table = TransformTable(d, np.zeros((n, d.n_coeffs, 3)), np.full(n, 100),
...                        np.zeros((n, 3)), np.zeros(n, bool), np.arange(n))
>>> raw = RawImage(np.full((16, 16), 0.25, np.float32), d.cfa, np.zeros(4), 1.0)
>>> p = prepare(table, raw)
>>> p.render().shape, p.render(8).dtype.name
((16, 16, 3), 'uint8')
"""

from __future__ import annotations

import contextlib
import dataclasses
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Any

import numpy as np

from l3cli import buffers
from l3cli.errors import TableError
from l3cli.kernelset import KernelSet, prepare_kernels, render_display, render_mosaic

if TYPE_CHECKING:
    from l3cli.io.raw import RawImage
    from l3cli.multiscale.stage import Multiscale
    from l3cli.table import TransformTable

__all__ = ["Prepared", "check_fits", "plain", "prepare", "render_raw"]


@dataclasses.dataclass(frozen=True)
class Prepared:
    """A raw prepared for a table (:func:`prepare`): what :meth:`render` runs.

    Attributes
    ----------
    kernels
        The raw's :class:`~l3cli.kernelset.KernelSet` (kernels, gains, curve,
        post matrix).
    mosaic
        float32 (H, W): the mosaic the kernel set renders (the raw's own
        where its gains are folded into the tile kernel, the usual case).
    stage
        The table's multi-scale stage, or None.
    """

    kernels: KernelSet
    mosaic: np.ndarray
    stage: Multiscale | None = None

    @property
    def output_space(self) -> str:
        """The space of :meth:`render`'s float output (the table's)."""
        return self.kernels.output_space

    def render(self, bits: int | None = None, *,
               lock: AbstractContextManager | None = None) -> np.ndarray:
        """Render: float32 (H, W, n_out) in :attr:`output_space` (``bits`` None),
        or display integers, uint8 (``bits`` 8) or uint16 (16), as
        :func:`l3cli.io.encode.display_encode` makes them.

        ``lock`` is held around each call of the (parallel) compiled loops
        (the file pipeline's render lock).
        """
        if bits not in (None, 8, 16):
            raise ValueError(f"bits must be None, 8 or 16, got {bits}")
        ks, held = self.kernels, lock if lock is not None else contextlib.nullcontext()
        if self.stage is not None:  # the stage takes the float render
            from l3cli.multiscale import stage as multiscale

            with held:
                y = render_mosaic(ks, self.mosaic)
                if bits is None:
                    out = multiscale.apply_stage(self.stage, y, inplace=True)
                else:  # display-encoded as each row is blended
                    out = multiscale.apply_display(self.stage, y, ks.output_space, bits,
                                                   inplace=True)
            buffers.release(y)
            return out
        if bits is None:
            with held:
                return render_mosaic(ks, self.mosaic)
        return render_display(ks, self.mosaic, bits, render_lock=lock)


def check_fits(table: TransformTable, raw: RawImage, *, table_name: str = "table") -> None:
    """Raise :class:`TableError` when ``table`` cannot render ``raw``.

    The table's CFA (with its phase) must equal the raw's, and the raw must be
    at least one patch and one CFA period large; the message names both.
    """
    name = getattr(raw, "path", None) or "raw"
    if raw.cfa.spec != table.cfa.spec:
        raise TableError(
            f"{table_name} is for CFA {table.cfa.spec} but {name} has CFA {raw.cfa.spec}"
        )
    h, w = raw.mosaic.shape
    s = table.patch
    if h < max(s, table.cfa.period[0]) or w < max(s, table.cfa.period[1]):
        raise TableError(
            f"{table_name} uses {s}x{s} patches but {name} is only {w}x{h} pixels"
        )


def prepare(table: TransformTable, raw: RawImage, *, white_balance: np.ndarray | None = None,
            table_name: str = "table", inplace: bool = False) -> Prepared:
    """The per-raw step of a render: ``raw`` prepared for ``table``.

    Parameters
    ----------
    table
        The transform table.
    raw
        The raw (not changed unless ``inplace``).
    white_balance
        Gains ``[r, g, b]`` instead of the raw's own (white-balancing tables only).
    table_name
        The table's name in messages.
    inplace
        The raw's mosaic may be multiplied in place where its gains cannot be
        folded into the tile kernel (a decoded mosaic the caller owns).

    Raises
    ------
    TableError
        The table does not fit the raw (CFA, size).
    InputError
        The table expects a white balance the raw does not have, or one is
        given for a table trained without.
    """
    check_fits(table, raw, table_name=table_name)
    ks = prepare_kernels(table, raw, white_balance=white_balance, table_name=table_name)
    return Prepared(ks, ks.prepare_mosaic(raw.mosaic, inplace=inplace),
                    getattr(table, "multiscale", None))


def plain(table: TransformTable, mosaic: np.ndarray, *, stage: bool = False) -> Prepared:
    """A mosaic that needs no per-raw step (already corrected: training's
    images, a warm-up's), prepared with the table's plain kernels; with its
    multi-scale stage when ``stage``."""
    return Prepared(KernelSet.plain(table), mosaic,
                    getattr(table, "multiscale", None) if stage else None)


def render_raw(table: TransformTable, raw: RawImage, *, table_name: str = "table",
               white_balance: np.ndarray | None = None, bits: int | None = None,
               lock: Any = None) -> np.ndarray:
    """Render a :class:`l3cli.io.raw.RawImage` (not changed): :func:`prepare`, then
    :meth:`Prepared.render` (float32 in the table's space, or ``bits`` display
    integers)."""
    return prepare(table, raw, white_balance=white_balance,
                   table_name=table_name).render(bits, lock=lock)
