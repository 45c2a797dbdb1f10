"""Per-class sufficient statistics of the L3 regression.

For every class ``c`` training needs only

* ``n_c``   -- number of samples,
* ``XᵀX_c`` -- (q, q) with ``q = S*S + 1`` (patch values and a constant 1, last),
* ``XᵀY_c`` -- (q, n_out),
* ``Σy²_c`` -- (n_out,) sum of squared targets,

accumulated in float64. They add over images, so memory does not grow with
the data and statistics computed separately (other processes, machines) are
merged with ``+``. :mod:`l3cli.train.ridge` solves the ridge problem and its
generalised cross-validation exactly from them.

Accumulation: the classes of the selected pixels are computed by the shared
classifier (:mod:`l3cli.classify`), a counting sort lists each class's pixels,
and a numba kernel, parallel over classes, gathers each class's patches 64 at
a time straight from the mosaic into an L1-resident block and forms the
products with register-tiled, vectorised sums (BLAS's own threads would fight
numba's on these many small products).
"""

from __future__ import annotations

import functools
import heapq
import os
from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np

from l3cli.cfa import CFA
from l3cli.classify import ClassDefinition, band_rows, describe_difference
from l3cli.errors import InputError, TableError
from l3cli.io.atomic import atomic_path
from l3cli.startup import lean_cache

__all__ = ["ClassStats", "accumulate"]

STATS_FORMAT = "l3-stats"
STATS_VERSION = 1


@dataclass(eq=False)
class ClassStats:
    """Sufficient statistics per class (adds with ``+``).

    Attributes
    ----------
    definition
        The class definition the statistics were collected with.
    n
        int64 (n_classes,) sample counts.
    xtx
        float64 (n_classes, q, q).
    xty
        float64 (n_classes, q, n_out).
    yy
        float64 (n_classes, n_out).
    target_space
        Colour space of the targets.
    """

    definition: ClassDefinition
    n: np.ndarray
    xtx: np.ndarray
    xty: np.ndarray
    yy: np.ndarray
    target_space: str = "xyz"

    @classmethod
    def zeros(cls, definition: ClassDefinition, n_out: int, *,
              target_space: str = "xyz") -> ClassStats:
        """Empty statistics for ``definition`` and ``n_out`` target channels."""
        nc, q = definition.n_classes, definition.n_coeffs
        return cls(definition, np.zeros(nc, np.int64), np.zeros((nc, q, q)),
                   np.zeros((nc, q, n_out)), np.zeros((nc, n_out)), target_space)

    @property
    def n_out(self) -> int:
        """Number of target channels."""
        return int(self.yy.shape[1])

    def _check_compatible(self, other: ClassStats) -> None:
        if not self.definition.same_as(other.definition):
            raise TableError("cannot add statistics collected with different class definitions"
                             f" ({describe_difference(self.definition, other.definition)})")
        if self.n_out != other.n_out or self.target_space != other.target_space:
            raise TableError(
                f"cannot add statistics for {self.n_out} {self.target_space} outputs and "
                f"{other.n_out} {other.target_space} outputs"
            )

    def __add__(self, other: ClassStats) -> ClassStats:
        if other == 0:  # sum() starts with 0
            return self
        self._check_compatible(other)
        return ClassStats(self.definition, self.n + other.n, self.xtx + other.xtx,
                          self.xty + other.xty, self.yy + other.yy, self.target_space)

    __radd__ = __add__

    def __iadd__(self, other: ClassStats) -> ClassStats:
        self._check_compatible(other)
        self.n += other.n
        self.xtx += other.xtx
        self.xty += other.xty
        self.yy += other.yy
        return self

    # ----------------------------------------------------------------- files
    def save(self, path: str | os.PathLike) -> Path:
        """Write as NPZ (atomic), with the class definition."""
        path = Path(path)
        arrays = {"format": np.array(STATS_FORMAT), "version": np.array(STATS_VERSION),
                  **self.definition.to_dict(), "n": self.n, "xtx": self.xtx, "xty": self.xty,
                  "yy": self.yy, "target_space": np.array(self.target_space)}
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> ClassStats:
        """Read statistics written by :meth:`save`."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                a = {k: z[k] for k in z.files}
        except Exception as exc:  # noqa: BLE001 - any reading problem is a damaged file
            raise TableError(f"{path}: not a statistics NPZ or damaged ({exc})") from exc
        if str(a.get("format", "")) != STATS_FORMAT or int(a.get("version", -1)) != STATS_VERSION:
            raise TableError(f"{path}: not an {STATS_FORMAT} version {STATS_VERSION} file")
        d = ClassDefinition(
            cfa=CFA.from_spec(str(a["cfa"])), patch=int(a["patch"]),
            level_cuts=a["level_cuts"], level_spacing=str(a["level_spacing"]),
            contrast_cuts=a["contrast_cuts"],
            saturation_threshold=float(a["saturation_threshold"]),
            position_group=a["position_group"], contrast_eps=float(a["contrast_eps"]),
            contrast_rule=str(a["contrast_rule"]), saturation_rule=str(a["saturation_rule"]),
        )
        s = cls(d, a["n"].astype(np.int64), a["xtx"], a["xty"], a["yy"], str(a["target_space"]))
        nc, q = d.n_classes, d.n_coeffs
        if s.xtx.shape != (nc, q, q) or s.xty.shape[:2] != (nc, q) or s.yy.shape != (
                nc, s.xty.shape[2]) or s.n.shape != (nc,):
            raise TableError(f"{path}: statistics shapes do not fit the class definition")
        return s


# --------------------------------------------------------------- kernels
@lean_cache
@nb.njit(cache=True)
def _class_sort(cls, mask, use_mask, nc):
    """Band pixels (flat indices) in class order, and each class's start (counting sort).

    Pixels where ``use_mask`` and not ``mask`` are left out. Within a class the
    pixels keep their raster order, so the result does not depend on threads.
    """
    rows, w = cls.shape
    starts = np.zeros(nc + 1, dtype=np.int64)
    for i in range(rows):
        for x in range(w):
            if not use_mask or mask[i, x]:
                starts[cls[i, x] + 1] += 1
    for c in range(nc):
        starts[c + 1] += starts[c]
    nxt = starts[:-1].copy()
    idx = np.empty(starts[nc], dtype=np.int64)
    for i in range(rows):
        for x in range(w):
            if not use_mask or mask[i, x]:
                c = cls[i, x]
                idx[nxt[c]] = i * w + x
                nxt[c] += 1
    return idx, starts


_BLOCK = 64  # samples per block: the block's transposed samples stay in L1


@functools.cache
def _gram_kernel(S: int, n_out: int):
    """The per-class Gram kernel, compiled for patch size ``S`` and ``n_out`` targets.

    For each class assigned to a thread, its samples are gathered straight
    from the mosaic (mirror indices at the borders) and the target, 64 at a
    time, into a transposed block ``T`` (one row per coefficient: patch, 1,
    targets; zero-padded to a multiple of 4 rows and to 64 samples), and the
    upper triangle of ``T Tᵀ`` is accumulated in float64 by 4x2 register tiles
    whose sums over the block vectorise. float32 products are exact in
    float64, so the result depends only on the order of the samples (raster
    order within each class), never on the threads.
    """
    P = S * S
    q = P + 1
    M = q + n_out
    MP = 4 * ((M + 3) // 4)
    r = S // 2
    B = _BLOCK

    @lean_cache
    @nb.njit(cache=True, parallel=True, fastmath={"reassoc", "contract"})
    def gram(mosaic, yi, xi, y0, idx, starts, assign, target, weight, use_w, xtx, xty, yy):
        W = mosaic.shape[1]
        for t in nb.prange(assign.shape[0]):
            T = np.zeros((MP, B))
            G = np.zeros((MP, MP))
            for ai in range(assign.shape[1]):
                c = assign[t, ai]
                if c < 0:
                    break
                a = starts[c]
                b = starts[c + 1]
                G[:, :] = 0.0
                for n0 in range(a, b, B):
                    nn = min(b, n0 + B) - n0
                    for n in range(nn):
                        p = idx[n0 + n]
                        i = p // W
                        x = p - i * W
                        y = y0 + i
                        inner = x >= r and x < W - r
                        k = 0
                        for dy in range(S):
                            row = yi[y + dy]  # padded row y + dy is image row y + dy - r
                            for dx in range(S):
                                col = x - r + dx if inner else xi[x + dx]
                                T[k, n] = mosaic[row, col]
                                k += 1
                        T[P, n] = 1.0
                        for o in range(n_out):
                            T[q + o, n] = target[y, x, o]
                        if use_w:  # weighted sample: sqrt(w) on every row of its column
                            sw = np.sqrt(np.float64(weight[y, x]))
                            for k in range(M):
                                T[k, n] *= sw
                    for n in range(nn, B):
                        for k in range(M):
                            T[k, n] = 0.0
                    for i0 in range(0, MP, 4):
                        for j0 in range(i0, MP, 2):
                            s00 = 0.0
                            s01 = 0.0
                            s10 = 0.0
                            s11 = 0.0
                            s20 = 0.0
                            s21 = 0.0
                            s30 = 0.0
                            s31 = 0.0
                            for n in range(B):
                                u0 = T[j0, n]
                                u1 = T[j0 + 1, n]
                                t0 = T[i0, n]
                                t1 = T[i0 + 1, n]
                                t2 = T[i0 + 2, n]
                                t3 = T[i0 + 3, n]
                                s00 += t0 * u0
                                s01 += t0 * u1
                                s10 += t1 * u0
                                s11 += t1 * u1
                                s20 += t2 * u0
                                s21 += t2 * u1
                                s30 += t3 * u0
                                s31 += t3 * u1
                            G[i0, j0] += s00
                            G[i0, j0 + 1] += s01
                            G[i0 + 1, j0] += s10
                            G[i0 + 1, j0 + 1] += s11
                            G[i0 + 2, j0] += s20
                            G[i0 + 2, j0 + 1] += s21
                            G[i0 + 3, j0] += s30
                            G[i0 + 3, j0 + 1] += s31
                for i in range(q):
                    xtx[c, i, i] += G[i, i]
                    for j in range(i + 1, q):
                        xtx[c, i, j] += G[i, j]
                        xtx[c, j, i] += G[i, j]
                    for o in range(n_out):
                        xty[c, i, o] += G[i, q + o]
                for o in range(n_out):
                    yy[c, o] += G[q + o, q + o]

    return gram


def _assign_classes(counts: np.ndarray, n_threads: int) -> np.ndarray:
    """Classes with samples, spread over threads largest first onto the least
    loaded thread (int64 (n_threads, k), padded with -1)."""
    nz = np.flatnonzero(counts)
    order = nz[np.argsort(-counts[nz], kind="stable")]
    load = [(0, t) for t in range(n_threads)]
    lists: list[list[int]] = [[] for _ in range(n_threads)]
    for c in order.tolist():
        ld, t = heapq.heappop(load)
        lists[t].append(c)
        heapq.heappush(load, (ld + int(counts[c]), t))
    out = np.full((n_threads, max(1, max(len(v) for v in lists))), -1, dtype=np.int64)
    for t, v in enumerate(lists):
        out[t, : len(v)] = v
    return out


def accumulate(stats: ClassStats, mosaic: np.ndarray, target: np.ndarray, *,
               mask: np.ndarray | None = None, weight: np.ndarray | None = None,
               max_pixels: int = 1 << 20) -> None:
    """Add the patches of one (mosaic, target) pair to ``stats`` in place.

    Parameters
    ----------
    stats
        Statistics to update; its definition classifies the pixels.
    mosaic
        float32 (H, W) normalised raw mosaic, CFA phase as the definition.
    target
        float32 (H, W, n_out) pixel-aligned target.
    mask
        Optional bool (H, W): only these pixels are used (subsampling).
    weight
        Optional float (H, W) non-negative sample weights: weighted least
        squares, every product of a sample times its weight (the constant
        column's product, ``xtx[c, -1, -1]``, is then the class's weight sum;
        ``n`` still counts samples).
    max_pixels
        Pixels per band of rows (bounds memory: about 12 bytes per pixel of
        a band for its classes and sorted indices).

    Notes
    -----
    Per band: the shared classifier (:func:`l3cli.classify.classify`) gives
    the classes, a counting sort lists each class's pixels, and
    :func:`_gram_kernel` forms the float64 products per class, parallel over
    classes. Bands, classes within a band and samples within a class are
    visited in a fixed order, so the statistics are bit-identical whatever
    the number of threads.
    """
    from l3cli.classify import check_mosaic, classify

    d = stats.definition
    mosaic = check_mosaic(mosaic, d.cfa, d.patch)
    target = np.asarray(target, dtype=np.float32)
    if target.ndim == 2:
        target = target[:, :, None]
    target = np.ascontiguousarray(target)
    if target.shape[:2] != mosaic.shape:
        raise InputError(
            f"target is {target.shape[1]}x{target.shape[0]} but the raw is "
            f"{mosaic.shape[1]}x{mosaic.shape[0]}"
        )
    if target.shape[2] != stats.n_out:
        raise InputError(f"target has {target.shape[2]} channels, expected {stats.n_out}")
    if mask is not None:
        mask = np.ascontiguousarray(mask, dtype=np.bool_)
        if mask.shape != mosaic.shape:
            raise InputError(f"mask shape {mask.shape} differs from the raw's {mosaic.shape}")
    if weight is not None:
        weight = np.ascontiguousarray(weight, dtype=np.float32)
        if weight.shape != mosaic.shape:
            raise InputError(f"weight shape {weight.shape} differs from the raw's "
                             f"{mosaic.shape}")
        if not (np.all(np.isfinite(weight)) and weight.min() >= 0):
            raise InputError("sample weights must be finite and non-negative")
    h, w = mosaic.shape
    yi, xi = d.mirror_maps(h, w)
    gram = _gram_kernel(d.patch, stats.n_out)
    no_mask = np.zeros((1, 1), dtype=np.bool_)
    no_weight = np.zeros((1, 1), dtype=np.float32)
    n_threads = nb.get_num_threads()
    for y0, y1 in band_rows(h, w, max_pixels=max_pixels):
        cls = classify(mosaic, d, rows=(y0, y1))
        band_mask = mask[y0:y1] if mask is not None else no_mask
        idx, starts = _class_sort(cls, band_mask, mask is not None, d.n_classes)
        if idx.size == 0:
            continue
        counts = np.diff(starts)
        gram(mosaic, yi, xi, y0, idx, starts, _assign_classes(counts, n_threads), target,
             weight if weight is not None else no_weight, weight is not None,
             stats.xtx, stats.xty, stats.yy)
        stats.n += counts
