"""Each step of the simulation chain against an analytic or independent result.

Includes issue 3's must-shows: the photon-transfer check, the diffraction
(slanted-edge MTF vs Airy OTF) check and the Macbeth colorimetry check.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.constants as const

from l3cli.camera import camera_from_dict, load_camera
from l3cli.simulate import make_scene, prepare_camera, simulate_capture
from l3cli.simulate.core import illuminant_irradiance
from l3cli.simulate.optics import airy_otf
from l3cli.simulate.scenes import Scene, edge_area_coverage
from tests.builders import uniform_scene

REPO = Path(__file__).resolve().parents[2]


def flat_qe_camera(tmp_path: Path, *, cfa="W", qe=0.5, f_number=4.0, pitch=2.0, read_noise=0.0,
                   dark=0.0, prnu=0.0, dsnu=0.0, cg=100.0, swing=1.0, bits=12, black=64,
                   grid=(400, 700, 10), gain=1.0, mode="fixed", time_s=0.01):
    chans = sorted({c for row in ([cfa] if isinstance(cfa, str) else cfa) for c in (row if isinstance(row, list) else [row])})
    csv = tmp_path / "flat_qe.csv"
    wl = np.arange(380, 1101, 10)
    csv.write_text("wavelength_nm," + ",".join(chans) + "\n"
                   + "\n".join(f"{w}," + ",".join(str(qe) for _ in chans) for w in wl) + "\n")
    data = {
        "name": "flat",
        "optics": {"f_number": f_number},
        "pixel": {"pitch_um": pitch, "conversion_gain_uv_per_e": cg, "voltage_swing_v": swing,
                  "read_noise_e": read_noise, "dark_current_e_per_s": dark,
                  "prnu_percent": prnu, "dsnu_e": dsnu},
        "readout": {"bit_depth": bits, "black_level_dn": black, "analog_gain": gain},
        "cfa": {"pattern": cfa, "qe": str(csv)},
        "spectrum": {"wavelength_nm": list(grid)},
        "exposure": {"mode": mode, "time_s": time_s, "illuminant": "E"},
    }
    return camera_from_dict(data, file=tmp_path / "flat.toml")




# --------------------------------------------------------------- radiometry

def test_illuminant_scaled_to_lux_matches_colour_luminous_flux() -> None:
    import colour

    wl = np.arange(380.0, 781.0, 5.0)
    e = illuminant_irradiance("D65", 250.0, wl)
    sd = colour.SpectralDistribution(dict(zip(wl, e, strict=True)))
    assert colour.luminous_flux(sd) == pytest.approx(250.0, rel=2e-3)


def test_flat_field_electrons_match_first_principles(tmp_path: Path) -> None:
    cam = flat_qe_camera(tmp_path, f_number=2.0, pitch=3.0, time_s=0.02)
    model = prepare_camera(cam)
    wl = model.wavelengths
    lux, refl, t = 50.0, 0.5, 0.02
    cap = simulate_capture(model, uniform_scene(32, 48, wl, refl), illuminant="E", lux=lux,
                           seed=0, noise=False)
    # Independent: E_e flat with 683 * sum(V) * dλ = lux; radiance R E / π;
    # sensor irradiance π L / (1 + 4 N²); photons λ / (h c); QE 0.5; area p².
    import colour

    v = colour.colorimetry.SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"]
    vv = np.interp(wl, v.wavelengths, v.values)
    e_flat = lux / (const.physical_constants["luminous efficacy"][0] * vv.sum() * 10.0)
    es = refl * e_flat / (1 + 4 * 2.0**2)
    photons = es * wl * 1e-9 / (const.h * const.c)
    electrons = t * (3e-6) ** 2 * 0.5 * photons.sum() * 10.0
    expected = electrons * 100e-6 / 1.0  # fraction of swing
    np.testing.assert_allclose(cap.noise_free, expected, rtol=2e-3)
    assert cap.exposure_s == t
    # The noise-free raw is the same number quantised.
    span = cam.readout.white_level_dn - cam.readout.black_level_dn
    np.testing.assert_array_equal(cap.dn, np.rint(expected * span) + cam.readout.black_level_dn)


def test_target_scale_fixed_and_proportional_to_exposure(tmp_path: Path) -> None:
    cam = load_camera(REPO / "sample_configs" / "bayer.toml")
    model = prepare_camera(cam)
    scene = uniform_scene(16, 16, model.wavelengths, 0.5)
    a = simulate_capture(model, scene, illuminant="D65", lux=10.0, seed=0, noise=False, exposure_s=0.01)
    b = simulate_capture(model, scene, illuminant="D65", lux=100.0, seed=0, noise=False, exposure_s=0.01)
    c = simulate_capture(model, scene, illuminant="D65", lux=100.0, seed=0, noise=False, exposure_s=0.02)
    ya, yb, yc = (float(x.target[..., 1].mean()) for x in (a, b, c))
    assert yb == pytest.approx(10 * ya, rel=1e-4) and yc == pytest.approx(2 * yb, rel=1e-4)
    # Raw and target scale together.
    assert float(b.noise_free.mean()) / yb == pytest.approx(float(c.noise_free.mean()) / yc, rel=1e-4)
    # Y equals the sensor photometric exposure / H_ref.
    h_v = 100.0 * 0.5 / (1 + 4 * 4.0**2) * 0.01
    assert yb == pytest.approx(h_v / model.h_ref, rel=5e-3)


# ------------------------------------------------------------------- optics

def _pupil_autocorrelation(nu: float, n: int = 801) -> float:
    """OTF of a circular pupil by direct overlap counting (independent of the formula)."""
    x = np.linspace(-1, 1, n)
    xx, yy = np.meshgrid(x, x)
    inside = xx**2 + yy**2 <= 1
    shifted = (xx - 2 * nu) ** 2 + yy**2 <= 1
    return float((inside & shifted).sum() / inside.sum())


@pytest.mark.parametrize("nu", [0.0, 0.1, 0.25, 0.5, 0.75, 0.95, 1.0, 1.2])
def test_airy_otf_equals_pupil_autocorrelation(nu: float) -> None:
    lam, n = 550.0, 4.0
    f = nu / (lam * 1e-6 * n)
    assert float(airy_otf(f, lam, n)) == pytest.approx(_pupil_autocorrelation(min(nu, 1.0)), abs=4e-3)


def test_edge_coverage_is_exact_area() -> None:
    h, w, ang = 12, 16, 5.0
    cov = edge_area_coverage(h, w, angle_deg=ang)
    ss = 200
    sub = (np.arange(ss) + 0.5) / ss
    brute = np.zeros((h, w))
    s = math.tan(math.radians(ang))
    for i in range(h):
        y = i + sub  # sub-rows
        xe = w / 2 + s * (y - h / 2)
        for j in range(w):
            x = j + sub
            brute[i, j] = np.mean(x[None, :] < xe[:, None])
    np.testing.assert_allclose(cov, brute, atol=1e-2)
    assert np.all((cov >= 0) & (cov <= 1))
    # Row integral: total covered area of a row = x_e at the row centre.
    np.testing.assert_allclose(cov.sum(axis=1), w / 2 + s * (np.arange(h) + 0.5 - h / 2), atol=1e-9)


def _edge_mtf(img: np.ndarray, angle_deg: float, oversample: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """ISO 12233-style MTF from a near-vertical edge (light left): frequencies in cycles/pixel."""
    h, w = img.shape
    # Edge location per row from the centroid of the row derivative.
    d = np.abs(np.diff(img, axis=1))
    xs = np.arange(w - 1) + 1.0
    cent = (d * xs).sum(axis=1) / d.sum(axis=1)
    rows = np.arange(h)
    slope, icpt = np.polyfit(rows + 0.5, cent, 1)
    # Project pixel centres onto the edge normal (horizontal distance to the edge line).
    yy, xx = np.mgrid[0:h, 0:w]
    dist = (xx + 0.5) - (icpt + slope * (yy + 0.5))
    dist *= math.cos(math.atan(slope))
    bins = np.floor(dist * oversample).astype(int)
    lo = bins.min()
    counts = np.bincount((bins - lo).ravel())
    sums = np.bincount((bins - lo).ravel(), weights=img.ravel())
    ok = counts > 0
    esf = sums[ok] / counts[ok]
    lsf = np.gradient(esf)
    lsf *= np.hanning(lsf.size)
    mtf = np.abs(np.fft.rfft(lsf))
    mtf /= mtf[0]
    f = np.fft.rfftfreq(lsf.size, d=1.0 / oversample)  # cycles per pixel
    # Remove the binning (box of 1/oversample px) and the central-difference derivative.
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.sinc(f / oversample) * np.sinc(2 * f / oversample)
    return f, mtf / corr


@pytest.mark.parametrize("n_f, pitch, oversample", [(8.0, 2.0, 4), (4.0, 1.4, 1), (2.8, 2.0, 2)])
def test_slanted_edge_mtf_matches_airy_otf(tmp_path: Path, n_f: float, pitch: float,
                                           oversample: int) -> None:
    """Must show: noise-free ideal sensor edge MTF = Airy OTF within 3 % below Nyquist."""
    cam = flat_qe_camera(tmp_path, f_number=n_f, pitch=pitch, time_s=1e-4)
    model = prepare_camera(cam)
    wl = model.wavelengths
    scene = make_scene("slanted-edge", 160, 160, wl, oversample=oversample)
    cap = simulate_capture(model, scene, illuminant="E", lux=1000.0, seed=0, noise=False)
    img = cap.noise_free[:, :, 0] if cap.noise_free.ndim == 3 else cap.noise_free
    assert img.max() < 0.99  # not clipped
    x0, y0, x1, y1 = scene.edge["roi"]
    f, mtf = _edge_mtf(img[y0:y1, x0:x1].astype(np.float64), 5.0)
    # Expected: photon-weighted polychromatic Airy OTF times the pixel aperture (box of one pitch).
    weights = wl / wl.sum()  # flat energy x flat QE: photons ∝ λ
    f_mm = f / (pitch * 1e-3)
    otf = (weights[:, None] * airy_otf(f_mm[None, :], wl[:, None], n_f)).sum(axis=0)
    expected = otf * np.sinc(f)
    below = (f > 0) & (f <= 0.5)
    err = np.abs(mtf[below] - expected[below])
    print(f"edge MTF vs Airy x pixel: max abs error {err.max():.4f} below Nyquist "
          f"(MTF at Nyquist {np.interp(0.5, f, mtf):.3f}, expected {np.interp(0.5, f, expected):.3f})")
    assert err.max() < 0.03, f"max |MTF - Airy| = {err.max():.4f} at {f[below][err.argmax()]:.3f} cy/px"


# ----------------------------------------------------------------- sensor

def test_photon_transfer_recovers_gain_and_read_noise(tmp_path: Path) -> None:
    """Must show: mean-variance slope = conversion gain (2 %), intercept = read noise (10 %)."""
    read_noise = 3.0
    cam = flat_qe_camera(tmp_path, read_noise=read_noise, cg=50.0, swing=1.0, bits=14, black=100,
                         time_s=1e-3)
    model = prepare_camera(cam)
    k_true = model.dn_per_e  # DN per electron
    scene = uniform_scene(256, 256, model.wavelengths, 1.0)
    means, variances = [], []
    for i, lux in enumerate([1e-6, 5, 10, 20, 50, 100, 200, 500, 1000, 2000]):
        cap = simulate_capture(model, scene, illuminant="E", lux=lux, seed=7, stem=f"ptc{i}")
        dn = cap.dn.astype(np.float64) - cam.readout.black_level_dn
        means.append(dn.mean())
        variances.append(dn.var(ddof=1))
    means, variances = np.array(means), np.array(variances)
    assert means.max() < 0.8 * (cam.readout.white_level_dn - cam.readout.black_level_dn)
    # Weighted least squares (the sd of a variance estimate is proportional to the variance).
    wts = 1.0 / variances
    a = np.stack([means, np.ones_like(means)], axis=1) * wts[:, None]
    slope, intercept = np.linalg.lstsq(a, variances * wts, rcond=None)[0]
    assert slope == pytest.approx(k_true, rel=0.02)
    read_dn = math.sqrt(intercept - 1.0 / 12.0)  # remove ADC quantisation noise
    print(f"PTC: slope {slope:.5f} DN/e- (true {k_true:.5f}, {100 * (slope / k_true - 1):+.2f} %), "
          f"read noise {read_dn / k_true:.3f} e- (true {read_noise}, "
          f"{100 * (read_dn / k_true / read_noise - 1):+.2f} %)")
    assert read_dn / k_true == pytest.approx(read_noise, rel=0.10)


def test_full_well_clip_and_white_level(tmp_path: Path) -> None:
    cam = flat_qe_camera(tmp_path, read_noise=2.0, time_s=1.0)
    model = prepare_camera(cam)
    cap = simulate_capture(model, uniform_scene(16, 16, model.wavelengths, 1.0), illuminant="E",
                           lux=1e5, seed=1)
    assert np.all(cap.dn >= cam.readout.white_level_dn - 2)
    assert np.all(cap.noise_free == 1.0)


def test_dark_current_and_dsnu(tmp_path: Path) -> None:
    cam = flat_qe_camera(tmp_path, dark=1000.0, dsnu=5.0, cg=50.0, bits=14, time_s=0.5)
    model = prepare_camera(cam)
    cap = simulate_capture(model, uniform_scene(128, 128, model.wavelengths, 0.0), illuminant="E",
                           lux=1.0, seed=3)
    e = (cap.dn.astype(np.float64) - cam.readout.black_level_dn) / model.dn_per_e
    assert e.mean() == pytest.approx(500.0, rel=0.01)
    # Variance: Poisson (500) + DSNU² (25), quantisation small.
    assert e.var() == pytest.approx(525.0, rel=0.06)


def test_prnu_is_multiplicative_fixed_pattern(tmp_path: Path) -> None:
    cam = flat_qe_camera(tmp_path, prnu=2.0, cg=20.0, swing=2.0, bits=16, time_s=0.05)
    model = prepare_camera(cam)
    scene = uniform_scene(96, 96, model.wavelengths, 1.0)
    a = simulate_capture(model, scene, illuminant="E", lux=200.0, seed=5, stem="a")
    b = simulate_capture(model, scene, illuminant="E", lux=200.0, seed=5, stem="b")
    ea = (a.dn.astype(np.float64) - 64) / model.dn_per_e
    eb = (b.dn.astype(np.float64) - 64) / model.dn_per_e
    mu = ea.mean()
    # Temporal noise differs, the fixed pattern is shared: cov(a, b) ≈ (σ_prnu μ)².
    cov = np.mean((ea - ea.mean()) * (eb - eb.mean()))
    assert math.sqrt(cov) / mu == pytest.approx(0.02, rel=0.1)


def test_analog_gain_scales_dn(tmp_path: Path) -> None:
    c1 = flat_qe_camera(tmp_path, gain=1.0)
    c2 = flat_qe_camera(tmp_path, gain=2.0)
    m1, m2 = prepare_camera(c1), prepare_camera(c2)
    assert m2.dn_per_e == pytest.approx(2 * m1.dn_per_e)
    assert m2.sat_e == pytest.approx(m1.sat_e / 2)
    s = uniform_scene(8, 8, m1.wavelengths)
    a = simulate_capture(m1, s, illuminant="E", lux=100, seed=0, noise=False)
    b = simulate_capture(m2, s, illuminant="E", lux=100, seed=0, noise=False)
    np.testing.assert_allclose(b.noise_free, 2 * a.noise_free, rtol=1e-5)


def test_auto_exposure_reaches_target_fraction() -> None:
    cam = load_camera(REPO / "sample_configs" / "bayer.toml")
    model = prepare_camera(cam)
    scene = make_scene("macbeth", 96, 128, model.wavelengths)
    cap = simulate_capture(model, scene, illuminant="D65", lux=1000.0, seed=0, noise=False)
    assert cap.exposure_s < cam.exposure.max_time_s
    assert float(cap.noise_free.max()) == pytest.approx(0.95, abs=2e-3)
    dark = simulate_capture(model, scene, illuminant="D65", lux=0.01, seed=0, noise=False)
    assert dark.exposure_s == cam.exposure.max_time_s  # capped


def _auto_camera(tmp_path: Path, **exposure):
    """flat_qe_camera in auto mode with extra [exposure] / [readout] keys."""
    import dataclasses

    cam = flat_qe_camera(tmp_path, mode="auto", dark=exposure.pop("dark", 0.0))
    clamp = exposure.pop("black_clamp", False)
    return dataclasses.replace(cam, exposure=dataclasses.replace(cam.exposure, **exposure),
                               readout=dataclasses.replace(cam.readout, black_clamp=clamp))


def test_auto_gain_beyond_the_time_cap(tmp_path: Path) -> None:
    """Auto ISO: where the time is capped, the gain brings the peak to the target;
    electrons stay those of the capped time; the target scales with time x gain."""
    cam = _auto_camera(tmp_path, max_time_s=0.01, max_analog_gain=16.0)
    model = prepare_camera(cam)
    s = uniform_scene(8, 8, model.wavelengths)
    bright = simulate_capture(model, s, illuminant="E", lux=1e5, seed=0, noise=False)
    assert bright.exposure_s < 0.01 and bright.analog_gain == 1.0
    # the level 1/4 of the one that reaches the target at 0.01 s: gain 4
    lux4 = 1e5 * bright.exposure_s / 0.01 / 4
    dim = simulate_capture(model, s, illuminant="E", lux=lux4, seed=0, noise=False)
    assert dim.exposure_s == 0.01
    assert dim.analog_gain == pytest.approx(4.0, rel=1e-6)
    np.testing.assert_allclose(dim.noise_free, bright.noise_free, rtol=1e-5)  # same response
    np.testing.assert_allclose(dim.target, bright.target, rtol=1e-5)  # target follows the gain
    # electrons: those of 0.01 s, so DN per electron is 4x the base one
    e_dim = (dim.dn.astype(np.float64).mean() - 64) / (4 * model.dn_per_e)
    assert e_dim == pytest.approx(model.sat_e * 0.95 / 4, rel=0.01)
    # darker still: the gain stops at its maximum and the raw is darker
    dark = simulate_capture(model, s, illuminant="E", lux=lux4 / 8, seed=0, noise=False)
    assert dark.analog_gain == 16.0
    assert float(dark.noise_free.max()) == pytest.approx(0.95 / 2, rel=1e-4)


def test_auto_gain_off_by_default(tmp_path: Path) -> None:
    model = prepare_camera(_auto_camera(tmp_path, max_time_s=0.01))
    s = uniform_scene(8, 8, model.wavelengths)
    cap = simulate_capture(model, s, illuminant="E", lux=1.0, seed=0, noise=False)
    assert cap.exposure_s == 0.01 and cap.analog_gain == 1.0


def test_black_clamp_removes_the_dark_current_mean(tmp_path: Path) -> None:
    """A dark frame averages the black level with the clamp, black + dark x t without."""
    for clamp in (False, True):
        cam = _auto_camera(tmp_path, max_time_s=0.5, dark=200.0, black_clamp=clamp)
        model = prepare_camera(cam)
        s = uniform_scene(64, 64, model.wavelengths, reflectance=0.0)
        cap = simulate_capture(model, s, illuminant="E", lux=1.0, seed=3, stem="d")
        mean_e = (cap.dn.astype(np.float64).mean() - 64) / model.dn_per_e
        want = 0.0 if clamp else 200.0 * 0.5
        assert mean_e == pytest.approx(want, abs=1.0)
        # the dark current's shot noise stays: sqrt(100 e-)
        assert (cap.dn.astype(np.float64) / model.dn_per_e).std() == pytest.approx(10.0, rel=0.1)


def test_seed_reproducible_and_order_independent() -> None:
    cam = load_camera(REPO / "sample_configs" / "bayer.toml")
    model = prepare_camera(cam)
    scene = make_scene("macbeth", 64, 96, model.wavelengths)
    a = simulate_capture(model, scene, illuminant="D65", lux=100, seed=11, stem="x")
    simulate_capture(model, scene, illuminant="D65", lux=10, seed=11, stem="y")
    b = simulate_capture(model, scene, illuminant="D65", lux=100, seed=11, stem="x")
    c = simulate_capture(model, scene, illuminant="D65", lux=100, seed=12, stem="x")
    np.testing.assert_array_equal(a.dn, b.dn)
    assert np.any(a.dn != c.dn)


# -------------------------------------------------------------- colorimetry

def test_macbeth_target_matches_colour_science() -> None:
    """Must show: ideal target XYZ per patch vs colour-science within ΔE*ab 0.5."""
    import colour

    from l3cli import spectral

    cam = load_camera(REPO / "sample_configs" / "bayer.toml")
    model = prepare_camera(cam)
    scene = make_scene("macbeth", 128, 192, model.wavelengths)
    # A perfect lens isolates the colorimetry: with the f/4 Airy PSF the patch means also
    # carry diffraction flare from their neighbours (physical, part of the target).
    cap = simulate_capture(model, scene, illuminant="D65", lux=500.0, seed=0, blur=False)
    ours = np.array(cap.chart["reference_xyz"])
    white = np.array(cap.extra["white_xyz"])
    lab_ours = colour.XYZ_to_Lab(ours / white[1], colour.XYZ_to_xy(white))

    refl = spectral._bundled("reflectance_macbeth.csv")
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    d65 = colour.SDS_ILLUMINANTS["D65"]
    white_cs = colour.sd_to_XYZ(colour.sd_ones(), cmfs, d65) / 100
    des = []
    wl5 = np.arange(380.0, 781.0, 5.0)  # ASTM E308 needs 1/5/10/20 nm; linear interpolation
    for i in range(24):
        sd = colour.SpectralDistribution(
            dict(zip(wl5, np.interp(wl5, refl.wavelengths, refl.values[:, i]), strict=True)))
        xyz = colour.sd_to_XYZ(sd, cmfs, d65) / 100
        lab = colour.XYZ_to_Lab(xyz, colour.XYZ_to_xy(white_cs))
        des.append(colour.delta_E(lab, lab_ours[i], method="CIE 1976"))
    des = np.array(des)
    print(f"Macbeth target vs colour-science: mean ΔE*ab {des.mean():.3f}, max {des.max():.3f}")
    assert des.max() < 0.5, f"max ΔE*ab {des.max():.3f} at patch {des.argmax()}"


def test_cos4_falloff(tmp_path: Path) -> None:
    data_cam = flat_qe_camera(tmp_path)
    import dataclasses

    cam = dataclasses.replace(data_cam, optics=dataclasses.replace(data_cam.optics, cos4=True,
                                                                     focal_length_mm=0.2))
    model = prepare_camera(cam)
    h, w = 40, 60
    cap = simulate_capture(model, uniform_scene(h, w, model.wavelengths), illuminant="E", lux=100,
                           seed=0, noise=False, blur=False)
    p = cam.pixel.pitch_um * 1e-3
    # Corner pixel centre vs the image centre.
    r = math.hypot((w - 1) / 2 * p, (h - 1) / 2 * p)
    theta = math.atan(r / 0.2)
    centre = cap.noise_free[h // 2 - 1:h // 2 + 1, w // 2 - 1:w // 2 + 1].mean()
    assert cap.noise_free[0, 0] / centre == pytest.approx(math.cos(theta) ** 4, rel=2e-3)


@pytest.mark.parametrize("rgb", [(0.6, 0.3, 0.2), (0.1, 0.5, 0.8), (0.18, 0.18, 0.18)])
def test_natural_upsampling_round_trips_srgb_under_d65(tmp_path: Path, rgb) -> None:
    """Mallett 2019 reflectances lit by D65 give back the linear sRGB they came from."""
    from l3cli.colourspace import convert
    from l3cli.simulate.scenes import rgb_to_reflectance_basis

    cam = flat_qe_camera(tmp_path, grid=(380, 780, 5))
    model = prepare_camera(cam)
    maps = np.ones((4, 8, 8), np.float32)
    maps[:3] *= np.array(rgb, np.float32)[:, None, None]
    scene = Scene("t", maps, rgb_to_reflectance_basis(model.wavelengths))
    cap = simulate_capture(model, scene, illuminant="D65", lux=100, seed=0, noise=False, blur=False)
    xyz = cap.target[4, 4] / cap.extra["white_xyz"][1]
    back = convert(xyz[None, None].astype(np.float32), "xyz", "linear-srgb")[0, 0]
    np.testing.assert_allclose(back, rgb, atol=3e-3)


def test_radiance_cube_scaled_to_18_percent_grey(tmp_path: Path) -> None:
    from l3cli.simulate.scenes import spectral_cube_scene

    cam = load_camera(REPO / "sample_configs" / "bayer.toml")
    model = prepare_camera(cam)
    wl = np.arange(380.0, 781.0, 10.0)
    cube = np.tile((wl / 500.0).astype(np.float32), (20, 30, 1))  # any spectrum
    np.savez(tmp_path / "rad.npz", wavelength=wl, radiance=cube)
    scene = spectral_cube_scene(tmp_path / "rad.npz", 20, 30, model.wavelengths)
    cap = simulate_capture(model, scene, illuminant="D65", lux=300.0, seed=0, noise=False,
                           exposure_s=0.01)
    # Mean luminance 0.18 * lux / π → sensor illuminance π L / (1 + 4N²) → Y = H_v / H_ref.
    h_v = 0.18 * 300.0 / (1 + 4 * cam.optics.f_number**2) * 0.01
    assert float(cap.target[..., 1].mean()) == pytest.approx(h_v / model.h_ref, rel=5e-3)


@pytest.mark.parametrize("n_f, pitch, oversample", [(8.0, 2.0, 4), (4.0, 1.4, 1), (2.8, 2.0, 2)])
def test_slanted_edge_with_l3_metrics_mtf(tmp_path: Path, n_f: float, pitch: float,
                                          oversample: int) -> None:
    """Cross-check with l3cli.metrics.mtf (the evaluator's ISO 12233 code): MTF50 within 3 %."""
    from l3cli.metrics.mtf import slanted_edge_mtf

    cam = flat_qe_camera(tmp_path, f_number=n_f, pitch=pitch, time_s=1e-4)
    model = prepare_camera(cam)
    wl = model.wavelengths
    scene = make_scene("slanted-edge", 160, 160, wl, oversample=oversample)
    cap = simulate_capture(model, scene, illuminant="E", lux=1000.0, seed=0, noise=False)
    res = slanted_edge_mtf(cap.noise_free, roi=tuple(scene.edge["roi"]), pixel_pitch_um=pitch)
    f = np.linspace(0.0, 1.0, 4001)
    weights = wl / wl.sum()
    expected = (weights[:, None] * airy_otf((f / (pitch * 1e-3))[None, :], wl[:, None], n_f)).sum(0)
    expected *= np.sinc(f)
    mtf50 = f[np.argmax(expected < 0.5)]
    assert res.mtf50_cy_per_px == pytest.approx(mtf50, rel=0.03)
    below = (res.frequencies > 0) & (res.frequencies <= 0.5)
    err = np.abs(res.mtf[below] - np.interp(res.frequencies[below], f, expected))
    assert err.max() < 0.03


def test_fused_and_streaming_optics_paths_agree(monkeypatch) -> None:
    import l3cli.simulate.core as core

    cam = load_camera(REPO / "sample_configs" / "bayer.toml")
    model = prepare_camera(cam)
    scene = make_scene("natural:coffee", 48, 64, model.wavelengths)
    w = core.spectral_weights(model, scene, "D65", 100.0)
    fused = core.render_planes(model, scene, w)
    monkeypatch.setattr(core, "_FUSED_MAX_MAPS", 0)
    streamed = core.render_planes(model, scene, w)
    np.testing.assert_allclose(fused, streamed, rtol=1e-4, atol=1e-6 * float(np.abs(fused).max()))


def test_capture_stems_are_distinct() -> None:
    from l3cli.simulate import capture_stem

    assert capture_stem("macbeth", "D65", 100) == "macbeth_D65_0100lux"
    assert capture_stem("macbeth", "D65", 12.5) != capture_stem("macbeth", "D65", 12.4)


def test_fill_factor_and_transmittance_scale_the_signal(tmp_path: Path) -> None:
    """Fill factor scales photo-electrons (not the target); lens transmittance scales both."""
    import dataclasses

    base = flat_qe_camera(tmp_path, time_s=0.01)
    half_fill = dataclasses.replace(base, pixel=dataclasses.replace(base.pixel, fill_factor=0.5))
    dim_lens = dataclasses.replace(base, optics=dataclasses.replace(base.optics, transmittance=0.25))
    caps = []
    for cam in (base, half_fill, dim_lens):
        model = prepare_camera(cam)
        caps.append(simulate_capture(model, uniform_scene(8, 8, model.wavelengths), illuminant="E",
                                     lux=100, seed=0, noise=False, blur=False, exposure_s=0.01))
    a, b, c = caps
    np.testing.assert_allclose(b.noise_free, 0.5 * a.noise_free, rtol=1e-5)
    np.testing.assert_allclose(c.noise_free, 0.25 * a.noise_free, rtol=1e-5)
    # The target is the optical image on the camera's fixed scale Y = H_v / H_ref: the lens
    # dims H_v; the fill factor leaves H_v alone but doubles H_ref (the exposure that
    # saturates the pixel), so raw and target keep their ratio.
    np.testing.assert_allclose(c.target, 0.25 * a.target, rtol=1e-5)
    assert prepare_camera(half_fill).h_ref == pytest.approx(2 * prepare_camera(base).h_ref,
                                                            rel=1e-9)
    np.testing.assert_allclose(b.target, 0.5 * a.target, rtol=1e-5)


def test_ir_cut_filter_multiplies_every_channel(tmp_path: Path) -> None:
    """QE with an IR-cut filter = QE x the filter's transmittance (read here from its CSV)."""
    import dataclasses

    from l3cli import spectral

    cam = load_camera(REPO / "sample_configs" / "bayer.toml")
    open_cam = dataclasses.replace(cam, cfa=dataclasses.replace(cam.cfa, ir_cut="none",
                                                                 ir_cut_source="none"))
    wl = np.arange(400.0, 1001.0, 10.0)
    text = [ln for ln in (spectral.DATA_DIR / "filter_ircf_public.csv").read_text().splitlines()
            if ln and not ln.startswith("#")][1:]
    rows = np.array([[float(v) for v in ln.split(",")] for ln in text])
    t = np.interp(wl, rows[:, 0], rows[:, 1])
    np.testing.assert_allclose(cam.qe_curves(wl), open_cam.qe_curves(wl) * t[:, None], rtol=1e-6)
    # and it does block the near infrared
    assert t[wl >= 750].max() < 0.05 and t[(wl >= 450) & (wl <= 600)].min() > 0.75
