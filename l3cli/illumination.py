"""A lens's relative illumination as a camera file describes it.

``[optics.relative_illumination]`` (``docs/camera-toml.md``) gives the measured
fall-off of the light per CFA channel over the normalised radius (1 = the
half-diagonal). This module holds its check, for the camera reader
(:mod:`l3cli.camera`); the simulator applies it (:func:`l3cli.simulate.optics.raw_shading`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["check_relative_illumination"]


def check_relative_illumination(value: Any, channels: list[str], where: str) -> dict:
    """Validate ``[optics.relative_illumination]`` (:mod:`l3cli.camera`): ``radius``
    (increasing, from 0, at most 1.5) and per CFA channel a list of the same length with
    values in (0, 1.5]; ``where`` names the file and key in messages.

    Raises
    ------
    ConfigError
        Not a table, unknown keys, bad lists or values.
    """
    from l3cli.errors import ConfigError

    if not isinstance(value, dict):
        raise ConfigError(f"{where} must be a table (radius = [...], one list per channel)")
    unknown = sorted(set(value) - {"radius", *channels})
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r}; allowed: radius, "
                          f"{', '.join(channels)} (the CFA's channels)")

    def numbers(k: str) -> list[float]:
        v = value.get(k)
        if not isinstance(v, list) or not v or not all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                for x in v):
            raise ConfigError(f"{where}.{k} must be a list of finite numbers, got {v!r}")
        return [float(x) for x in v]

    radius = numbers("radius")
    if len(radius) < 2 or radius[0] != 0 or np.any(np.diff(radius) <= 0) or radius[-1] > 1.5:
        raise ConfigError(f"{where}.radius = {radius} must increase from 0 in at least 2 "
                          "steps, to at most 1.5 (1 = the half-diagonal)")
    out: dict[str, list[float]] = {"radius": radius}
    for c in channels:
        if c not in value:
            continue
        v = numbers(c)
        if len(v) != len(radius):
            raise ConfigError(f"{where}.{c} has {len(v)} values, radius {len(radius)}")
        if min(v) <= 0 or max(v) > 1.5:
            raise ConfigError(f"{where}.{c} = {v} must lie in (0, 1.5]")
        out[c] = v
    if len(out) == 1:
        raise ConfigError(f"{where} gives no channel; add a list for one of "
                          f"{', '.join(channels)}")
    return out
