"""Lens shading in training (:mod:`l3cli.lens.field`; ``l3 train --shading``).

``l3 train`` learns the gain field from the pairs before anything else, so
that every later step (level cut points, white adaptation, tone curve,
statistics) sees the corrected mosaics (:func:`l3cli.whitebalance.model.training_mosaic`
applies the fitted field, :class:`l3cli.train.options.Fitted`). The field is fitted
in the renders' linear space (sRGB decoding), or in the space of the learned tone
curve when there is one, curve and field refitted in turn until the field's
held-out residual stops falling (:func:`learn_shading`). The field itself (its
model chosen by held-out blocks: other images, or spatial folds of a single image)
is :func:`l3cli.lens.fit.fit_field`'s.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from l3cli.colourspace import convert, srgb_encode
from l3cli.lens.field import GainField
from l3cli.lens.fit import BlockSamples, block_samples, fit_field
from l3cli.pairs import Pair, load_pair

__all__ = ["pair_blocks", "fit_pairs_shading", "learn_shading"]

log = logging.getLogger(__name__)

#: Alternations of tone curve and gain field at most (:func:`learn_shading`).
ALTERNATIONS = 4


def pair_blocks(pairs: Sequence[Pair], opts, tone_model=None
                ) -> tuple[list[BlockSamples], object, tuple | None]:
    """Block samples of every pair (uncorrected mosaics), the full raws' CFA and size;
    the targets in the space of ``tone_model`` (the renders' tone curve) when given.

    The size is None when the training raws differ in size or a render is a
    resized copy (no field is learned then).
    """
    from l3cli.align import ScaledAlignment
    from l3cli.train.pixels import training_pixels
    from l3cli.whitebalance.model import training_mosaic, training_target

    samples, sizes, cfa = [], set(), None
    for i, pair in enumerate(pairs):
        loaded = load_pair(pair, target_space=opts.target_space)
        raw = loaded.raw
        if isinstance(loaded.alignment, ScaledAlignment):
            log.warning("%s: a resized render; no shading gain field is learned", pair.target)
            return [], None, None
        meta = raw.metadata
        full = tuple(meta.get("full_size", raw.mosaic.shape))
        y0, x0 = (meta.get("crop") or (0, 0))[:2]
        sizes.add((int(full[0]), int(full[1])))
        cfa = raw.cfa.shifted(-y0, -x0)
        mask = training_pixels(raw.mosaic.shape, loaded.weight_mask, opts, i)
        target = training_target(loaded.target, pair.raw, opts)
        if tone_model is not None:
            target = tone_model.linearise(srgb_encode(np.clip(target, 0.0, 1.0)))
        elif opts.target_space in ("srgb", "lab"):  # the model needs a linear space
            target = convert(target, opts.target_space, "linear-srgb")
        samples.append(block_samples(training_mosaic(raw, opts), raw.cfa, target, mask,
                                     full_shape=full, origin=(int(y0), int(x0)),
                                     saturation=opts.saturation))
    if len(sizes) != 1:
        log.warning("the training raws differ in size (%s); no shading gain field is learned",
                    ", ".join(f"{w}x{h}" for h, w in sorted(sizes)))
        return [], cfa, None
    return samples, cfa, sizes.pop()


def fit_pairs_shading(pairs: Sequence[Pair], opts, tone_model=None
                      ) -> tuple[GainField | None, dict]:
    """The gain field of the pairs (None when it does not help on held-out images).

    Returns
    -------
    field, record
        The record goes to the table's provenance (``shading``).
    """
    samples, cfa, size = pair_blocks(pairs, opts, tone_model)
    if size is None:
        return None, {"reason": "raws of different sizes or resized renders"}
    field, record = fit_field(samples, cfa, size)
    if field is None:
        # a fit that was made but is not usable is dropped with a note; "no better than
        # none" and "too few blocks" are the ordinary outcomes (info)
        level = logging.WARNING if record.get("unusable") else logging.INFO
        log.log(level, "shading: %s; training without a gain field", record.get("reason"))
    else:
        log.info("shading: gain field kept (%s; held-out block residual %.4g vs %.4g "
                 "without): %s", record.get("model"), record.get("heldout_rms"),
                 record.get("none_heldout_rms"), field.summary())
    return field, record


def learn_shading(pairs: Sequence[Pair], opts) -> tuple[GainField | None, dict]:
    """The gain field, learned jointly with the renders' tone curve (``opts.tone_curve``).

    The field is fitted in the linear space of the tone curve (the space the
    kernels train in); the curve is fitted on the corrected mosaics. Curve and
    field are refitted in turn (curve on the raws as they are, field, curve on
    the corrected raws, field, ...) until the field's held-out block residual
    falls by less than 1 %, at most :data:`ALTERNATIONS` times (without a tone
    curve: the field once, in the sRGB decoding of the renders). The record's
    ``alternations`` lists each round's held-out residual.
    """
    from l3cli.tone.fit import fit_pairs_curve
    from l3cli.train.options import Fitted

    work = Fitted()
    field, record = None, {}
    rounds: list[float] = []
    for _ in range(ALTERNATIONS if opts.tone_curve else 1):
        if opts.tone_curve:
            work = Fitted(shading_field=work.shading_field,
                          tone_model=fit_pairs_curve(pairs, opts, work)[0])
        new_field, new_record = fit_pairs_shading(pairs, opts, work.tone_model)
        if new_field is None:
            if field is None:
                field, record = None, new_record
            break
        score = float(new_record.get("heldout_rms", np.inf))
        if rounds and score > rounds[-1]:  # worse than the round before: keep that one
            break
        field, record = new_field, new_record
        rounds.append(score)
        work = Fitted(shading_field=field, tone_model=work.tone_model)
        if len(rounds) > 1 and score > 0.99 * rounds[-2]:
            break
    if rounds:
        record["alternations"] = rounds
    return field, record
