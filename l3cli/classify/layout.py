"""The tile kernel's argument layout: what it needs of a class definition.

:func:`kernel_tables` builds, once per :class:`~l3cli.classify.ClassDefinition`,
the arrays and scalars the numba kernel (:mod:`l3cli.classify.tile_kernel`) takes
as its ``tables`` tuple, in the order of :class:`KernelTables`' fields, in which
every entry point unpacks it (a test checks it against the kernel's source). :func:`pack_taps`
lays a table's transforms out for the render loops
(:func:`l3cli.render_rows.affine_taps`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from l3cli.classify.definition import ClassDefinition
from l3cli.classify.features import CONTEXT_EPS, CONTEXT_RULES, orientation_centres
from l3cli.classify.levels import level_lookup

__all__ = ["MODE_CLASSES", "MODE_DISPLAY", "MODE_FEATURES", "MODE_RENDER", "RENDER_LANES",
           "TILE_COLS", "TILE_ROWS", "KernelTables", "kernel_tables", "pack_taps", "tap_lanes",
           "tap_tail"]


#: Output rows and columns of one tile. A tile's padded band, its
#: ring of horizontal sums and its output rows stay in the core's L2 cache.
#: 64 rows rather than 32: the S - 1 rows of horizontal sums a tile shares with
#: the tile above are computed twice, and halving that cost 4-5 % less CPU
#: per render (9 MP, patch 5 and 7; 128 rows gave no more).
TILE_ROWS = 64
TILE_COLS = 512

#: What the tile kernel does with each pixel's class (see :func:`l3cli.classify.kernel.run_tiles`).
MODE_CLASSES, MODE_FEATURES, MODE_RENDER, MODE_DISPLAY = 0, 1, 2, 3


class KernelTables(NamedTuple):
    """What the tile kernel needs of a class definition, in the order it unpacks them."""

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


# ------------------------------------------ the render loops' kernel layout
#: Output lanes of the vectorised render path (tables with up to 4 outputs).
RENDER_LANES = 4


def tap_lanes(S: int) -> int:
    """Lanes of one patch row in :func:`l3cli.render_rows.affine_taps`: ``S`` taps padded
    to whole 8-lane vectors (8 for patches up to 7, 16 for 11 and more); 8 for patch 9,
    whose 9th column is a vector of its own (:func:`tap_tail`)."""
    return 8 if tap_tail(S) else 8 * -(-S // 8)


def tap_tail(S: int) -> bool:
    """Whether patch ``S`` renders its last column apart (patch 9: 8 lanes per row, then
    the 9th column's first 8 rows as one 8-lane vector and its last tap as another, 11
    multiply-adds per output instead of 18 of 16 lanes)."""
    return S == 9


def pack_taps(k: np.ndarray, outputs: int = RENDER_LANES) -> np.ndarray:
    """Kernels (n_classes, S*S + 1, 4) in :func:`l3cli.render_rows.affine_taps`' layout,
    (n_classes, outputs S L + 4) with ``L = tap_lanes(S)`` (patch 9: outputs (S + 2) 8 + 4).

    Per patch row ``dy``, per output ``o`` of the first ``outputs`` (3 for
    three-output tables: no block of zeros to load past): the row's ``S`` taps
    and ``L - S`` zeros (entry ``(dy * outputs + o) * L + dx``); then the 4
    constants. Patch 9 (:func:`tap_tail`): per row and output the taps of columns
    0-7; then per output the 9th column's taps of rows 0-7; then per output its
    row 8 tap and 7 zeros; then the 4 constants.
    """
    nc, q, lanes = k.shape
    S = int(round((q - 1) ** 0.5))
    if S * S + 1 != q or lanes != RENDER_LANES or outputs not in (3, 4):
        raise ValueError(f"kernels of shape {k.shape} are not (n, S*S + 1, 4), "
                         f"or {outputs} outputs not 3 or 4")
    L = tap_lanes(S)
    grid = k[:, :S * S, :outputs].reshape(nc, S, S, outputs).transpose(0, 1, 3, 2)
    taps = np.zeros((nc, S, outputs, L), dtype=np.float32)  # (class, dy, output, dx)
    parts = [taps]
    if tap_tail(S):
        taps[...] = grid[..., :L]
        col = grid[:, :L, :, L].transpose(0, 2, 1)  # (class, output, dy): column 8, rows 0-7
        corner = np.zeros((nc, outputs, L), dtype=np.float32)
        corner[..., 0] = grid[:, L, :, L]
        parts += [col, corner]
    else:
        taps[..., :S] = grid
    return np.ascontiguousarray(np.concatenate([p.reshape(nc, -1) for p in parts]
                                               + [k[:, S * S]], axis=1), dtype=np.float32)
