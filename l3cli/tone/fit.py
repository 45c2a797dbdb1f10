"""The renders' tone curve in training (:mod:`l3cli.tone.curve`; ``--tone-curve``).

``l3 train`` fits the curve to every pair's flat blocks, as pass 2 sees them
(white-balanced mosaic, adapted target), keeps it only where it predicts
held-out images better than the sRGB decoding
(:func:`l3cli.tone.curve.select_curve`), accumulates the statistics in its
space and stores its inverse look-up table in the table.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from l3cli.colourspace import srgb_encode
from l3cli.pairs import Pair, load_pair
from l3cli.table import TransformTable
from l3cli.train.options import NO_CURVE, NOTHING, Fitted, TrainOptions
from l3cli.train.pixels import training_pixels

__all__ = ["curve_samples", "fit_pairs_curve", "chosen_curve", "attach_curve"]

log = logging.getLogger(__name__)


def curve_samples(mosaic: np.ndarray, cfa, target: np.ndarray, mask: np.ndarray | None,
                  opts: TrainOptions):
    """Flat-block samples of one pair for the tone curve (:func:`l3cli.tone.curve.block_samples`)."""
    from l3cli.tone.curve import block_samples

    enc = srgb_encode(np.clip(target, 0.0, 1.0))
    return block_samples(mosaic, cfa, enc, saturation=opts.saturation, mask=mask)


def fit_pairs_curve(pairs: Sequence[Pair], opts: TrainOptions, fitted: Fitted = NOTHING):
    """The renders' tone curve, from every training pair (as pass 2 sees them: with the
    shading field and the white adaptation of ``fitted``).

    Returns
    -------
    curve, record
        The curve, or None when it does not generalise better than the sRGB
        decoding (:func:`l3cli.tone.curve.select_curve`) or the renders have
        too few flat, unclipped blocks (with a warning): the table is then
        trained in the target space itself, as with ``--no-tone-curve``.
    """
    from l3cli.whitebalance.model import training_mosaic, training_target

    samples = []
    for i, pair in enumerate(pairs):
        loaded = load_pair(pair, target_space=opts.target_space)
        mask = training_pixels(loaded.raw.mosaic.shape, loaded.weight_mask, opts, i)
        samples.append(curve_samples(training_mosaic(loaded.raw, opts, fitted), loaded.raw.cfa,
                                     training_target(loaded.target, pair.raw, opts, fitted),
                                     mask, opts))
    return chosen_curve(samples)


def chosen_curve(samples) -> tuple:
    """:func:`l3cli.tone.curve.select_curve` with the log lines of ``l3 train``."""
    from l3cli.tone.curve import select_curve

    curve, record = select_curve(samples)
    if record.get("reason"):
        log.warning(NO_CURVE)
    elif curve is None:
        log.info("tone curve: held-out residual %.3g vs %.3g for the sRGB decoding; "
                 "training without it", record["heldout_rms"], record["srgb_heldout_rms"])
    else:
        log.info("tone curve: held-out residual %.3g vs %.3g for the sRGB decoding; "
                 "training in its space", record["heldout_rms"], record["srgb_heldout_rms"])
    return curve, record


def attach_curve(table: TransformTable, curve, record: dict | None = None) -> TransformTable:
    """Store a fitted tone curve's inverse look-up table in ``table`` (None: nothing)."""
    if curve is not None:
        table.tone_lut = curve.lut(table.output_space)
        table.provenance["tone_curve"] = {**(record or {}), **curve.as_dict()}
    elif record is not None:
        table.provenance["tone_curve"] = record
    return table
