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
``out = y`` (within float32 rounding).

The low-passes of ``sigma >= 3`` are computed at reduced resolution (rule
``gauss-bands-v2``): the image's means over ``f x f`` blocks (:func:`factor`:
the largest power of two ``f <= sigma / 1.5``), a Gaussian of ``sigma'``
(:func:`low_sigma`: ``sigma`` less the variance the block mean and the
upsampling add, in low-resolution pixels) on them, and bilinear upsampling
back to the image's pixels (:func:`l3cli.multiscale._loops.stage_rows`); the
finer ones, and the energy's, are the full-resolution Gaussian. The stage is
then one pass over the image's rows after a pass over its blocks, fused with
the display encoder for TIFF, PNG and JPEG output (:func:`apply_display`);
training (:func:`feature_maps`) runs the same loop, so a pixel's bands and
class are the same in both. (Rule ``gauss-bands-v1``, before, took every
low-pass at full resolution: about 10x the render's time.)

Tables that render linear light (``xyz``, ``linear-srgb``) are blended in a
perceptual coding: the stage encodes the render with the sRGB transfer curve
(extended as an odd function beyond [0, 1], from a table: :func:`encode`),
blends, and decodes (:func:`decode`); so the least-squares fit weighs errors in the
shadows as the eye (and S-CIELAB) does, not by their linear size (measured:
linear blending lost 4 % held-out S-CIELAB on the bundled frames).
``srgb`` and ``lab`` tables are blended as they are (``transfer = "none"``).

The blend is fitted after the L3 table by per-class ridge regression of
``target - lp_n`` on the bands (:mod:`l3cli.multiscale.fit`, which renders
the training raws). It is stored in
the table as the optional ``multiscale_*`` keys (:meth:`Multiscale.to_arrays`,
:meth:`Multiscale.from_arrays`) and applied to every render's float output
(:func:`apply`), before a display output is encoded.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from l3cli.errors import TableError
from l3cli.multiscale._exec import split as _split
from l3cli.multiscale._layout import MODE_DISPLAY, MODE_FEATURES, MODE_FLOAT
from l3cli.multiscale.coding import (
    CODE_SHIFT,
    code_table,
    code_values,
    decode,
    direct_table,
    encode,
)
from l3cli.tablekeys import optional_group

__all__ = ["CODE_SHIFT", "MULTISCALE_RULE", "TRANSFERS", "Multiscale", "apply",
           "apply_display", "apply_stage", "blend_features", "classes", "code_table", "decode",
           "default_transfer", "direct_table", "encode", "factor", "feature_maps", "gauss_taps",
           "low_sigma", "lowpass", "radius"]

#: The rule the stage's arrays follow (stored in the table; a reader refuses others).
MULTISCALE_RULE = "gauss-bands-v2"
#: The rule before (every low-pass at full resolution): its tables load and render with
#: :data:`MULTISCALE_RULE`'s low-passes, with a warning.
OLD_RULE = "gauss-bands-v1"
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


def factor(sigma: float) -> int:
    """The block size a low-pass of ``sigma`` is computed at: the largest power of two
    ``f`` with ``1.5 f <= sigma`` (1: full resolution)."""
    f = 1
    while 3.0 * f <= float(sigma):
        f *= 2
    return f


def low_sigma(sigma: float, f: int) -> float:
    """The Gaussian on ``f x f`` block means that, with the block mean (variance
    ``(f² - 1) / 12``) and the bilinear upsampling (``f² / 6``), makes a low-pass of
    variance ``sigma²``: in low-resolution pixels."""
    return float(np.sqrt((float(sigma) ** 2 - f * f / 4.0 + 1.0 / 12.0) / (f * f)))


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


def lowpass(image: np.ndarray, sigma: float) -> np.ndarray:
    """The stage's Gaussian low-pass of each channel of ``image`` (H, W, C), float32.

    Borders are mirrored (``scipy.ndimage``'s ``"reflect"``), the support is
    :data:`TRUNCATE` standard deviations: ``scipy.ndimage.gaussian_filter(image,
    (sigma, sigma, 0), mode="reflect", truncate=TRUNCATE)``'s taps and order of
    operations in float32 (:func:`l3cli.multiscale._loops.gauss_rows`; within float32
    rounding of scipy's float64 sums, tested).
    """
    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.ndim != 3:
        raise ValueError(f"lowpass takes (H, W, C) images, got shape {img.shape}")
    return _lowpass_into(img, sigma, np.empty_like(img), np.empty_like(img))


def _lowpass_into(img: np.ndarray, sigma: float, tmp: np.ndarray, out: np.ndarray) -> np.ndarray:
    """:func:`lowpass` of ``img`` (float32, C-contiguous) into ``out``, which may be ``img``
    itself (the pass along axis 0 reads every row of ``img`` into ``tmp``, scratch of its
    shape, before the pass along axis 1 writes ``out``)."""
    if img.size:
        taps = gauss_taps(sigma).astype(np.float32)
        for horizontal in (False, True):  # every row along axis 0 first
            _split("gauss_rows", (img, taps, tmp, out, horizontal), img.shape[0])
    return out


def classes(lev: np.ndarray, en: np.ndarray, level_cuts: np.ndarray,
            energy_cuts: np.ndarray) -> np.ndarray:
    """Coarse class of each pixel: ``level_bin * n_energy + energy_bin`` (int32 (H, W)).

    ``level_cuts`` (n_levels - 1,) increasing; ``energy_cuts``
    (n_levels, n_energy - 1), increasing in each row. A value equal to a
    cut falls in the bin above it (float32 comparisons;
    :func:`l3cli.multiscale._loops.class_rows`, one parallel pass).
    """
    lev2 = np.ascontiguousarray(lev, dtype=np.float32)
    shape = lev2.shape
    lev2 = lev2.reshape(shape[0] if lev2.ndim > 1 else 1, -1)
    out = np.empty(lev2.shape, dtype=np.int32)
    _split("class_rows", (lev2, np.ascontiguousarray(en, dtype=np.float32).reshape(lev2.shape),
                          np.ascontiguousarray(level_cuts, dtype=np.float32),
                          np.ascontiguousarray(energy_cuts, dtype=np.float32), out),
           lev2.shape[0])
    return out.reshape(shape)


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

    def features(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(stack, coarse, classes)`` of an image in the stage's coding
        (``encode(render, transfer)``; :func:`feature_maps`, :func:`classes`)."""
        stack, coarse, lev, en = feature_maps(u, self.sigmas)
        return stack, coarse, classes(lev, en, self.level_cuts, self.energy_cuts)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The table keys of the stage."""
        return {"multiscale_rule": np.array(MULTISCALE_RULE), "multiscale_sigmas": self.sigmas,
                "multiscale_level_cuts": self.level_cuts,
                "multiscale_energy_cuts": self.energy_cuts, "multiscale_blend": self.blend,
                "multiscale_counts": self.counts, "multiscale_transfer": np.array(self.transfer)}

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
        rule = arrs.get("multiscale_rule")
        if rule is not None and rule.dtype.kind == "U" and str(rule) == OLD_RULE:
            # the same stage, fitted on full-resolution low-passes: still loads, renders
            # with this rule's (8-bit codes move by one at about 1 % of pixels, measured)
            logging.getLogger(__name__).warning(
                "the table's multi-scale stage was fitted with rule %r; rendered with %r "
                "(a few codes move by one; retrain with --multiscale for an exact match)",
                OLD_RULE, MULTISCALE_RULE)
            arrs = {**arrs, "multiscale_rule": np.array(MULTISCALE_RULE)}
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


#: Output rows of one band of :func:`l3cli.multiscale._loops.stage_rows` (its
#: temporaries: the low-passes of these rows and the energy's halo).
BAND_ROWS = 32


def radius(sigma: float) -> int:
    """Rows (or columns) a Gaussian low-pass of ``sigma`` reaches on each side."""
    return int(TRUNCATE * float(sigma) + 0.5)


_F32, _F32_2 = np.zeros((1, 1, 1), np.float32), np.zeros((1, 1), np.float32)
_U8, _U16 = np.zeros(1, np.uint8), np.zeros(1, np.uint16)


def _run(sigmas, u: np.ndarray, mode: int, *, stage: Multiscale | None = None,
         src: np.ndarray | None = None, **outs) -> None:
    """:func:`l3cli.multiscale._loops.stage_rows` on ``u`` (H, W, C) float32 in the stage's
    coding: the pyramid of 2 x 2 block means, the coarse scales' low-resolution
    Gaussians and their upsampling along the columns first. ``src``: the render itself,
    coded into ``u`` here (may be ``u``), in the pass that makes the pyramid's first
    level."""
    h, w, c = u.shape
    sigmas = np.asarray(sigmas, dtype=np.float64)
    ns = sigmas.size
    fac = np.array([factor(s) for s in sigmas], dtype=np.int64)
    if src is not None and fac.max() == 1:  # no pyramid: a pass of its own
        code_values(src, inverse=False, out=u)
    pyramid = {1: u}  # f: the means of f x f blocks, each level from the one below
    f = 2
    while f <= fac.max():
        below = pyramid[f // 2]
        pyramid[f] = np.empty(((below.shape[0] + 1) // 2, (below.shape[1] + 1) // 2, c),
                              np.float32)
        code = src is not None and f == 2
        _split("half_means", (src if code else below, pyramid[f], u, code,
                              *code_table(False)), pyramid[f].shape[0])
        f *= 2
    from l3cli import buffers

    sizes = [pyramid[int(f)].shape[0] * w * c if f > 1 else 0 for f in fac]
    wides = buffers.empty((max(1, sum(sizes)),), np.float32)  # recycled in a folder's render
    at = 0
    # a low-pass overwrites its pyramid level when no later scale reads it (every level
    # is made first); the low-passes share one scratch array
    tmp = np.empty(max((pyramid[int(f)].size for f in fac if f > 1), default=0), np.float32)
    rads = np.zeros(ns, np.int64)
    taps = np.zeros((ns, max(radius(s) for s in sigmas) + 1), np.float32)
    for j, (s, f) in enumerate(zip(sigmas, fac, strict=True)):
        if f == 1:
            t = gauss_taps(s)
            taps[j, :t.size] = t
            rads[j] = t.size - 1
            continue
        f = int(f)
        last = j == max(i for i in range(ns) if fac[i] == f)  # no later scale reads it
        lo = _lowpass_into(pyramid[f], low_sigma(s, f), tmp[:pyramid[f].size].reshape(
            pyramid[f].shape), pyramid[f] if last else np.empty_like(pyramid[f]))
        num = 2 * np.arange(w, dtype=np.int64) + 1 - f  # the column's place among blocks
        i0 = num // (2 * f)
        ctx = (num - i0 * 2 * f).astype(np.float32) / np.float32(2 * f)
        wide = wides[at:at + sizes[j]].reshape(lo.shape[0], w, c)
        at += sizes[j]
        _split("upsample_cols", (lo, np.clip(i0, 0, lo.shape[1] - 1),
                                 np.clip(i0 + 1, 0, lo.shape[1] - 1), ctx, wide), lo.shape[0])
    e_taps = gauss_taps(sigmas[0]).astype(np.float32)
    if stage is not None:
        lc = stage.level_cuts.astype(np.float32)
        ec = np.ascontiguousarray(stage.energy_cuts, dtype=np.float32)
        blend, coded = stage.blend, stage.transfer == "srgb"
    else:
        lc, ec, blend, coded = np.zeros(0, np.float32), np.zeros((1, 0), np.float32), \
            np.zeros((1, ns * c, c), np.float32), False
    params = outs.get("params")
    if params is None:
        params = (False, np.eye(3), np.zeros(2, np.float32), np.zeros(1, np.uint16),
                  np.zeros(2, np.float32), 16)
    bits = outs.get("bits", 8)
    out = outs.get("out")
    direct = bool(outs.get("direct", False))
    cell_code, uthr = direct_table() if direct else (np.zeros(2, np.uint8),
                                                      np.zeros(2, np.float32))
    band_rows = int(BAND_ROWS)
    _split("stage_rows", (
        u, wides, fac, taps, rads, e_taps, lc, ec, blend, coded, *code_table(True), mode,
        outs.get("stack", _F32), outs.get("coarse", _F32), outs.get("lev", _F32_2),
        outs.get("en", _F32_2), outs.get("outf", _F32), *params,
        out.reshape(-1) if out is not None and bits == 8 else _U8,
        out.reshape(-1) if out is not None and bits == 16 else _U16, bits,
        direct, cell_code, uthr, band_rows), -(-h // band_rows))
    buffers.release(wides)


def feature_maps(u: np.ndarray, sigmas) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The stage's features of ``u`` (H, W, C), the render in the stage's coding.

    Returns
    -------
    stack : numpy.ndarray
        float32 (H, W, n_scales * C): the bands ``b_0, ..., b_{n-1}`` one after another
        along the last axis (channel ``c`` of band ``j`` at ``j * C + c``).
    coarse : numpy.ndarray
        float32 (H, W, C): ``lp_n``.
    lev, en : numpy.ndarray
        float32 (H, W): the coarse level and the band energy.
    """
    u = np.ascontiguousarray(u, dtype=np.float32)
    h, w, c = u.shape
    stack = np.empty((h, w, len(sigmas) * c), np.float32)
    coarse = np.empty_like(u)
    lev = np.empty((h, w), np.float32)
    en = np.empty((h, w), np.float32)
    if u.size:
        _run(sigmas, u, MODE_FEATURES, stack=stack, coarse=coarse, lev=lev, en=en)
    return stack, coarse, lev, en


def _checked(stage: Multiscale, y: np.ndarray, inplace: bool) -> tuple[np.ndarray, np.ndarray]:
    """``y`` (float32, C-contiguous) and the array its coding goes into (``y`` itself when
    ``inplace`` or the stage blends the values as they are)."""
    y = np.ascontiguousarray(y, dtype=np.float32)
    if y.ndim != 3 or y.shape[2] != stage.n_out:
        raise ValueError(f"the multiscale stage takes (H, W, {stage.n_out}) images, "
                         f"got {y.shape}")
    return y, y if inplace or stage.transfer == "none" else np.empty_like(y)


def apply_stage(stage: Multiscale, y: np.ndarray, *, inplace: bool = False) -> np.ndarray:
    """``lp_n + sum_j A_{k,j} b_j`` for every pixel of ``y`` (float32 (H, W, C), a new
    array; ``inplace``: ``y``'s memory is used for its coding)."""
    y, u = _checked(stage, y, inplace)
    out = np.empty_like(u)
    if u.size:
        _run(stage.sigmas, u, MODE_FLOAT, stage=stage, outf=out,
             src=y if stage.transfer == "srgb" else None)
    return out


def apply_display(stage: Multiscale, y: np.ndarray, space: str, bits: int, *,
                  inplace: bool = False) -> np.ndarray:
    """The stage on ``y`` display-encoded (:func:`l3cli.io.encode.display_encode`'s
    integers of :func:`apply_stage`'s output, row by row as it is blended: no float
    output is held). ``lab`` tables take the float output and ``display_encode``."""
    from l3cli.io.encode import display_encode, display_params

    params = display_params(space, stage.n_out, bits)
    if params is None:
        return display_encode(apply_stage(stage, y, inplace=inplace), space, bits)
    y, u = _checked(stage, y, inplace)
    out = np.empty(u.shape, np.uint16 if bits == 16 else np.uint8)
    direct = (bits == 8 and stage.transfer == "srgb" and stage.n_out == 3
              and space == "linear-srgb")  # decoding and encoding: one look-up
    if u.size:
        _run(stage.sigmas, u, MODE_DISPLAY, stage=stage, params=tuple(params), bits=bits,
             out=out, direct=direct, src=y if stage.transfer == "srgb" else None)
    return out


def blend_features(stack: np.ndarray, coarse: np.ndarray, cls: np.ndarray,
                   blend: np.ndarray) -> np.ndarray:
    """``coarse + sum_r stack_r blend[cls, r]`` of :func:`feature_maps` (float32, in the
    stage's coding): the blend :func:`apply_stage` makes, for callers that hold the
    features (cross-validation)."""
    r = stack.shape[2]
    out = coarse.astype(np.float32, copy=True)
    a = blend[cls]  # (H, W, R, C)
    for i in range(r):
        out += stack[..., i:i + 1] * a[:, :, i, :]
    return out


def apply(table, y: np.ndarray) -> np.ndarray:
    """The table's multi-scale stage on its rendered float output ``y`` (``y`` itself without one)."""
    stage = getattr(table, "multiscale", None)
    return y if stage is None else apply_stage(stage, y)
