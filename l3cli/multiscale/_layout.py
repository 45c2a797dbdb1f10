"""What the multi-scale stage's loops (:mod:`l3cli.multiscale._loops`) and their caller
(:mod:`l3cli.multiscale.stage`) share, without numba: the caller runs the loops' stored
machine code (:mod:`l3cli.kernel_store`) and imports neither numba nor the loops.
"""

from __future__ import annotations

__all__ = ["MODE_DISPLAY", "MODE_FEATURES", "MODE_FLOAT"]

#: What :func:`l3cli.multiscale._loops.stage_rows` writes: the feature maps, the float
#: output, display integers.
MODE_FEATURES, MODE_FLOAT, MODE_DISPLAY = 0, 1, 2

