"""Condition-indexed tables: one set of kernels per ISO bin, interpolated at render time.

A camera's pipeline changes with the shot's conditions: at high ISO it
denoises harder. ``l3 train --by iso`` learns one set of kernels per ISO
found among the training raws (each distinct ISO is a bin), on one class
definition shared by all bins, and keeps the pooled kernels (all shots) as
well. ``l3 render`` reads each raw's ISO and interpolates the kernels of the
two neighbouring bins linearly in log2(ISO) (clamped at the ends). A class
with too few samples in a bin (fewer than the training's minimum) uses the
pooled kernel there. ``l3 inspect`` lists the bins.

NPZ keys (optional; absent in tables trained without ``--by``):
``cond_by`` (str, ``"iso"``), ``cond_values`` (float64 (n_bins,), increasing),
``cond_kernels`` (float32 (n_bins, n_classes, S*S + 1, n_out)),
``cond_counts`` (int64 (n_bins, n_classes)).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.errors import InputError, TableError

__all__ = ["CONDITIONS", "Conditioned", "file_condition", "raw_condition", "kernels_for"]

#: Conditions ``--by`` accepts.
CONDITIONS = ("iso",)


@dataclass
class Conditioned:
    """Per-bin kernels of a table (see the module docstring)."""

    by: str
    values: np.ndarray
    kernels: np.ndarray
    counts: np.ndarray

    def __post_init__(self) -> None:
        self.values = np.asarray(self.values, dtype=np.float64)
        self.kernels = np.ascontiguousarray(self.kernels, dtype=np.float32)
        self.counts = np.asarray(self.counts, dtype=np.int64)
        if self.by not in CONDITIONS:
            raise TableError(f"condition {self.by!r} is not one of {', '.join(CONDITIONS)}")
        n = self.values.size
        if n < 1 or self.kernels.ndim != 4 or self.kernels.shape[0] != n \
                or self.counts.shape != (n, self.kernels.shape[1]):
            raise TableError("condition bins: values, kernels and counts do not fit together")
        if not np.all(np.isfinite(self.values)) or np.any(self.values <= 0) \
                or np.any(np.diff(self.values) <= 0):
            raise TableError("condition bins must be positive and increasing")
        if not np.all(np.isfinite(self.kernels)):
            raise TableError("condition kernels hold NaN or Inf")

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"cond_by": np.array(self.by), "cond_values": self.values,
                "cond_kernels": self.kernels, "cond_counts": self.counts}

    @classmethod
    def from_arrays(cls, arrs: dict[str, np.ndarray]) -> Conditioned | None:
        if "cond_by" not in arrs:
            return None
        missing = [k for k in ("cond_values", "cond_kernels", "cond_counts") if k not in arrs]
        if missing:
            raise TableError(f"condition bins: missing keys {', '.join(missing)}")
        return cls(str(arrs["cond_by"]), arrs["cond_values"], arrs["cond_kernels"],
                   arrs["cond_counts"])


def raw_condition(raw: Any, by: str) -> float | None:
    """The condition value of a :class:`l3cli.io.raw.RawImage` (its ISO), or None."""
    v = ((raw.metadata or {}).get("shot") or {}).get(by)
    return float(v) if v is not None and float(v) > 0 else None


def file_condition(path: str | os.PathLike, by: str) -> float:
    """The condition value of a raw file, from its metadata.

    Raises
    ------
    InputError
        The file's metadata do not say it.
    """
    from l3cli.io.metadata import read_shot_metadata

    p = Path(path)
    shot = read_shot_metadata(p)
    if shot.get(by) is None and p.suffix.lower() != ".raw":
        try:
            import rawpy

            with rawpy.imread(str(p)) as rp:
                shot = read_shot_metadata(p, rp)
        except Exception:  # noqa: BLE001 - reported below as missing metadata
            pass
    v = shot.get(by)
    if v is None or not float(v) > 0:
        raise InputError(f"{p}: the metadata give no {by.upper()}; --by {by} needs it for "
                         "every training raw")
    return float(v)


def kernels_for(table: Any, value: float | None) -> np.ndarray:
    """The kernels to render a raw of condition ``value`` with (pooled when unknown)."""
    cond: Conditioned | None = getattr(table, "conditions", None)
    if cond is None or value is None:
        return table.kernels
    logs = np.log2(cond.values)
    x = float(np.clip(np.log2(value), logs[0], logs[-1]))
    j = int(np.searchsorted(logs, x, side="right"))
    i = max(j - 1, 0)
    j = min(j, logs.size - 1)
    t = 0.0 if i == j else (x - logs[i]) / (logs[j] - logs[i])
    k = (1 - t) * _bin_kernels(table, cond, i) + t * _bin_kernels(table, cond, j)
    return k.astype(np.float32)


def _bin_kernels(table: Any, cond: Conditioned, b: int) -> np.ndarray:
    trained = cond.counts[b] > 0
    return np.where(trained[:, None, None], cond.kernels[b], table.kernels)


def group_pairs(pairs: Sequence[Any], by: str) -> dict[float, list[int]]:
    """Indices of the pairs per condition value (sorted)."""
    groups: dict[float, list[int]] = {}
    for i, p in enumerate(pairs):
        groups.setdefault(file_condition(p.raw, by), []).append(i)
    return dict(sorted(groups.items()))
