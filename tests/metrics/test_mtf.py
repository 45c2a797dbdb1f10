"""Slanted-edge MTF against the analytic MTF of a Gaussian-blurred edge.

An edge blurred by a Gaussian of standard deviation sigma (pixels) has the line
spread function exp(-d^2 / (2 sigma^2)) across the edge, whose Fourier transform
is MTF(f) = exp(-2 pi^2 sigma^2 f^2). Setting it to 1/2:
2 pi^2 sigma^2 f^2 = ln 2, so MTF50 = sqrt(ln 2 / 2) / (pi sigma) cycles/pixel.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ndtr

from l3cli.errors import InputError
from l3cli.metrics.mtf import mtf50, slanted_edge_mtf


def analytic_mtf50(sigma: float) -> float:
    return math.sqrt(math.log(2) / 2) / (math.pi * sigma)


def blurred_edge(h, w, angle_deg, sigma, *, noise=0.0, seed=0, horizontal=False, dark_right=False):
    """Point samples of a straight edge through the centre blurred by a Gaussian."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    t = math.radians(angle_deg)
    d = ((x - (w - 1) / 2) - math.tan(t) * (y - (h - 1) / 2)) * math.cos(t)
    step = ndtr(-d / sigma) if dark_right else ndtr(d / sigma)
    img = 0.1 + 0.7 * step
    if noise:
        img = img + np.random.default_rng(seed).normal(0.0, noise, img.shape)
    return img.T if horizontal else img


def test_analytic_value():
    # sigma = 1: sqrt(ln2/2)/pi = 0.58871/3.14159 = 0.18739 cy/px
    assert analytic_mtf50(1.0) == pytest.approx(0.18739, abs=1e-5)
    f = analytic_mtf50(1.7)
    assert math.exp(-2 * math.pi**2 * 1.7**2 * f**2) == pytest.approx(0.5)


@pytest.mark.parametrize("angle", [3.0, 5.0, 7.5, 10.0])
@pytest.mark.parametrize("sigma", [1.0, 1.5, 2.0])
@pytest.mark.parametrize("noise", [0.0, 0.005])
def test_mtf50_of_gaussian_blurred_edge(angle, sigma, noise):
    img = blurred_edge(120, 80, angle, sigma, noise=noise, seed=int(angle * 10 + sigma * 100))
    res = slanted_edge_mtf(img, pixel_pitch_um=2.0)
    expected = analytic_mtf50(sigma)
    assert res.mtf50_cy_per_px == pytest.approx(expected, rel=0.02)
    assert res.mtf50_cy_per_mm == pytest.approx(res.mtf50_cy_per_px / 2.0e-3)
    assert res.angle_deg == pytest.approx(angle, abs=0.2)
    assert res.mtf[0] == pytest.approx(1.0)


@pytest.mark.parametrize("horizontal", [False, True])
@pytest.mark.parametrize("dark_right", [False, True])
def test_orientation_and_polarity(horizontal, dark_right):
    img = blurred_edge(100, 90, 5.0, 1.2, horizontal=horizontal, dark_right=dark_right)
    res = slanted_edge_mtf(img)
    assert res.orientation == ("horizontal" if horizontal else "vertical")
    assert res.mtf50_cy_per_px == pytest.approx(analytic_mtf50(1.2), rel=0.02)


def test_rgb_uses_luminance_weights_and_roi():
    lum = blurred_edge(100, 80, 6.0, 1.0)
    rgb = np.repeat(lum[:, :, None], 3, axis=2)
    big = np.zeros((140, 130, 3))
    big[20:120, 30:110] = rgb
    res = slanted_edge_mtf(big, roi=(30, 20, 110, 120))
    assert res.mtf50_cy_per_px == pytest.approx(analytic_mtf50(1.0), rel=0.02)
    # the curve is returned up to 1 cycle/pixel
    assert res.frequencies[0] == 0 and res.frequencies[-1] <= 1.0
    assert res.frequencies.shape == res.mtf.shape


def test_flat_region_has_no_edge():
    with pytest.raises(InputError, match="no edge found"):
        slanted_edge_mtf(np.full((60, 60), 0.4))


def test_noise_only_region_has_no_edge():
    img = 0.4 + np.random.default_rng(0).normal(0, 0.02, (60, 60))
    with pytest.raises(InputError, match="no edge found"):
        slanted_edge_mtf(img)


def test_unslanted_edge_is_refused():
    img = blurred_edge(60, 60, 0.0, 1.0)
    with pytest.raises(InputError, match="no edge found.*degrees"):
        slanted_edge_mtf(img)


def test_roi_outside_image():
    with pytest.raises(InputError, match="not inside the 60x50 image"):
        slanted_edge_mtf(np.zeros((50, 60)), roi=(10, 10, 70, 40))


def test_mtf50_interpolates():
    f = np.array([0.0, 0.1, 0.2, 0.3])
    m = np.array([1.0, 0.8, 0.6, 0.4])
    assert mtf50(f, m) == pytest.approx(0.25)
    with pytest.raises(InputError, match="does not fall below 0.5"):
        mtf50(f, np.ones(4))
