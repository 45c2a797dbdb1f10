"""The row-pair render (:func:`l3cli.render_rows.affine4`) against the one-row-at-a-time loop.

The render computes two patch rows' multiply-add chains side by side; each
lane must still see the same rounded operations as the plain loop below
(per patch row a chain of fused multiply-adds over its taps, starting from
the rounded product, and the rows' sums added to the constant in row order),
so the pixels are bit for bit equal, for every patch size and output count.
Tables of more than 4 outputs take the generic loop, checked the same way.
"""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest

from l3cli.classify import classify
from l3cli.render import render_mosaic
from l3cli.render_rows import pack_lanes, row_groups
from tests.test_table import make_table


@nb.njit(fastmath={"contract"})
def _plain_loop(padded, cls, k, row_sums):
    """out[y, x, q] = const + the taps: with ``row_sums`` one chain per patch row, the rows'
    sums added in order (the row-pair path); without, one chain over all taps in raster
    order (the generic loop of tables with more than 4 outputs)."""
    h, w = cls.shape
    nc, q, n_out = k.shape
    S = int(round((q - 1) ** 0.5))
    out = np.empty((h, w, n_out), np.float32)
    for y in range(h):
        for x in range(w):
            c = cls[y, x]
            for o in range(n_out):
                a = k[c, S * S, o]
                for dy in range(S):
                    r = np.float32(0.0) if row_sums else a
                    for dx in range(S):
                        r += padded[y + dy, x + dx] * k[c, dy * S + dx, o]
                    a = a + r if row_sums else r
                out[y, x, o] = a
    return out


def _check_against_plain_loop(t, m, *, row_sums):
    got = render_mosaic(t, m)
    yi, xi = t.definition.mirror_maps(*m.shape)
    want = _plain_loop(np.ascontiguousarray(m[np.ix_(yi, xi)]), classify(m, t.definition),
                       t.kernels.astype(np.float32), row_sums)
    assert got.shape == want.shape
    np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))


@pytest.mark.parametrize(("patch", "n_out"), [
    *((p, n) for p in (1, 3, 5, 7) for n in (1, 2, 3, 4)),
    pytest.param(9, 3, marks=pytest.mark.slow),  # the tuning's other patch: a kernel compile
])
def test_row_pair_render_is_bit_identical_to_the_one_row_loop(patch, n_out):
    t = make_table("RGGB", patch=patch, n_out=n_out, seed=patch + n_out)
    rng = np.random.default_rng(patch * 10 + n_out)
    # two tile rows, two tile columns; the second tile 21 pixels wide (the 4-pixel
    # groups of 3-output tables end with a single pixel)
    m = (rng.random((70, 533)) * 1.1).astype(np.float32)
    _check_against_plain_loop(t, m, row_sums=True)


@pytest.mark.parametrize("n_out", [5, 6])
def test_tables_of_more_than_4_outputs_render_every_output(n_out):
    """More than 4 outputs take the generic loop (kernels tap-major, n_out lanes)."""
    t = make_table("RGGB", patch=5, n_out=n_out, seed=n_out)
    rng = np.random.default_rng(n_out)
    m = (rng.random((40, 90)) * 1.1).astype(np.float32)
    _check_against_plain_loop(t, m, row_sums=False)


def test_pack_lanes_layout():
    """Row groups and the interleaved layout, entry by entry."""
    assert row_groups(5) == [(0, 2), (2, 2), (4, 1)]
    assert row_groups(1) == [(0, 1)]
    S = 3
    k = np.arange(2 * (S * S + 1) * 4, dtype=np.float32).reshape(2, S * S + 1, 4)
    p = pack_lanes(k)
    assert p.shape == (2, 4 * (S * S + 1))
    # group (0, 2): index 8 dx + 2 lane + row; group (2, 1) from 24: 4 dx + lane; constant at 36
    for c in range(2):
        for dx in range(S):
            for lane in range(4):
                for j in range(2):
                    assert p[c, 8 * dx + 2 * lane + j] == k[c, j * S + dx, lane]
                assert p[c, 24 + 4 * dx + lane] == k[c, 2 * S + dx, lane]
        np.testing.assert_array_equal(p[c, 36:], k[c, S * S])
    with pytest.raises(ValueError, match="not"):
        pack_lanes(np.zeros((2, 10, 3), np.float32))
