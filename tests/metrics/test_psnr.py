"""PSNR: definition on known errors, data range from the encoding, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from l3cli.errors import InputError
from l3cli.metrics.psnr import data_range_for, psnr


def test_known_mse():
    a = np.zeros((10, 10, 3))
    b = a + 0.01  # MSE = 1e-4 -> 10 log10(1 / 1e-4) = 40 dB
    assert psnr(a, b, data_range=1.0) == pytest.approx(40.0)
    # an 8-bit view: error of 1 code in 255 -> 20 log10(255) = 48.13 dB
    c = a + 1 / 255
    assert psnr(a, c, data_range=data_range_for("srgb")) == pytest.approx(20 * math.log10(255))


def test_linear_range_is_the_white_level():
    a = np.full((4, 4), 50.0)
    assert psnr(a, a + 1.0, data_range=data_range_for("linear", white_level=100.0)) == pytest.approx(40.0)
    with pytest.raises(InputError, match="white level"):
        data_range_for("linear")


def test_identical_is_infinite():
    a = np.random.default_rng(0).random((5, 5, 3))
    assert psnr(a, a, data_range=1.0) == math.inf


def test_matches_scikit_image_definition_by_hand():
    rng = np.random.default_rng(2)
    a = rng.random((16, 16, 3))
    b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1)
    mse = ((a - b) ** 2).mean()
    assert psnr(a, b, data_range=1.0) == pytest.approx(10 * np.log10(1 / mse))


def test_unknown_encoding():
    with pytest.raises(InputError, match="unknown image encoding 'gamma22'; allowed: srgb, linear"):
        data_range_for("gamma22")


def test_different_sizes():
    with pytest.raises(InputError, match="8x4.*8x5|8x5.*8x4"):
        psnr(np.zeros((5, 8)), np.zeros((4, 8)), data_range=1.0)
