"""Dihedral augmentation of the training statistics (mirrored and rotated pairs).

A training pair mirrored or rotated by an element ``g`` of the symmetry group
of the square (D4), raw and render together, is another valid training pair
of the same pipeline when the pipeline itself has no preferred direction. Its
CFA phase differs from the raw's (a left-right flip of a GRBG raw of even
width starts with R), so it is re-phased by dropping one row and/or column --
after which each of its pixels sits at a CFA position whose patch layout is
``g`` applied to the layout of the original pixel's position.

That pair's statistics need no second pass over the pixels. The classifier
looks only at mirror-invariant features of a patch (channel means, contrast,
saturation; orientation bins turn with the patch), so a pixel of class
``(a, s, l, t)`` lands in class ``(b, s, l, t')`` of the mirrored image, with
``b`` the group whose layout is ``g`` of ``a``'s (:func:`l3cli.smooth.symmetry.symmetry_map`)
and ``t'`` its texture bin moved by ``g``, and its patch is the original with
its taps permuted. The statistics of the mirrored pair are therefore the
original ones with the classes relabelled and the rows and columns of ``XᵀX``
and ``XᵀY`` permuted (exact up to the one dropped row/column and the
mirrored padding at the image border; the context feature of
``--context-block`` is only approximately mirror-invariant, its guide blocks
are not). :func:`augment_stats` adds them for every element of the group.

The augmented statistics are the plain sums (a class of a Bayer table gets
8 copies' worth: GCV sees the copies as samples, which lowers λ; by
leave-one-image-out on the bundled frames that did slightly better than
dividing by the copies, 1.305 against 1.311). Which classes count as trained
is decided on the per-copy count (:func:`augment_copies`), as without
augmentation.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from l3cli.errors import ConfigError
from l3cli.train.stats import ClassStats

__all__ = ["AUGMENT_CHOICES", "augment_elements", "augment_copies", "augment_stats"]

#: Values of ``l3 train --augment``: the D4 elements added to each pair.
AUGMENT_CHOICES: dict[str, tuple[str, ...]] = {
    "none": ("identity",),
    "flips": ("identity", "flip-lr", "flip-ud", "rot180"),
    "d4": ("identity", "flip-lr", "flip-ud", "rot180", "transpose", "anti-transpose",
           "rot90", "rot270"),
}


def augment_elements(name: str) -> tuple[str, ...]:
    """D4 element names of an ``--augment`` choice (:data:`AUGMENT_CHOICES`)."""
    if name not in AUGMENT_CHOICES:
        raise ConfigError(f"--augment {name!r} is not known; use {', '.join(AUGMENT_CHOICES)}")
    return AUGMENT_CHOICES[name]


def _names(elements: Sequence[str] | str) -> tuple[str, ...]:
    from l3cli.smooth.symmetry import D4_ELEMENTS

    names = augment_elements(elements) if isinstance(elements, str) else tuple(elements)
    bad = [n for n in names if n not in D4_ELEMENTS]
    if bad:
        raise ConfigError(f"augmentation elements {bad} are not D4 elements")
    return names


def augment_copies(definition, elements: Sequence[str] | str = "d4") -> np.ndarray:
    """int64 (n_classes,): how many copies (original included) each class's
    augmented statistics sum (:func:`augment_stats`)."""
    from l3cli.smooth.symmetry import symmetry_map

    names = _names(elements)
    ng = definition.n_groups
    hits = np.ones(ng, dtype=np.int64)
    if names != ("identity",):
        smap = symmetry_map(definition)
        hits[:] = 0
        for e, name in enumerate(smap.names):
            if name in names:
                for b in smap.target[:, e]:
                    if b >= 0:
                        hits[b] += 1
    return np.repeat(hits, definition.n_classes // ng)


def augment_stats(stats: ClassStats, elements: Sequence[str] | str = "d4", *,
                  normalise: bool = False) -> ClassStats:
    """Statistics of the pairs and their mirrored/rotated copies (see the module notes).

    Parameters
    ----------
    stats
        Statistics of the original pairs.
    elements
        D4 element names (:data:`l3cli.smooth.symmetry.D4_ELEMENTS`) or an
        ``--augment`` choice name; must form a group (the identity included).
        Elements that map a position group onto no group of this CFA are skipped.
    normalise
        Divide each class's statistics by the number of copies it received
        (:func:`augment_copies`; keeps the sample count of the original data).

    Returns
    -------
    ClassStats
        New statistics (``n`` rounded to integers when normalised).
    """
    from l3cli.smooth.symmetry import _rest_perms, symmetry_map

    names = _names(elements)
    d = stats.definition
    if names == ("identity",):
        return ClassStats(d, stats.n.copy(), stats.xtx.copy(), stats.xty.copy(),
                          stats.yy.copy(), stats.target_space)
    smap = symmetry_map(d)
    rp = _rest_perms(d, smap)
    ng = d.n_groups
    rest = d.n_saturation * d.n_levels * d.n_texture
    q, n_out = d.n_coeffs, stats.n_out
    n = stats.n.astype(np.float64).reshape(ng, rest)
    xtx = stats.xtx.reshape(ng, rest, q, q)
    xty = stats.xty.reshape(ng, rest, q, n_out)
    yy = stats.yy.reshape(ng, rest, n_out)
    on, oxtx = np.zeros_like(n), np.zeros_like(xtx)
    oxty, oyy = np.zeros_like(xty), np.zeros_like(yy)
    hits = np.zeros(ng)
    for e, name in enumerate(smap.names):
        if name not in names:
            continue
        # tap k of the original patch moves to tap perm[k]: moved = x[inv]
        inv = np.argsort(np.concatenate([smap.perms[e], [q - 1]]))
        for a in range(ng):
            b = int(smap.target[a, e])
            if b < 0:
                continue
            dst = rp[e]
            on[b, dst] += n[a]
            oxtx[b, dst] += xtx[a][:, inv][:, :, inv]
            oxty[b, dst] += xty[a][:, inv]
            oyy[b, dst] += yy[a]
            hits[b] += 1
    if normalise:
        scale = 1.0 / np.maximum(hits, 1.0)
        on *= scale[:, None]
        oxtx *= scale[:, None, None, None]
        oxty *= scale[:, None, None, None]
        oyy *= scale[:, None, None]
    return ClassStats(d, np.rint(on).astype(np.int64).reshape(-1), oxtx.reshape(stats.xtx.shape),
                      oxty.reshape(stats.xty.shape), oyy.reshape(stats.yy.shape),
                      stats.target_space)
