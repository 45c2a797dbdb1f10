"""Dihedral augmentation and sample weights of the training statistics (issue 14).

The stats-domain augmentation (:func:`l3cli.train.augment.augment_stats`) is
checked against the explicit construction it replaces: the pair mirrored or
rotated with numpy, raw and target together, re-phased by dropping one row
and/or column so its CFA pattern is the raw's again (found here by comparing
the moved CFA label image with the pattern, independently of the library),
and accumulated pixel by pixel.
"""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.classify import ClassDefinition
from l3cli.errors import ConfigError, InputError
from l3cli.render import render_mosaic
from l3cli.train import TrainOptions, table_from_stats
from l3cli.train.augment import augment_copies, augment_stats
from l3cli.train.stats import ClassStats, accumulate
from l3cli.train.weights import luminance, sample_weights
from tests.builders import TUNE_OPTS, design_matrix, tune_pairs

#: numpy's version of each D4 element (acting on (row, column) image coordinates)
NUMPY_MOVES = {
    "identity": lambda a: a,
    "flip-lr": lambda a: a[:, ::-1],
    "flip-ud": lambda a: a[::-1],
    "rot180": lambda a: a[::-1, ::-1],
    "transpose": lambda a: np.swapaxes(a, 0, 1),
    "anti-transpose": lambda a: np.swapaxes(a, 0, 1)[::-1, ::-1],
    "rot90": lambda a: np.rot90(a, 1),
    "rot270": lambda a: np.rot90(a, -1),
}
BAYER = ["RGGB", "GRBG", "GBRG", "BGGR"]


def _labels(spec: str, h: int, w: int) -> np.ndarray:
    """Channel letter of every pixel of an (h, w) mosaic with a 2x2 pattern ``spec``."""
    tile = np.array(list(spec)).reshape(2, 2)
    return np.tile(tile, (h // 2 + 1, w // 2 + 1))[:h, :w]


def _rephase(spec: str, moved_labels: np.ndarray) -> tuple[int, int]:
    """Rows and columns to drop so the moved mosaic has the pattern ``spec`` again."""
    for dy in (0, 1):
        for dx in (0, 1):
            if "".join(moved_labels[dy:dy + 2, dx:dx + 2].ravel()) == spec:
                return dy, dx
    raise AssertionError("no re-phasing")


def _moved_pair(spec, name, mosaic, target, mask):
    move = NUMPY_MOVES[name]
    dy, dx = _rephase(spec, move(_labels(spec, *mosaic.shape)))
    crop = (slice(dy, None), slice(dx, None))
    return (np.ascontiguousarray(move(mosaic)[crop]), np.ascontiguousarray(move(target)[crop]),
            np.ascontiguousarray(move(mask)[crop]))


def _scene(seed, shape=(46, 58)):
    rng = np.random.default_rng(seed)
    m = (0.03 + 0.6 * rng.random(shape)).astype(np.float32)
    m[5:9, 7:12] = 0.99  # a saturated blob: saturation patterns move too
    t = rng.random((*shape, 3)).astype(np.float32)
    return rng, m, t


def _definition(spec, patch=5):
    return ClassDefinition.build(spec, patch=patch, level_cuts=[0.25, 0.32, 0.4],
                                 contrast_cuts=0.3, saturation_threshold=0.95)


@pytest.mark.parametrize("spec", BAYER)
def test_every_element_equals_the_explicitly_mirrored_and_rephased_pair(spec):
    _, m, t = _scene(1)
    d = _definition(spec)
    # interior pixels only: the mirrored padding at the border and the dropped
    # row/column are the only places the two constructions may differ
    b = d.patch // 2 + 2
    mask = np.zeros(m.shape, dtype=bool)
    mask[b:-b, b:-b] = True
    orig = ClassStats.zeros(d, 3)
    accumulate(orig, m, t, mask=mask)
    for name in NUMPY_MOVES:
        mm, tm, km = _moved_pair(spec, name, m, t, mask)
        explicit = ClassStats.zeros(d, 3)
        accumulate(explicit, mm, tm, mask=km)
        moved = augment_stats(orig, [name])
        np.testing.assert_array_equal(moved.n, explicit.n, err_msg=f"{spec} {name}")
        np.testing.assert_allclose(moved.xtx, explicit.xtx, rtol=1e-10, atol=1e-9,
                                   err_msg=f"{spec} {name}")
        np.testing.assert_allclose(moved.xty, explicit.xty, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(moved.yy, explicit.yy, rtol=1e-10, atol=1e-9)


def test_a_non_trivial_element_changes_the_statistics():
    """The comparison above can fail: the unmoved statistics differ from a moved pair's."""
    _, m, t = _scene(2)
    d = _definition("GRBG")
    orig = ClassStats.zeros(d, 3)
    accumulate(orig, m, t)
    mm, tm, km = _moved_pair("GRBG", "transpose", m, t, np.ones(m.shape, bool))
    explicit = ClassStats.zeros(d, 3)
    accumulate(explicit, mm, tm, mask=km)
    assert not np.allclose(orig.xtx, explicit.xtx, rtol=1e-3)


def _asymmetric_target(m):
    """A render no mirror leaves alone: each output mixes a pixel with its right
    and lower neighbours."""
    t = np.stack([m + 0.5 * np.roll(m, -1, 1), m + 0.3 * np.roll(m, -1, 0),
                  m - 0.2 * np.roll(m, (-1, -1), (0, 1))], axis=2)
    return t.astype(np.float32)


@pytest.mark.parametrize("spec", ["GRBG", "BGGR"])
def test_an_augmented_table_renders_a_mirrored_raw_as_the_mirrored_render(spec):
    rng = np.random.default_rng(3)
    m = (0.05 + 0.5 * rng.random((96, 120))).astype(np.float32)
    t = _asymmetric_target(m)
    d = ClassDefinition.build(spec, patch=5, level_cuts=[0.3], saturation_threshold=2.0)
    st = ClassStats.zeros(d, 3)
    accumulate(st, m, t)
    b = 4
    for augment, equivariant in (("d4", True), ("none", False)):
        table = table_from_stats(st, TrainOptions(augment=augment, min_samples_factor=2))
        out = render_mosaic(table, m)
        worst = 0.0
        for name in NUMPY_MOVES:
            mm, om, _ = _moved_pair(spec, name, m, out, np.ones(m.shape, bool))
            got = render_mosaic(table, mm)
            worst = max(worst, float(np.abs(got - om)[b:-b, b:-b].max()))
        if equivariant:
            assert worst < 2e-5, worst
        else:
            assert worst > 1e-2, worst


def test_copies_and_counts():
    _, m, t = _scene(4)
    d = _definition("RGGB")
    st = ClassStats.zeros(d, 3)
    accumulate(st, m, t)
    np.testing.assert_array_equal(augment_copies(d, "d4"), 8)
    np.testing.assert_array_equal(augment_copies(d, "flips"), 4)
    np.testing.assert_array_equal(augment_copies(d, "none"), 1)
    aug = augment_stats(st, "d4")
    assert aug.n.sum() == 8 * st.n.sum()
    norm = augment_stats(st, "d4", normalise=True)
    np.testing.assert_allclose(norm.xtx.sum(axis=0), aug.xtx.sum(axis=0) / 8)
    table = table_from_stats(st, TrainOptions(augment="d4", min_samples_factor=2))
    assert table.counts.sum() == pytest.approx(st.n.sum(), abs=d.n_classes)


def test_unknown_choices_are_refused():
    with pytest.raises(ConfigError, match="--augment"):
        TrainOptions(augment="d8")
    with pytest.raises(ConfigError, match="--sample-weight"):
        TrainOptions(sample_weight="chroma")


# ---------------------------------------------------------------- weights
def test_weighted_statistics_equal_explicit_weighted_sums():
    rng, m, t = _scene(5, (40, 52))
    d = _definition("GRBG")
    w = rng.random(m.shape).astype(np.float32) * 3
    st = ClassStats.zeros(d, 3)
    accumulate(st, m, t, weight=w)
    plain = ClassStats.zeros(d, 3)
    accumulate(plain, m, t)
    from l3cli.classify import classify

    X = design_matrix(m, d)
    Y = t.reshape(-1, 3).astype(np.float64)
    ww = w.ravel().astype(np.float64)
    cls = classify(m, d).ravel()
    for c in np.unique(cls):
        sel = cls == c
        np.testing.assert_allclose(st.xtx[c], (X[sel] * ww[sel, None]).T @ X[sel], rtol=1e-9)
        np.testing.assert_allclose(st.xty[c], (X[sel] * ww[sel, None]).T @ Y[sel], rtol=1e-9)
        np.testing.assert_allclose(st.yy[c], (ww[sel, None] * Y[sel] ** 2).sum(0), rtol=1e-9)
    np.testing.assert_array_equal(st.n, plain.n)  # n counts samples
    with pytest.raises(InputError, match="weight"):
        accumulate(st, m, t, weight=-w)


def test_constant_weights_leave_the_table_unchanged():
    """Weights are rescaled per class to sum to its count: a constant weight is no weight."""
    _, m, t = _scene(6, (60, 80))
    d = _definition("RGGB")
    a, b = ClassStats.zeros(d, 3), ClassStats.zeros(d, 3)
    accumulate(a, m, t)
    accumulate(b, m, t, weight=np.full(m.shape, 2.5, np.float32))
    opts = TrainOptions(min_samples_factor=2)
    np.testing.assert_allclose(table_from_stats(b, opts).kernels,
                               table_from_stats(a, opts).kernels, rtol=1e-5, atol=1e-6)


def test_weighted_fit_follows_the_heavy_samples():
    """Two populations in one class disagree; the weighted fit sides with the heavier."""
    rng = np.random.default_rng(7)
    m = (0.2 + 0.05 * rng.random((60, 60))).astype(np.float32)
    d = ClassDefinition.build("RGGB", patch=1, level_cuts=[0.5], saturation_threshold=2.0)
    half = np.zeros(m.shape, bool)
    half[:, 30:] = True
    t = np.where(half[..., None], 2 * m[..., None], 3 * m[..., None]).repeat(3, 2)
    w = np.where(half, 100.0, 1.0).astype(np.float32)
    st = ClassStats.zeros(d, 3)
    accumulate(st, m, t.astype(np.float32), weight=w)
    k = table_from_stats(st, TrainOptions(patch=1, min_samples_factor=2)).kernels
    pred = k[:, 0, 0] * 0.225 + k[:, 1, 0]
    assert np.all(np.abs(pred - 2 * 0.225) < 0.05 * 0.225)


def test_luminance_weights():
    y = np.array([[0.0, 0.005, 0.02], [0.5, 1.0, np.nan]], dtype=np.float32)
    mask = np.array([[True, True, True], [True, True, False]])
    w = sample_weights(y, mask, "luminance", floor=0.01, exponent=1.0)
    assert w[mask].mean() == pytest.approx(1.0, rel=1e-6)
    assert w[0, 0] == w[0, 1] < w[0, 2] < w[1, 0] < w[1, 1]
    assert w[1, 1] / w[1, 0] == pytest.approx(2.0)
    w2 = sample_weights(y, mask, "luminance", floor=0.01, exponent=1.5)
    assert w2[1, 1] / w2[1, 0] == pytest.approx(2.0 ** 1.5, rel=1e-5)
    assert sample_weights(y, mask, "none") is None
    rgb = np.ones((2, 2, 3), np.float32) * 0.5
    np.testing.assert_allclose(luminance(rgb, "linear-srgb"), 0.5, rtol=1e-5)
    np.testing.assert_allclose(luminance(np.ones((1, 1, 3), np.float32), "srgb"), 1.0,
                               rtol=1e-5)


def test_cfa_without_symmetric_partners_is_augmented_only_where_valid():
    """R G / W B: transposing moves R's right neighbour (G) below it, a layout no
    position has, so only the four flips are valid there; Bayer takes all eight."""
    d = ClassDefinition.build("RGWB", patch=3, level_cuts=[0.3], saturation_threshold=2.0)
    np.testing.assert_array_equal(augment_copies(d, "d4"), 4)
    _, m, t = _scene(8, (30, 40))
    st = ClassStats.zeros(d, 3)
    accumulate(st, m, t)
    assert augment_stats(st, "d4").n.sum() == 4 * st.n.sum()
    bayer = ClassDefinition.build("RGGB", patch=3, level_cuts=[0.3], saturation_threshold=2.0)
    np.testing.assert_array_equal(augment_copies(bayer, "d4"), 8)


# ---------------------------------------------------------------- train / CV / CLI
def test_cross_validation_statistics_are_those_of_l3_train(tmp_path):
    """--tune's folds solve what l3 train solves: same weights, same augmentation."""

    from l3cli.train import find_pairs, train
    from l3cli.train.cv import layout_stats, load_cv_images, make_units, space_stats

    folder = tune_pairs(tmp_path / "p", {"a": (5, 1.0), "b": (6, 0.8)})
    pairs = find_pairs([folder])
    opts = TrainOptions(target_space="linear-srgb", augment="d4", sample_weight="luminance",
                        **TUNE_OPTS)
    images = load_cv_images(pairs, opts)
    layout = layout_stats(images, make_units(images), opts, None)
    via_cv = table_from_stats(space_stats(layout, "linear-srgb"), opts)
    direct = train(pairs, opts)
    np.testing.assert_array_equal(via_cv.counts, direct.counts)
    np.testing.assert_allclose(via_cv.kernels, direct.kernels, rtol=1e-4, atol=1e-5)
    plain = train(pairs, TrainOptions(target_space="linear-srgb", **TUNE_OPTS))
    assert not np.allclose(plain.kernels, direct.kernels, rtol=1e-3, atol=1e-4)


def test_cli_defaults_for_pairs_folders_and_switching_on(tmp_path, runner):

    from l3cli.cli.main import cli
    from l3cli.table import load_table

    folder = tune_pairs(tmp_path / "p", {"a": (5, 1.0)})
    on, off = tmp_path / "on.npz", tmp_path / "off.npz"
    common = ["--patch", "5", "--levels", "4", "--contrast-bins", "1", "--no-tune"]
    res = runner.invoke(cli, ["train", str(folder), "-o", str(off), *common])
    assert res.exit_code == 0, res.output
    opts = load_table(off).provenance["options"]  # both off by default (defaults.py)
    assert "augment" not in opts and "sample_weight" not in opts
    res = runner.invoke(cli, ["train", str(folder), "-o", str(on), *common,
                              "--augment", "d4", "--sample-weight", "luminance"])
    assert res.exit_code == 0, res.output
    opts = load_table(on).provenance["options"]
    assert opts["augment"] == "d4" and opts["sample_weight"] == "luminance"
    assert not np.allclose(load_table(on).kernels, load_table(off).kernels)
    bad = runner.invoke(cli, ["train", str(folder), "-o", str(off), "--augment", "d8"])
    assert bad.exit_code == 2
