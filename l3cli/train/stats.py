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
classifier (:mod:`l3cli.classify`); the patches are gathered in class order
into a float64 design matrix (one column per sample) by a numba kernel (a
counting sort) and each class block is reduced by a numba kernel of
contiguous dot products (parallel over classes; BLAS's own threads would
fight numba's on these many small products).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np

from l3cli.cfa import CFA
from l3cli.classify import ClassDefinition, band_rows, pad_mosaic
from l3cli.errors import InputError, TableError
from l3cli.io.atomic import atomic_path

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
        nc, q = definition.n_classes, definition.n_coeffs
        return cls(definition, np.zeros(nc, np.int64), np.zeros((nc, q, q)),
                   np.zeros((nc, q, n_out)), np.zeros((nc, n_out)), target_space)

    @property
    def n_out(self) -> int:
        return int(self.yy.shape[1])

    def _check_compatible(self, other: ClassStats) -> None:
        if not self.definition.same_as(other.definition):
            raise TableError("cannot add statistics collected with different class definitions")
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
@nb.njit(cache=True)
def _sorted_slots(cls_sel, starts):
    """Destination row of every selected sample in class order (counting sort)."""
    nxt = starts.copy()
    dest = np.empty(cls_sel.shape[0], dtype=np.int64)
    for i in range(cls_sel.shape[0]):
        c = cls_sel[i]
        dest[i] = nxt[c]
        nxt[c] += 1
    return dest


@nb.njit(cache=True, parallel=True)
def _scatter(band, ys, xs, dest, S, target, XY):
    """Row ``dest[i]`` of XY = [patch of pixel i (ys[i], xs[i]) of the band, 1, target].

    Reads stream in pixel order from a small (cache-resident) band; each
    sample is one contiguous row, appended to its class's run of rows."""
    P = S * S
    n_out = target.shape[2]
    for i in nb.prange(ys.shape[0]):
        j = dest[i]
        y = ys[i]
        x = xs[i]
        k = 0
        for dy in range(S):
            for dx in range(S):
                XY[j, k] = band[y + dy, x + dx]
                k += 1
        XY[j, P] = 1.0
        for o in range(n_out):
            XY[j, P + 1 + o] = target[y, x, o]


_CHUNK = 128  # samples per block of the Gram products (a block stays in L1)
_SUB_PIXELS = 1 << 14  # pixels per gather sub-band


@nb.njit(cache=True, parallel=True, fastmath={"reassoc", "contract"})
def _gram(XY, q, starts, classes, xtx, xty, yy):
    """Add XᵀX, XᵀY and Σy² of each class's run of rows of XY = [X | Y] (float64).

    Own kernel rather than BLAS: OpenBLAS threads fight numba's on these many
    small products. Parallel over classes; each block of rows is transposed
    into an L1 buffer so every product is a contiguous, vectorised dot.
    """
    m = XY.shape[1]
    n_out = m - q
    for t in nb.prange(classes.shape[0]):
        c = classes[t]
        a = starts[c]
        b = starts[c + 1]
        G = np.zeros((q, q))
        R = np.zeros((q, n_out))
        Q = np.zeros(n_out)
        T = np.empty((m, _CHUNK))
        for n0 in range(a, b, _CHUNK):
            nn = min(b, n0 + _CHUNK) - n0
            for n in range(nn):
                for k in range(m):
                    T[k, n] = np.float64(XY[n0 + n, k])
            for i in range(q):
                xi = T[i, :nn]
                for j in range(i, q):
                    xj = T[j, :nn]
                    s = 0.0
                    for n in range(nn):
                        s += xi[n] * xj[n]
                    G[i, j] += s
                for o in range(n_out):
                    yo = T[q + o, :nn]
                    s = 0.0
                    for n in range(nn):
                        s += xi[n] * yo[n]
                    R[i, o] += s
            for o in range(n_out):
                yo = T[q + o, :nn]
                s = 0.0
                for n in range(nn):
                    s += yo[n] * yo[n]
                Q[o] += s
        for i in range(q):
            for j in range(i, q):
                xtx[c, i, j] += G[i, j]
                if j != i:
                    xtx[c, j, i] += G[i, j]
            for o in range(n_out):
                xty[c, i, o] += R[i, o]
        for o in range(n_out):
            yy[c, o] += Q[o]


def accumulate(stats: ClassStats, mosaic: np.ndarray, target: np.ndarray, *,
               mask: np.ndarray | None = None, max_pixels: int = 1 << 18) -> None:
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
    max_pixels
        Pixels per band (bounds memory: about ``max_pixels * (q + n_out) * 8`` bytes).
    """
    from l3cli.classify import classify

    d = stats.definition
    mosaic = np.asarray(mosaic, dtype=np.float32)
    target = np.asarray(target, dtype=np.float32)
    if target.ndim == 2:
        target = target[:, :, None]
    if target.shape[:2] != mosaic.shape:
        raise InputError(
            f"target is {target.shape[1]}x{target.shape[0]} but the raw is "
            f"{mosaic.shape[1]}x{mosaic.shape[0]}"
        )
    if target.shape[2] != stats.n_out:
        raise InputError(f"target has {target.shape[2]} channels, expected {stats.n_out}")
    cls_map = classify(mosaic, d)
    S = d.patch
    r = S // 2
    q = d.n_coeffs
    nc = d.n_classes
    h, w = mosaic.shape
    ph, pw = d.cfa.period
    for Y0, Y1 in band_rows(h, w, max_pixels=max_pixels):
        # samples of this band in pixel (row-major) order, and their class-sorted slots
        if mask is None:
            yy, xx = np.divmod(np.arange((Y1 - Y0) * w, dtype=np.int64), w)
        else:
            yy, xx = np.nonzero(mask[Y0:Y1])
            yy = yy.astype(np.int64)
            xx = xx.astype(np.int64)
        if yy.size == 0:
            continue
        cls_sel = cls_map[Y0:Y1][yy, xx].astype(np.int64)
        counts = np.bincount(cls_sel, minlength=nc)
        starts = np.zeros(nc + 1, dtype=np.int64)
        np.cumsum(counts, out=starts[1:])
        dest = _sorted_slots(cls_sel, starts[:-1])
        # float32 holds the float32 mosaic/target values exactly; products and
        # sums are formed in float64 by _gram
        XY = np.empty((yy.size, q + stats.n_out), dtype=np.float32)
        # gather from small sub-bands (their padded rows stay in cache)
        row_start = np.searchsorted(yy, np.arange(Y1 - Y0 + 1))
        for y0, y1 in band_rows(Y1 - Y0, w, max_pixels=_SUB_PIXELS):
            s0, s1 = row_start[y0], row_start[y1]
            if s1 == s0:
                continue
            band = pad_mosaic(mosaic, r, (ph, pw), rows=(Y0 + y0, Y0 + y1))
            _scatter(band, yy[s0:s1] - y0, xx[s0:s1], dest[s0:s1], S,
                     target[Y0 + y0 : Y0 + y1], XY)
        # largest classes first: better balance across threads
        nz = np.flatnonzero(counts)
        order = nz[np.argsort(-counts[nz], kind="stable")]
        _gram(XY, q, starts, order, stats.xtx, stats.xty, stats.yy)
        stats.n += counts
