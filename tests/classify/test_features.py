"""Orientation and context class features (issue 14, parts 3 and 4)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from l3cli.cfa import CFA
from l3cli.classify import ClassDefinition, classify, patch_features
from l3cli.classify.features import context_map, orientation_permutation
from l3cli.errors import ConfigError
from l3cli.smooth.symmetry import D4_ELEMENTS, symmetrize_kernels, symmetry_map
from l3cli.table import TransformTable, load_table, save_table

N_BINS = 4


def _edge(h: int, w: int, angle_deg: float) -> np.ndarray:
    """A soft straight edge whose intensity gradient points at ``angle_deg``
    (0 = along +x, the columns; 90 = along +y, the rows)."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    y -= (h - 1) / 2
    x -= (w - 1) / 2
    a = np.deg2rad(angle_deg)
    t = x * np.cos(a) + y * np.sin(a)
    return (0.1 + 0.3 / (1 + np.exp(-t / 1.5))).astype(np.float32)


def _definition(spec: str, **kw) -> ClassDefinition:
    return ClassDefinition.build(spec, patch=7, level_cuts=[0.01, 0.1], contrast_cuts=0.05,
                                 orientation_bins=N_BINS, coherence_threshold=0.5, **kw)


def _orientation(d: ClassDefinition, cls: np.ndarray) -> np.ndarray:
    return np.asarray(d.texture_tuple(np.asarray(d.class_tuple(cls)[3]))[1])


def _rotated_spec(spec: str, op) -> str:
    pat = np.array(list(spec)).reshape(2, 2)
    return "".join(op(pat).ravel())


@pytest.mark.parametrize("angle, expected", [(0, 1), (90, 3), (45, 2), (135, 4), (180, 1)])
def test_edge_angle_lands_in_its_bin(angle, expected):
    # bins 1..4 are gradient angles 0, 45, 90, 135 degrees (bin 0 = isotropic)
    d = _definition("RGGB")
    m = _edge(32, 32, angle)
    cls = classify(m, d)
    assert _orientation(d, cls[16, 16]) == expected


def test_flat_patch_is_isotropic():
    d = _definition("RGGB")
    cls = classify(np.full((16, 16), 0.2, np.float32), d)
    assert np.all(_orientation(d, cls) == 0)


@pytest.mark.parametrize("element, op, moved", [
    ("rot90", np.rot90, lambda y, x, h, w: (w - 1 - x, y)),
    ("transpose", np.transpose, lambda y, x, h, w: (x, y)),
    ("flip-lr", np.fliplr, lambda y, x, h, w: (y, w - 1 - x)),
])
@pytest.mark.parametrize("angle", [10, 50, 100, 140])
def test_rotated_edge_lands_in_rotated_class(element, op, moved, angle):
    h = w = 32
    spec = "GRBG"
    m = _edge(h, w, angle)
    d = _definition(spec)
    d2 = _definition(_rotated_spec(spec, op))
    m2 = np.ascontiguousarray(op(m))
    perm = orientation_permutation(np.array(D4_ELEMENTS[element]), N_BINS)
    o = _orientation(d, classify(m, d))
    o2 = _orientation(d2, classify(m2, d2))
    for y, x in [(15, 15), (16, 16), (15, 16), (16, 15)]:
        y2, x2 = moved(y, x, h, w)
        assert o[y, x] > 0
        assert o2[y2, x2] == perm[o[y, x]]


def test_orientation_equals_numpy_structure_tensor():
    rng = np.random.default_rng(3)
    m = (0.2 + 0.1 * rng.random((24, 24))).astype(np.float32)
    m += _edge(24, 24, 30) * 0.5
    d = _definition("GRBG")
    o = _orientation(d, classify(m, d))
    r, ph, pw = 3, 2, 2
    theta = np.pi * np.arange(N_BINS) / N_BINS
    for y in range(r, 24 - r):
        for x in range(r, 24 - r):
            p = m[y - r:y + r + 1, x - r:x + r + 1].astype(np.float64)
            a, b = p[:-ph, :-pw], p[:-ph, pw:]
            c, dd = p[ph:, :-pw], p[ph:, pw:]
            gx, gy = (b - a) + (dd - c), (c - a) + (dd - b)
            jxx, jyy, jxy = (gx * gx).sum(), (gy * gy).sum(), (gx * gy).sum()
            u, v, t = jxx - jyy, 2 * jxy, jxx + jyy
            coh = np.hypot(u, v) / t
            if abs(coh - 0.5) < 1e-3:
                continue  # float32 vs float64 at the threshold
            if coh <= 0.5:
                assert o[y, x] == 0
                continue
            proj = u * np.cos(2 * theta) + v * np.sin(2 * theta)
            best = np.sort(proj)
            if best[-1] - best[-2] < 1e-6 * t:
                continue  # a tie between two bins
            assert o[y, x] == 1 + int(np.argmax(proj)), (y, x)


def test_symmetric_positions_stay_symmetric_after_smoothing():
    d = _definition("GRBG")
    rng = np.random.default_rng(0)
    k = rng.normal(size=(d.n_classes, d.n_coeffs, 3))
    w = rng.integers(0, 100, d.n_classes).astype(np.float64)
    smap = symmetry_map(d)
    out = symmetrize_kernels(k, w, d, smap)
    ng = d.n_groups
    P = d.n_coeffs - 1
    kk = out.reshape(ng, -1, d.n_coeffs, 3)
    nt = d.n_texture
    nsl = d.n_saturation * d.n_levels
    checked = 0
    for a in range(ng):
        for e in range(len(smap.names)):
            b = int(smap.target[a, e])
            if b < 0:
                continue
            rest = (np.arange(nsl)[:, None] * nt + smap.tex_perm[e][None, :]).ravel()
            moved = kk[b][rest]  # the class of b each class of a moves to
            # K_b[g u] == K_a[u] for every tap u, and the constants agree
            np.testing.assert_allclose(moved[:, smap.perms[e]], kk[a][:, :P], atol=1e-12)
            np.testing.assert_allclose(moved[:, P], kk[a][:, P], atol=1e-12)
            if not np.array_equal(smap.tex_perm[e], np.arange(nt)):
                checked += 1
    assert checked > 0  # some element moved orientation bins


def test_orientation_permutation_is_a_homomorphism():
    names = list(D4_ELEMENTS)
    mats = {n: np.array(D4_ELEMENTS[n]) for n in names}
    for a in names:
        for b in names:
            ab = mats[a] @ mats[b]
            pa = orientation_permutation(mats[a], 8)
            pb = orientation_permutation(mats[b], 8)
            np.testing.assert_array_equal(pa[pb], orientation_permutation(ab, 8))


# ------------------------------------------------------------------ context
def _numpy_context(m: np.ndarray, cfa: CFA, block: int) -> np.ndarray:
    """Independent: per-block per-channel means by loops, bilinear by scipy."""
    h, w = m.shape
    cmap = cfa.channel_map(h, w)
    nby, nbx = -(-h // block), -(-w // block)
    g = np.zeros((nby, nbx))
    for i in range(nby):
        for j in range(nbx):
            blk = m[i * block:(i + 1) * block, j * block:(j + 1) * block]
            cm = cmap[i * block:(i + 1) * block, j * block:(j + 1) * block]
            g[i, j] = np.mean([blk[cm == c].mean() for c in np.unique(cm)])
    cy = block * (np.arange(nby) + 0.5) - 0.5
    cx = block * (np.arange(nbx) + 0.5) - 0.5
    f = RegularGridInterpolator((cy, cx), g, method="linear")
    yy, xx = np.mgrid[0:h, 0:w]
    pts = np.stack([np.clip(yy, cy[0], cy[-1]), np.clip(xx, cx[0], cx[-1])], axis=-1)
    return f(pts.reshape(-1, 2)).reshape(h, w)


def test_context_map_equals_numpy():
    rng = np.random.default_rng(1)
    m = rng.random((70, 90)).astype(np.float32)
    cfa = CFA.from_spec("GRBG")
    got = context_map(m, cfa, 16)
    np.testing.assert_allclose(got, _numpy_context(m, cfa, 16), rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(context_map(m, cfa, 16, rows=(10, 30)), got[10:30])


@pytest.mark.parametrize("shape", [(9, 9), (17, 16), (16, 17), (33, 25)])
def test_context_of_sizes_whose_last_block_misses_a_cfa_row(shape):
    """9 rows in blocks of 8: the last block holds only row 8, CFA phase 0 (it raised
    IndexError in numpy's reduceat); the guide equals the numpy reference, and the
    classifier runs on such sizes."""
    rng = np.random.default_rng(3)
    m = rng.random(shape).astype(np.float32)
    cfa = CFA.from_spec("RGGB")
    np.testing.assert_allclose(context_map(m, cfa, 8), _numpy_context(m, cfa, 8), rtol=1e-5, atol=1e-6)
    d = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.01, 0.1], context_block=8,
                              context_cuts=[0.3, 0.6], context_rule="mean")
    assert classify(m, d).shape == shape


def test_uniform_image_has_one_context_bin():
    d = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.01, 0.1], context_block=16,
                              context_cuts=[0.05, 0.3], context_rule="mean")
    cls = classify(np.full((40, 48), 0.2, np.float32), d)
    ctx = np.asarray(d.texture_tuple(np.asarray(d.class_tuple(cls)[3]))[2])
    assert np.all(ctx == 1)


@pytest.mark.parametrize("rule", ["mean", "ratio"])
def test_context_bin_equals_numpy(rule):
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[0:64, 0:80]
    m = (0.02 + 0.5 * xx / 80 + 0.05 * rng.random((64, 80))).astype(np.float32)
    cuts = [0.1, 0.3] if rule == "mean" else [0.9, 1.1]
    d = ClassDefinition.build("GRBG", patch=5, level_cuts=[0.01, 0.1], context_block=16,
                              context_cuts=cuts, context_rule=rule)
    cls = classify(m, d)
    got = np.asarray(d.texture_tuple(np.asarray(d.class_tuple(cls)[3]))[2])
    ctx = _numpy_context(m.astype(np.float64), d.cfa, 16)
    lev, _, _ = patch_features(m, d.cfa, patch=5)
    feat = ctx if rule == "mean" else np.maximum(lev, 0) / (ctx + 1e-4)
    want = np.searchsorted(np.array(cuts), feat, side="right")
    near = np.min(np.abs(feat[..., None] - np.array(cuts)), axis=-1) < 1e-4
    np.testing.assert_array_equal(got[~near], want[~near])


def test_features_round_trip_and_validate(tmp_path):
    d = _definition("GRBG", context_block=32, context_cuts=[0.1, 0.2], context_rule="ratio")
    nc, q = d.n_classes, d.n_coeffs
    t = TransformTable(definition=d, kernels=np.zeros((nc, q, 3), np.float32),
                       counts=np.zeros(nc, np.int64), lambdas=np.full((nc, 3), np.nan),
                       empty=np.zeros(nc, bool), source_class=np.arange(nc),
                       output_space="xyz", provenance={})
    back = load_table(save_table(tmp_path / "t.npz", t))
    assert back.definition.same_as(d) and back.definition.n_texture == 2 * 5 * 3
    with pytest.raises(ConfigError, match="orientation bins 3"):
        _definition("GRBG").__class__.build("RGGB", level_cuts=[0.1], orientation_bins=3)
    with pytest.raises(ConfigError, match="context block"):
        ClassDefinition.build("RGGB", level_cuts=[0.1], context_block=15, context_cuts=[0.1])


def test_features_off_keep_the_layout():
    d = ClassDefinition.build("RGGB", level_cuts=[0.01, 0.1], contrast_cuts=0.2)
    assert d.n_texture == d.n_contrast and "orientation_bins" not in d.to_dict()
    assert int(d.class_index(1, 0, 2, 1)) == ((1 * 8 + 0) * 3 + 2) * 2 + 1


# ---------------------------------------------------------------- highlights
def test_highlight_bin_counts_saturated_pixels():
    rng = np.random.default_rng(4)
    m = (0.3 + 0.3 * rng.random((40, 40))).astype(np.float32)
    m[rng.random((40, 40)) < 0.3] = 1.0  # clipped pixels scattered over the image
    d = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.01, 0.1], highlight_bins=2,
                              highlight_fraction=0.25)
    hl = np.asarray(d.texture_tuple(np.asarray(d.class_tuple(classify(m, d))[3]))[3])
    sat = (m >= d.saturation_threshold).astype(np.int64)
    for y in range(2, 38):
        for x in range(2, 38):
            n = sat[y - 2:y + 3, x - 2:x + 3].sum()
            assert hl[y, x] == int(n >= 0.25 * 25), (y, x, n)
    assert 0 < hl.mean() < 1
