"""Which pixels of a training image train: its valid pixels within a seeded random subset.

Used by every training pass that reads pairs (:mod:`l3cli.train.fit`, the tone
curve's :mod:`l3cli.tone.fit`, cross-validation), so it lives below them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from l3cli.train.options import TrainOptions

__all__ = ["sample_mask", "training_pixels"]


def sample_mask(shape: tuple[int, int], fraction: float, seed: int, index: int,
                stream: int = 0) -> np.ndarray | None:
    """Deterministic random pixel subset of image number ``index`` (None = all)."""
    if fraction >= 1.0:
        return None
    rng = np.random.default_rng([seed, index, stream])
    return rng.random(shape, dtype=np.float32) < fraction


def training_pixels(shape: tuple[int, int], valid: np.ndarray | None, opts: TrainOptions,
                    index: int) -> np.ndarray | None:
    """The pixels of image number ``index`` that train (None = all): its valid render
    pixels (``valid``, None = all) within ``opts.sample_fraction``'s subset."""
    mask = sample_mask(shape, opts.sample_fraction, opts.seed, index)
    if valid is None:
        return mask
    return valid if mask is None else mask & valid
