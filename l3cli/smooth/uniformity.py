"""Uniformity prior: a uniform scene renders uniform.

Under a spatially uniform scene every raw pixel of channel ``c`` reads its own
value ``v_c``. Every patch then has the same per-channel means, no texture and
the same saturated channels, so all CFA positions fall into the same
(saturation, level, contrast) slot and differ only in their position group
``p``. The rendered value at a pixel of group ``p`` is

.. math:: o_p = \\sum_c S_{p,c}\\, v_c + b_p, \\qquad
          S_{p,c} = \\sum_{k:\\, L_p[k] = c} K_p[k],

so the image is uniform for *every* ``v`` exactly when the per-channel sums
``S_{p,c}`` and the offsets ``b_p`` agree across groups (per output channel).
Otherwise a flat wall renders with a fixed pattern of the CFA period (the
classic "maze" or grid artefact).

The smallest change (least squares over the kernel taps, weighted by the
class's sample count ``w_p``) that enforces common values ``S*_c``, ``b*`` is

.. math:: \\min \\sum_p w_p \\lVert K'_p - K_p \\rVert^2
          \\ \\text{s.t.}\\ S'_{p,c} = S^*_c,\\ b'_p = b^*

For fixed targets, the minimum-norm change of group ``p`` spreads
``(S^*_c - S_{p,c}) / n_{p,c}`` equally over its ``n_{p,c}`` taps of channel
``c`` (the projection onto an affine hyperplane along its normal), costing
``w_p (S^*_c - S_{p,c})^2 / n_{p,c}``; minimising over the targets gives

.. math:: S^*_c = \\frac{\\sum_p (w_p / n_{p,c}) S_{p,c}}{\\sum_p w_p / n_{p,c}},
          \\qquad b^* = \\frac{\\sum_p w_p b_p}{\\sum_p w_p}.

This *least-squares* choice (``target="least-squares"``) moves the flat-field
colour towards the best-sampled positions. The default, ``target="period-mean"``,
takes instead the mean over the CFA positions (each group counted by how
many positions it holds, ``m_p``),

.. math:: S^*_c = \\frac{\\sum_p m_p S_{p,c}}{\\sum_p m_p}, \\qquad
          b^* = \\frac{\\sum_p m_p b_p}{\\sum_p m_p},

which leaves the *average* rendering of every flat area over one CFA period
unchanged (so chart colours do not move) and removes only the fixed
pattern; for these targets the change of each kernel is still the
minimum-norm one. A channel missing from some group's patch (``n_{p,c} = 0``, only
for patches smaller than the CFA repeat) could only agree by having zero
weight everywhere; it is left alone (:func:`missing_channels`). Groups with no data weigh 0 (equal weights when none has data).
The correction is spread equally over taps of a channel, so symmetric
kernels stay symmetric.

A class with no data of its own (still empty after the other priors) whose
slot has trained classes at other positions would render a flat field with a
pattern through its fallback kernel; with ``fill`` its fallback kernel gets
the same minimum-norm change towards the common values (without influencing
them), and it counts as filled by uniformity.

References
----------
.. [1] G. Strang, *Introduction to Linear Algebra*, 5th ed., Wellesley (2016),
   §4.4 (least-squares projection onto a subspace, minimum-norm solutions).
.. [2] H. Jiang, Q. Tian, J. Farrell, B. A. Wandell, "Learning the image
   processing pipeline", IEEE Trans. Image Processing 26(10), 5032-5042 (2017).
"""

from __future__ import annotations

import numpy as np

from l3cli.classify import ClassDefinition

__all__ = ["channel_sums", "make_uniform", "uniformity_error", "fillable", "missing_channels",
           "TARGETS"]


def _layouts(definition: ClassDefinition) -> np.ndarray:
    """(n_groups, S*S) channel index of each tap."""
    s = definition.patch
    out = []
    for g in range(definition.n_groups):
        p = int(np.flatnonzero(definition.position_group == g)[0])
        out.append(definition.cfa.neighbourhood(p, s).ravel())
    return np.stack(out)


def channel_sums(kernels: np.ndarray, definition: ClassDefinition) -> np.ndarray:
    """Per-channel summed weights ``S`` of every class.

    Returns
    -------
    numpy.ndarray
        float64 (n_classes, n_channels, n_out).
    """
    ng = definition.n_groups
    q = definition.n_coeffs
    k = np.asarray(kernels, dtype=np.float64).reshape(ng, -1, q, kernels.shape[-1])
    lay = _layouts(definition)
    nch = definition.cfa.n_channels
    out = np.zeros((ng, k.shape[1], nch, k.shape[-1]))
    for g in range(ng):
        for c in range(nch):
            taps = lay[g] == c
            out[g, :, c] = k[g][:, :-1][:, taps].sum(axis=1)
    return out.reshape(-1, nch, k.shape[-1])


def uniformity_error(kernels: np.ndarray, definition: ClassDefinition,
                     mask: np.ndarray | None = None) -> float:
    """Largest spread across groups of ``S_{p,c}`` or ``b_p`` over all slots.

    ``mask`` (n_classes,) limits the comparison to those classes.
    """
    ng = definition.n_groups
    q = definition.n_coeffs
    s = channel_sums(kernels, definition).reshape(ng, -1, definition.cfa.n_channels,
                                                   kernels.shape[-1])
    b = np.asarray(kernels, dtype=np.float64).reshape(ng, -1, q, kernels.shape[-1])[:, :, -1]
    m = np.ones((ng, s.shape[1]), dtype=bool) if mask is None else np.asarray(mask).reshape(ng, -1)
    worst = 0.0
    for j in range(s.shape[1]):
        sel = m[:, j]
        if sel.sum() < 2:
            continue
        worst = max(worst, float(np.ptp(s[sel, j], axis=0).max()), float(np.ptp(b[sel, j], axis=0).max()))
    return worst


#: How the common values ``S*_c``, ``b*`` are chosen (see the module docstring).
TARGETS = ("period-mean", "least-squares")


def make_uniform(kernels: np.ndarray, weights: np.ndarray, definition: ClassDefinition, *,
                 active: np.ndarray | None = None, target: str = "period-mean",
                 fill: np.ndarray | None = None) -> np.ndarray:
    """Least-squares change making channel sums and offsets equal across groups.

    Parameters
    ----------
    kernels
        (n_classes, S*S + 1, n_out).
    weights
        (n_classes,) non-negative weights (sample counts).
    definition
        Class definition.
    active
        bool (n_classes,) classes taking part (default all). Inactive classes
        are neither changed nor counted (empty classes holding a fallback copy).
    target
        ``"period-mean"``: the common values are the means over the CFA
        positions (each group counted by its number of positions), so the mean
        rendering of a flat area over one CFA period is unchanged;
        ``"least-squares"``: the values minimising the total weighted change.
    fill
        bool (n_classes,) inactive classes to bring to the common values of the
        active classes of their slot (their kernel, a fallback copy, gets the
        minimum-norm change; they do not influence the common values). Use
        :func:`fillable` to see which of them have an active class to follow.

    Returns
    -------
    numpy.ndarray
        float64 kernels; in every (saturation, level, contrast) slot the
        active groups share ``S_{p,c}`` and ``b_p``.
    """
    ng = definition.n_groups
    q = definition.n_coeffs
    n_out = kernels.shape[-1]
    k = np.asarray(kernels, dtype=np.float64).reshape(ng, -1, q, n_out).copy()
    rest = k.shape[1]
    w = np.asarray(weights, dtype=np.float64).reshape(ng, rest)
    act = np.ones((ng, rest), dtype=bool) if active is None else np.asarray(active).reshape(ng, rest)
    lay = _layouts(definition)
    nch = definition.cfa.n_channels
    ntap = np.stack([np.bincount(lay[g], minlength=nch) for g in range(ng)]).astype(np.float64)
    # group multiplicity: number of CFA positions per group (equal-weight fallback)
    mult = np.bincount(definition.position_group, minlength=ng).astype(np.float64)
    sums = np.zeros((ng, rest, nch, n_out))
    for g in range(ng):
        for c in range(nch):
            sums[g, :, c] = k[g][:, :-1][:, lay[g] == c].sum(axis=1)
    if target not in TARGETS:
        from l3cli.errors import ConfigError

        raise ConfigError(f"uniformity target {target!r} is not known; use {', '.join(TARGETS)}")
    fil = np.zeros((ng, rest), dtype=bool) if fill is None else \
        np.asarray(fill).reshape(ng, rest) & ~act
    for j in range(rest):
        sel = np.flatnonzero(act[:, j])
        extra = np.flatnonzero(fil[:, j])
        if sel.size == 0 or sel.size + extra.size < 2:
            continue
        members = np.concatenate([sel, extra])
        wj = w[sel, j]
        if target == "period-mean" or wj.sum() <= 0:
            wj = mult[sel]
        for c in range(nch):
            n = ntap[sel, c]
            if np.any(ntap[members, c] == 0):
                continue  # see missing_channels: cannot be made uniform without zeroing it
            if target == "period-mean":
                goal = (wj[:, None] * sums[sel, j, c]).sum(axis=0) / wj.sum()
            else:
                a = wj / n
                goal = (a[:, None] * sums[sel, j, c]).sum(axis=0) / a.sum()
            for g in members:
                delta = (goal - sums[g, j, c]) / ntap[g, c]
                taps = lay[g] == c
                k[g, j, :-1][taps] += delta[None, :]
        bstar = (wj[:, None] * k[sel, j, -1]).sum(axis=0) / wj.sum()
        k[members, j, -1] = bstar[None, :]
    return k.reshape(kernels.shape)


def missing_channels(definition: ClassDefinition) -> list[str]:
    """Channels absent from the patch of some position group (tiny patches).

    For such a channel the flat-field response cannot agree across positions
    unless its weight is zero everywhere; :func:`make_uniform` leaves it alone.
    """
    lay = _layouts(definition)
    nch = definition.cfa.n_channels
    return [definition.cfa.channels[c] for c in range(nch) if np.any(~(lay == c).any(axis=1))]


def fillable(active: np.ndarray, definition: ClassDefinition) -> np.ndarray:
    """Inactive classes whose (saturation, level, contrast) slot has an active class."""
    ng = definition.n_groups
    act = np.asarray(active, dtype=bool).reshape(ng, -1)
    return (~act & act.any(axis=0, keepdims=True)).ravel()
