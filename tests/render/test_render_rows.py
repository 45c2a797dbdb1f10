"""The tap-lane render (:func:`l3cli.render_rows.affine_taps`) against exact arithmetic.

The render vectorises over a patch row's taps (tap lanes, a horizontal-add
tree, the 9th column of patch 9 apart, 16 lanes past patch 9); tables of more
than 4 outputs take the generic loop. Whatever the order and the fused
multiply-adds the machine chose, a pixel is a float32 sum of ``S*S`` products
plus the constant, so it lies within the standard bound of such a sum of the
exact value (computed here in float64 from the same float32 inputs):
``|got - exact| <= (n + 2) u sum |terms|``, ``u = 2**-24`` (Higham, *Accuracy and
Stability of Numerical Algorithms*, 2nd ed., §4.2). A tap packed against the
wrong coefficient is off by the size of a term, far outside it (checked).
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from l3cli.classify import classify
from l3cli.render import render_mosaic
from l3cli.render_rows import pack_taps, tap_lanes, tap_tail
from tests.builders import make_table

_U = 2.0 ** -24


def _exact(m, cls, k, yi, xi, S):
    """float64 sums of each pixel's products and constant, and the error bound of a
    float32 evaluation of them in any order: (H, W, n_out) each."""
    h, w = cls.shape
    padded = m[np.ix_(yi, xi)].astype(np.float64)
    win = sliding_window_view(padded, (S, S))[:h, :w].reshape(h, w, S * S)
    exact = np.empty((h, w, k.shape[2]))
    bound = np.empty_like(exact)
    for o in range(k.shape[2]):
        ko = k[:, :, o].astype(np.float64)[cls]  # (h, w, S*S + 1)
        terms = win * ko[..., :S * S]
        exact[..., o] = terms.sum(-1) + ko[..., S * S]
        bound[..., o] = (S * S + 2) * _U * (np.abs(terms).sum(-1) + np.abs(ko[..., S * S]))
    return exact, bound


def _check_against_exact(t, m):
    got = render_mosaic(t, m)
    d = t.definition
    S = d.patch
    yi, xi = d.mirror_maps(*m.shape)
    cls = classify(m, d)
    k = t.kernels.astype(np.float32)
    exact, bound = _exact(m, cls, k, yi, xi, S)
    assert got.shape == exact.shape and got.dtype == np.float32
    err = np.abs(got - exact)
    assert np.all(err <= bound), f"worst {float((err / bound).max()):.2f}x the bound"
    if S > 1:  # the bound catches a tap read against another tap's coefficient
        swapped = k.copy()
        swapped[:, :S * S] = k[:, :S * S].reshape(-1, S, S, k.shape[2]).transpose(
            0, 2, 1, 3).reshape(-1, S * S, k.shape[2])
        wrong, _ = _exact(m, cls, swapped, yi, xi, S)
        assert np.any(np.abs(got - wrong) > bound)


@pytest.mark.parametrize(("patch", "n_out"), [
    *((p, n) for p in (1, 3, 5, 7) for n in (1, 2, 3, 4)),
    (9, 3),  # the tuning's other patch, with its last column apart
    pytest.param(9, 4, marks=pytest.mark.slow),  # a kernel compile of its own
    pytest.param(11, 3, marks=pytest.mark.slow),  # 16 lanes: a kernel compile
])
def test_tap_lane_render_is_its_sum_within_float32_rounding(patch, n_out):
    t = make_table("RGGB", patch=patch, n_out=n_out, seed=patch + n_out)
    rng = np.random.default_rng(patch * 10 + n_out)
    # two tile rows, two tile columns, the second 21 pixels wide; values of both signs
    m = (rng.random((70, 533)) * 1.1 - 0.05).astype(np.float32)
    _check_against_exact(t, m)


@pytest.mark.parametrize("n_out", [5, 6])
def test_tables_of_more_than_4_outputs_render_every_output(n_out):
    """More than 4 outputs take the generic loop (kernels tap-major, n_out lanes)."""
    t = make_table("RGGB", patch=5, n_out=n_out, seed=n_out)
    rng = np.random.default_rng(n_out)
    m = (rng.random((40, 90)) * 1.1).astype(np.float32)
    _check_against_exact(t, m)


def test_pack_taps_layout():
    """Per patch row, per output, the row's taps then zero lanes; the constants last."""
    assert [tap_lanes(s) for s in (1, 3, 5, 7, 9, 11, 15)] == [8, 8, 8, 8, 8, 16, 16]
    assert [s for s in range(1, 20, 2) if tap_tail(s)] == [9]
    for S, outputs in ((3, 4), (11, 4), (7, 3)):
        L = tap_lanes(S)
        k = np.arange(2 * (S * S + 1) * 4, dtype=np.float32).reshape(2, S * S + 1, 4) + 1
        p = pack_taps(k, outputs)
        assert p.shape == (2, outputs * S * L + 4)
        for c in range(2):
            for dy in range(S):
                for o in range(outputs):
                    row = p[c, (dy * outputs + o) * L:(dy * outputs + o + 1) * L]
                    np.testing.assert_array_equal(row[:S], k[c, dy * S:(dy + 1) * S, o])
                    assert not row[S:].any()
            np.testing.assert_array_equal(p[c, outputs * S * L:], k[c, S * S])
    # patch 9: columns 0-7 per row, then the 9th column's rows 0-7, then its row 8 tap
    S, L = 9, 8
    for outputs in (3, 4):
        k = np.arange(2 * (S * S + 1) * 4, dtype=np.float32).reshape(2, S * S + 1, 4) + 1
        p = pack_taps(k, outputs)
        assert p.shape == (2, outputs * (S + 2) * L + 4)
        for c in range(2):
            for o in range(outputs):
                for dy in range(S):
                    row = p[c, (dy * outputs + o) * L:(dy * outputs + o + 1) * L]
                    np.testing.assert_array_equal(row, k[c, dy * S:dy * S + 8, o])
                col = p[c, (S * outputs + o) * L:(S * outputs + o + 1) * L]
                np.testing.assert_array_equal(col, k[c, [j * S + 8 for j in range(8)], o])
                corner = p[c, ((S + 1) * outputs + o) * L:((S + 1) * outputs + o + 1) * L]
                assert corner[0] == k[c, 8 * S + 8, o] and not corner[1:].any()
            np.testing.assert_array_equal(p[c, outputs * (S + 2) * L:], k[c, S * S])
    with pytest.raises(ValueError, match="not"):
        pack_taps(np.zeros((2, 10, 3), np.float32))
    with pytest.raises(ValueError, match="not 3 or 4"):
        pack_taps(np.zeros((2, 10, 4), np.float32), 2)
