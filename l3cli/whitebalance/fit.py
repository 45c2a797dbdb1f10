"""The white-balance adaptation model of the training shots (a training pass).

The model's value and its use at render time are :mod:`l3cli.whitebalance.model`
(the model layer); fitting it reads the training pairs, so it is training's:
it lives here, above the inputs (:mod:`l3cli.pairs`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from l3cli.whitebalance.model import (
    ADAPT_SPACE,
    WhiteBalanceModel,
    _key,  # the capture key training_target looks up
    apply_gains,
    fit_adaptation_model,
    fit_shot_matrix,
    quick_rgb,
    training_gains,
)

__all__ = ["fit_white_adaptation"]


def fit_white_adaptation(pairs: Sequence[Any], opts: Any
                         ) -> tuple[WhiteBalanceModel, dict[str, list]]:
    """The adaptation model of the training shots (an extra pass of training).

    For every training pair, the 3x3 ``F_s`` that best maps a plain demosaic
    (:func:`~l3cli.whitebalance.model.quick_rgb`) of the white-balanced raw onto the target in the
    linear :data:`~l3cli.whitebalance.model.ADAPT_SPACE` (valid, unsaturated pixels): what the
    converter did to this shot's colours, up to its spatial processing,
    which all shots share. ``F`` is modelled as linear in the white's
    features (:func:`~l3cli.whitebalance.model.fit_adaptation_model`), and the adaptation of a white is
    ``A(w) = F(w) F(w_0)^-1`` relative to the mean training white ``w_0``.
    The table is then trained on the targets with ``A(w_s)`` taken out, so
    every shot teaches the same mapping; rendering applies ``A`` of the raw's
    own white. When all training whites coincide the model is the identity
    and nothing is taken out.

    Returns
    -------
    model, adapt
        The model, and per capture (its raw's absolute path) the inverse of
        its modelled matrix (empty when the whites coincide).
    """
    from scipy.ndimage import minimum_filter

    from l3cli.colourspace import convert
    from l3cli.pairs import load_pair

    space = ADAPT_SPACE[opts.target_space]
    whites, mats, keys = [], [], []
    for pair in pairs:
        keys.append(_key(pair.raw))
        loaded = load_pair(pair, target_space=opts.target_space)
        raw, target, valid = loaded.raw, loaded.target, loaded.weight_mask
        gains = training_gains(raw, opts)
        whites.append(gains)
        rgb = quick_rgb(apply_gains(raw.mosaic, raw.cfa, gains, opts.saturation), raw.cfa)
        t = convert(target, opts.target_space, space) if opts.target_space != space else target
        ok = minimum_filter(raw.mosaic < opts.saturation, size=5)
        if valid is not None:
            ok &= valid
        mats.append(fit_shot_matrix(rgb, t, ok))
    whites_a = np.array(whites)
    if len({tuple(np.round(np.log(w), 3)) for w in whites_a}) < 2:
        ident = np.eye(3).reshape(1, 9)
        return WhiteBalanceModel(space, np.zeros(0), ident, whites_a), {}
    f_model = fit_adaptation_model(whites_a, np.array(mats), space)
    f0_inv = np.linalg.inv(f_model.coef[0].reshape(3, 3))
    # A(w) = F(w) F0^-1 is linear in the features too: right-multiply every term.
    coef = np.array([(c.reshape(3, 3) @ f0_inv).ravel() for c in f_model.coef])
    model = WhiteBalanceModel(space, f_model.center, coef, whites_a)
    adapt = {k: np.linalg.inv(model.matrix(w)).tolist() for k, w in zip(keys, whites_a,
                                                                          strict=True)}
    return model, adapt
