"""The tap-lane render (:func:`l3cli.render_rows.affine_taps`) against a plain loop of its order.

The render vectorises over a patch row's taps; a pixel must still be a fixed
sequence of rounded operations (per output, per tap column a chain of fused
multiply-adds over the patch rows, starting from the first row's product;
the columns summed as a horizontal-add tree; the constant added last), so
the pixels are bit for bit those of the plain loop below, for every patch
size and output count. Tables of more than 4 outputs take the generic loop
(one chain over all taps in raster order), checked the same way.
"""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest

from l3cli.classify import classify
from l3cli.render import render_mosaic
from l3cli.render_rows import pack_taps, tap_lanes, tap_tail
from tests.builders import make_table


@nb.njit
def _tree(s):
    """The tap lanes' sum in the render's order: lanes j and 8 + j, then the 8-lane tree."""
    if s.size == 16:
        s = s[:8] + s[8:]
    return ((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]))


@nb.njit(fastmath={"contract"})
def _plain_loop(padded, cls, k, tap_lanes_, tail=False):
    """out[y, x, q]: with ``tap_lanes_`` (L) the tap-lane order (zero lanes past the
    patch; ``tail``: the last column apart, its rows 0..L-1 added lane by lane after
    the rows' chains, then its last tap to lane 0); with 0 one chain over all taps in
    raster order from the constant (the generic loop of tables with more than 4
    outputs)."""
    h, w = cls.shape
    nc, q, n_out = k.shape
    S = int(round((q - 1) ** 0.5))
    out = np.empty((h, w, n_out), np.float32)
    lanes = np.zeros(max(tap_lanes_, 1), np.float32)
    for y in range(h):
        for x in range(w):
            c = cls[y, x]
            for o in range(n_out):
                if tap_lanes_ == 0:
                    a = k[c, S * S, o]
                    for dy in range(S):
                        for dx in range(S):
                            a += padded[y + dy, x + dx] * k[c, dy * S + dx, o]
                    out[y, x, o] = a
                    continue
                lanes[:] = 0.0
                for dx in range(S - 1 if tail else S):
                    r = padded[y, x + dx] * k[c, dx, o]
                    for dy in range(1, S):
                        r += padded[y + dy, x + dx] * k[c, dy * S + dx, o]
                    lanes[dx] = r
                if tail:  # the last column: rows 0..L-1 lane by lane, then its last tap
                    e = S - 1
                    for j in range(tap_lanes_):
                        lanes[j] += padded[y + j, x + e] * k[c, j * S + e, o]
                    lanes[0] += padded[y + e, x + e] * k[c, e * S + e, o]
                    for j in range(1, tap_lanes_):  # the zero lanes of that vector
                        lanes[j] += np.float32(0.0) * np.float32(0.0)
                out[y, x, o] = _tree(lanes) + k[c, S * S, o]
    return out


def _check_against_plain_loop(t, m, *, tap_order):
    got = render_mosaic(t, m)
    yi, xi = t.definition.mirror_maps(*m.shape)
    S = t.definition.patch
    want = _plain_loop(np.ascontiguousarray(m[np.ix_(yi, xi)]), classify(m, t.definition),
                       t.kernels.astype(np.float32), tap_lanes(S) if tap_order else 0,
                       tap_order and tap_tail(S))
    assert got.shape == want.shape
    np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))


@pytest.mark.parametrize(("patch", "n_out"), [
    *((p, n) for p in (1, 3, 5, 7) for n in (1, 2, 3, 4)),
    (9, 3),  # the tuning's other patch, with its last column apart
    pytest.param(9, 4, marks=pytest.mark.slow),  # a kernel compile of its own
    pytest.param(11, 3, marks=pytest.mark.slow),  # 16 lanes: a kernel compile
])
def test_tap_lane_render_is_bit_identical_to_its_plain_loop(patch, n_out):
    t = make_table("RGGB", patch=patch, n_out=n_out, seed=patch + n_out)
    rng = np.random.default_rng(patch * 10 + n_out)
    # two tile rows, two tile columns, the second 21 pixels wide; values of both signs
    m = (rng.random((70, 533)) * 1.1 - 0.05).astype(np.float32)
    _check_against_plain_loop(t, m, tap_order=True)


@pytest.mark.parametrize("n_out", [5, 6])
def test_tables_of_more_than_4_outputs_render_every_output(n_out):
    """More than 4 outputs take the generic loop (kernels tap-major, n_out lanes)."""
    t = make_table("RGGB", patch=5, n_out=n_out, seed=n_out)
    rng = np.random.default_rng(n_out)
    m = (rng.random((40, 90)) * 1.1).astype(np.float32)
    _check_against_plain_loop(t, m, tap_order=False)


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
