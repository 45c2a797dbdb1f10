"""Condition-indexed tables: one set of kernels per condition bin, interpolated at render time.

A camera's pipeline changes with the shot's conditions: at high ISO or long
exposures it denoises harder, and its colour processing follows the white
balance. ``l3 train --by CONDITION`` learns one set of kernels per value of
the condition found among the training raws (each distinct value, to four
significant digits, is a bin), on one class definition shared by all bins,
and keeps the pooled kernels (all shots) as well. ``l3 render`` reads each
raw's value and interpolates the kernels of the two neighbouring bins
linearly in ``log`` of the value (clamped at the ends). A class with too few
samples in a bin (fewer than the training's minimum) uses the pooled kernel
there, unless ``l3 smooth`` filled it from the neighbouring bins (its
smoothing spline over ``log`` value, :func:`l3cli.smooth.spline.smooth_conditions`).
``l3 inspect`` lists the bins.

The conditions (one getter each, :func:`condition_value`; all positive, so
``log`` spacing applies to all):

``iso``
    The shot's ISO (EXIF ISO / LibRaw ``iso_speed``).
``exposure``
    The exposure time in seconds (EXIF ``ExposureTime`` / LibRaw
    ``shutter_speed``; a simulation manifest's ``exposure_s``).
``white-balance``
    The shot's white as the ratio ``b/r`` of its camera response, from the
    as-shot gains (``gain_r / gain_b``; :func:`l3cli.whitebalance.model.raw_gains`),
    so the bins are evenly spaced in ``log(b/r)`` -- the axis along which
    daylight, shade and tungsten whites differ most.

NPZ keys (optional; absent in tables trained without ``--by``):
``cond_by`` (str, one of :data:`CONDITIONS`), ``cond_values`` (float64
(n_bins,), increasing), ``cond_kernels`` (float32 (n_bins, n_classes,
S*S + 1, n_out)), ``cond_counts`` (int64 (n_bins, n_classes)),
``cond_filled`` (bool (n_bins, n_classes); classes ``l3 smooth`` filled
from neighbouring bins; absent = none).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.errors import InputError, TableError

__all__ = ["CONDITIONS", "LABELS", "MAX_KERNEL_GAIN", "Conditioned", "condition_value",
           "file_condition", "kernel_gain", "raw_condition", "kernels_for", "group_pairs"]

#: Conditions ``--by`` accepts.
CONDITIONS = ("iso", "exposure", "white-balance")
#: How messages and ``l3 inspect`` name each condition's value.
LABELS = {"iso": "ISO", "exposure": "exposure time (s)", "white-balance": "white b/r"}

#: Largest absolute sum of one class's kernel (weights and constant, per output):
#: with raw values up to 1e8 (normalised units; far beyond any white level) every
#: output stays below 1e38, finite in float32 (largest 3.4e38). The table's kernels
#: (:class:`l3cli.table.TransformTable`) and the per-bin ones here are held to it.
MAX_KERNEL_GAIN = 1e30


def kernel_gain(kernels: np.ndarray) -> float:
    """The largest absolute sum of one class's kernel over one output (float64).

    >>> kernel_gain(np.array([[[1.0], [-2.0]], [[0.5], [0.5]]]))
    3.0
    """
    if kernels.size == 0:
        return 0.0
    return float(np.abs(kernels, dtype=np.float64).sum(axis=-2).max())


@dataclass
class Conditioned:
    """Per-bin kernels of a table (see the module docstring)."""

    by: str
    values: np.ndarray
    kernels: np.ndarray
    counts: np.ndarray
    filled: np.ndarray | None = field(default=None)

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
        self.filled = (np.zeros(self.counts.shape, dtype=bool) if self.filled is None
                       else np.asarray(self.filled, dtype=bool))
        if self.filled.shape != self.counts.shape:
            raise TableError("condition bins: filled and counts do not fit together")
        if not np.all(np.isfinite(self.values)) or np.any(self.values <= 0) \
                or np.any(np.diff(self.values) <= 0):
            raise TableError("condition bins must be positive and increasing")
        if not np.all(np.isfinite(self.kernels)):
            raise TableError("condition kernels hold NaN or Inf")
        if kernel_gain(self.kernels) > MAX_KERNEL_GAIN:
            raise TableError(f"condition kernels have an absolute sum beyond "
                             f"{MAX_KERNEL_GAIN:g}: their outputs would overflow float32")
        if np.any(self.counts < 0):
            raise TableError("condition bins: counts hold negative sample counts")

    @property
    def own(self) -> np.ndarray:
        """bool (n_bins, n_classes): the bin has a kernel of its own (trained or filled)."""
        return (self.counts > 0) | self.filled

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"cond_by": np.array(self.by), "cond_values": self.values,
               "cond_kernels": self.kernels, "cond_counts": self.counts}
        if self.filled.any():
            out["cond_filled"] = self.filled
        return out

    @classmethod
    def from_arrays(cls, arrs: Mapping[str, np.ndarray]) -> Conditioned | None:
        if "cond_by" not in arrs:
            return None
        missing = [k for k in ("cond_values", "cond_kernels", "cond_counts") if k not in arrs]
        if missing:
            raise TableError(f"condition bins: missing keys {', '.join(missing)}")
        return cls(str(arrs["cond_by"]), arrs["cond_values"], arrs["cond_kernels"],
                   arrs["cond_counts"], arrs["cond_filled"] if "cond_filled" in arrs else None)


def _positive(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if np.isfinite(f) and f > 0 else None


def condition_value(by: str, shot: Mapping[str, Any], gains: Any = None) -> float | None:
    """The value of condition ``by`` from shot metadata (and as-shot gains), or None.

    Parameters
    ----------
    by
        One of :data:`CONDITIONS`.
    shot
        Shot metadata (:func:`l3cli.io.metadata.read_shot_metadata`), plus a
        simulation manifest's ``exposure_s`` where known.
    gains
        As-shot white-balance gains ``[r, g, b]`` (for ``white-balance``).
    """
    if by == "iso":
        return _positive(shot.get("iso"))
    if by == "exposure":
        v = _positive(shot.get("exposure_time"))
        return v if v is not None else _positive(shot.get("exposure_s"))
    if by == "white-balance":
        if gains is None:
            return None
        g = np.asarray(gains, dtype=np.float64)
        return _positive(g[0] / g[2])  # white's camera b/r = gain_r / gain_b
    raise TableError(f"condition {by!r} is not one of {', '.join(CONDITIONS)}")


def raw_condition(raw: Any, by: str) -> float | None:
    """The condition value of a :class:`l3cli.io.raw.RawImage`, or None when unknown."""
    shot = (raw.metadata or {}).get("shot") or {}
    gains = None
    if by == "white-balance":
        from l3cli.whitebalance.model import raw_gains

        gains = raw_gains(raw)
    return condition_value(by, shot, gains)


def file_condition(path: str | os.PathLike, by: str,
                   metadata: Mapping[str, Any] | None = None) -> float:
    """The condition value of a raw file, from its metadata (and its pair's facts).

    Raises
    ------
    InputError
        The file's metadata do not say it.
    """
    from l3cli.io.metadata import read_shot_metadata

    p = Path(path)
    gains = None
    if by == "white-balance":
        from l3cli.whitebalance.model import file_gains

        gains = file_gains(p)
        v = condition_value(by, {}, gains)
    else:
        shot = {**(metadata or {}), **read_shot_metadata(p)}
        v = condition_value(by, shot)
        if v is None and p.suffix.lower() != ".raw":
            try:
                import rawpy

                with rawpy.imread(str(p)) as rp:
                    v = condition_value(by, {**(metadata or {}), **read_shot_metadata(p, rp)})
            except Exception:  # noqa: BLE001 - reported below as missing metadata
                pass
    if v is None:
        raise InputError(f"{p}: the metadata give no {LABELS[by]}; --by {by} needs it for "
                         "every training raw")
    return v


def kernels_for(table: Any, value: float | None) -> np.ndarray:
    """The kernels to render a raw of condition ``value`` with (pooled when unknown)."""
    cond: Conditioned | None = getattr(table, "conditions", None)
    if cond is None or value is None:
        return table.kernels
    logs = np.log(cond.values)
    x = float(np.clip(np.log(value), logs[0], logs[-1]))
    j = int(np.searchsorted(logs, x, side="right"))
    i = max(j - 1, 0)
    j = min(j, logs.size - 1)
    t = 0.0 if i == j else (x - logs[i]) / (logs[j] - logs[i])
    k = (1 - t) * _bin_kernels(table, cond, i) + t * _bin_kernels(table, cond, j)
    return k.astype(np.float32)


def _bin_kernels(table: Any, cond: Conditioned, b: int) -> np.ndarray:
    return np.where(cond.own[b][:, None, None], cond.kernels[b], table.kernels)


def group_pairs(pairs: Sequence[Any], by: str) -> dict[float, list[int]]:
    """Indices of the pairs per condition value (4 significant digits; sorted)."""
    groups: dict[float, list[int]] = {}
    for i, p in enumerate(pairs):
        v = file_condition(p.raw, by, getattr(p, "metadata", None))
        groups.setdefault(float(f"{v:.4g}"), []).append(i)
    return dict(sorted(groups.items()))
