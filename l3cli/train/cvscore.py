"""S-CIELAB against one fixed reference, fast enough to score many candidates.

Cross-validation (:mod:`l3cli.train.cv`) scores every candidate table on the
same held-out images. :class:`ReferenceSCIELAB` filters the reference once
and keeps the spectra of the opponent filters, so each candidate costs one
forward and one inverse real FFT per opponent channel (float32) and a
CIELAB conversion. It computes the mean ΔE*ab of
:func:`l3cli.metrics.scielab.scielab` (same filters, same symmetric padding,
same clipping to ``[0, white]``, same opponent matrices); the tests check it
against that function.
"""

from __future__ import annotations

import numpy as np
import scipy.fft

from l3cli import defaults
from l3cli.errors import InputError
from l3cli.metrics.scielab import (
    samples_per_degree,
    scielab_filter_1d,
    xyz_to_opponent_matrix,
)

__all__ = ["DEFAULT_OPPONENT", "ReferenceSCIELAB", "lab_from_xyz"]

#: Opponent transform of the cross-validation score: ISETCam's 10° matrix, the
#: one default of l3 evaluate (the metric of docs/results.md).
DEFAULT_OPPONENT = defaults.SCIELAB_OPPONENT

_EPS = (6.0 / 29.0) ** 3
_KAPPA = 1.0 / (3.0 * (6.0 / 29.0) ** 2)


def lab_from_xyz(xyz: np.ndarray, white: np.ndarray) -> np.ndarray:
    """CIE 1976 L*a*b* (CIE 015:2018, 8.2.1) of ``xyz`` relative to ``white``; float32."""
    t = np.asarray(xyz, dtype=np.float32) / np.asarray(white, dtype=np.float32)
    f = np.where(t > _EPS, np.cbrt(np.maximum(t, 0.0)), t * _KAPPA + 4.0 / 29.0)
    lab = np.empty_like(f)
    lab[..., 0] = 116.0 * f[..., 1] - 16.0
    lab[..., 1] = 500.0 * (f[..., 0] - f[..., 1])
    lab[..., 2] = 200.0 * (f[..., 1] - f[..., 2])
    return lab


class ReferenceSCIELAB:
    """Mean S-CIELAB ΔE*ab of test images against one reference.

    Parameters
    ----------
    reference_xyz
        (H, W, 3) CIE XYZ, on the scale of ``white``.
    white
        XYZ of the white (CIELAB reference and clipping bound).
    dpi, distance
        Display resolution and viewing distance (96 dpi at 1 m by default).
    opponent
        XYZ -> opponent matrix name (:func:`l3cli.metrics.scielab.xyz_to_opponent_matrix`).
    border
        Pixels removed on each side before filtering (as ``l3 evaluate
        --exclude-border``).
    version
        S-CIELAB filter version.
    """

    def __init__(self, reference_xyz: np.ndarray, *, white: np.ndarray,
                 dpi: float = 96.0, distance: float = 1.0,
                 opponent: str = DEFAULT_OPPONENT, border: int = 4,
                 version: str = "distribution") -> None:
        ref = np.asarray(reference_xyz, dtype=np.float32)
        if ref.ndim != 3 or ref.shape[2] != 3:
            raise InputError(f"S-CIELAB needs a (H, W, 3) XYZ reference, got {ref.shape}")
        h, w = ref.shape[:2]
        if h <= 2 * border + 1 or w <= 2 * border + 1:
            raise InputError(f"a {w}x{h} image is too small to score with a {border}-pixel border")
        self.border = int(border)
        self.white = np.asarray(white, dtype=np.float64).reshape(3)
        self.m = xyz_to_opponent_matrix(opponent).astype(np.float32)
        self.m_inv = np.linalg.inv(xyz_to_opponent_matrix(opponent)).astype(np.float32)
        spd = samples_per_degree(dpi, distance)
        kernels = [sum(wt * np.outer(g, g) for wt, g in parts)
                   for parts in scielab_filter_1d(spd, version=version)]
        self.r = kernels[0].shape[0] // 2
        self.shape = (h - 2 * self.border, w - 2 * self.border)
        ph, pw = self.shape[0] + 2 * self.r, self.shape[1] + 2 * self.r
        self.fft_shape = (scipy.fft.next_fast_len(ph, real=True),
                          scipy.fft.next_fast_len(pw, real=True))
        self.spectra = [scipy.fft.rfft2(k.astype(np.float32), s=self.fft_shape) for k in kernels]
        self.reference_lab = self._lab(ref)

    def _lab(self, xyz: np.ndarray) -> np.ndarray:
        b, r = self.border, self.r
        img = xyz[b:xyz.shape[0] - b, b:xyz.shape[1] - b] if b else xyz
        img = np.clip(img, 0.0, self.white.astype(np.float32))
        opp = img @ self.m.T
        h, w = self.shape
        out = np.empty((h, w, 3), dtype=np.float32)
        for c in range(3):
            padded = np.pad(opp[..., c], r, mode="symmetric")
            spec = scipy.fft.rfft2(padded, s=self.fft_shape, workers=-1)
            spec *= self.spectra[c]
            full = scipy.fft.irfft2(spec, s=self.fft_shape, workers=-1)
            out[..., c] = full[2 * r:2 * r + h, 2 * r:2 * r + w]
        return lab_from_xyz(out @ self.m_inv.T, self.white)

    def delta_e_map(self, test_xyz: np.ndarray) -> np.ndarray:
        """Per-pixel S-CIELAB ΔE*ab (float32 (H - 2 border, W - 2 border))."""
        test = np.asarray(test_xyz, dtype=np.float32)
        want = (self.shape[0] + 2 * self.border, self.shape[1] + 2 * self.border, 3)
        if test.shape != want:
            raise InputError(f"test image is {test.shape} but the reference is {want}")
        d = self._lab(test) - self.reference_lab
        return np.sqrt(np.sum(d * d, axis=2))

    def mean(self, test_xyz: np.ndarray, columns: tuple[int, int] | None = None) -> float:
        """Mean ΔE*ab, over all pixels or only image columns ``[x0, x1)``."""
        de = self.delta_e_map(test_xyz)
        if columns is not None:
            x0 = max(columns[0] - self.border, 0)
            x1 = min(columns[1] - self.border, de.shape[1])
            de = de[:, x0:x1]
        return float(np.mean(de, dtype=np.float64))
