"""Diffraction-limited optics: the Airy OTF and its application in the frequency domain.

For an aberration-free lens with a circular pupil in incoherent light, the
optical transfer function at radial spatial frequency ``ρ`` (cycles per unit
length in the image plane) is

.. math:: H(ρ) = \\frac{2}{π}\\left(\\arccos ν - ν\\sqrt{1-ν^2}\\right),\\quad ν = ρ λ N \\le 1,

and 0 beyond the cut-off ``1/(λN)`` ([1]_, eq. 6-31). Irradiance at the image
plane of a distant Lambertian object of radiance ``L`` on the optical axis is
``E = π T L / (1 + 4 N²)`` ([2]_, as in ISETCam's ``oiCompute``).

References
----------
.. [1] Goodman, J. W. (2005). Introduction to Fourier Optics, 3rd ed., §6.3.
.. [2] Farrell, J. E., Catrysse, P. B. and Wandell, B. A. (2012). Digital camera
   simulation. Applied Optics 51(4), A80-A90.
"""

from __future__ import annotations

import numpy as np

__all__ = ["airy_otf", "radial_frequency", "cos4_falloff", "irradiance_factor", "raw_shading"]


def airy_otf(freq_cy_per_mm: np.ndarray, wavelength_nm: float | np.ndarray, f_number: float) -> np.ndarray:
    """Diffraction-limited OTF of a circular pupil.

    Parameters
    ----------
    freq_cy_per_mm
        Radial spatial frequency in cycles/mm (any shape, broadcast with
        ``wavelength_nm``).
    wavelength_nm
        Wavelength(s) in nm.
    f_number
        Working f-number N.

    Returns
    -------
    numpy.ndarray
        OTF in [0, 1].
    """
    f = np.asarray(freq_cy_per_mm, dtype=np.float64)
    lam_mm = np.asarray(wavelength_nm, dtype=np.float64) * 1e-6
    nu = np.clip(f * lam_mm * f_number, 0.0, 1.0)
    return (2.0 / np.pi) * (np.arccos(nu) - nu * np.sqrt(1.0 - nu * nu))


def radial_frequency(height: int, width: int, pitch_mm: float) -> np.ndarray:
    """|f| in cycles/mm on the ``rfft2`` grid of an (height, width) image; float32 (H, W//2+1)."""
    fy = np.fft.fftfreq(height, d=pitch_mm).astype(np.float32)
    fx = np.fft.rfftfreq(width, d=pitch_mm).astype(np.float32)
    return np.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2)


def irradiance_factor(f_number: float, transmittance: float = 1.0) -> float:
    """Sensor irradiance / (π × scene radiance) on axis: ``T / (1 + 4 N²)``."""
    return transmittance / (1.0 + 4.0 * f_number**2)


def cos4_falloff(height: int, width: int, pitch_mm: float, focal_length_mm: float) -> np.ndarray:
    """Relative illumination ``cos⁴ θ`` with ``tan θ = r / f``; float32 (H, W)."""
    y = (np.arange(height, dtype=np.float64) - (height - 1) / 2) * pitch_mm
    x = (np.arange(width, dtype=np.float64) - (width - 1) / 2) * pitch_mm
    r2 = y[:, None] ** 2 + x[None, :] ** 2
    return (1.0 / (1.0 + r2 / focal_length_mm**2) ** 2).astype(np.float32)



def raw_shading(camera, height: int, width: int) -> np.ndarray | None:
    """What multiplies the raw's signal alone (float32 (H, W)), or None: the measured
    per-channel relative illumination (``[optics.relative_illumination]``, linear in
    the normalised radius, held beyond its last radius) and, for a camera that corrects
    its shading (``shading_corrected``), the cos⁴ fall-off, which then leaves the
    target unshaded."""
    from l3cli.lens.field import normalised_coords

    optics = camera.optics
    out = None
    if optics.cos4 and optics.shading_corrected:
        out = cos4_falloff(height, width, camera.pixel.pitch_um * 1e-3, optics.focal_length_mm)
    table = optics.relative_illumination
    if table:
        v, u = normalised_coords(height, width)
        r = np.sqrt(v[:, None] ** 2 + u[None, :] ** 2)
        cfa = camera.cfa.cfa
        chan = cfa.channel_map(height, width)
        ri = np.ones((height, width), dtype=np.float32)
        for i, name in enumerate(cfa.channels):
            if name in table:
                sel = chan == i
                ri[sel] = np.interp(r[sel], table["radius"], table[name])
        out = ri if out is None else out * ri
    return out
