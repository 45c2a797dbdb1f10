"""Symmetry prior: kernels of mirror/rotation-related CFA positions agree.

The patch classifier only looks at per-channel statistics of the patch
(channel means, standard deviations, which channels saturate), all of
which are unchanged when the patch is mirrored or rotated *as long as every
raw pixel keeps its channel*. So if an element ``g`` of the symmetry group of
the square (the dihedral group D4: identity, left-right and up-down flips,
180° rotation, transpose, anti-transpose and the two 90° rotations) maps the
channel layout of the patch around CFA position group ``a`` onto the layout
around group ``b``,

.. math:: L_b[g u] = L_a[u] \\quad \\text{for every tap } u,

then a scene mirrored by ``g`` puts every pixel of class ``(a, s, l, c)``
into class ``(b, s, l, c)`` with the same patch values moved to ``g u``; the
colour it should render is unchanged (output channels are colours, not
positions). The ideal kernels therefore satisfy

.. math:: K_b[g u] = K_a[u], \\qquad K_b[\\text{const}] = K_a[\\text{const}].

The valid pairs ``(a, g) -> b`` form a groupoid (closed under composition
and inverses). The orthogonal projection onto the kernels satisfying all
constraints is the groupoid average: for a representative ``a`` of each orbit,

.. math:: K_a \\leftarrow \\frac{\\sum_{g \\in V_a} w_{T(a,g)}\\, g^{-1} K_{T(a,g)}}
                              {\\sum_{g \\in V_a} w_{T(a,g)}},

with ``V_a`` the elements valid at ``a`` and ``w`` the class sample counts
(empty classes weigh 0; where the whole orbit is empty, equal weights). The
other members are then *copied* exactly, ``K_b = g K_a``, and the
representative is made exactly invariant under its stabiliser (each orbit of
taps gets one value), so symmetric kernels agree bit for bit.

A class that had too few samples but whose mirror partner was trained gets
its partner's (mirrored) kernel: it is filled by symmetry.

References
----------
.. [1] Q. Tian, S. Lansel, J. E. Farrell, B. A. Wandell, "Automating the design
   of image processing pipelines for novel color filter arrays: Local, Linear,
   Learned (L3) method", Proc. SPIE 9023, Digital Photography X (2014).
.. [2] J.-P. Serre, *Linear Representations of Finite Groups*, Springer (1977),
   §2.6 (projection onto invariants by group averaging).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from l3cli.classify import ClassDefinition

__all__ = ["D4_ELEMENTS", "SymmetryMap", "symmetry_map", "tap_permutation", "symmetrize_kernels"]

#: The eight elements of D4 as 2x2 integer matrices acting on centred tap
#: coordinates ``(dy, dx)``.
D4_ELEMENTS: dict[str, tuple[tuple[int, int], tuple[int, int]]] = {
    "identity": ((1, 0), (0, 1)),
    "flip-lr": ((1, 0), (0, -1)),
    "flip-ud": ((-1, 0), (0, 1)),
    "rot180": ((-1, 0), (0, -1)),
    "transpose": ((0, 1), (1, 0)),
    "anti-transpose": ((0, -1), (-1, 0)),
    "rot90": ((0, -1), (1, 0)),
    "rot270": ((0, 1), (-1, 0)),
}


def tap_permutation(name: str, size: int) -> np.ndarray:
    """Permutation of raster taps of a ``size`` x ``size`` patch under a D4 element.

    Returns
    -------
    numpy.ndarray
        int64 (size*size,): ``perm[k]`` is the raster index of ``g u_k`` where
        ``u_k`` is the centred coordinate of tap ``k``. So ``(g A)[perm] = A``
        and ``(g^{-1} A) = A[perm]`` for a raveled patch array ``A``.
    """
    m = np.array(D4_ELEMENTS[name], dtype=np.int64)
    r = size // 2
    dy, dx = np.divmod(np.arange(size * size), size)
    u = np.stack([dy - r, dx - r])
    v = m @ u
    return (v[0] + r) * size + (v[1] + r)


@dataclass(frozen=True)
class SymmetryMap:
    """Which D4 elements map the patch layout of each position group onto another.

    Attributes
    ----------
    target
        int64 (n_groups, 8): ``target[a, e]`` is the group ``b`` whose layout is
        element ``e`` applied to the layout of ``a`` (``-1`` when none).
    perms
        int64 (8, S*S) tap permutations (:func:`tap_permutation`).
    names
        Names of the 8 elements (order of :data:`D4_ELEMENTS`).
    orbits
        Lists of groups related by some element (each sorted; representative first).
    tex_perm
        int64 (8, n_texture): ``tex_perm[e, t]`` is the texture bin (contrast,
        orientation, context) that bin ``t`` becomes when the patch moves by
        element ``e``; the identity unless the table has orientation bins
        (an edge's angle turns with the patch).
    """

    target: np.ndarray
    perms: np.ndarray
    names: tuple[str, ...]
    orbits: tuple[tuple[int, ...], ...]
    tex_perm: np.ndarray | None = None

    def describe(self) -> dict:
        """JSON-friendly summary: orbits, each group's stabiliser, one element per map."""
        stab = {}
        maps = []
        for a in range(self.target.shape[0]):
            stab[str(a)] = [n for e, n in enumerate(self.names)
                            if self.target[a, e] == a and n != "identity"]
            done = set()
            for e, name in enumerate(self.names):
                b = int(self.target[a, e])
                if b >= 0 and b != a and b not in done:
                    done.add(b)
                    maps.append({"from": a, "to": b, "element": name})
        return {"orbits": [list(o) for o in self.orbits], "stabilisers": stab, "maps": maps}


def symmetry_map(definition: ClassDefinition, *, elements: tuple[str, ...] | None = None
                 ) -> SymmetryMap:
    """Find the symmetry relations between the position groups of a class definition.

    Parameters
    ----------
    definition
        The table's class definition (CFA, patch size, position groups).
    elements
        D4 element names to use (default: all eight). The set is closed into a
        group by composition, so the projection is exact.
    """
    names = tuple(D4_ELEMENTS)
    allowed = _closure(elements) if elements is not None else set(names)
    s = definition.patch
    cfa = definition.cfa
    ng = definition.n_groups
    layouts = []
    for g in range(ng):
        p = int(np.flatnonzero(definition.position_group == g)[0])
        layouts.append(cfa.neighbourhood(p, s).ravel())
    perms = np.stack([tap_permutation(n, s) for n in names])
    key = {lay.tobytes(): g for g, lay in enumerate(layouts)}
    target = np.full((ng, len(names)), -1, dtype=np.int64)
    for a in range(ng):
        for e, name in enumerate(names):
            if name not in allowed:
                continue
            moved = np.empty_like(layouts[a])
            moved[perms[e]] = layouts[a]
            b = key.get(moved.tobytes())
            if b is not None:
                target[a, e] = b
    # orbits (connected components)
    seen: set[int] = set()
    orbits = []
    for a in range(ng):
        if a in seen:
            continue
        orb = sorted({int(b) for b in target[a] if b >= 0} | {a})
        seen.update(orb)
        orbits.append(tuple(orb))
    tex_perm = np.stack([definition.texture_permutation(np.array(D4_ELEMENTS[n]))
                         for n in names])
    return SymmetryMap(target=target, perms=perms, names=names, orbits=tuple(orbits),
                       tex_perm=tex_perm)


def _rest_perms(definition: ClassDefinition, smap: SymmetryMap) -> np.ndarray:
    """int64 (8, rest): the class (within a group) each class moves to under each element."""
    ns_nl = definition.n_saturation * definition.n_levels
    nt = definition.n_texture
    tp = smap.tex_perm if smap.tex_perm is not None else np.tile(np.arange(nt), (8, 1))
    base = (np.arange(ns_nl) * nt)[:, None]
    return (base[None] + tp[:, None, :]).reshape(len(smap.names), ns_nl * nt)


def _closure(elements: tuple[str, ...]) -> set[str]:
    """Names of the subgroup of D4 generated by ``elements``."""
    from l3cli.errors import ConfigError

    mats = {}
    for n in elements:
        if n not in D4_ELEMENTS:
            raise ConfigError(f"symmetry element {n!r} is not known; use {', '.join(D4_ELEMENTS)}")
        mats[n] = np.array(D4_ELEMENTS[n])
    inv = {np.array(v).tobytes(): k for k, v in D4_ELEMENTS.items()}
    group = {"identity"} | set(mats)
    changed = True
    while changed:
        changed = False
        for a in list(group):
            for b in list(group):
                m = np.array(D4_ELEMENTS[a]) @ np.array(D4_ELEMENTS[b])
                n = inv[m.tobytes()]
                if n not in group:
                    group.add(n)
                    changed = True
    return group


def _tap_orbits(perms: np.ndarray) -> np.ndarray:
    """Label of each tap's orbit under the permutations (union-find)."""
    n = perms.shape[1]
    parent = np.arange(n)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for perm in perms:
        for k in range(n):
            a, b = find(k), find(int(perm[k]))
            if a != b:
                parent[max(a, b)] = min(a, b)
    return np.array([find(k) for k in range(n)])


def symmetrize_kernels(kernels: np.ndarray, weights: np.ndarray, definition: ClassDefinition,
                       smap: SymmetryMap) -> np.ndarray:
    """Project kernels onto the symmetric ones (groupoid average, exact copies).

    Parameters
    ----------
    kernels
        float (n_classes, S*S + 1, n_out).
    weights
        float (n_classes,) non-negative weights (sample counts; 0 = no data).
    definition
        The class definition.
    smap
        Relations from :func:`symmetry_map`.

    Returns
    -------
    numpy.ndarray
        float64 kernels of the same shape; for every valid ``a --g--> b`` and
        every (saturation, level, contrast), ``K_b[perm_g] == K_a`` exactly.
    """
    ng = definition.n_groups
    rest = definition.n_saturation * definition.n_levels * definition.n_texture
    q = definition.n_coeffs
    P = q - 1
    k = np.asarray(kernels, dtype=np.float64).reshape(ng, rest, q, -1)
    w = np.asarray(weights, dtype=np.float64).reshape(ng, rest)
    out = k.copy()
    rp = _rest_perms(definition, smap)
    moves_classes = definition.orientation_bins > 0
    for orb in smap.orbits:
        a = orb[0]
        valid = [(e, int(smap.target[a, e])) for e in range(len(smap.names))
                 if smap.target[a, e] >= 0]
        num = np.zeros((rest, q, k.shape[3]))
        den = np.zeros(rest)
        eq = np.zeros((rest, q, k.shape[3]))
        for e, b in valid:
            kb = k[b][rp[e]]  # the class of b that class r of a moves to
            moved = kb.copy()
            moved[:, :P] = kb[:, smap.perms[e]]  # g^{-1} K_b
            wb = w[b][rp[e]]
            num += wb[:, None, None] * moved
            den += wb
            eq += moved
        ka = np.where(den[:, None, None] > 0, num / np.where(den > 0, den, 1.0)[:, None, None],
                      eq / len(valid))
        if not moves_classes:
            # exact invariance under the stabiliser of a (with orientation bins the
            # stabiliser also moves classes; the average above is then invariant
            # up to rounding)
            stab = np.array([smap.perms[e] for e, b in valid if b == a])
            labels = _tap_orbits(stab)
            taps = ka[:, :P]
            for lab in np.unique(labels):
                members = np.flatnonzero(labels == lab)
                if members.size > 1:
                    taps[:, members] = taps[:, members].mean(axis=1, keepdims=True)
        out[a] = ka
        for b in orb[1:]:
            e = next(e for e, bb in valid if bb == b)
            kb = ka.copy()
            kb[:, smap.perms[e]] = ka[:, :P]  # g K_a
            out[b][rp[e]] = kb
    return out.reshape(kernels.shape)


def orbit_weights(weights: np.ndarray, definition: ClassDefinition, smap: SymmetryMap
                  ) -> np.ndarray:
    """Sum of ``weights`` over each class's symmetry orbit (same for all members)."""
    ng = definition.n_groups
    w = np.asarray(weights, dtype=np.float64).reshape(ng, -1)
    out = w.copy()
    rp = _rest_perms(definition, smap)
    for orb in smap.orbits:
        a = orb[0]
        moves = {a: np.arange(w.shape[1])}
        for b in orb[1:]:
            e = next(e for e in range(len(smap.names)) if smap.target[a, e] == b)
            moves[b] = rp[e]
        tot = sum(w[b][moves[b]] for b in orb)
        for b in orb:
            out[b][moves[b]] = tot
    return out.reshape(np.shape(weights))
