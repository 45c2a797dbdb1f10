"""The spline-grid lens-shading field (l3cli.lens.grid), its choice by held-out
blocks, spatial folds of a single image (l3cli.lens.fit), and its table keys."""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.cfa import CFA
from l3cli.errors import TableError
from l3cli.lens.field import corrected, gain_map, gains_at, normalised_coords
from l3cli.lens.fit import BlockSamples, fit_field, spatial_folds
from l3cli.lens.grid import SplineField, bspline_matrix, frame_extent
from l3cli.table import SHADING_VERSION, load_table, save_table
from tests.builders import make_table, mosaic_raw

SIZE = (600, 800)


def _lens(v, u):
    """A colour shading no radial polynomial about one centre fits: per channel
    (R, G, B) its own centre and an elliptical fall-off, R to about 0.5 in the far
    corner. Returns the correction (1 / relative illumination), (n, 3)."""
    out = []
    for (cy, cx), k, e in [((-0.10, -0.14), 0.36, 0.15), ((-0.05, -0.08), 0.22, 0.10),
                           ((0.02, -0.03), 0.28, -0.08)]:
        r2 = (1 + e) * (v - cy) ** 2 + (1 - e) * (u - cx) ** 2
        out.append((1 + k * r2) ** 2)
    return np.stack(out, axis=1)


def _samples(n_images=3, n=900, seed=0, shaded=True, noise=0.0):
    """Blocks of the model t = M_i (g m) with the lens above (or none), random
    matrices near the identity, uniform positions over a 600x800 frame."""
    rng = np.random.default_rng(seed)
    vh, uh = frame_extent(*SIZE)
    out = []
    for _ in range(n_images):
        v = rng.uniform(-vh, vh, n)
        u = rng.uniform(-uh, uh, n)
        m = rng.uniform(0.05, 0.6, (n, 3))
        g = _lens(v, u) if shaded else np.ones((n, 3))
        mat = np.eye(3) + rng.normal(0, 0.2, (3, 3))
        t = (m / g.max() * g) @ mat.T
        out.append(BlockSamples(v, u, m, t * (1 + rng.normal(0, noise, t.shape))))
    return out


def _red_brighter_to_the_top(s, rng):
    """60 % of the blocks (the mask returned) rendered with R up to 8 % brighter toward the
    top of the frame (a camera's non-linear step biasing them), and the targets."""
    biased = rng.random(s.v.size) < 0.6
    t = s.target.copy()
    t[biased, 0] *= 1.0 + 0.04 * (1.0 - s.v[biased] / np.abs(s.v).max())
    return biased, t


def _check_weighing(weighed, unweighed, cfa):
    """The field of the weighed blocks is within 0.5 % of the lens per colour; that of the
    same blocks without the weight is over 1 % off."""
    field, rec = fit_field(weighed, cfa, SIZE, orders=(2,))
    assert field is not None, rec
    assert max(_field_rms(field, cfa)) < 0.005, rec
    alike, rec = fit_field(unweighed, cfa, SIZE, orders=(2,))
    assert alike is not None and max(_field_rms(alike, cfa)) > 0.01, rec


def _field_rms(field, cfa):
    """Rms relative error per colour of a field against the lens (each colour's scale
    removed), on every 3rd pixel of the frame."""
    g = gain_map(field, SIZE, cfa.period)[::3, ::3].astype(np.float64)
    v, u = normalised_coords(*SIZE)
    vv, uu = np.meshgrid(v[::3], u[::3], indexing="ij")
    truth = _lens(vv.ravel(), uu.ravel()).reshape(*vv.shape, 3)
    chan = cfa.channel_map(*SIZE)[::3, ::3]
    out = []
    for c in range(3):
        q = g[chan == c] / truth[..., c][chan == c]
        out.append(float(np.sqrt(np.mean((q / q.mean() - 1) ** 2))))
    return out


def test_bspline_basis_is_a_partition_of_unity_and_reproduces_lines():
    """Uniform cubic B-splines sum to one and reproduce a straight line from control
    values at their centres (the Greville abscissae lo + (i - 1) h): textbook facts."""
    x = np.linspace(-0.6, 0.6, 101)
    b = bspline_matrix(x, -0.6, 0.6, 5)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, atol=1e-12)
    h = 1.2 / 5
    centres = -0.6 + (np.arange(8) - 1) * h
    np.testing.assert_allclose(b @ (2 * centres + 0.3), 2 * x + 0.3, atol=1e-12)


def test_spline_map_values_and_gains_at_agree():
    rng = np.random.default_rng(1)
    f = SplineField(1 + 0.3 * rng.random((4, 6, 7)), (24, 32))
    g = gain_map(f, (24, 32), (2, 2))
    ys, xs = rng.integers(0, 24, 50), rng.integers(0, 32, 50)
    np.testing.assert_allclose(gains_at(f, ys, xs, (24, 32), (2, 2)), g[ys, xs], rtol=1e-6)
    flat = SplineField(np.full((4, 6, 7), 1.25), (24, 32))  # constant controls: constant gain
    np.testing.assert_allclose(gain_map(flat, (24, 32), (2, 2)), 1.25, rtol=1e-7)


def test_spline_table_round_trip_and_errors(tmp_path):
    rng = np.random.default_rng(2)
    t = make_table()
    t.shading = SplineField(1 + 0.3 * rng.random((4, 5, 6)), (24, 32))
    p = save_table(tmp_path / "grid.npz", t)
    back = load_table(p)
    assert back.file_version == SHADING_VERSION and isinstance(back.shading, SplineField)
    np.testing.assert_array_equal(back.shading.grid, t.shading.grid)
    np.testing.assert_array_equal(gain_map(back.shading, (24, 32), (2, 2)),
                                  gain_map(t.shading, (24, 32), (2, 2)))
    from l3cli.inspect import format_summary, table_summary

    assert "spline grid of 2x3 intervals" in format_summary(table_summary(back))
    with np.load(p, allow_pickle=False) as z:
        arrs = {k: z[k] for k in z.files}
    for name, change, msg in [("neg", -np.ones((4, 5, 6)), "not positive"),
                              ("shape", np.ones((2, 5, 6)), "(4, ny, nx)"),
                              ("nan", np.full((4, 5, 6), np.nan), "NaN")]:
        q = tmp_path / f"{name}.npz"
        np.savez(q, **{**arrs, "shading_grid": change})
        with pytest.raises(TableError, match=msg):
            load_table(q)


def test_spline_correction_keeps_clipping():
    """As the radial field: gains >= 1 lift no pixel above white, clipped pixels stay 1."""
    t = make_table()
    t.shading = SplineField(np.full((4, 5, 6), 1.0) + np.linspace(0, 1, 6), (24, 32))
    m = np.random.default_rng(3).uniform(0, 1.2, (24, 32)).astype(np.float32)
    g = gain_map(t.shading, (24, 32), (2, 2))
    assert g.min() >= 1.0
    np.testing.assert_array_equal(corrected(t, mosaic_raw(m)).mosaic,
                                  np.minimum(m * g, np.maximum(m, 1)))


def test_fit_chooses_a_grid_for_colour_shading_about_different_centres():
    """Noise-free blocks of a lens whose colours fall off about different centres and
    elliptically: a radial field misses it by more than 1 % rms, the chosen spline grid
    is within 0.5 % of the truth per colour."""
    cfa = CFA.from_spec("GRBG")
    s = _samples()
    field, rec = fit_field(s, cfa, SIZE, orders=(2,))
    assert field is not None and isinstance(field, SplineField), rec
    assert max(_field_rms(field, cfa)) < 0.005, rec
    radial, _ = fit_field(s, cfa, SIZE, orders=(3,), intervals=())
    assert max(_field_rms(radial, cfa)) > 0.01
    # least gain one: scaled on a 129 x 129 lattice, so a pixel between its points may
    # lie a hair lower (the surface is smooth: 1e-4)
    assert gain_map(field, SIZE, cfa.period).min() >= 1 - 1e-4


def test_one_image_is_checked_on_spatial_folds():
    """A single image: the field is chosen and checked on spatial folds of its blocks
    (each of 3 x 3 tiles held out in turn); one shot of a shaded lens keeps a field that
    undoes most of the shading, one shot of an unshaded one keeps none."""
    cfa = CFA.from_spec("RGGB")
    one = _samples(n_images=1, n=2000, noise=0.002)
    folds = spatial_folds(one[0])
    assert len(folds) == 9 and np.all(sum(f.astype(int) for f in folds) == 1)
    box = np.ptp(one[0].v) * np.ptp(one[0].u)
    for f in folds:  # each fold is one contiguous ninth of the frame
        assert np.ptp(one[0].v[f]) * np.ptp(one[0].u[f]) < 0.15 * box
    field, rec = fit_field(one, cfa, SIZE, orders=(2,))
    assert field is not None and rec["folds"] == "spatial", rec
    # the lens varies by 45 % (R) over the frame; a radial field (one shot favours it)
    # leaves about 3 % of it, a spline grid less
    assert max(_field_rms(field, cfa)) < 0.05, rec
    flat, rec = fit_field(_samples(n_images=1, n=2000, shaded=False, noise=0.01), cfa, SIZE,
                          orders=(2,))
    assert flat is None and "no better" in rec["reason"], rec


def test_one_image_keeps_its_field_by_quadrants():
    """One image: the model is chosen on 3 x 3 tiles but kept only where it predicts whole
    held-out quadrants better than no field (on 3 x 3 tiles alone an unshaded shot kept a
    spurious field): the record's held-out scores are the quadrants' (recomputed here from
    the folds), and they differ from the 3 x 3 tiles' choice score."""
    from l3cli.lens.fit import CHECK_TILES, TILES, _fit_model, _gain_sse, heldout_folds

    cfa = CFA.from_spec("RGGB")
    one = _samples(n_images=1, n=2000, noise=0.002)
    field, rec = fit_field(one, cfa, SIZE, orders=(2,))
    assert field is not None and (TILES, CHECK_TILES) == (3, 2)
    kind, arg = rec["model"].split()
    model = (kind, int(arg))
    n_blocks = one[0].raw.shape[0]
    sse = {}
    for tiles in (CHECK_TILES, TILES):
        with_f = without = 0.0
        for train, test in heldout_folds(one, tiles):
            gains, _ = _fit_model(model, train, SIZE)
            with_f += sum(_gain_sse(t, gains(t)) for t in test)
            without += sum(_gain_sse(t, None) for t in test)
        sse[tiles] = (np.sqrt(with_f / (3 * n_blocks)), np.sqrt(without / (3 * n_blocks)))
    np.testing.assert_allclose((rec["heldout_rms"], rec["none_heldout_rms"]),
                               sse[CHECK_TILES], rtol=1e-9)
    np.testing.assert_allclose(rec["model_heldout_rms"][rec["model"]], sse[TILES][0],
                               rtol=1e-9)
    assert not np.isclose(sse[TILES][0], sse[CHECK_TILES][0])


@pytest.mark.slow
def test_standin_camera_one_shot_learns_its_lens(tmp_path):
    """One shot of the stand-in camera (scripts/standin/camera.py: colour shading about
    different centres, elliptical, red to 0.5 in the far corner; noise reduction,
    sharpening and a tone curve in the render): the field is checked on spatial folds
    and kept, and undoes most of the known shading (R varies by 45 % over the frame):
    within 8 % rms per colour (each colour's scale removed; a loose bound: with quadrant
    folds one shot kept the radial field, which cannot follow colours about different
    centres, 1.6 / 6.2 / 3.1 % G / R / B measured on this crop)."""
    import importlib.util

    from l3cli.io.raw import read_raw
    from l3cli.lens.train import learn_shading
    from l3cli.pairs import find_pairs
    from l3cli.train.options import TrainOptions
    from tests.builders import REPO as ROOT

    spec = importlib.util.spec_from_file_location("standin",
                                                  ROOT / "scripts" / "standin" / "camera.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    src = ROOT / "examples" / "infinite_isp" / "frames" / "Outdoor1_crop.tif"
    mod.main([str(tmp_path), str(src), "--crop", "512x704"])
    pairs = find_pairs([tmp_path / "shaded" / "frames"])
    opts = TrainOptions(target_space="linear-srgb", tone_curve=True, shading=True)
    field, rec = learn_shading(pairs, opts)
    assert field is not None and rec["folds"] == "spatial", rec
    cfa = read_raw(pairs[0].raw).cfa
    err = mod.field_error(gain_map(field, field.size, cfa.period), cfa)
    assert max(err.values()) < 0.08, (err, rec)


def test_textured_blocks_weigh_less():
    """Blocks on texture, where a camera's non-linear steps (noise reduction, sharpening on
    the encoded image) move a block's mean, bend the field where the scene puts them: here
    most blocks are textured, and their R renders up to 8 % brighter toward the top of the
    frame than the block model says (too smooth a bias for the robust weights to reject).
    Weighed by their render's local contrast (``texture``), the field stays within 0.5 % of
    the lens per colour; every block alike, it is over 1 % off."""
    from l3cli.lens.grid import TEXTURE_SCALE

    cfa = CFA.from_spec("GRBG")
    rng = np.random.default_rng(3)
    biased, plain = [], []
    for s in _samples(noise=0.001, seed=5):
        textured, t = _red_brighter_to_the_top(s, rng)
        texture = np.where(textured, 20 * TEXTURE_SCALE, 0.1 * TEXTURE_SCALE)
        biased.append(BlockSamples(s.v, s.u, s.raw, t, texture))
        plain.append(BlockSamples(s.v, s.u, s.raw, t))
    _check_weighing(biased, plain, cfa)


def test_block_texture_is_the_renders_local_contrast():
    """``block_samples`` gives a flat render's blocks no texture and a fine checkerboard's
    (contrast 1:3) its local contrast; the block means are those of the pixels."""
    from l3cli.lens.fit import block_samples

    cfa = CFA.from_spec("RGGB")
    h, w = 64, 96
    mosaic = np.full((h, w), 0.3)
    flat = np.full((h, w, 3), 0.2)
    s = block_samples(mosaic, cfa, flat, None, full_shape=(h, w))
    assert s.texture is not None and np.allclose(s.texture, 0.0, atol=1e-6)
    assert np.allclose(s.target, 0.2) and np.allclose(s.raw, 0.3)
    checker = np.where((np.indices((h, w)).sum(axis=0) % 2)[..., None] == 0, 0.1, 0.3)
    checker = np.broadcast_to(checker, (h, w, 3))
    s = block_samples(mosaic, cfa, checker, None, full_shape=(h, w))
    # 3 x 3 windows hold 5 of one value and 4 of the other: sd 0.0994, mean 0.189 or 0.211
    assert np.all((s.texture > 0.40) & (s.texture < 0.50)), s.texture


def test_blocks_in_varied_neighbourhoods_weigh_less():
    """A camera's noise reduction on the encoded image mixes a block's colour with its
    neighbours' (non-linearly), more where they differ: blocks in colourful neighbourhoods
    (``context``) render biased, here R up to 8 % brighter toward the top of the frame on
    60 % of the blocks, whose render is locally flat (no ``texture``). Weighed by their
    neighbourhood's colour variation, the field stays within 0.5 % of the lens per colour;
    by texture alone, it is over 1 % off."""
    from l3cli.lens.grid import CONTEXT_SCALE, TEXTURE_SCALE

    cfa = CFA.from_spec("GRBG")
    rng = np.random.default_rng(4)
    weighed, texture_only = [], []
    for s in _samples(noise=0.001, seed=6):
        varied, t = _red_brighter_to_the_top(s, rng)
        context = np.where(varied, 20 * CONTEXT_SCALE, 0.1 * CONTEXT_SCALE)
        flat = np.full(s.v.size, 0.1 * TEXTURE_SCALE)
        weighed.append(BlockSamples(s.v, s.u, s.raw, t, flat, context))
        texture_only.append(BlockSamples(s.v, s.u, s.raw, t, flat))
    _check_weighing(weighed, texture_only, cfa)


def test_block_context_is_the_neighbourhoods_colour_variation():
    """``block_samples``' ``context``: none on a flat render; a colour edge 8 pixels beside a
    block, outside its 3 x 3 contrast windows (no ``texture``), is in its 33-pixel
    neighbourhood (per channel sd over mean + 0.02, the largest channel)."""
    from l3cli.lens.fit import CONTEXT, block_samples

    cfa = CFA.from_spec("RGGB")
    h, w = 64, 96
    mosaic = np.full((h, w), 0.3)
    flat = np.full((h, w, 3), 0.2)
    s = block_samples(mosaic, cfa, flat, None, full_shape=(h, w))
    assert s.context is not None and np.allclose(s.context, 0.0, atol=1e-6)
    edge = flat.copy()
    edge[:, 56:, 0] = 0.6  # red from column 56: blocks of columns 32-47 and 48-63 are near
    s = block_samples(mosaic, cfa, edge, None, full_shape=(h, w))
    cols = np.round((s.u - s.u.min()) / np.ptp(s.u) * 5).astype(int)  # block column 0..5
    near = cols == 2  # columns 32-47: the edge is 8-23 px away, inside CONTEXT // 2
    assert CONTEXT // 2 >= 16
    assert np.all(s.texture[near] < 1e-6) and np.all(s.context[near] > 0.2), s.context
    assert np.all(s.context[cols == 0] < 1e-6)  # columns 0-15: 40 px away
