"""The simulation chain: scene radiance → optics → pixel → electrons → DN.

For a capture of a :class:`~l3cli.simulate.scenes.Scene` under an illuminant
scaled to ``lux`` (illuminance on the scene, lm/m²):

1. **Scene radiance** of a Lambertian surface ``L(λ) = R(λ) E(λ) / π``
   (W/sr/m²/nm); ``E`` is the illuminant's relative spectrum scaled so that
   ``683 Σ V(λ) E(λ) Δλ = lux``.
2. **Optics**: sensor irradiance ``E_s = π T L / (1 + 4N²)`` (on axis; optional
   cos⁴ fall-off), blurred per wavelength by the diffraction-limited Airy OTF
   (frequency domain, reflect-padded borders). Because the scene is a sum of
   K maps times spectra, the blur of channel ``c`` is exactly
   ``Σ_k IFFT(FFT(a_k) · Σ_λ w_{c,k}(λ) OTF_λ)``: K forward and one inverse
   FFT per output, whatever the number of wavelengths.
3. **Pixel**: mean photo-electrons ``μ = t A_pix Σ_λ QE_c(λ) E_s,q(λ) Δλ``
   (photons = energy λ / hc; ``A_pix`` = pitch² × fill factor; QE includes
   the IR-cut filter).
4. **Sensor noise**: PRNU (gain, fixed pattern) → dark current + DSNU (fixed
   pattern) → Poisson shot noise → full-well clip → Gaussian read noise
   (electrons) → conversion gain (V/e-) × analog gain → ADC:
   ``DN = black + round(V / swing × (white − black))`` clipped to [0, white].
   With ``readout.black_clamp`` the mean dark signal (dark current × time)
   is subtracted before the ADC, as a sensor's optical-black clamp does (its
   shot noise and the DSNU stay); without it (ISETCam) it stays in the raw.
5. **Noise-free response**: ``min(μ + dark, full well) × gain × cg / swing``
   (less the clamped dark mean), clipped to 1 (same normalisation as the raw
   mosaic: 0 black, 1 white level).
6. **Ideal target**: CIE 1931 XYZ of the same optical image (same optics and
   pixel aperture, no QE, no noise, no clipping) on a fixed photometric scale:
   ``Y = H_v / H_ref`` where ``H_v`` is the photometric exposure at the pixel
   (lux·s at the sensor plane) and ``H_ref`` is a camera constant: the sensor
   photometric exposure of an equal-energy (illuminant E) light that brings
   the camera's most sensitive channel to saturation. ``X`` and ``Z`` share the
   same constant. So the target scales with the raw signal and never depends
   on a capture's auto-exposure decision.

Exposure: ``fixed`` (given time) or ``auto`` as ISETCam's default
auto-exposure: the time at which the brightest noise-free pixel reaches
``target_fraction`` of saturation, capped at ``max_time_s`` (ISETCam has no
cap); below the cap's light level the analog gain rises, up to
``max_analog_gain``, as a camera's auto ISO (:func:`exposure_setting`). The
ideal target scales with time x that gain, as the raw signal does.

References
----------
.. [1] Farrell, J. E., Catrysse, P. B. and Wandell, B. A. (2012). Digital camera
   simulation. Applied Optics 51(4), A80-A90.
.. [2] EMVA Standard 1288 Release 4.0 (2021): linear sensor model, photon transfer.
.. [3] Goodman, J. W. (2005). Introduction to Fourier Optics, 3rd ed.
"""

from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from l3cli import spectral
from l3cli.camera import Camera
from l3cli.errors import ConfigError
from l3cli.simulate.optics import (
    airy_otf,
    cos4_falloff,
    irradiance_factor,
    radial_frequency,
    raw_shading,
)
from l3cli.simulate.scenes import Scene

__all__ = [
    "CameraModel",
    "Capture",
    "prepare_camera",
    "illuminant_irradiance",
    "render_planes",
    "simulate_capture",
    "exposure_setting",
    "capture_seed",
    "TARGET_SCALE_DOC",
]

TARGET_SCALE_DOC = (
    "CIE 1931 XYZ (2 deg) of the optical image at each pixel with Y = H_v / H_ref: H_v is the "
    "photometric exposure at the sensor plane (lux s, pixel-averaged, after the lens), H_ref = "
    "{h_ref:.6g} lux s is a constant of this camera (the sensor photometric exposure of an "
    "equal-energy light that saturates its most sensitive channel); the same for every capture "
    "and light level, so the target scales with the raw signal."
)

_OTF_BINS = 8192


@dataclass(frozen=True)
class CameraModel:
    """Per-camera constants derived from a :class:`~l3cli.camera.Camera`.

    Attributes
    ----------
    camera
        The camera.
    wavelengths
        (N,) nm.
    dlambda
        Wavelength step (nm) used as the integration weight.
    qe
        (N, C) effective QE per CFA channel (``camera.cfa.cfa.channels`` order).
    cmfs
        (N, 3) CIE 1931 2° colour-matching functions.
    sat_e
        Electrons at which the DN saturates (full well, or earlier with analog gain > 1).
    dn_per_e
        Digital numbers per electron (above black).
    h_ref
        Target scale constant (lux s at the sensor plane), see module notes.
    """

    camera: Camera
    wavelengths: np.ndarray
    dlambda: float
    qe: np.ndarray
    cmfs: np.ndarray
    sat_e: float
    dn_per_e: float
    h_ref: float

    @property
    def channels(self) -> tuple[str, ...]:
        """CFA channel names."""
        return self.camera.cfa.cfa.channels


def prepare_camera(camera: Camera) -> CameraModel:
    """Precompute the spectral and electrical constants of a camera."""
    wl = camera.wavelengths
    dl = float(camera.spectrum.step_nm)
    qe = camera.qe_curves(wl)
    cmfs = spectral.cie_cmfs(wl)
    px, ro = camera.pixel, camera.readout
    g = ro.analog_gain
    sat_e = min(px.full_well_e, px.voltage_swing_v / (g * px.conversion_gain_uv_per_e * 1e-6))
    dn_per_e = g * px.conversion_gain_uv_per_e * 1e-6 / px.voltage_swing_v * (
        ro.white_level_dn - ro.black_level_dn)
    # Equal-energy irradiance of 1 lux at the sensor: electrons per lux s per channel.
    v = cmfs[:, 1]
    e_flat = 1.0 / (spectral.KM * np.sum(v) * dl)  # W/m²/nm
    photons = e_flat * wl * 1e-9 / (spectral.H_PLANCK * spectral.C_LIGHT)
    e_per_lux_s = px.area_m2 * np.sum(qe * photons[:, None], axis=0) * dl
    best = float(np.max(e_per_lux_s))
    if best <= 0:
        raise ConfigError(f"{camera.file}: the camera's QE is zero over {wl[0]:g}-{wl[-1]:g} nm")
    return CameraModel(camera=camera, wavelengths=wl, dlambda=dl, qe=qe, cmfs=cmfs,
                       sat_e=float(sat_e), dn_per_e=float(dn_per_e), h_ref=sat_e / best)


def illuminant_irradiance(name: str, lux: float, wavelengths: np.ndarray) -> np.ndarray:
    """Spectral irradiance (W/m²/nm) of an illuminant scaled to ``lux``.

    Raises
    ------
    ConfigError
        Unknown illuminant, range not covered, ``lux <= 0`` or an illuminant
        with no visible power.
    """
    if not (np.isfinite(lux) and lux > 0):
        raise ConfigError(f"light level must be > 0 lux, got {lux!r}")
    wl = np.asarray(wavelengths, dtype=np.float64)
    rel = spectral.load_illuminant(name, wl)
    step = float(np.mean(np.diff(wl))) if wl.size > 1 else 1.0
    lum = spectral.KM * np.sum(rel * spectral.luminous_efficiency(wl)) * step
    if lum <= 0:
        raise ConfigError(f"illuminant {name!r} has no visible power over {wl[0]:g}-{wl[-1]:g} nm")
    return rel * (lux / lum)


def _sensor_irradiance_spectra(model: CameraModel, scene: Scene, illuminant: str, lux: float) -> np.ndarray:
    """Sensor irradiance per unit map (W/m²/nm), (K, N), on axis."""
    cam = model.camera
    wl = model.wavelengths
    k_irr = irradiance_factor(cam.optics.f_number, cam.optics.transmittance)
    if scene.kind == "reflectance":
        e = illuminant_irradiance(illuminant, lux, wl)
        return k_irr * scene.spectra * e[None, :]
    if not (np.isfinite(lux) and lux > 0):
        raise ConfigError(f"light level must be > 0 lux, got {lux!r}")
    # Radiance scene: mean luminance = that of an 18 % grey under `lux`.
    mean_w = scene.maps.reshape(scene.maps.shape[0], -1).mean(axis=1)
    lum = spectral.KM * np.sum((mean_w @ scene.spectra) * spectral.luminous_efficiency(wl)) * model.dlambda
    if lum <= 0:
        raise ConfigError(f"{scene.source}: the radiance cube has no visible luminance")
    scale = 0.18 * lux / np.pi / lum
    return k_irr * np.pi * scale * scene.spectra


def spectral_weights(model: CameraModel, scene: Scene, illuminant: str, lux: float) -> np.ndarray:
    """Weights (C + 3, K, N): channel electrons/s and target units/s per unit map and wavelength."""
    es = _sensor_irradiance_spectra(model, scene, illuminant, lux)  # (K, N) W/m²/nm
    wl = model.wavelengths
    photons = es * (wl * 1e-9 / (spectral.H_PLANCK * spectral.C_LIGHT))[None, :]  # photons/s/m²/nm
    area = model.camera.pixel.area_m2
    w_ch = area * model.dlambda * np.einsum("nc,kn->ckn", model.qe, photons)
    w_xyz = spectral.KM * model.dlambda / model.h_ref * np.einsum("nj,kn->jkn", model.cmfs, es)
    return np.concatenate([w_ch, w_xyz], axis=0)


def _pad_widths(size: int, margin: int) -> tuple[int, int, int]:
    from scipy.fft import next_fast_len

    total = next_fast_len(size + 2 * margin, real=True)
    before = (total - size) // 2
    return total, before, total - size - before


def render_planes(model: CameraModel, scene: Scene, weights: np.ndarray, *,
                  blur: bool = True, workers: int | None = None,
                  outputs: list[int] | None = None) -> np.ndarray:
    """Blurred output planes per second of exposure, float32 (len(outputs), H, W).

    Parameters
    ----------
    model
        Camera constants.
    scene
        The scene (K maps).
    weights
        (O, K, N) from :func:`spectral_weights`.
    blur
        Apply the Airy OTF (False: a perfect lens, for tests).
    workers
        FFT threads (default: all cores, as scipy.fft workers=-1).
    outputs
        Which of the O outputs to compute (default all).
    """
    from scipy import fft

    workers = -1 if workers is None else workers
    cam = model.camera
    maps = scene.maps
    spectra_w = np.asarray(weights, dtype=np.float64)
    k, h, w = maps.shape
    s = scene.oversample
    outs = list(range(spectra_w.shape[0])) if outputs is None else list(outputs)
    pitch_mm = cam.pixel.pitch_um * 1e-3 / s
    falloff = (cos4_falloff(h, w, pitch_mm, cam.optics.focal_length_mm)
               if cam.optics.cos4 and not cam.optics.shading_corrected else None)
    if not blur:
        planes = np.empty((len(outs), h, w), dtype=np.float32)
        wsum = spectra_w.sum(axis=2)  # (O, K)
        for i, o in enumerate(outs):
            acc = np.zeros((h, w), dtype=np.float32)
            for j in range(k):
                if wsum[o, j] != 0:
                    acc += np.float32(wsum[o, j]) * maps[j]
            if falloff is not None:
                acc *= falloff
            planes[i] = acc
        return _bin(planes, s)

    lam_max = float(model.wavelengths[-1])
    margin = int(min(64 * s, max(8, np.ceil(10 * lam_max * 1e-6 * cam.optics.f_number / pitch_mm))))
    hp, pt, pb = _pad_widths(h, margin)
    wp, pl, pr = _pad_widths(w, margin)
    rho = radial_frequency(hp, wp, pitch_mm)
    rho_max = float(np.sqrt(2.0) * 0.5 / pitch_mm) * 1.0001
    idx = np.rint(rho * ((_OTF_BINS - 1) / rho_max)).astype(np.int32)
    del rho
    grid = np.linspace(0.0, rho_max, _OTF_BINS)
    otf = airy_otf(grid[None, :], model.wavelengths[:, None], cam.optics.f_number)  # (N, bins)
    tables = np.einsum("okn,nb->okb", spectra_w[outs], otf).astype(np.float32)  # (O', K, bins)

    if k <= _FUSED_MAX_MAPS:
        specs = np.empty((k, hp, wp // 2 + 1), dtype=np.complex64)
        for j in range(k):
            a = maps[j] if falloff is None else maps[j] * falloff
            specs[j] = fft.rfft2(np.pad(a, ((pt, pb), (pl, pr)), mode="symmetric"), workers=workers)
        acc_arr = _combine_spectra(specs, tables, idx)
        del specs
        planes = np.empty((len(outs), h, w), dtype=np.float32)
        for i in range(len(outs)):
            planes[i] = fft.irfft2(acc_arr[i], s=(hp, wp), workers=workers)[pt:pt + h, pl:pl + w]
        return _bin(planes, s)

    acc = [np.zeros((hp, wp // 2 + 1), dtype=np.complex64) for _ in outs]
    for j in range(k):
        if not np.any(tables[:, j, 0]) and not np.any(tables[:, j]):
            continue
        a = maps[j] if falloff is None else maps[j] * falloff
        padded = np.pad(a, ((pt, pb), (pl, pr)), mode="symmetric")
        spec = fft.rfft2(padded, workers=workers)
        del padded
        for i in range(len(outs)):
            t = tables[i, j]
            if t[0] == 0 and not np.any(t):
                continue
            acc[i] += spec * t[idx]
        del spec
    planes = np.empty((len(outs), h, w), dtype=np.float32)
    for i in range(len(outs)):
        full = fft.irfft2(acc[i], s=(hp, wp), workers=workers)
        planes[i] = full[pt:pt + h, pl:pl + w]
        acc[i] = None  # free
        del full
    return _bin(planes, s)


_FUSED_MAX_MAPS = 16


def _combine_spectra(specs: np.ndarray, tables: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``out[o] = Σ_k specs[k] · tables[o, k, idx]`` in one parallel pass (numba)."""
    return _combine_kernel()(specs, tables, idx)


@functools.cache
def _combine_kernel():
    import numba as nb

    from l3cli.startup import lean_cache

    @lean_cache
    @nb.njit(cache=True, parallel=True)
    def kernel(specs, tables, idx):  # pragma: no cover - compiled
        k, hp, wf = specs.shape
        o = tables.shape[0]
        out = np.zeros((o, hp, wf), dtype=np.complex64)
        for y in nb.prange(hp):
            row = idx[y]
            for j in range(k):
                sp = specs[j, y]
                for i in range(o):
                    t = tables[i, j]
                    dst = out[i, y]
                    for x in range(wf):
                        dst[x] += sp[x] * t[row[x]]
        return out

    return kernel


def _bin(planes: np.ndarray, s: int) -> np.ndarray:
    """Average s x s blocks (the pixel aperture over oversampled scene samples)."""
    if s == 1:
        return planes
    o, h, w = planes.shape
    return planes.reshape(o, h // s, s, w // s, s).mean(axis=(2, 4), dtype=np.float64).astype(np.float32)


def capture_seed(seed: int, stem: str) -> np.random.SeedSequence:
    """Seed sequence of one capture: from ``--seed`` and the capture's stem.

    Captures are independent of their order and of which other captures are
    simulated.
    """
    return np.random.SeedSequence([int(seed) & 0xFFFFFFFF, zlib.crc32(stem.encode("utf-8"))])


def fixed_pattern(camera: Camera, seed: int, height: int, width: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """PRNU gain (1 + σ·n) and DSNU offset (electrons) maps of the sensor (fixed per camera and seed)."""
    px = camera.pixel
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0x5EED])))
    gain = offset = None
    if px.prnu_percent > 0:
        gain = 1.0 + np.float32(px.prnu_percent / 100.0) * rng.standard_normal((height, width), dtype=np.float32)
        np.maximum(gain, 0.0, out=gain)
    if px.dsnu_e > 0:
        offset = np.float32(px.dsnu_e) * rng.standard_normal((height, width), dtype=np.float32)
    return gain, offset


@dataclass
class Capture:
    """One simulated capture (arrays + metadata for the manifest)."""

    stem: str
    scene: str
    illuminant: str
    lux: float
    exposure_s: float
    dn: np.ndarray  # (H, W) uint16
    noise_free: np.ndarray  # (H, W) float32
    target: np.ndarray  # (H, W, 3) float32
    seed: int
    chart: dict[str, Any] | None = None
    edge: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    analog_gain: float = 1.0  # total analog gain of the capture (readout gain x auto gain)
    auto_gain: float = 1.0  # the part auto exposure added (1 unless the time was capped)


def _mosaic_select(planes: np.ndarray, cfa_index: np.ndarray) -> np.ndarray:
    h, w = planes.shape[1:]
    ph, pw = cfa_index.shape
    out = np.empty((h, w), dtype=np.float32)
    for dy in range(ph):
        for dx in range(pw):
            out[dy::ph, dx::pw] = planes[cfa_index[dy, dx], dy::ph, dx::pw]
    return out


def exposure_setting(model: CameraModel, peak_rate: float,
                     exposure_s: float | None = None) -> tuple[float, float]:
    """Exposure time (s) and auto-exposure gain of a capture.

    ``auto`` mode, as ISETCam's default auto exposure (``aeLuminance``): the
    time at which the brightest noise-free pixel (photo-electrons plus dark
    current) reaches ``target_fraction`` of saturation, at most
    ``max_time_s``. Where the cap is reached, the analog gain is raised, as a
    camera's auto ISO does, by up to ``max_analog_gain`` so that the brightest
    pixel still reaches the target (the electrons, and so the shot and read
    noise, stay those of the capped time). ``fixed`` mode and ``exposure_s``:
    that time and gain 1.

    Parameters
    ----------
    model
        Camera constants.
    peak_rate
        Photo-electrons per second of the brightest pixel (noise-free).
    exposure_s
        A fixed time that overrides the camera's exposure control.

    Returns
    -------
    (float, float)
        Exposure time in seconds and the gain factor (>= 1) on top of the
        readout's ``analog_gain``.
    """
    ex = model.camera.exposure
    if exposure_s is not None:
        return float(exposure_s), 1.0
    if ex.mode == "fixed":
        return float(ex.time_s), 1.0
    dark_rate = model.camera.pixel.dark_current_e_per_s
    peak = peak_rate + dark_rate
    if peak <= 0:
        return float(ex.max_time_s), float(ex.max_analog_gain)
    goal = ex.target_fraction * model.sat_e  # electrons at the base gain
    t = min(ex.max_time_s, goal / peak)
    gain = min(ex.max_analog_gain, max(1.0, goal / (peak * t)))
    return float(t), float(gain)


def simulate_capture(model: CameraModel, scene: Scene, *, illuminant: str, lux: float,
                     seed: int, stem: str | None = None, blur: bool = True,
                     noise: bool = True, exposure_s: float | None = None,
                     workers: int | None = None) -> Capture:
    """Simulate one capture of ``scene`` (see module notes for the chain).

    Parameters
    ----------
    model
        From :func:`prepare_camera`.
    scene
        The scene.
    illuminant
        Illuminant name (:data:`l3cli.spectral.ILLUMINANTS`); ignored for radiance scenes.
    lux
        Scene illuminance in lux (> 0).
    seed
        ``--seed``; the capture's noise comes from ``capture_seed(seed, stem)``.
    stem
        Capture name (default ``SCENE_ILLUMINANT_LUXlux``).
    blur
        Apply the optics OTF.
    noise
        Apply noise (False: the raw is the quantised noise-free signal).
    exposure_s
        Override the camera's exposure control with a fixed time.
    workers
        FFT threads.
    """
    cam = model.camera
    if not (np.isfinite(lux) and lux > 0):
        raise ConfigError(f"light level must be > 0 lux, got {lux!r}")
    stem = stem or capture_stem(scene.name, illuminant, lux)
    weights = spectral_weights(model, scene, illuminant, lux)
    c = len(model.channels)
    planes = render_planes(model, scene, weights, blur=blur, workers=workers)
    rate = _mosaic_select(planes[:c], cam.cfa.cfa.index_pattern)  # photo-electrons / s
    shading = raw_shading(cam, *rate.shape)  # the raw's alone: the target stays unshaded
    if shading is not None:
        rate *= shading
    xyz_rate = planes[c:]
    del planes
    px, ro = cam.pixel, cam.readout
    dark_rate = px.dark_current_e_per_s
    t, ae_gain = exposure_setting(model, float(np.max(rate)), exposure_s)
    np.maximum(rate, 0.0, out=rate)
    mu = rate * np.float32(t)
    del rate
    dark = np.float32(dark_rate * t)
    scale = np.float32(ae_gain * ro.analog_gain * px.conversion_gain_uv_per_e * 1e-6 / px.voltage_swing_v)
    # optical-black clamp: the mean dark signal is taken out before the ADC
    clamp = dark if ro.black_clamp else np.float32(0.0)
    noise_free = (np.minimum(mu + dark, np.float32(px.full_well_e)) - clamp) * scale
    np.minimum(noise_free, 1.0, out=noise_free)
    ss = capture_seed(seed, stem)
    span = ro.white_level_dn - ro.black_level_dn
    if noise:
        rng = np.random.Generator(np.random.PCG64(ss))
        gain, offset = fixed_pattern(cam, seed, *mu.shape)
        lam = mu if gain is None else mu * gain
        lam = lam + dark if offset is None else lam + np.maximum(dark + offset, 0.0)
        electrons = rng.poisson(lam).astype(np.float32)
        del lam
        np.minimum(electrons, np.float32(px.full_well_e), out=electrons)
        if px.read_noise_e > 0:
            electrons += np.float32(px.read_noise_e) * rng.standard_normal(electrons.shape, dtype=np.float32)
        signal = (electrons - clamp) * scale
        del electrons
    else:
        signal = (np.minimum(mu + dark, np.float32(px.full_well_e)) - clamp) * scale
    del mu
    dn = np.rint(signal * np.float32(span)) + np.float32(ro.black_level_dn)
    np.clip(dn, 0, ro.white_level_dn, out=dn)
    # the target scales with the raw signal: exposure time x the auto-exposure gain
    target = np.ascontiguousarray(np.moveaxis(xyz_rate * np.float32(t * ae_gain), 0, 2))
    cap = Capture(stem=stem, scene=scene.name, illuminant=illuminant if scene.kind == "reflectance" else "",
                  lux=float(lux), exposure_s=float(t), dn=dn.astype(np.uint16), noise_free=noise_free,
                  target=target, seed=int(seed), chart=None, edge=scene.edge,
                  analog_gain=float(ae_gain * ro.analog_gain), auto_gain=float(ae_gain))
    if scene.kind == "reflectance":
        # Perfect white diffuser (reflectance 1) on the target scale, on axis, this capture.
        es = illuminant_irradiance(illuminant, lux, model.wavelengths) * irradiance_factor(
            cam.optics.f_number, cam.optics.transmittance)
        white = spectral.KM * model.dlambda / model.h_ref * (model.cmfs.T @ es) * (t * ae_gain)
        cap.extra["white_xyz"] = [float(v) for v in white]
        cap.extra["photometric_exposure_white_lux_s"] = float(white[1] * model.h_ref / ae_gain)
    if scene.chart is not None:
        chart = dict(scene.chart)
        ref = []
        for x0, y0, x1, y1 in chart["patches"]:
            dx, dy = (x1 - x0) // 4, (y1 - y0) // 4
            ref.append([float(v) for v in target[y0 + dy:y1 - dy, x0 + dx:x1 - dx].reshape(-1, 3).mean(axis=0)])
        chart["reference_xyz"] = ref
        chart["reference_region"] = "mean of the ideal target over the central half of each patch box"
        cap.chart = chart
    return cap


def capture_stem(scene: str, illuminant: str, lux: float) -> str:
    """Capture file stem, e.g. ``macbeth_D65_0100lux``."""
    lx = f"{int(lux):04d}" if float(lux).is_integer() else f"{lux:g}".replace(".", "p")
    ill = illuminant.replace("/", "-") or "radiance"
    return f"{scene}_{ill}_{lx}lux"
