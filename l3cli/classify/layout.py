"""The tile kernel's argument layout: what it needs of a class definition.

:func:`kernel_tables` builds, once per :class:`~l3cli.classify.ClassDefinition`,
the arrays and scalars the numba kernel (:mod:`l3cli.classify.kernel`) takes
in the order of :class:`KernelTables`' fields, which is the kernel's argument
order (a test checks it against the kernel's signature).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from l3cli.classify.definition import ClassDefinition
from l3cli.classify.features import CONTEXT_EPS, CONTEXT_RULES, orientation_centres
from l3cli.classify.levels import level_lookup

__all__ = ["KernelTables", "kernel_tables"]


class KernelTables(NamedTuple):
    """What the tile kernel needs of a class definition, in its argument order."""

    #: int64 (ph, pw): channel index of each CFA position.
    idx_pattern: np.ndarray
    #: float32 (n_positions, n_channels): 1 / pixels of each channel in a patch (0 if none).
    cnt_inv: np.ndarray
    #: float32 (n_positions, n_channels): 1 / channels present in a patch (0 if absent).
    wc: np.ndarray
    #: int64 (n_positions,): position group of each CFA position.
    group: np.ndarray
    #: int32 (n_buckets,): cuts below each level bucket (:class:`~l3cli.classify.levels.LevelLookup`).
    lut: np.ndarray
    #: Right shift of the float32 level bits that numbers the buckets.
    lut_shift: int
    #: Bucket number of the first cut.
    lut_base: int
    #: float32 (n_buckets, 2): level cuts inside each bucket, NaN where none.
    cuts: np.ndarray
    #: float32 (n_levels, n_contrast - 1): contrast thresholds per level.
    ccuts: np.ndarray
    #: float32 saturation threshold.
    sat_thr: np.float32
    #: float32 ``eps`` of the contrast rule.
    eps: np.float32
    #: Number of saturation patterns, ``2 ** n_channels``.
    n_sat: int
    #: Entries of the orientation axis (1 = off).
    n_or: int
    #: float32 (max(N, 1),): cos 2θ_j of the angle-bin centres.
    ori_c: np.ndarray
    #: float32 (max(N, 1),): sin 2θ_j of the angle-bin centres.
    ori_s: np.ndarray
    #: float32 squared coherence threshold.
    coh2: np.float32
    #: 0 = no context, 1 = the guide, 2 = patch level / guide.
    ctx_mode: int
    #: float32 (n_context - 1,) context cut points (one unused entry when off).
    xcuts: np.ndarray
    #: float32 ``eps`` of the ratio rule.
    ctx_eps: np.float32
    #: Highlight bins (1 = off).
    n_hl: int
    #: float32 saturated pixels per patch from which a patch is a strong highlight.
    hl_cnt: np.float32


def kernel_tables(definition: ClassDefinition) -> KernelTables:
    """The :class:`KernelTables` of a definition (built once, cached on it)."""
    tables = definition._tables
    if "kernel" not in tables:
        cfa, s = definition.cfa, definition.patch
        npos, nch = cfa.n_positions, cfa.n_channels
        cnt_inv = np.zeros((npos, nch), dtype=np.float32)
        wc = np.zeros((npos, nch), dtype=np.float32)
        for p in range(npos):
            counts = np.bincount(cfa.neighbourhood(p, s).ravel(), minlength=nch)
            present = counts > 0
            cnt_inv[p, present] = 1.0 / counts[present]
            wc[p, present] = 1.0 / present.sum()
        lut = level_lookup(definition.level_cuts)
        nb_or = definition.orientation_bins
        oc, os_ = orientation_centres(nb_or) if nb_or else (np.zeros(1, np.float32),) * 2
        ctx_mode = 0 if not definition.context_block else 1 + CONTEXT_RULES.index(
            definition.context_rule)
        xcuts = definition.context_cuts.astype(np.float32) if ctx_mode else np.zeros(
            1, np.float32)
        tables["kernel"] = KernelTables(
            idx_pattern=cfa.index_pattern.astype(np.int64), cnt_inv=cnt_inv, wc=wc,
            group=definition.position_group.astype(np.int64), lut=lut.lut,
            lut_shift=int(lut.shift), lut_base=int(lut.base), cuts=lut.cuts,
            ccuts=np.ascontiguousarray(definition.contrast_cuts, dtype=np.float32),
            sat_thr=np.float32(definition.saturation_threshold),
            eps=np.float32(definition.contrast_eps), n_sat=int(definition.n_saturation),
            n_or=int(definition.n_orientation), ori_c=oc, ori_s=os_,
            coh2=np.float32(definition.coherence_threshold ** 2), ctx_mode=int(ctx_mode),
            xcuts=xcuts, ctx_eps=np.float32(CONTEXT_EPS),
            n_hl=int(definition.n_highlight),
            hl_cnt=np.float32(np.ceil(definition.highlight_fraction * s * s - 1e-9)),
        )
    return tables["kernel"]
