"""The bundled spectral data are the ISETCam data they claim to be (read here
independently from ISETCam's .mat files in ../shared/data), and the analytic
illuminants agree with colour-science."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from l3cli import spectral

ISETCAM = "spectral/isetcam/data"


def mat(shared: Path, rel: str) -> tuple[np.ndarray, np.ndarray]:
    import scipy.io as sio

    path = shared / ISETCAM / rel
    if not path.exists():
        pytest.skip(f"{path} is absent")
    m = sio.loadmat(path, squeeze_me=True)
    data = np.asarray(m["data"], dtype=np.float64)
    return np.atleast_1d(m["wavelength"]).astype(np.float64), data.reshape(data.shape[0], -1)


def on(wl_src: np.ndarray, data: np.ndarray, wl: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(wl, wl_src, data[:, k]) for k in range(data.shape[1])], axis=1)


@pytest.mark.parametrize("preset, rel, columns", [
    ("bayer-rgb", "sensor/colorfilters/RGB.mat", "RGB"),
    ("interleaved-rgbw", "sensor/colorfilters/interleavedRGBW.mat", "RGBW"),
    ("nikon-d200-ir", "sensor/colorfilters/nikon/NikonD200IR.mat", "RGB"),
    ("mt9v024-rgb", "sensor/colorfilters/auto/MT9V024_RGB.mat", "RGB"),
    ("mt9v024-rgbw", "sensor/colorfilters/auto/MT9V024_RGBW.mat", "RGBW"),
])
def test_qe_presets_match_isetcam(shared_data, preset, rel, columns):
    wl_src, data = mat(shared_data, rel)
    qe = spectral.load_qe(preset)
    assert qe.names == tuple(columns)
    assert qe.wavelengths[0] >= wl_src[0] and qe.wavelengths[-1] <= wl_src[-1]
    np.testing.assert_allclose(qe.values, on(wl_src, data, qe.wavelengths), rtol=1e-5, atol=1e-7)


def test_rgb_nir_preset_is_isetcam_filters_times_silicon(shared_data):
    wl_f, filt = mat(shared_data, "sensor/cfa/cfaRGBNearIR.mat")
    wl_si, rgbw = mat(shared_data, "sensor/colorfilters/interleavedRGBW.mat")
    qe = spectral.load_qe("rgb-nir")
    assert qe.names == ("R", "G", "B", "NIR")
    wl = qe.wavelengths
    silicon = np.interp(wl, wl_si, rgbw[:, 3])
    np.testing.assert_allclose(qe.values[:, :3], on(wl_f, filt[:, :3], wl) * silicon[:, None],
                               rtol=1e-5, atol=1e-7)
    # the NIR pixel: dark in the visible, silicon-limited in the NIR
    assert qe.values[wl < 650, 3].max() < 0.05 * qe.values[:, 3].max()
    assert np.all(qe.values[wl > 850, 3] <= silicon[wl > 850] + 1e-6)


@pytest.mark.parametrize("name, rel", [("ircf-public", "sensor/ircf_public.mat"),
                                       ("schott", "sensor/irfilters/irFilter_schott.mat")])
def test_ir_filters_match_isetcam(shared_data, name, rel):
    wl_src, data = mat(shared_data, rel)
    f = spectral.load_ir_filter(name)
    np.testing.assert_allclose(f.values[:, :1], on(wl_src, data[:, :1], f.wavelengths),
                               rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("tag", ["A", "CWF", "DAY", "U30"])
def test_visible_ir_illuminants_match_isetcam(shared_data, tag):
    wl_src, data = mat(shared_data, f"lights/visible_ir/ill_{tag}.mat")
    wl = np.arange(380.0, 1061.0, 10.0)
    np.testing.assert_allclose(spectral.load_illuminant(f"visir-{tag}", wl),
                               np.interp(wl, wl_src, data[:, 0]), rtol=1e-5)


def test_macbeth_reflectances_match_isetcam_in_reading_order(shared_data):
    wl_src, data = mat(shared_data, "surfaces/reflectances/macbethChart.mat")
    wl = np.arange(380.0, 1061.0, 10.0)
    ours = spectral.macbeth_reflectances(wl)
    # ISETCam stores the 4x6 chart column by column; l3 uses reading order.
    theirs = on(wl_src, data, wl)
    for i in range(24):
        row, col = divmod(i, 6)
        np.testing.assert_allclose(ours[:, i], theirs[:, col * 4 + row], rtol=1e-5, atol=1e-7)
    vis = (wl >= 400) & (wl <= 700)
    means = ours[vis].mean(axis=0)
    assert means.argmax() == 18 and means.argmin() == 23  # white, black
    assert list(np.argsort(means[18:24])) == [5, 4, 3, 2, 1, 0]  # the grey ramp


def test_cie_a_matches_colour_science():
    import colour

    wl = np.arange(380.0, 781.0, 5.0)
    ours = spectral.load_illuminant("A", wl)
    ref = colour.SDS_ILLUMINANTS["A"].copy().align(colour.SpectralShape(380, 780, 5)).values
    np.testing.assert_allclose(ours / ours[wl == 560], ref / ref[wl == 560], rtol=1e-3)
