"""Macbeth ΔE: an ideal chart scores ~0, a known CIELAB shift gives its ΔE, white
normalisation removes exposure, and chart corners map to patch centres."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from l3cli.errors import InputError
from l3cli.metrics.macbeth import (
    MACBETH_WHITE_INDEX,
    chart_patches_from_corners,
    homography,
    macbeth_delta_e,
    patch_means,
)


def ideal_chart_xyz(scale: float = 1.0) -> np.ndarray:
    """The 24 ColorChecker patches (colour-science data, D50 xyY) as XYZ."""
    cc = colour.CCS_COLOURCHECKERS["ColorChecker24 - After November 2014"]
    xyy = np.array(list(cc.data.values()))
    return colour.xyY_to_XYZ(xyy) * scale


def chart_image(xyz: np.ndarray, *, cell: int = 20, gap: int = 4, margin: int = 10):
    """An axis-aligned 4x6 chart with dark gaps; returns image and full-patch boxes."""
    h = margin * 2 + 4 * cell
    w = margin * 2 + 6 * cell
    img = np.full((h, w, 3), 0.02)
    boxes = []
    for i, v in enumerate(xyz):
        r, c = divmod(i, 6)
        x0 = margin + c * cell + gap // 2
        y0 = margin + r * cell + gap // 2
        x1, y1 = x0 + cell - gap, y0 + cell - gap
        img[y0:y1, x0:x1] = v
        boxes.append((x0, y0, x1, y1))
    return img, boxes


def test_ideal_chart_scores_near_zero():
    ideal = ideal_chart_xyz(50.0)
    img, boxes = chart_image(ideal)
    # a little blur over the patch borders, as a rendered target has
    from scipy.ndimage import gaussian_filter

    img = gaussian_filter(img, sigma=(0.7, 0.7, 0))
    measured = patch_means(img, boxes, fraction=0.5)
    res = macbeth_delta_e(measured, ideal)
    assert res.mean_ab < 0.5
    assert res.mean_2000 < 0.5


def test_known_chroma_shift_gives_expected_delta_e():
    ideal = ideal_chart_xyz(1.0)
    white = ideal[MACBETH_WHITE_INDEX]
    xy = colour.XYZ_to_xy(white)
    lab = colour.XYZ_to_Lab(ideal / white[1], xy)
    # shifting a* by 3 and b* by 4 leaves L* (so Y and the white scale) alone:
    # ΔE*ab = sqrt(3^2 + 4^2) = 5 on every patch.
    shifted = colour.Lab_to_XYZ(lab + [0.0, 3.0, 4.0], xy) * white[1]
    res = macbeth_delta_e(shifted * 7.0, ideal)  # exposure factor 7 is normalised away
    np.testing.assert_allclose(res.delta_e_ab, 5.0, rtol=1e-6)
    assert res.white_scale == pytest.approx(1 / 7.0)
    assert res.mean_ab == pytest.approx(5.0, rel=1e-6)
    de2000 = colour.delta_E(lab + [0.0, 3.0, 4.0], lab, method="CIE 2000")
    np.testing.assert_allclose(res.delta_e_2000, de2000, rtol=1e-6)


def test_exposure_alone_is_normalised_away():
    ideal = ideal_chart_xyz(1.0)
    res = macbeth_delta_e(ideal * 0.37, ideal)
    np.testing.assert_allclose(res.delta_e_ab, 0.0, atol=1e-9)


def test_without_white_normalisation_exposure_counts():
    ideal = ideal_chart_xyz(1.0)
    res = macbeth_delta_e(ideal * 0.5, ideal, normalise_white=False)
    assert res.mean_ab > 10


def test_corners_on_an_axis_aligned_chart():
    ideal = ideal_chart_xyz(40.0)
    img, boxes = chart_image(ideal, cell=20, gap=4, margin=10)
    corners = [10, 10, 130, 10, 130, 90, 10, 90]
    sample = chart_patches_from_corners(corners, image_shape=img.shape, fraction=0.5)
    assert len(sample) == 24
    np.testing.assert_allclose(patch_means(img, sample), ideal, rtol=1e-12)


def test_corners_under_perspective():
    ideal = ideal_chart_xyz(40.0)
    corners = np.array([[30.0, 20.0], [190.0, 35.0], [175.0, 140.0], [40.0, 120.0]])
    h_map = homography(corners, [[0, 0], [6, 0], [6, 4], [0, 4]])
    yy, xx = np.mgrid[0:160, 0:220]
    pts = np.c_[xx.ravel(), yy.ravel(), np.ones(xx.size)] @ h_map.T
    u, v = pts[:, 0] / pts[:, 2], pts[:, 1] / pts[:, 2]
    img = np.zeros((160 * 220, 3))
    inside = (u >= 0) & (u < 6) & (v >= 0) & (v < 4)
    idx = (np.floor(v[inside]) * 6 + np.floor(u[inside])).astype(int)
    img[inside] = ideal[idx]
    img = img.reshape(160, 220, 3)
    boxes = chart_patches_from_corners(corners.ravel(), image_shape=img.shape, fraction=0.5)
    np.testing.assert_allclose(patch_means(img, boxes), ideal, rtol=1e-12)


def test_corner_outside_image():
    with pytest.raises(InputError, match=r"bottom-right \(300, 90\) is outside the 200x100 image"):
        chart_patches_from_corners([10, 10, 150, 10, 300, 90, 10, 90], image_shape=(100, 200, 3))


def test_degenerate_corners():
    with pytest.raises(InputError, match="degenerate"):
        chart_patches_from_corners([10, 10, 20, 10, 30, 10, 40, 10], image_shape=(100, 200, 3))


def test_bad_shapes():
    with pytest.raises(InputError, match=r"\(24, 3\)"):
        macbeth_delta_e(np.ones((24, 3)), np.ones((23, 3)))
    with pytest.raises(InputError, match="outside the 10x10 image"):
        patch_means(np.zeros((10, 10, 3)), [(5, 5, 20, 20)])
