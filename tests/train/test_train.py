"""Training: sufficient statistics, ridge + GCV, exactness, additivity, inputs."""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.classify import ClassDefinition, classify
from l3cli.errors import InputError, TableError
from l3cli.train import (
    ClassStats,
    TrainOptions,
    accumulate,
    find_pairs,
    gcv_curve,
    load_pair,
    solve_class,
    table_from_stats,
    train,
)
from l3cli.train.fit import fallback_sources
from l3cli.train.ridge import DEFAULT_LAMBDA_GRID
from tests.builders import design_matrix, sim_dir

RTOL = 1e-8




def _synthetic(seed=0, shape=(120, 160), spec="RGGB"):
    rng = np.random.default_rng(seed)
    m = (0.05 + 0.55 * rng.random(shape)).astype(np.float32)
    d = ClassDefinition.build(spec, patch=5, level_cuts=[0.3, 0.34], contrast_cuts=0.3,
                              saturation_threshold=2.0)
    return rng, m, d


# ---------------------------------------------------------------- exactness
def test_noise_free_affine_kernels_are_recovered_with_near_zero_lambda():
    rng, m, d = _synthetic()
    cls = classify(m, d).ravel()
    X = design_matrix(m, d)
    K = rng.normal(size=(d.n_classes, d.n_coeffs, 3))
    Y = np.einsum("nq,nqo->no", X, K[cls]).reshape(*m.shape, 3).astype(np.float32)
    Yd = Y.reshape(-1, 3).astype(np.float64)
    stats = ClassStats.zeros(d, 3)
    accumulate(stats, m, Y)
    table = table_from_stats(stats, TrainOptions(min_samples_factor=3))
    trained = np.flatnonzero(~table.empty)
    assert trained.size >= 8
    # the float32 target is the only rounding: compare with the exact solution of it
    for c in trained:
        sel = cls == c
        exact, *_ = np.linalg.lstsq(X[sel], Yd[sel], rcond=None)
        np.testing.assert_allclose(table.kernels[c], exact, atol=1e-5)
        np.testing.assert_allclose(table.kernels[c], K[c], atol=1e-4)
        sol = solve_class(float(stats.n[c]), stats.xtx[c], stats.xty[c], stats.yy[c])
        assert np.all(sol.lam_rel <= 1e-7), sol.lam_rel


def test_full_training_recovers_exact_affine_kernels_to_1e5_with_near_zero_lambda():
    """The whole path (classify, accumulate float32 inputs, GCV, solve, float32 table)
    against the known filters themselves. Raw values k/256 and weights j/64 make every
    target exactly representable in float32, so nothing but the solver can be off."""
    rng = np.random.default_rng(0)
    m = (rng.integers(13, 155, (120, 160)) / 256).astype(np.float32)
    d = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.3, 0.34], contrast_cuts=0.3,
                              saturation_threshold=2.0)
    cls = classify(m, d).ravel()
    X = design_matrix(m, d)
    K = rng.integers(-128, 129, size=(d.n_classes, d.n_coeffs, 3)) / 64
    Y = np.einsum("nq,nqo->no", X, K[cls])
    Y32 = Y.astype(np.float32)
    assert np.array_equal(Y32, Y)  # exact in float32
    stats = ClassStats.zeros(d, 3)
    accumulate(stats, m, Y32.reshape(*m.shape, 3))
    table = table_from_stats(stats, TrainOptions(min_samples_factor=3))
    # empty = fewer samples than 3x the coefficients (some classes on each side)
    np.testing.assert_array_equal(table.empty, stats.n < 3 * d.n_coeffs)
    assert (table.empty & (stats.n > 0)).any()
    trained = np.flatnonzero(~table.empty)
    assert trained.size >= 12
    np.testing.assert_allclose(table.kernels[trained], K[trained], rtol=0, atol=1e-5)
    # the λ training chose, relative to the mean eigenvalue: the bottom of the grid
    # (1e-9 .. 1e-7 of a grid reaching 10; rounding decides between its first values)
    p = d.n_coeffs - 1
    for c in trained:
        zc = X[cls == c, :p] - X[cls == c, :p].mean(0)
        lam_rel = table.lambdas[c] / (np.trace(zc.T @ zc) / p)
        assert np.all(lam_rel <= 1e-7), (c, lam_rel)
    # with noise on the target the same classes need a clearly larger λ
    noisy = Y32 + 0.5 * rng.standard_normal(Y32.shape).astype(np.float32)
    sn = ClassStats.zeros(d, 3)
    accumulate(sn, m, noisy.reshape(*m.shape, 3))
    tn = table_from_stats(sn, TrainOptions(min_samples_factor=3))
    zc = X[cls == trained[0], :p] - X[cls == trained[0], :p].mean(0)
    assert np.all(tn.lambdas[trained[0]] / (np.trace(zc.T @ zc) / p) > 1e-4)


def test_exact_float64_targets_to_1e5():
    rng, m, d = _synthetic(seed=5)
    cls = classify(m, d).ravel()
    X = design_matrix(m, d)
    K = rng.normal(size=(d.n_classes, d.n_coeffs, 2))
    Y = np.einsum("nq,nqo->no", X, K[cls])
    stats = ClassStats.zeros(d, 2)
    for c in np.unique(cls):  # accumulate the float64 targets directly
        Xc, Yc = X[cls == c], Y[cls == c]
        stats.n[c] += Xc.shape[0]
        stats.xtx[c] += Xc.T @ Xc
        stats.xty[c] += Xc.T @ Yc
        stats.yy[c] += (Yc**2).sum(0)
    for c in np.flatnonzero(stats.n > 3 * d.n_coeffs):
        sol = solve_class(float(stats.n[c]), stats.xtx[c], stats.xty[c], stats.yy[c])
        np.testing.assert_allclose(sol.kernel, K[c], atol=1e-5)
        assert sol.lam_rel.max() <= 1e-7


# --------------------------------------------------- GCV equals explicit SVD
def _gcv_svd(X, y, lambdas):
    n = X.shape[0]
    Z = X[:, :-1]
    Zc = Z - Z.mean(axis=0)
    yc = y - y.mean()
    U, s, Vt = np.linalg.svd(Zc, full_matrices=False)
    uty = U.T @ yc
    out = []
    for lam in lambdas:
        beta = Vt.T @ (s / (s**2 + lam) * uty)
        resid = y - (Zc @ beta + y.mean())
        rss = resid @ resid
        df = 1 + np.sum(s**2 / (s**2 + lam))
        out.append(n * rss / (n - df) ** 2)
    return np.array(out)


@pytest.mark.parametrize("seed", [0, 1])
def test_gcv_from_statistics_equals_svd(seed):
    rng = np.random.default_rng(seed)
    n, p = 800, 25
    base = rng.random((n, 1))
    Z = 0.6 * base + 0.4 * rng.random((n, p))  # correlated like neighbouring pixels
    X = np.hstack([Z, np.ones((n, 1))])
    beta = rng.normal(size=p)
    Y = np.stack([Z @ beta + 0.3 + 0.05 * rng.standard_normal(n),
                  Z @ (0.5 * beta) - 0.1 + 0.2 * rng.standard_normal(n)], axis=1)
    xtx, xty, yy = X.T @ X, X.T @ Y, (Y**2).sum(0)
    zc = Z - Z.mean(0)
    scale = np.trace(zc.T @ zc) / p
    lambdas = DEFAULT_LAMBDA_GRID * scale
    gcv, _, _ = gcv_curve(float(n), xtx, xty, yy, lambdas)
    for o in range(2):
        ref = _gcv_svd(X, Y[:, o], lambdas)
        np.testing.assert_allclose(gcv[:, o], ref, rtol=RTOL)
    # the solution at the chosen λ is the ridge solution with an unpenalised intercept
    sol = solve_class(float(n), xtx, xty, yy)
    for o in range(2):
        lam = sol.lam[o]
        A = zc.T @ zc + lam * np.eye(p)
        b = np.linalg.solve(A, zc.T @ (Y[:, o] - Y[:, o].mean()))
        np.testing.assert_allclose(sol.kernel[:p, o], b, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(sol.kernel[p, o], Y[:, o].mean() - Z.mean(0) @ b, rtol=1e-7)
        assert sol.lam[o] == pytest.approx(lambdas[np.argmin(_gcv_svd(X, Y[:, o], lambdas))], rel=1e-12)


def test_gcv_prefers_more_regularisation_for_noisier_data():
    rng = np.random.default_rng(3)
    n, p = 300, 25
    Z = rng.random((n, p))
    X = np.hstack([Z, np.ones((n, 1))])
    y = Z @ (0.05 * rng.normal(size=p))
    lam_rel = []
    for noise in (0.0, 0.3, 3.0):
        Y = (y + noise * rng.standard_normal(n))[:, None]
        sol = solve_class(float(n), X.T @ X, X.T @ Y, (Y**2).sum(0))
        lam_rel.append(sol.lam_rel[0])
    assert lam_rel[0] < lam_rel[1] <= lam_rel[2]


# ---------------------------------------------------------------- additivity
def test_statistics_add_and_round_trip(tmp_path):
    rng, a, d = _synthetic(seed=1)
    b = (0.05 + 0.55 * rng.random(a.shape)).astype(np.float32)
    ta = rng.random((*a.shape, 3)).astype(np.float32)
    tb = rng.random((*a.shape, 3)).astype(np.float32)
    one = ClassStats.zeros(d, 3)
    accumulate(one, a, ta)
    accumulate(one, b, tb)
    sa, sb = ClassStats.zeros(d, 3), ClassStats.zeros(d, 3)
    accumulate(sa, a, ta)
    accumulate(sb, b, tb)
    sa.save(tmp_path / "a.npz")
    sb.save(tmp_path / "b.npz")
    merged = ClassStats.load(tmp_path / "a.npz") + ClassStats.load(tmp_path / "b.npz")
    for k in ("n", "xtx", "xty", "yy"):
        np.testing.assert_allclose(getattr(merged, k), getattr(one, k), rtol=1e-13, atol=1e-12)
    opts = TrainOptions()
    t1, t2 = table_from_stats(one, opts), table_from_stats(merged, opts)
    np.testing.assert_allclose(t1.kernels, t2.kernels, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(t1.empty, t2.empty)
    assert sum([sa, sb]).n.sum() == one.n.sum()


def test_adding_statistics_of_other_definitions_fails():
    _, m, d = _synthetic()
    d2 = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.3], contrast_cuts=0.3,
                               saturation_threshold=2.0)
    with pytest.raises(TableError, match=r"different class definitions \(level cut points \(3 vs 2 levels\); contrast cut points\)"):
        ClassStats.zeros(d, 3) + ClassStats.zeros(d2, 3)


def test_accumulate_counts_every_pixel_once_and_mask():
    rng, m, d = _synthetic()
    t = rng.random((*m.shape, 3)).astype(np.float32)
    s = ClassStats.zeros(d, 3)
    accumulate(s, m, t, max_pixels=1000)  # many bands
    np.testing.assert_array_equal(s.n, np.bincount(classify(m, d).ravel(), minlength=d.n_classes))
    np.testing.assert_allclose(s.xtx[:, -1, -1], s.n)
    np.testing.assert_allclose(s.yy.sum(0), (t.astype(np.float64) ** 2).sum((0, 1)), rtol=1e-10)
    mask = rng.random(m.shape) < 0.3
    s2 = ClassStats.zeros(d, 3)
    accumulate(s2, m, t, mask=mask)
    assert s2.n.sum() == mask.sum()


def test_accumulate_rejects_size_mismatch():
    _, m, d = _synthetic()
    with pytest.raises(InputError, match="target is 10x10 but the raw is 160x120"):
        accumulate(ClassStats.zeros(d, 3), m, np.zeros((10, 10, 3), np.float32))


# ---------------------------------------------------------------- fallback
def test_fallback_goes_to_nearest_trained_level_same_position_and_contrast():
    d = ClassDefinition.build("RGGB", patch=3, level_cuts=[0.1, 0.2, 0.3, 0.4],
                              contrast_cuts=0.5)
    trained = np.zeros(d.n_classes, bool)
    trained[d.class_index(0, 0, 1, 0)] = True
    trained[d.class_index(0, 0, 4, 0)] = True
    trained[d.class_index(0, 0, 3, 1)] = True
    for g in (1, 2, 3):
        trained[d.class_index(g, 0, 0, 0)] = True
    src = fallback_sources(d, trained)
    assert src[d.class_index(0, 0, 0, 0)] == d.class_index(0, 0, 1, 0)
    assert src[d.class_index(0, 0, 2, 0)] == d.class_index(0, 0, 1, 0)  # tie -> lower level
    assert src[d.class_index(0, 0, 3, 0)] == d.class_index(0, 0, 4, 0)
    assert src[d.class_index(0, 0, 0, 1)] == d.class_index(0, 0, 3, 1)
    assert src[d.class_index(0, 5, 2, 1)] == d.class_index(0, 0, 3, 1)  # saturated -> unsaturated
    assert src[d.class_index(1, 0, 4, 1)] == d.class_index(1, 0, 0, 0)
    assert np.all(trained[src])
    with pytest.raises(TableError, match="no class has enough"):
        fallback_sources(d, np.zeros(d.n_classes, bool))
    trained[d.class_index(3, 0, 0, 0)] = False
    with pytest.raises(TableError, match=r"CFA positions \[3\] have no trained class"):
        fallback_sources(d, trained)


# ------------------------------------------------------------- input folders




def test_find_pairs_simulation_and_pairs_folders(tmp_path):
    sim = sim_dir(tmp_path)
    pairs = find_pairs([sim])
    assert [p.name for p in pairs] == ["cap0", "cap1"]
    assert pairs[0].metadata == {} and not pairs[0].align
    loaded = load_pair(pairs[0])
    raw, target = loaded.raw, loaded.target
    assert loaded.space == "xyz" and loaded.weight_mask is None
    assert target.shape == (40, 48, 3) and raw.cfa.spec == "RG/GB"
    pf = tmp_path / "pairs"
    pf.mkdir()
    from l3cli.io.image import write_image
    from l3cli.io.raw import write_raw

    write_raw(pf / "a.dng", np.full((40, 48), 1000, np.uint16), "RGGB", white_level=4095)
    write_image(pf / "a.png", np.full((40, 48, 3), 0.5, np.float32), space="srgb")
    pp = find_pairs([pf])
    assert len(pp) == 1 and pp[0].target.name == "a.png"
    t = load_pair(pp[0], target_space="srgb").target
    np.testing.assert_allclose(t, 0.5, atol=1 / 255)


@pytest.mark.parametrize("space", ["xyz", "linear-srgb", "srgb", "lab"])
def test_targets_are_converted_to_the_training_space(tmp_path, space):
    """--target: the XYZ targets of a simulation become linear sRGB, encoded sRGB or
    CIELAB (colour-science as the reference) and the table renders into that space."""
    import colour

    sim = sim_dir(tmp_path, n=2, seed=13)
    pairs = find_pairs([sim])
    xyz = load_pair(pairs[0], target_space="xyz").target.astype(np.float64)
    got = load_pair(pairs[0], target_space=space).target
    from l3cli.colourspace import D65_XYZ  # l3's documented Lab white (D65, Y = 1)

    d65 = colour.XYZ_to_xy(D65_XYZ)
    lin = colour.XYZ_to_sRGB(xyz, apply_cctf_encoding=False)
    ref = {"xyz": xyz, "linear-srgb": lin,
           "srgb": colour.cctf_encoding(np.clip(lin, 0, 1), function="sRGB"),
           "lab": colour.XYZ_to_Lab(xyz, d65)}[space]
    np.testing.assert_allclose(got, ref, atol=1e-3 if space == "lab" else 1e-5)  # float32
    t = train(pairs, TrainOptions(levels=3, target_space=space, min_samples_factor=2))
    assert t.output_space == space


def test_bad_inputs(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no training pairs"):
        find_pairs([empty])
    with pytest.raises(InputError, match="no such file or folder"):
        find_pairs([tmp_path / "missing"])
    nan = sim_dir(tmp_path, seed=1, nan=True)
    with pytest.raises(InputError, match="NaN or Inf.*x=4, y=3"):
        train(find_pairs([nan]), TrainOptions(levels=3))
    bad = sim_dir(tmp_path, seed=2, bad_size=True)
    with pytest.raises(InputError, match="target is 48x38 but raw cap1.dng is 48x40"):
        train(find_pairs([bad]), TrainOptions(levels=3))
    lonely = tmp_path / "lonely"
    lonely.mkdir()
    from l3cli.io.raw import write_raw

    write_raw(lonely / "x.dng", np.zeros((40, 48), np.uint16), "RGGB", white_level=4095)
    with pytest.raises(InputError, match="no rendered image with the same stem"):
        find_pairs([lonely])


def test_one_run_on_a_and_b_equals_merged_statistics_of_separate_runs(tmp_path):
    """Training on captures A + B in one run == statistics of A and of B collected in
    separate runs (written to and read from files), added, then solved."""
    from l3cli.train import collect_stats, define_classes

    sim = sim_dir(tmp_path, n=2, shape=(48, 64), seed=12)
    pairs = find_pairs([sim])
    opts = TrainOptions(levels=4, sample_fraction=0.6, min_samples_factor=2, seed=5)
    one = train(pairs, opts)
    d = define_classes(pairs, opts)  # the shared class definition of both runs
    assert d.same_as(one.definition)
    sa = collect_stats(pairs[:1], d, opts)
    sb = collect_stats(pairs[1:], d, opts, index_offset=1)  # B is image 1 of the set
    assert sa.n.sum() > 0 and sb.n.sum() > 0
    merged = (ClassStats.load(sa.save(tmp_path / "a.npz"))
              + ClassStats.load(sb.save(tmp_path / "b.npz")))
    both = collect_stats(pairs, d, opts)
    np.testing.assert_array_equal(merged.n, both.n)
    for k in ("xtx", "xty", "yy"):
        np.testing.assert_allclose(getattr(merged, k), getattr(both, k), rtol=1e-12, atol=1e-12)
    t = table_from_stats(merged, opts)
    np.testing.assert_array_equal(t.counts, one.counts)
    np.testing.assert_array_equal(t.empty, one.empty)
    np.testing.assert_array_equal(t.source_class, one.source_class)
    np.testing.assert_allclose(t.kernels, one.kernels, rtol=1e-6, atol=1e-6)
    assert (~one.empty).sum() >= 4


def test_too_little_data_gives_zero_trained_classes(tmp_path):
    sim = sim_dir(tmp_path, n=1, shape=(40, 48), seed=3)
    with pytest.raises(TableError, match="no class has enough training samples"):
        train(find_pairs([sim]), TrainOptions(levels=40, min_samples_factor=50))


def test_train_is_deterministic_with_seed_and_subsampling(tmp_path):
    sim = sim_dir(tmp_path, n=2, seed=4, shape=(48, 64))
    pairs = find_pairs([sim])
    opts = dict(levels=4, sample_fraction=0.5, min_samples_factor=2)
    t1 = train(pairs, TrainOptions(seed=7, **opts))
    t2 = train(pairs, TrainOptions(seed=7, **opts))
    t3 = train(pairs, TrainOptions(seed=8, **opts))
    np.testing.assert_array_equal(t1.kernels, t2.kernels)
    np.testing.assert_array_equal(t1.definition.level_cuts, t2.definition.level_cuts)
    assert t1.counts.sum() == pytest.approx(0.5 * 2 * 48 * 64, rel=0.05)
    assert not np.array_equal(t1.counts, t3.counts)


def test_accumulated_statistics_equal_explicit_sums_with_mask():
    rng, m, d = _synthetic(seed=9, shape=(70, 90))
    t = rng.random((*m.shape, 3)).astype(np.float32)
    mask = rng.random(m.shape) < 0.4
    s = ClassStats.zeros(d, 3)
    accumulate(s, m, t, mask=mask, max_pixels=2000)  # several bands
    X = design_matrix(m, d)
    Y = t.reshape(-1, 3).astype(np.float64)
    cls = classify(m, d).ravel()
    keep = mask.ravel()
    for c in np.unique(cls[keep]):
        sel = keep & (cls == c)
        np.testing.assert_allclose(s.xtx[c], X[sel].T @ X[sel], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(s.xty[c], X[sel].T @ Y[sel], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(s.yy[c], (Y[sel] ** 2).sum(0), rtol=1e-12)
        assert s.n[c] == sel.sum()


def test_statistics_do_not_depend_on_the_number_of_threads():
    import numba

    rng, m, d = _synthetic(seed=11, shape=(90, 130))
    t = rng.random((*m.shape, 3)).astype(np.float32)
    before = numba.get_num_threads()
    runs = []
    try:
        for n in sorted({1, numba.config.NUMBA_NUM_THREADS}):
            numba.set_num_threads(n)
            s = ClassStats.zeros(d, 3)
            accumulate(s, m, t, max_pixels=3000)
            runs.append(s)
    finally:
        numba.set_num_threads(before)
    for s in runs[1:]:
        np.testing.assert_array_equal(s.xtx, runs[0].xtx)
        np.testing.assert_array_equal(s.xty, runs[0].xty)
        np.testing.assert_array_equal(s.yy, runs[0].yy)


def test_pairs_folder_with_two_renders_of_one_raw_is_refused(tmp_path):
    """`l3 train` reads pairs folders through l3cli.pairs: one render per raw."""
    from l3cli.io.image import write_image
    from l3cli.io.raw import write_raw

    write_raw(tmp_path / "a.dng", np.full((40, 48), 1000, np.uint16), "RGGB", white_level=4095)
    write_image(tmp_path / "a.png", np.full((40, 48, 3), 0.5, np.float32), space="srgb")
    write_image(tmp_path / "a.jpg", np.full((40, 48, 3), 0.2, np.float32), space="srgb")
    with pytest.raises(InputError, match=r"several rendered images.*a\.jpg, a\.png"):
        find_pairs([tmp_path])
