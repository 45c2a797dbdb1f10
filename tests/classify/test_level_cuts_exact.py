"""Levels exactly on a cut point, through the real tile kernel (issue 30).

A level equal to a cut belongs to the bin above it (``cut <= level``, as
``searchsorted(cuts, level, side="right")``). The reference in ``l3ref`` is
float64 and its features differ from the kernel's float32 ones in the last
ulps, so the comparison with it skips pixels near a cut: these tests put the
levels exactly on the cuts instead, with expected classes written out.
"""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.classify import ClassDefinition, classify, patch_features

# Cuts that are powers of two: a flat mosaic of such a value has exactly that
# level in float32 (channel sums and the mean of channel means are exact).
CUTS = [0.0625, 0.25, 0.5]


def _definition(**kw):
    return ClassDefinition.build("RGGB", patch=5, level_cuts=CUTS, contrast_cuts=0.5,
                                 merge_positions=False, **kw)


def test_flat_levels_are_exact_powers_of_two():
    for v in (0.0625, 0.25, 0.5):
        lev, con, sat = patch_features(np.full((12, 12), v, np.float32), "RGGB", patch=5)
        assert np.all(lev == np.float32(v))
        assert np.all(con == 0) and not sat.any()


@pytest.mark.parametrize(
    ("value", "expected"),
    [
        # RGGB, 4 positions x 8 saturation patterns x 4 levels x 2 contrast bins:
        # class = ((position * 8 + 0) * 4 + level) * 2 + 0; positions of the 2x2
        # block at (6, 6) are 0 1 / 2 3.
        (0.0625, [[2, 66], [130, 194]]),   # on the first cut: level 1
        (0.25, [[4, 68], [132, 196]]),     # on the second: level 2
        (0.5, [[6, 70], [134, 198]]),      # on the third: level 3
        (float(np.nextafter(np.float32(0.25), np.float32(0))), [[2, 66], [130, 194]]),  # just below: 1
        (float(np.nextafter(np.float32(0.25), np.float32(1))), [[4, 68], [132, 196]]),  # just above: 2
        (0.03125, [[0, 64], [128, 192]]),  # below every cut: level 0
    ],
)
def test_level_on_a_cut_goes_to_the_bin_above(value, expected):
    d = _definition()
    assert d.shape == (4, 8, 4, 2)
    cls = classify(np.full((12, 12), value, np.float32), d)
    np.testing.assert_array_equal(cls[6:8, 6:8], expected)
    # the pattern repeats with the CFA over the whole mosaic, borders included
    np.testing.assert_array_equal(cls, np.tile(np.array(expected), (6, 6)))


def test_every_cut_hit_exactly_with_many_cuts():
    # 23 cuts (the default 24 levels) taken from the kernel's own float32 levels
    # of a textured mosaic, so that those pixels sit exactly on a cut; the
    # lookup then has buckets holding two cuts. Each such pixel is in the bin
    # above its cut; every pixel is in searchsorted(..., side="right")'s bin.
    rng = np.random.default_rng(30)
    m = (rng.random((40, 48)) ** 2 * 0.9 + 0.01).astype(np.float32)
    lev, _, _ = patch_features(m, "RGGB", patch=5)
    flat = np.unique(lev.ravel())
    cuts32 = flat[np.linspace(5, flat.size - 6, 23).astype(int)]
    d = ClassDefinition.build("RGGB", patch=5, level_cuts=cuts32.astype(np.float64),
                              contrast_cuts=0.5, merge_positions=False)
    level_bin = d.class_tuple(classify(m, d))[2]
    np.testing.assert_array_equal(level_bin, np.searchsorted(cuts32, lev, side="right"))
    for k, c in enumerate(cuts32):
        on = lev == c
        assert on.any()
        assert np.all(level_bin[on] == k + 1)


def test_contrast_on_a_cut_goes_to_the_bin_above():
    # the same rule for the contrast thresholds (``contrast >= cut``): cuts taken
    # from the kernel's own float32 contrasts, so those pixels sit exactly on one
    rng = np.random.default_rng(31)
    m = (rng.random((30, 36)) * 0.5 + 0.2).astype(np.float32)
    lev, con, _ = patch_features(m, "RGGB", patch=5)
    c0 = np.float32(np.median(con))
    c0 = con.ravel()[np.argmin(np.abs(con.ravel() - c0))]  # a contrast that occurs
    d = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.01, 0.9], contrast_cuts=float(c0),
                              merge_positions=False)
    assert np.all((lev > 0.01) & (lev < 0.9))  # one level bin: the middle one
    group, sat, level, contrast = d.class_tuple(classify(m, d))
    assert np.all(level == 1) and not sat.any()
    on = con == c0
    assert on.any()
    assert np.all(contrast[on] == 1)
    np.testing.assert_array_equal(contrast, (con >= c0).astype(contrast.dtype))


def test_cut_points_written_out():
    from l3cli.classify import level_cuts_between

    # n_levels - 1 cuts; one cut: the geometric mean for log spacing, the midpoint for linear
    np.testing.assert_allclose(level_cuts_between(0.01, 0.04, 2), [0.02], rtol=1e-15)
    np.testing.assert_allclose(level_cuts_between(0.01, 0.04, 2, "linear"), [0.025], rtol=1e-15)
    np.testing.assert_allclose(level_cuts_between(0.001, 1.0, 5), [0.001, 0.01, 0.1, 1.0], rtol=1e-12)
    np.testing.assert_allclose(level_cuts_between(0.1, 0.4, 5, "linear"), [0.1, 0.2, 0.3, 0.4], rtol=1e-12)
