"""Render: equals a plain numpy reference, full size, fits checks, bounded bands."""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.cfa import CFA
from l3cli.errors import TableError
from l3cli.io.raw import RawImage
from l3cli.render import check_fits, render_mosaic, render_raw
from tests.builders import make_table
from tests.l3ref import render_reference


def _raw(mosaic, spec):
    cfa = CFA.from_spec(spec)
    return RawImage(mosaic=mosaic, cfa=cfa, black_level=np.zeros(cfa.n_positions),
                    white_level=1.0)


#: Each (patch, CFA period width) is a kernel compile of its own (10-20 s on a fresh
#: machine): the 4-wide CFA at patch 5, the width 2 at both sizes.
@pytest.mark.parametrize(("spec", "patch"), [("RGGB", 3), ("RGGB", 5),
                                             ("RGBW/GWRB/BRWG/WBGR", 5)])
def test_render_equals_numpy_reference(spec, patch):
    table = make_table(spec=spec, patch=patch)
    rng = np.random.default_rng(0)
    m = (rng.random((23, 30)) ** 2).astype(np.float32)
    m[4, 7] = 1.0  # a saturated pixel
    out = render_mosaic(table, m)
    assert out.shape == (23, 30, 3) and out.dtype == np.float32
    np.testing.assert_allclose(out, render_reference(table, m), rtol=1e-5, atol=1e-5)


def test_render_bands_and_tiles_do_not_change_the_result():
    table = make_table()
    m = np.random.default_rng(1).random((75, 1100)).astype(np.float32)  # several tiles
    full = render_mosaic(table, m)
    parts = np.concatenate([render_mosaic(table, m, rows=(y, min(75, y + 7)))
                            for y in range(0, 75, 7)])
    np.testing.assert_array_equal(parts, full)
    # pixels inside a crop (offset by whole CFA periods) render as in the full mosaic
    crop = render_mosaic(table, m[10:50, 520:1000])
    np.testing.assert_array_equal(crop[2:-2, 2:-2], full[12:48, 522:998])


def test_identity_kernel_returns_the_mosaic_at_every_pixel():
    table = make_table(n_out=1)
    table.kernels[:] = 0
    table.kernels[:, 12, 0] = 1.0  # centre of the 5x5 patch
    m = np.random.default_rng(2).random((17, 19)).astype(np.float32)
    np.testing.assert_array_equal(render_mosaic(table, m)[:, :, 0], m)


def test_table_for_another_cfa_or_too_small_raw():
    table = make_table("RGGB", patch=5)
    with pytest.raises(TableError, match="table is for CFA RG/GB but .* has CFA GR/BG"):
        render_raw(table, _raw(np.zeros((16, 16), np.float32), "GRBG"))
    with pytest.raises(TableError, match="uses 5x5 patches but .* is only 4x4"):
        check_fits(table, _raw(np.zeros((4, 4), np.float32), "RGGB"))
