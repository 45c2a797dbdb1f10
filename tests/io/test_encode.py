"""Display encoding (l3cli.io.encode): the same integers as colour-science + rounding."""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.colourspace import LINEAR_SRGB_TO_XYZ, XYZ_TO_LINEAR_SRGB
from l3cli.io import encode
from l3cli.io.encode import display_encode, quantise_reference, srgb_thresholds


def _colour_reference(img: np.ndarray, space: str, bits: int) -> np.ndarray:
    """What l3 wrote before: colour-science's conversion in float32 steps, then rounding."""
    import colour

    img = img.astype(np.float32)
    if space == "xyz":
        m = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB, dtype=np.float64)
        img = np.asarray(img @ m.T, dtype=np.float32)
    elif space == "lab":
        xy = colour.XYZ_to_xy(np.array([0.95047, 1.0, 1.08883]))
        xyz = np.asarray(colour.Lab_to_XYZ(img, illuminant=xy), dtype=np.float32)
        m = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB, dtype=np.float64)
        img = np.asarray(xyz @ m.T, dtype=np.float32)
    if space != "srgb":
        lin = np.clip(img, np.float32(0), np.float32(1))
        img = np.asarray(colour.cctf_encoding(lin, function="sRGB"), dtype=np.float32)
    maxv = (1 << bits) - 1
    return np.round(np.clip(img, 0.0, 1.0) * maxv).astype(np.uint16 if bits == 16 else np.uint8)


def test_srgb_matrices_are_colour_sciences():
    import colour

    cs = colour.RGB_COLOURSPACES["sRGB"]
    np.testing.assert_array_equal(XYZ_TO_LINEAR_SRGB, cs.matrix_XYZ_to_RGB)
    np.testing.assert_array_equal(LINEAR_SRGB_TO_XYZ, cs.matrix_RGB_to_XYZ)


@pytest.mark.parametrize("space", ["xyz", "linear-srgb", "srgb", "lab"])
@pytest.mark.parametrize("bits", [8, 16])
def test_display_encode_equals_colour_science_then_rounding(space, bits):
    rng = np.random.default_rng(bits)
    img = (rng.random((61, 83, 3)) * 1.3 - 0.15).astype(np.float32)  # out of range too
    img[0, :20, :] = rng.random((20, 3)).astype(np.float32) * 0.004  # linear toe of the curve
    if space == "lab":
        img = img * np.float32(100) - np.float32([0, 50, 50])
    got = display_encode(img, space, bits)
    assert got.dtype == (np.uint16 if bits == 16 else np.uint8)
    np.testing.assert_array_equal(got, _colour_reference(img, space, bits))


def test_other_channel_counts_and_data_are_clipped_and_quantised_only():
    img = np.linspace(-0.2, 1.2, 4 * 5 * 2, dtype=np.float32).reshape(4, 5, 2)
    for space in ("xyz", "data"):
        got = display_encode(img, space, 8)
        np.testing.assert_array_equal(got, np.round(np.clip(img, 0, 1) * 255).astype(np.uint8))
    nan = np.full((2, 2, 3), np.nan, np.float32)
    assert display_encode(nan, "linear-srgb", 8).max() == 0


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("encode_", [True, False])
def test_threshold_tables_are_exact(bits, encode_):
    """Every threshold is the first float32 of its code; random floats land on their code."""
    thr, _ = srgb_thresholds(bits, encode_)
    k = np.arange(1, 1 << bits)
    first = thr[1:-1]
    before = (first.view(np.int32) - 1).view(np.float32)
    np.testing.assert_array_equal(quantise_reference(first, bits, encode=encode_), k)
    np.testing.assert_array_equal(quantise_reference(before, bits, encode=encode_), k - 1)
    pats = np.random.default_rng(3).integers(0, encode._ONE_BITS + 1, 500_000).astype(np.int32)
    v = pats.view(np.float32)
    np.testing.assert_array_equal(np.searchsorted(thr, v, side="right") - 1,
                                  quantise_reference(v, bits, encode=encode_))


def test_reference_transfer_function_is_colour_sciences():
    import colour

    v = np.random.default_rng(5).random(200_000).astype(np.float32)
    np.testing.assert_array_equal(encode._srgb_oetf64(v), colour.cctf_encoding(v, function="sRGB"))
