"""Noise reduction beyond the patch: a learned multi-scale stage after the L3 kernels.

An L3 kernel sees an S x S patch, so it can average noise over at most that
many pixels; a camera's noise reduction reaches much further (its sky is
smooth where a 7 x 7 kernel's is grainy). This stage works on the rendered
image ``y`` (H, W, C), in the table's output space. Wide Gaussian low-passes
``lp_j = G_{sigma_j} * y`` (``sigma_1 < ... < sigma_n``) split it into bands

    ``b_0 = y - lp_1, b_1 = lp_1 - lp_2, ..., b_{n-1} = lp_{n-1} - lp_n``

and the output is the coarsest low-pass plus a learned blend of the bands,

    ``out = lp_n + sum_j A_{k,j} b_j``

with one C x C matrix per band and *coarse class* ``k`` of the pixel. The
classes come from the rendered image itself: bins of the coarse level (the
channel mean of ``lp_n``) times bins of the local band energy
(``sqrt(G_{sigma_1} * mean_c (y - lp_n)^2)``, cut at per-level quantiles of the
training data). Flat noisy regions learn ``A ~ 0`` (take the low-pass), edges
and texture ``A ~ I`` (keep the detail). ``A = I`` for every band gives
``out = y`` exactly.

Tables that render linear light (``xyz``, ``linear-srgb``) are blended in a
perceptual coding: the stage encodes the render with the sRGB transfer curve
(extended as an odd function beyond [0, 1]: :func:`encode`), blends, and
decodes (:func:`decode`); so the least-squares fit weighs errors in the
shadows as the eye (and S-CIELAB) does, not by their linear size (measured:
linear blending lost 4 % held-out S-CIELAB on the bundled frames).
``srgb`` and ``lab`` tables are blended as they are (``transfer = "none"``).

The blend is fitted after the L3 table by per-class ridge regression of
``target - lp_n`` on the bands (:func:`accumulate`, :func:`solve`;
:mod:`l3cli.train.multiscale` renders the training raws). It is stored in
the table as the optional ``multiscale_*`` keys (:meth:`Multiscale.to_arrays`,
:meth:`Multiscale.from_arrays`) and applied to every render's float output
(:func:`apply`), before a display output is encoded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from l3cli.errors import TableError
from l3cli.tablekeys import optional_group

__all__ = ["MULTISCALE_RULE", "TRANSFERS", "Multiscale", "MultiscaleStats", "accumulate",
           "apply", "apply_stage", "bands", "classes", "decode", "default_transfer", "encode",
           "energy", "gauss_taps", "level", "lowpass", "place_cuts", "radius", "solve"]

#: The rule the stage's arrays follow (stored in the table; a reader refuses others).
MULTISCALE_RULE = "gauss-bands-v1"
#: Gaussian support in standard deviations (scipy's ``truncate``).
TRUNCATE = 3.0
#: The codings the stage blends in: ``"none"`` (the table's values) or ``"srgb"``.
TRANSFERS = ("none", "srgb")
#: Low-pass standard deviations a stored stage may hold, pixels: below 0.25 a Gaussian is
#: one tap (its neighbours' weight < 4e-4), above 64 its support (3 sigma a side) is far
#: beyond any noise grain and its cost grows with it (l3 trains 1, 3, 9).
SIGMA_RANGE = (0.25, 64.0)
#: Scales (low-passes) at most: each is a pass over the image.
MAX_SCALES = 16
#: The largest absolute sum of one class's blend weights onto one output channel: the
#: stage's output is then within (1 + 2 MAX_BLEND) times the render's range (to the
#: power 2.4 in the sRGB coding), finite in float32 for any render of a sane raw. A
#: fitted blend is near 0 .. 1 per band; a class of a few flat pixels may reach
#: |target| / |band|, hundreds or thousands, which this bound leaves to training.
MAX_BLEND = 1e6
_F32_MAX = float(np.finfo(np.float32).max)


def encode(v: np.ndarray, transfer: str) -> np.ndarray:
    """The stage's coding of ``v`` (float32): the sRGB transfer curve (IEC 61966-2-1)
    extended to an odd function on all reals for ``"srgb"``, ``v`` itself for ``"none"``.

    In float32 as numpy computes ``sign(v) * where(|v| <= 0.0031308, 12.92 |v|,
    1.055 |v| ** (1 / 2.4) - 0.055)`` (:func:`l3cli.multiscale_kernel.transfer_rows`,
    one parallel pass: a test checks it bit for bit against that expression).
    """
    v = np.asarray(v, dtype=np.float32)
    return v if transfer == "none" else _transfer(v, inverse=False)


def decode(u: np.ndarray, transfer: str) -> np.ndarray:
    """The inverse of :func:`encode` (``sign(u) * where(|u| <= 0.04045, |u| / 12.92,
    ((|u| + 0.055) / 1.055) ** 2.4)`` in float32)."""
    u = np.asarray(u, dtype=np.float32)
    return u if transfer == "none" else _transfer(u, inverse=True)


def _transfer(v: np.ndarray, *, inverse: bool) -> np.ndarray:
    from l3cli.multiscale_kernel import transfer_rows

    src = np.asarray(v, order="C")  # (ascontiguousarray would make a 0-d array 1-d)
    out = np.empty_like(src)
    rows = src.shape[0] if src.ndim > 1 else 1
    transfer_rows(src.reshape(rows, -1), out.reshape(rows, -1), inverse)
    return out


def default_transfer(output_space: str) -> str:
    """The coding a table of ``output_space`` is blended in: ``"srgb"`` for linear light."""
    return "srgb" if output_space in ("xyz", "linear-srgb") else "none"


def gauss_taps(sigma: float) -> np.ndarray:
    """float64 (radius + 1,): the normalised Gaussian's centre tap and its taps at
    distance 1..radius (``scipy.ndimage``'s kernel: ``exp(-x² / (2 sigma²))`` over
    ``|x| <= radius(sigma)``, divided by its sum)."""
    r = radius(sigma)
    x = np.arange(-r, r + 1)
    phi = np.exp(-0.5 / (float(sigma) * float(sigma)) * x ** 2)
    phi = phi / phi.sum()
    return np.ascontiguousarray(phi[r:])


def lowpass(image: np.ndarray, sigma: float, *, out: np.ndarray | None = None,
            tmp: np.ndarray | None = None) -> np.ndarray:
    """Separable Gaussian low-pass of each channel of ``image`` (H, W, C), float32.

    Borders are mirrored (``scipy.ndimage``'s ``"reflect"``), the support is
    :data:`TRUNCATE` standard deviations: ``scipy.ndimage.gaussian_filter(image,
    (sigma, sigma, 0), mode="reflect", truncate=TRUNCATE)`` bit for bit
    (:func:`l3cli.multiscale_kernel.gauss_rows` and ``gauss_cols``, vectorised
    along rows and parallel over them; a test checks it against scipy). ``out`` and
    ``tmp`` (C-contiguous float32 of the image's shape, neither the image) are used
    when given (the result goes to ``out``).
    """
    from l3cli.multiscale_kernel import gauss_cols, gauss_rows

    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.ndim != 3:
        raise ValueError(f"lowpass takes (H, W, C) images, got shape {img.shape}")
    w = gauss_taps(sigma)
    h = img.shape[0]
    tmp = np.empty_like(img) if tmp is None else tmp
    out = np.empty_like(img) if out is None else out
    if img.size:
        gauss_rows(img.reshape(h, -1), w, tmp.reshape(h, -1))
        gauss_cols(tmp, w, out)
    return out


def bands(y: np.ndarray, sigmas: np.ndarray, *, stack: np.ndarray | None = None,
          work: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The band stack of ``y`` and its coarsest low-pass.

    ``stack`` (the result's shape) and ``work`` (float32, at least 3 ``y.size``
    values; the returned low-pass lies in it) are used when given: a caller
    that runs many bands allocates them once (fresh memory is zeroed by the
    kernel page by page: most of the stage's time when every band allocated).

    Returns
    -------
    stack : numpy.ndarray
        float32 (H, W, n_scales * C): ``b_0, ..., b_{n-1}`` one after another
        along the last axis (channel ``c`` of band ``j`` at ``j * C + c``).
    coarse : numpy.ndarray
        float32 (H, W, C): ``lp_n``.
    """
    y = np.asarray(y, dtype=np.float32)
    c = y.shape[2]
    if stack is None:
        stack = np.empty(y.shape[:2] + (len(sigmas) * c,), dtype=np.float32)
    if work is None:
        work = np.empty(3 * y.size, dtype=np.float32)
    lps = [work[k * y.size:(k + 1) * y.size].reshape(y.shape) for k in range(3)]
    finer = y
    for j, s in enumerate(sigmas):
        lp = lowpass(y, s, out=lps[j % 2], tmp=lps[2])  # the two last low-passes alternate
        np.subtract(finer, lp, out=stack[..., j * c:(j + 1) * c])
        finer = lp
    return stack, finer


def level(coarse: np.ndarray) -> np.ndarray:
    """The coarse level feature: the channel mean of the coarsest low-pass (float32 (H, W)),
    as ``coarse.mean(axis=2, dtype=np.float32)`` (:func:`l3cli.multiscale_kernel.level_rows`;
    a test checks it bit for bit)."""
    from l3cli.multiscale_kernel import level_rows

    c = np.ascontiguousarray(coarse, dtype=np.float32)
    out = np.empty(c.shape[:2], dtype=np.float32)
    level_rows(c, out)
    return out


def energy(y: np.ndarray, coarse: np.ndarray, sigma: float, *,
           work: np.ndarray | None = None) -> np.ndarray:
    """The local band energy: ``sqrt(G_sigma * mean_c (y - coarse)^2)`` (float32 (H, W)).

    ``work`` (float32, at least ``y.size + 2 H W`` values; the result lies in it) is
    used when given (:func:`bands`)."""
    y = np.asarray(y, dtype=np.float32)
    hw = y.shape[0] * y.shape[1]
    if work is None:
        work = np.empty(y.size + 2 * hw, dtype=np.float32)
    d = np.subtract(y, coarse, out=work[:y.size].reshape(y.shape))
    e = np.einsum("hwc,hwc->hw", d, d, dtype=np.float32) / np.float32(d.shape[2])
    out = work[y.size:y.size + hw].reshape(y.shape[0], y.shape[1], 1)
    e = lowpass(e[:, :, None], sigma, out=out,
                tmp=work[y.size + hw:y.size + 2 * hw].reshape(out.shape))[:, :, 0]
    return np.sqrt(np.maximum(e, 0.0, out=e), out=e)


def classes(lev: np.ndarray, en: np.ndarray, level_cuts: np.ndarray,
            energy_cuts: np.ndarray) -> np.ndarray:
    """Coarse class of each pixel: ``level_bin * n_energy + energy_bin`` (int32 (H, W)).

    ``level_cuts`` (n_levels - 1,) increasing; ``energy_cuts``
    (n_levels, n_energy - 1), increasing in each row. A value equal to a
    cut falls in the bin above it (float32 comparisons;
    :func:`l3cli.multiscale_kernel.class_rows`, one parallel pass).
    """
    from l3cli.multiscale_kernel import class_rows

    lev2 = np.ascontiguousarray(lev, dtype=np.float32)
    shape = lev2.shape
    lev2 = lev2.reshape(shape[0] if lev2.ndim > 1 else 1, -1)
    out = np.empty(lev2.shape, dtype=np.int32)
    class_rows(lev2, np.ascontiguousarray(en, dtype=np.float32).reshape(lev2.shape),
               np.ascontiguousarray(level_cuts, dtype=np.float32),
               np.ascontiguousarray(energy_cuts, dtype=np.float32), out)
    return out.reshape(shape)


def place_cuts(lev: np.ndarray, en: np.ndarray, n_levels: int,
               n_energy: int) -> tuple[np.ndarray, np.ndarray]:
    """Level cuts at quantiles of ``lev``, energy cuts at quantiles of ``en`` within each level.

    Returns
    -------
    level_cuts, energy_cuts
        float64 (n_levels - 1,) and (n_levels, n_energy - 1), strictly increasing
        (ties, as in a constant image, are spread by a tiny step).
    """
    lev = np.asarray(lev, dtype=np.float64).ravel()
    en = np.asarray(en, dtype=np.float64).ravel()
    q = np.linspace(0, 1, n_levels + 1)[1:-1]
    lcuts = _increasing(np.quantile(lev, q)) if n_levels > 1 else np.zeros(0)
    lb = np.searchsorted(lcuts, lev, side="right")
    qe = np.linspace(0, 1, n_energy + 1)[1:-1]
    ecuts = np.zeros((n_levels, n_energy - 1))
    for b in range(n_levels):
        sel = en[lb == b]
        ecuts[b] = _increasing(np.quantile(sel if sel.size else en, qe)) if n_energy > 1 else 0
    return lcuts, ecuts


def _increasing(cuts: np.ndarray) -> np.ndarray:
    cuts = np.asarray(cuts, dtype=np.float64).copy()
    for i in range(1, cuts.size):
        if cuts[i] <= cuts[i - 1]:
            cuts[i] = np.nextafter(cuts[i - 1], np.inf) + 1e-12 * max(1.0, abs(cuts[i - 1]))
    return cuts


@dataclass(eq=False)
class Multiscale:
    """A fitted multi-scale stage (see the module docstring).

    Attributes
    ----------
    sigmas
        float64 (n_scales,) increasing low-pass standard deviations, pixels.
    level_cuts
        float64 (n_levels - 1,) increasing cut points of the coarse level.
    energy_cuts
        float64 (n_levels, n_energy - 1) band-energy cut points per level.
    blend
        float32 (n_classes, n_scales * C, C): ``out_c = lp_c + sum_r blend[k, r, c] stack_r``
        (``n_classes = n_levels * n_energy``).
    counts
        int64 (n_classes,) training pixels per class.
    transfer
        The coding the stage works in (:data:`TRANSFERS`, :func:`encode`).
    """

    sigmas: np.ndarray
    level_cuts: np.ndarray
    energy_cuts: np.ndarray
    blend: np.ndarray
    counts: np.ndarray
    transfer: str = "none"

    def __post_init__(self) -> None:
        self.sigmas = np.asarray(self.sigmas, dtype=np.float64).reshape(-1)
        self.level_cuts = np.asarray(self.level_cuts, dtype=np.float64).reshape(-1)
        self.energy_cuts = np.asarray(self.energy_cuts, dtype=np.float64)
        self.blend = np.ascontiguousarray(self.blend, dtype=np.float32)
        self.counts = np.asarray(self.counts, dtype=np.int64)
        problem = self._problem()
        if problem:
            raise TableError(f"inconsistent multiscale stage: {problem}")

    def _problem(self) -> str | None:
        """What makes the stage unusable (naming its table key), or None: a stage that
        passes renders finite values from a finite render, at a cost bounded by the image."""
        s, lc, ec, a = self.sigmas, self.level_cuts, self.energy_cuts, self.blend
        if s.size < 1 or not np.all(np.isfinite(s)) or np.any(s <= 0) or np.any(np.diff(s) <= 0):
            return f"sigmas {s.tolist()} must be positive and increasing"
        lo, hi = SIGMA_RANGE
        if s.size > MAX_SCALES or s[0] < lo or s[-1] > hi:
            return (f"multiscale_sigmas {s.tolist()[:4]}{' ...' if s.size > 4 else ''}: "
                    f"at most {MAX_SCALES} low-passes of {lo:g} .. {hi:g} pixels")
        n_levels = lc.size + 1
        if ec.ndim != 2 or ec.shape[0] != n_levels:
            return f"energy_cuts have shape {ec.shape}, expected ({n_levels}, n_energy - 1)"
        for name, cuts in (("level_cuts", lc[None, :]), ("energy_cuts", ec)):
            if not np.all(np.isfinite(cuts)) or np.any(np.diff(cuts, axis=1) <= 0):
                return f"{name} must be finite and increasing"
            if cuts.size and float(np.abs(cuts).max()) > _F32_MAX:
                return f"multiscale_{name} beyond float32's range (the classes compare in float32)"
        n_classes = n_levels * (ec.shape[1] + 1)
        if a.ndim != 3 or a.shape[0] != n_classes or a.shape[2] < 1 \
                or a.shape[1] != s.size * a.shape[2]:
            return (f"blend has shape {a.shape}, expected ({n_classes}, "
                    f"{s.size} * C, C)")
        if not np.all(np.isfinite(a)):
            return "blend holds NaN or Inf"
        worst = float(np.abs(a).sum(axis=1, dtype=np.float64).max()) if a.size else 0.0
        if worst > MAX_BLEND:
            return (f"multiscale_blend weights sum to {worst:.3g} in absolute value for one "
                    f"class and output, more than {MAX_BLEND:g} (the output would overflow)")
        if self.counts.shape != (n_classes,) or np.any(self.counts < 0):
            return f"counts have shape {self.counts.shape} or negative values"
        if self.transfer not in TRANSFERS:
            return f"transfer {self.transfer!r} is not one of {', '.join(TRANSFERS)}"
        return None

    @property
    def n_out(self) -> int:
        """Channels of the image the stage applies to."""
        return int(self.blend.shape[2])

    @property
    def n_classes(self) -> int:
        """Number of coarse classes."""
        return int(self.blend.shape[0])

    @classmethod
    def identity(cls, n_out: int, sigmas=(2.0,), level_cuts=(), energy_cuts=None,
                 transfer: str = "none") -> Multiscale:
        """A stage that changes nothing (``A = I`` for every band and class)."""
        lc = np.asarray(level_cuts, dtype=np.float64)
        ec = np.zeros((lc.size + 1, 0)) if energy_cuts is None else np.asarray(energy_cuts)
        nc = ec.shape[0] * (ec.shape[1] + 1)
        eye = np.tile(np.eye(n_out, dtype=np.float32), (len(sigmas), 1))
        return cls(np.asarray(sigmas), lc, ec, np.repeat(eye[None], nc, axis=0),
                   np.zeros(nc, np.int64), transfer)

    def features(self, y: np.ndarray, *, work: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(stack, coarse, classes)`` of an image in the stage's coding
        (``encode(render, transfer)``; :func:`bands`, :func:`classes`).

        ``work``: float32 of at least :meth:`work_size` values, used for every
        temporary and the stack and coarse low-pass returned (None: fresh arrays).
        """
        y = np.asarray(y, dtype=np.float32)
        stack = ew = bw = None
        if work is not None:
            n_st = y.size * len(self.sigmas)
            stack = work[:n_st].reshape(y.shape[:2] + (y.shape[2] * len(self.sigmas),))
            bw = work[n_st:n_st + 3 * y.size]
            ew = work[n_st + 3 * y.size:self.work_size(y.shape)]
        stack, coarse = bands(y, self.sigmas, stack=stack, work=bw)
        cls = classes(level(coarse), energy(y, coarse, self.sigmas[0], work=ew),
                      self.level_cuts, self.energy_cuts)
        return stack, coarse, cls

    def work_size(self, shape: tuple[int, ...]) -> int:
        """float32 values :meth:`features` uses for an image of ``shape`` (H, W, C)."""
        n = int(np.prod(shape))
        return n * len(self.sigmas) + 3 * n + n + 2 * int(shape[0]) * int(shape[1])

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The table keys of the stage."""
        return {"multiscale_rule": np.array(MULTISCALE_RULE),
                "multiscale_sigmas": self.sigmas,
                "multiscale_level_cuts": self.level_cuts,
                "multiscale_energy_cuts": self.energy_cuts,
                "multiscale_blend": self.blend,
                "multiscale_counts": self.counts,
                "multiscale_transfer": np.array(self.transfer)}

    @classmethod
    def from_arrays(cls, arrs: dict) -> Multiscale | None:
        """The stage stored in a table's arrays (None when the table has none).

        Raises
        ------
        TableError
            Missing keys, another rule, wrong dtypes or inconsistent shapes.
        """
        keys = ("multiscale_rule", "multiscale_sigmas", "multiscale_level_cuts",
                "multiscale_energy_cuts", "multiscale_blend", "multiscale_counts",
                "multiscale_transfer")
        if optional_group(arrs, keys, MULTISCALE_RULE) is None:
            return None
        for k in keys[1:5]:
            if arrs[k].dtype.kind != "f":
                raise TableError(f"key {k!r} has dtype {arrs[k].dtype}, expected floating point")
        blend = np.asarray(arrs["multiscale_blend"], dtype=np.float64)
        finite = np.abs(blend[np.isfinite(blend)])  # NaN and Inf: refused by the stage
        if finite.size and float(finite.max()) > _F32_MAX:
            raise TableError("multiscale_blend holds values beyond float32's range")
        if arrs["multiscale_counts"].dtype.kind not in "iu":
            raise TableError("key 'multiscale_counts' must hold integers")
        transfer = arrs["multiscale_transfer"]
        if transfer.dtype.kind != "U" or transfer.ndim != 0:
            raise TableError("key 'multiscale_transfer' must be a string")
        return cls(arrs["multiscale_sigmas"], arrs["multiscale_level_cuts"],
                   arrs["multiscale_energy_cuts"], arrs["multiscale_blend"],
                   arrs["multiscale_counts"], str(transfer))


#: Output rows of one band of :func:`apply_stage` (bounds its temporaries: the band
#: stack alone is n_scales * C floats per pixel).
BAND_ROWS = 512


def radius(sigma: float) -> int:
    """Rows (or columns) a Gaussian low-pass of ``sigma`` reaches on each side."""
    return int(TRUNCATE * float(sigma) + 0.5)


def apply_stage(stage: Multiscale, y: np.ndarray, *, band_rows: int = BAND_ROWS) -> np.ndarray:
    """``lp_n + sum_j A_{k,j} b_j`` for every pixel of ``y`` (float32 (H, W, C), a new array).

    The image is processed in bands of ``band_rows`` output rows, each with the
    rows its low-passes and band energy reach (``radius(sigma_1) +
    radius(sigma_n)`` above and below): the result is the whole image's, bit
    for bit, with temporaries of one band.
    """
    y = np.asarray(y, dtype=np.float32)
    if y.ndim != 3 or y.shape[2] != stage.n_out:
        raise ValueError(f"the multiscale stage takes (H, W, {stage.n_out}) images, "
                         f"got {y.shape}")
    from l3cli import buffers

    h = y.shape[0]
    halo = radius(stage.sigmas[0]) + radius(stage.sigmas[-1])
    step = max(1, int(band_rows))
    out = np.empty_like(y)
    rows = min(h, step + 2 * halo)  # the tallest band with its halo
    work = buffers.empty((stage.work_size((rows,) + y.shape[1:]),), np.float32)
    for b0 in range(0, h, step):
        b1 = min(h, b0 + step)
        a0, a1 = max(0, b0 - halo), min(h, b1 + halo)
        stack, coarse, cls = stage.features(encode(y[a0:a1], stage.transfer), work=work)
        part = blend_bands(stack, coarse, cls, stage.blend)
        out[b0:b1] = decode(part[b0 - a0:b1 - a0], stage.transfer)
        del stack, coarse
    buffers.release(work)  # one allocation per image; recycled in a folder's render
    return out


def blend_bands(stack: np.ndarray, coarse: np.ndarray, cls: np.ndarray,
                blend: np.ndarray) -> np.ndarray:
    """``coarse + sum_j A_{cls,j} b_j`` of a whole image's bands (:func:`bands`,
    :func:`classes`), in the stage's coding: :func:`apply_stage` without its row bands."""
    from l3cli.multiscale_kernel import blend_rows

    out = np.empty_like(coarse)
    blend_rows(stack, coarse, cls, blend, out)
    return out


def apply(table, y: np.ndarray) -> np.ndarray:
    """The table's multi-scale stage on its rendered float output ``y`` (``y`` itself without one)."""
    stage = getattr(table, "multiscale", None)
    return y if stage is None else apply_stage(stage, y)


# --------------------------------------------------------------------- fitting
@dataclass(eq=False)
class MultiscaleStats:
    """Per-class normal equations of the blend (they add across images).

    ``xtx[k] = sum stack stackᵀ``, ``xty[k] = sum stack (target - coarse)ᵀ``
    over the pixels of class ``k``.
    """

    xtx: np.ndarray  # float64 (n_classes, R, R), R = n_scales * C
    xty: np.ndarray  # float64 (n_classes, R, C)
    n: np.ndarray    # int64 (n_classes,)

    @classmethod
    def zeros(cls, n_classes: int, n_scales: int, n_out: int) -> MultiscaleStats:
        r = n_scales * n_out
        return cls(np.zeros((n_classes, r, r)), np.zeros((n_classes, r, n_out)),
                   np.zeros(n_classes, np.int64))

    def __add__(self, other: MultiscaleStats) -> MultiscaleStats:
        return MultiscaleStats(self.xtx + other.xtx, self.xty + other.xty, self.n + other.n)


def accumulate(stats: MultiscaleStats, stack: np.ndarray, coarse: np.ndarray, cls: np.ndarray,
               target: np.ndarray, mask: np.ndarray | None = None) -> MultiscaleStats:
    """Add one image's pixels (``mask``: those that train; None = all) to ``stats``."""
    r = stack.shape[2]
    x = stack.reshape(-1, r).astype(np.float64)
    t = (np.asarray(target, dtype=np.float64) - coarse).reshape(x.shape[0], -1)
    k = cls.reshape(-1)
    if mask is not None:
        m = np.asarray(mask, dtype=bool).reshape(-1)
        x, t, k = x[m], t[m], k[m]
    ok = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(t), axis=1)
    x, t, k = x[ok], t[ok], k[ok]
    order = np.argsort(k, kind="stable")
    x, t, k = x[order], t[order], k[order]
    bounds = np.searchsorted(k, np.arange(stats.n.size + 1))
    for c in range(stats.n.size):
        a, b = bounds[c], bounds[c + 1]
        if b > a:
            stats.xtx[c] += x[a:b].T @ x[a:b]
            stats.xty[c] += x[a:b].T @ t[a:b]
            stats.n[c] += b - a
    return stats


def solve(stats: MultiscaleStats, ridge: float, n_out: int) -> np.ndarray:
    """The blend of each class: ridge regression shrunk towards ``A = I``.

    ``A_k = argmin |t - X A|^2 + lam_k |A - I|^2`` with
    ``lam_k = ridge * trace(XᵀX) / R``: a class with no data keeps the
    identity (the L3 render unchanged).

    Returns
    -------
    numpy.ndarray
        float32 (n_classes, R, C).
    """
    nc, r, _ = stats.xtx.shape
    prior = np.tile(np.eye(n_out), (r // n_out, 1))
    out = np.empty((nc, r, n_out), dtype=np.float64)
    for k in range(nc):
        g = stats.xtx[k]
        lam = ridge * max(np.trace(g) / r, 1e-300)
        out[k] = np.linalg.solve(g + lam * np.eye(r), stats.xty[k] + lam * prior)
    return out.astype(np.float32)
