"""A learned per-channel tone curve: the renders' own linear space.

Camera pipelines apply a colour matrix to the demosaiced raw and then a
per-channel tone curve (a gamma LUT, often an S-curve). Unless that curve is
exactly the sRGB one, the "linear" version of the renders (``linear-srgb``) is
not linear in the raw, and the per-class affine kernels have to bend the
curve class by class -- the same level of two different hues sits at
different points of each channel's curve, so the kernels learned on one
image's colours miss another's.

:func:`fit_tone_curve` learns the curve from the training pairs: on flat,
unclipped blocks, each output channel's encoded value ``e`` must satisfy
``f_c(e) = M_c · r`` (``r`` the block's mean raw per CFA channel), with ``f_c``
piecewise linear on :data:`KNOTS` uniform knots over ``e`` in [0, 1],
smooth (second-difference penalty), normalised to ``f_c(1) = 1`` and made
monotone. :func:`select_curve` keeps it only where it predicts held-out
images better than the plain sRGB decoding does. ``l3 train`` then fits the kernels to ``f(e)`` (the "curve space",
in which the pipeline is linear), and the table stores the inverse as a
uniform look-up table from curve values to the table's output space;
:func:`apply_curve` applies it after the kernels, per pixel.

For a pipeline whose curve is the sRGB one, ``f`` is the sRGB decoding and
the curve space is ``linear-srgb`` up to scale.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["KNOTS", "LUT_SIZE", "ToneCurve", "block_samples", "fit_tone_curve", "select_curve",
           "apply_curve",
           "curve_arrays"]

#: Intervals of the piecewise-linear curve over the encoded value [0, 1] (leave-one-image-out
#: on the bundled frames: 8 -> 0.62, 16 -> 0.453, 24 -> 0.451, 32 -> 0.448).
KNOTS = 32
#: Entries of the inverse look-up table stored in the table.
LUT_SIZE = 1024
#: Block size (pixels) of the samples: large enough to average out demosaicking and sharpening.
BLOCK = 8
#: A block is flat when every channel's encoded standard deviation is below this.
FLAT_STD = 0.02
#: Encoded values outside (LOW, HIGH) are clipped by the pipeline: not used for the fit.
LOW, HIGH = 0.01, 0.98
#: Strength of the second-difference penalty, relative to the data's mean weight.
SMOOTHNESS = 1e-2
#: The learned curve is used only when, fitted without them, it predicts held-out images'
#: blocks with at most this fraction of the sRGB decoding's residual (:func:`select_curve`).
MIN_GAIN = 0.9


@dataclass
class ToneCurve:
    """A per-channel tone curve and its inverse look-up table.

    Attributes
    ----------
    knots
        float64 (KNOTS + 1, n_out): ``f_c`` at the encoded values
        ``linspace(0, 1, KNOTS + 1)`` (increasing, last row 1).
    space
        The encoding the curve's input is in (the renders' space, e.g. ``srgb``).
    matrix
        float64 (n_out, n_channels) the fitted ``M`` (None when not fitted).
    """

    knots: np.ndarray
    space: str = "srgb"
    matrix: np.ndarray | None = None

    def linearise(self, encoded: np.ndarray) -> np.ndarray:
        """``f(e)``: encoded values (H, W, n_out) to the curve space (float32)."""
        x = np.linspace(0.0, 1.0, self.knots.shape[0])
        out = np.empty(encoded.shape, dtype=np.float32)
        for c in range(encoded.shape[-1]):
            out[..., c] = np.interp(encoded[..., c], x, self.knots[:, c])
        return out

    def lut(self, output_space: str) -> tuple[np.ndarray, np.ndarray]:
        """Inverse look-up table from curve values to ``output_space``.

        Returns
        -------
        lut, lo_hi
            float32 (LUT_SIZE, n_out) values on the uniform grid
            ``linspace(lo, hi, LUT_SIZE)`` of each channel, and float32
            (2, n_out) the grid's ends (``f(0)``, ``f(1)``).
        """
        from l3cli.colourspace import convert

        x = np.linspace(0.0, 1.0, self.knots.shape[0])
        n_out = self.knots.shape[1]
        lo_hi = np.stack([self.knots[0], self.knots[-1]]).astype(np.float32)
        enc = np.empty((LUT_SIZE, n_out), dtype=np.float32)
        for c in range(n_out):
            v = np.linspace(lo_hi[0, c], lo_hi[1, c], LUT_SIZE)
            enc[:, c] = np.interp(v, self.knots[:, c], x)
        if output_space != self.space:
            enc = convert(enc[None], self.space, output_space)[0]
        return np.ascontiguousarray(enc, dtype=np.float32), lo_hi

    def as_dict(self) -> dict:
        """JSON form (provenance)."""
        return {"space": self.space, "knots": np.round(self.knots, 6).tolist()}


def block_samples(mosaic: np.ndarray, cfa, encoded: np.ndarray, *,
                  saturation: float = 0.95, mask: np.ndarray | None = None,
                  block: int = BLOCK) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean raw per CFA channel and mean encoded target of flat blocks.

    Returns
    -------
    raw, enc, ok
        float64 (n, n_channels), float64 (n, n_out), bool (n, n_out): blocks
        that are flat, unsaturated in the raw, fully valid (``mask``) and, per
        output channel, not clipped by the pipeline.
    """
    h, w = mosaic.shape
    bh, bw = h // block, w // block
    m = mosaic[:bh * block, :bw * block].reshape(bh, block, bw, block)
    e = encoded[:bh * block, :bw * block].reshape(bh, block, bw, block, -1)
    chan = cfa.channel_map(bh * block, bw * block).reshape(bh, block, bw, block)
    n_ch = cfa.n_channels
    raw = np.empty((bh, bw, n_ch))
    for k in range(n_ch):
        sel = chan == k
        raw[..., k] = (m * sel).sum(axis=(1, 3)) / np.maximum(sel.sum(axis=(1, 3)), 1)
    ok_block = (m.max(axis=(1, 3)) < saturation) & (e.std(axis=(1, 3)) < FLAT_STD).all(axis=-1)
    if mask is not None:
        ok_block &= mask[:bh * block, :bw * block].reshape(bh, block, bw, block).all(axis=(1, 3))
    enc = e.mean(axis=(1, 3), dtype=np.float64)
    ok = ok_block[..., None] & (e.min(axis=(1, 3)) > LOW) & (e.max(axis=(1, 3)) < HIGH)
    return raw.reshape(-1, n_ch), enc.reshape(-1, enc.shape[-1]), ok.reshape(-1, enc.shape[-1])


def _hat_basis(e: np.ndarray, knots: int) -> np.ndarray:
    """(n, knots + 1) piecewise-linear interpolation weights of ``e`` in [0, 1]."""
    t = np.clip(e, 0.0, 1.0) * knots
    i = np.minimum(t.astype(np.int64), knots - 1)
    f = t - i
    b = np.zeros((e.size, knots + 1))
    rows = np.arange(e.size)
    b[rows, i] = 1.0 - f
    b[rows, i + 1] = f
    return b


def fit_tone_curve(samples: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], *,
                   space: str = "srgb", knots: int = KNOTS,
                   smoothness: float = SMOOTHNESS) -> ToneCurve | None:
    """Fit ``f_c`` with ``f_c(e) = M_c · r`` on the blocks of :func:`block_samples`.

    Each output channel is one linear least-squares problem in the curve's
    knot values (the last fixed to 1) and the matrix row ``M_c``, with a
    second-difference penalty that also carries the curve through ranges
    without data. The result is made increasing.

    Returns
    -------
    ToneCurve or None
        None when a channel has too few blocks (fewer than 20 per unknown).
    """
    raw = np.concatenate([s[0] for s in samples])
    enc = np.concatenate([s[1] for s in samples])
    ok = np.concatenate([s[2] for s in samples])
    n_ch, n_out = raw.shape[1], enc.shape[1]
    n_unk = knots + n_ch
    d2 = np.diff(np.eye(knots + 1), n=2, axis=0)
    out = np.empty((knots + 1, n_out))
    mat = np.empty((n_out, n_ch))
    for c in range(n_out):
        sel = ok[:, c]
        if sel.sum() < 20 * n_unk:
            return None
        b = _hat_basis(enc[sel, c], knots)
        a = np.concatenate([b[:, :knots], -raw[sel]], axis=1)
        rhs = -b[:, knots]
        scale = np.mean(np.sum(b * b, axis=1))
        lam = smoothness * scale * sel.sum()
        pen = np.zeros((d2.shape[0], n_unk))
        pen[:, :knots] = d2[:, :knots]
        prhs = -d2[:, knots]
        ata = a.T @ a + lam * pen.T @ pen
        atb = a.T @ rhs + lam * pen.T @ prhs
        theta = np.linalg.solve(ata, atb)
        f = np.append(theta[:knots], 1.0)
        out[:, c] = _increasing(f)
        mat[c] = theta[knots:]
    return ToneCurve(out, space, mat)


def _residual(samples, curve_of, matrix) -> float:
    """RMS of ``f_c(e) - M_c · r`` over the usable blocks of ``samples``."""
    raw, enc, ok = samples
    res = [curve_of(enc[ok[:, c], c], c) - raw[ok[:, c]] @ matrix[c] for c in range(enc.shape[1])]
    res = np.concatenate(res)
    return float(np.sqrt(np.mean(res * res))) if res.size else float("nan")


def _srgb_matrix(samples) -> np.ndarray:
    """``M`` of the plain sRGB decoding (least squares per channel)."""
    from l3cli.colourspace import srgb_decode

    raw = np.concatenate([s[0] for s in samples])
    enc = np.concatenate([s[1] for s in samples])
    ok = np.concatenate([s[2] for s in samples])
    return np.stack([np.linalg.lstsq(raw[ok[:, c]], srgb_decode(enc[ok[:, c], c]), rcond=None)[0]
                     for c in range(enc.shape[1])])


def select_curve(samples: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], *,
                 knots: int = KNOTS, smoothness: float = SMOOTHNESS,
                 min_gain: float = MIN_GAIN) -> tuple[ToneCurve | None, dict]:
    """The learned curve when it generalises better than the sRGB decoding, else None.

    Leave-one-image-out over ``samples`` (one entry per image; a single
    image's blocks are split into a top and a bottom half): the curve and its
    matrix are fitted without the held-out image and predict its blocks; so
    does the sRGB decoding with its own fitted matrix. The curve (fitted to
    all the images) is used when its mean held-out residual is at most
    ``min_gain`` times the sRGB decoding's. A pipeline whose curve is sRGB
    (e.g. a raw converter) or whose shots disagree (per-shot adaptation the
    model only approximates) keeps the plain linear target.

    Returns
    -------
    curve, record
        The curve or None, and a JSON-friendly record of the decision.
    """
    from l3cli.colourspace import srgb_decode

    samples = list(samples)
    if len(samples) == 1:
        raw, enc, ok = samples[0]
        h = raw.shape[0] // 2
        units = [(raw[:h], enc[:h], ok[:h]), (raw[h:], enc[h:], ok[h:])]
    else:
        units = samples
    curve_res, srgb_res = [], []
    for u in range(len(units)):
        rest = [s for i, s in enumerate(units) if i != u]
        cv = fit_tone_curve(rest, knots=knots, smoothness=smoothness)
        if cv is None:
            return None, {"used": False, "reason": "too few flat blocks"}
        x = np.linspace(0.0, 1.0, cv.knots.shape[0])
        curve_res.append(_residual(units[u], lambda e, c, k=cv.knots, x=x: np.interp(e, x, k[:, c]),
                                   cv.matrix))
        srgb_res.append(_residual(units[u], lambda e, c: srgb_decode(e), _srgb_matrix(rest)))
    rc, rs = float(np.nanmean(curve_res)), float(np.nanmean(srgb_res))
    used = bool(rc <= min_gain * rs)
    record = {"used": used, "heldout_rms": round(rc, 6), "srgb_heldout_rms": round(rs, 6),
              "min_gain": min_gain}
    if not used:
        return None, record
    curve = fit_tone_curve(samples, knots=knots, smoothness=smoothness)
    return curve, record


def _increasing(f: np.ndarray) -> np.ndarray:
    """Strictly increasing version of knot values ending at 1 (running maximum plus a ramp)."""
    g = np.maximum.accumulate(f)
    ramp = 1e-4 * np.arange(f.size) / f.size
    g = g + ramp
    return g / g[-1]


def curve_arrays(lut: np.ndarray, lo_hi: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The look-up table as :func:`l3cli.render_rows.curve_row` reads it.

    Returns
    -------
    base, slope, lo, step_inv
        float32 (n_out, n_lut + 1) entries and their forward differences
        (the last entry repeated, so the clamped top maps to the last
        entry), float32 (n_out,) the grid's start and inverse step.
    """
    lut = np.asarray(lut, dtype=np.float32)
    ext = np.concatenate([lut, lut[-1:]], axis=0)
    base = np.ascontiguousarray(ext.T)
    slope = np.ascontiguousarray(np.diff(np.concatenate([ext, ext[-1:]], axis=0), axis=0).T)
    lo = np.ascontiguousarray(lo_hi[0], dtype=np.float32)
    step_inv = ((lut.shape[0] - 1) / np.maximum(np.asarray(lo_hi[1], np.float64)
                                                - np.asarray(lo_hi[0], np.float64), 1e-12))
    return base, slope, lo, step_inv.astype(np.float32)


def apply_curve(img: np.ndarray, lut: np.ndarray, lo_hi: np.ndarray) -> np.ndarray:
    """Map a render in the curve space through the inverse look-up table, in place.

    What ``l3 render`` does inside its tile kernel, for a whole image.

    Parameters
    ----------
    img
        float32 C-contiguous (H, W, n_out) kernel outputs (curve values).
    lut, lo_hi
        As :meth:`ToneCurve.lut` returns them (values outside ``[lo, hi]`` take
        the end entries).

    Returns
    -------
    numpy.ndarray
        ``img``, now in the table's output space.
    """
    if img.dtype != np.float32 or not img.flags.c_contiguous:
        raise ValueError("apply_curve needs a C-contiguous float32 image")
    from l3cli.render_rows import curve_row

    h, w, n = img.shape
    curve_row(img.reshape(-1), 0, h * w, n, *curve_arrays(lut, lo_hi))
    return img
