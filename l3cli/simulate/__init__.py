"""Spectral camera simulation (``l3 simulate``): scenes, optics, sensor, outputs.

See ``docs/simulation.md`` for the chain, the target scale and the manifest.
"""

from l3cli.simulate.core import (
    TARGET_SCALE_DOC,
    CameraModel,
    Capture,
    capture_seed,
    capture_stem,
    illuminant_irradiance,
    prepare_camera,
    render_planes,
    simulate_capture,
    spectral_weights,
)
from l3cli.simulate.scenes import SCENES, Scene, make_scene

__all__ = [
    "TARGET_SCALE_DOC",
    "CameraModel",
    "Capture",
    "Scene",
    "SCENES",
    "capture_seed",
    "capture_stem",
    "illuminant_irradiance",
    "make_scene",
    "prepare_camera",
    "render_planes",
    "simulate_capture",
    "spectral_weights",
]
