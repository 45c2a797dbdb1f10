"""Priors on transform tables (``l3 smooth``): symmetry, smoothness over levels, uniformity.

Independent facts used: D4 symmetries of the Bayer layout worked out by hand;
the group average is an orthogonal projection (idempotent, residual orthogonal
to the invariant subspace); the Whittaker smoother leaves straight lines alone,
interpolates at λ = 0 and tends to the weighted least-squares line (numpy
``polyfit``) as λ grows; the uniformity correction equals the minimum-norm
solution of the constrained least-squares problem solved generically (KKT via
``numpy.linalg.pinv``); a flat field renders flat.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from l3cli.cfa import CFA
from l3cli.classify import ClassDefinition
from l3cli.errors import ConfigError
from l3cli.smooth import filled_classes, smooth_table
from l3cli.smooth.spline import level_abscissa, smooth_levels, whittaker
from l3cli.smooth.symmetry import symmetrize_kernels, symmetry_map, tap_permutation
from l3cli.smooth.uniformity import channel_sums, make_uniform, uniformity_error
from l3cli.table import TransformTable, load_table, save_table
from tests.builders import plausible_table

RGBW = "WGWR/BWGW/WRWG/GWBW"  # sample_configs/rgbw-4x4.toml
CFAS = ["RGGB", "GRBG", RGBW, "RGBW/GWRB/BRWG/WBGR", "R G/NIR B", "RGB/GBR/BRG"]

#: The class layout these smoothing tests were designed with (the defaults
#: before issue 14): small simulated training sets, 24 levels, 2 median-split
#: contrast bins, 5x5 patches.
LAYOUT = ("--patch", "5", "--levels", "24", "--contrast-bins", "2",
          "--contrast-threshold", "quantile")




def flat_field(cfa: CFA, values: dict[str, float], h=40, w=44) -> np.ndarray:
    """Mosaic of a uniform scene: every channel at its own value."""
    v = np.array([values[c] for c in cfa.channels], dtype=np.float32)
    return v[cfa.channel_map(h, w)]


def _rel_spread(img: np.ndarray, border: int) -> np.ndarray:
    core = img[border:-border, border:-border].reshape(-1, img.shape[-1]).astype(np.float64)
    return core.std(axis=0) / np.abs(core.mean(axis=0))


# --------------------------------------------------------------------- symmetry
def test_bayer_symmetries_are_the_ones_worked_out_by_hand():
    d = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.1])
    smap = symmetry_map(d)
    names = smap.names
    # groups: 0 = R, 1 = G on R rows, 2 = G on B rows, 3 = B
    for g in (0, 3):  # R and B sites see a layout with the full symmetry of the square
        assert all(smap.target[g, e] == g for e in range(8))
    for g, other in ((1, 2), (2, 1)):
        for e, n in enumerate(names):
            expect = g if n in ("identity", "flip-lr", "flip-ud", "rot180") else other
            assert smap.target[g, e] == expect, (g, n)
    assert smap.orbits == ((0,), (1, 2), (3,))


def test_tap_permutation_is_the_array_transform():
    a = np.arange(25).reshape(5, 5)
    for name, ref in [("flip-lr", a[:, ::-1]), ("flip-ud", a[::-1]), ("rot180", a[::-1, ::-1]),
                      ("transpose", a.T), ("anti-transpose", a[::-1, ::-1].T)]:
        moved = np.empty(25, dtype=int)
        moved[tap_permutation(name, 5)] = a.ravel()  # (g A)[g u] = A[u]
        np.testing.assert_array_equal(moved.reshape(5, 5), ref, err_msg=name)


@pytest.mark.parametrize("spec", CFAS)
def test_after_symmetry_kernels_of_symmetric_positions_are_exactly_symmetric(spec):
    t = plausible_table(spec, seed=3)
    for kw in ({"spline": False, "uniformity": False}, {}):
        s = smooth_table(t, **kw)
        d = s.definition
        smap = symmetry_map(d)
        k = s.kernels.reshape(d.n_groups, -1, d.n_coeffs, 3)
        checked = 0
        for a in range(d.n_groups):
            for e in range(8):
                b = smap.target[a, e]
                if b < 0:
                    continue
                # K_b[g u] == K_a[u] exactly, offsets equal
                np.testing.assert_array_equal(k[b][:, smap.perms[e]], k[a][:, :-1])
                np.testing.assert_array_equal(k[b][:, -1], k[a][:, -1])
                checked += 1
        assert checked >= d.n_groups  # at least the identity everywhere


def test_symmetry_is_an_orthogonal_projection():
    t = plausible_table("RGGB", seed=4)
    d = t.definition
    smap = symmetry_map(d)
    ones = np.ones(d.n_classes)
    k = t.kernels.astype(np.float64)
    pk = symmetrize_kernels(k, ones, d, smap)
    np.testing.assert_allclose(symmetrize_kernels(pk, ones, d, smap), pk, atol=1e-14)
    other = symmetrize_kernels(np.random.default_rng(1).normal(size=k.shape), ones, d, smap)
    assert abs(np.sum((k - pk) * other)) < 1e-9 * np.abs(k).sum()
    assert np.abs(k - pk).max() > 1e-3  # it did change the kernels


def test_symmetric_table_renders_a_transposed_scene_transposed():
    from l3cli.render import render_mosaic

    t = plausible_table("RGGB", seed=5, empty_fraction=0.0)
    pat = np.array(CFA.from_spec("RGGB").pattern)
    assert (pat == pat.T).all()  # RGGB is its own transpose
    rng = np.random.default_rng(0)
    m = (0.05 + 0.5 * rng.random((36, 36)) ** 2).astype(np.float32)
    mt = np.ascontiguousarray(m.T)

    def mismatch(table):
        a = render_mosaic(table, m).transpose(1, 0, 2)
        b = render_mosaic(table, mt)
        return np.mean(np.abs(a - b).max(axis=2) > 1e-4)

    s = smooth_table(t, spline=False, uniformity=False)
    assert mismatch(s) < 2e-3  # only rounding at class boundaries may differ
    assert mismatch(t) > 0.2  # the unsymmetrised table does not have the property


def test_symmetry_fills_a_class_whose_mirror_partner_is_trained():
    t = plausible_table("RGGB", seed=6, empty_fraction=0.0)
    d = t.definition
    e = int(d.class_index(1, 0, 3, 0))  # G on R rows
    partner = int(d.class_index(2, 0, 3, 0))  # its transpose
    t.empty[e] = True
    t.counts[e] = 0
    t.source_class[e] = partner
    t.kernels[e] = t.kernels[partner]
    s = smooth_table(t, spline=False, uniformity=False)
    assert not s.empty[e] and s.source_class[e] == e
    assert e in filled_classes(s)["symmetry"]
    perm = tap_permutation("transpose", 5)
    np.testing.assert_array_equal(s.kernels[partner][perm], s.kernels[e][:-1])
    # only the trained partner contributed (made invariant under its own stabiliser:
    # both flips and the 180° turn)
    kp = t.kernels[partner][:-1].astype(np.float64)
    stab = np.mean([kp[tap_permutation(n, 5)] for n in ("identity", "flip-lr", "flip-ud",
                                                         "rot180")], axis=0)
    np.testing.assert_allclose(s.kernels[e][:-1], stab[perm], atol=1e-6)


# ---------------------------------------------------------------------- spline
def test_whittaker_facts():
    rng = np.random.default_rng(0)
    x = np.linspace(0, 5, 12) + 0.1 * rng.random(12)  # uneven grid
    w = rng.random(12) + 0.1
    line = np.stack([2.0 - 0.7 * x, 0.3 * x], axis=1)
    for lam in (0.0, 0.1, 100.0):  # a straight line has no roughness
        np.testing.assert_allclose(whittaker(x, line, w, strength=lam)[0], line, atol=1e-10)
    y = rng.normal(size=(12, 2))
    np.testing.assert_allclose(whittaker(x, y, w, strength=0.0)[0], y, atol=1e-10)
    z = whittaker(x, y, w, strength=1e7)[0]  # distance to the limit falls as 1/λ
    for j in range(2):
        fit = np.polyval(np.polyfit(x, y[:, j], 1, w=np.sqrt(w)), x)
        np.testing.assert_allclose(z[:, j], fit, atol=1e-6)


def test_whittaker_gcv_reduces_noise_on_a_smooth_curve():
    rng = np.random.default_rng(1)
    x = np.linspace(0, 4, 30)
    truth = np.sin(x)[:, None] * np.array([1.0, 0.5])
    y = truth + 0.1 * rng.normal(size=truth.shape)
    z, lam = whittaker(x, y, np.ones(30), strength=None)
    assert np.all(lam == lam[0]) and 0 < lam[0] < np.inf
    assert np.sqrt(np.mean((z - truth) ** 2)) < 0.6 * np.sqrt(np.mean((y - truth) ** 2))


def test_spline_fills_between_and_extrapolates_as_constants():
    d = ClassDefinition.build("RGGB", patch=3, level_cuts=np.geomspace(0.01, 0.5, 9))
    x = level_abscissa(d)
    np.testing.assert_allclose(np.diff(x), np.diff(x)[0])  # log spacing: even abscissa
    nl = d.n_levels
    q = d.n_coeffs
    # true coefficients linear in ln level
    truth = (0.5 + 0.2 * x)[:, None, None] * np.linspace(1, 2, q * 3).reshape(1, q, 3)
    k = np.zeros((d.n_classes, q, 3))
    w = np.zeros(d.n_classes)
    idx = [int(d.class_index(0, 0, lv, 0)) for lv in range(nl)]
    have = [2, 3, 7, 8]
    for lv in have:
        k[idx[lv]] = truth[lv]
        w[idx[lv]] = 1000.0
    out, filled, _ = smooth_levels(k, w, d, strength=0.3)
    for lv in range(2, 9):  # between trained levels: the line
        np.testing.assert_allclose(out[idx[lv]], truth[lv], atol=1e-9)
    for lv in (0, 1):
        np.testing.assert_allclose(out[idx[lv]], truth[2], atol=1e-9)
    np.testing.assert_allclose(out[idx[9]], truth[8], atol=1e-9)
    assert filled[idx].tolist() == [lv not in have for lv in range(nl)]
    # series without data are left alone and not reported as filled
    assert not filled[int(d.class_index(1, 0, 0, 0))]


# ------------------------------------------------------------------ uniformity
def test_uniformity_is_the_minimum_norm_constrained_least_squares_change():
    t = plausible_table("RGGB", patch=3, seed=7, empty_fraction=0.0)
    d = t.definition
    k = t.kernels.astype(np.float64)
    w = t.counts.astype(np.float64)
    u = make_uniform(k, w, d, target="least-squares")
    # generic solution for one slot and one output: min sum_g w_g |x'_g - x_g|^2
    # s.t. S_{g,c} = S_{0,c} and b_g = b_0 for every g
    slot = (0, 4, 1)
    cls = [int(d.class_index(g, *slot)) for g in range(d.n_groups)]
    q = d.n_coeffs
    x = np.concatenate([k[c][:, 0] for c in cls])
    dw = np.repeat(w[cls], q)
    rows = []
    lay = [d.cfa.neighbourhood(int(np.flatnonzero(d.position_group == g)[0]), 3).ravel()
           for g in range(d.n_groups)]
    for g in range(1, d.n_groups):
        for c in range(d.cfa.n_channels):
            r = np.zeros(x.size)
            r[g * q: g * q + q - 1][lay[g] == c] = 1
            r[0: q - 1][lay[0] == c] -= 1
            rows.append(r)
        r = np.zeros(x.size)
        r[g * q + q - 1] = 1
        r[q - 1] = -1
        rows.append(r)
    a = np.array(rows)
    dinv = np.diag(1 / dw)
    ref = x - dinv @ a.T @ np.linalg.pinv(a @ dinv @ a.T) @ (a @ x)
    got = np.concatenate([u[c][:, 0] for c in cls])
    np.testing.assert_allclose(got, ref, atol=1e-10)
    assert uniformity_error(u, d) < 1e-12 < 1e-3 < uniformity_error(k, d)
    # per-channel sums agree across groups in every slot
    s = channel_sums(u, d).reshape(d.n_groups, -1, d.cfa.n_channels, 3)
    np.testing.assert_allclose(s, np.broadcast_to(s[:1], s.shape), atol=1e-12)


@pytest.mark.parametrize("spec", ["RGGB", RGBW])
def test_uniformity_period_mean_keeps_the_flat_field_average(spec):
    t = plausible_table(spec, patch=5, seed=16, empty_fraction=0.0)
    d = t.definition
    k = t.kernels.astype(np.float64)
    u = make_uniform(k, t.counts, d)  # default target: period mean
    m = np.bincount(d.position_group, minlength=d.n_groups).astype(float)
    nch = d.cfa.n_channels
    s0 = channel_sums(k, d).reshape(d.n_groups, -1, nch, 3)
    s1 = channel_sums(u, d).reshape(d.n_groups, -1, nch, 3)
    np.testing.assert_allclose(np.einsum("g,gjco->jco", m, s1), np.einsum("g,gjco->jco", m, s0),
                               atol=1e-12)
    np.testing.assert_allclose(s1, np.broadcast_to(s1[:1], s1.shape), atol=1e-12)
    b0 = k.reshape(d.n_groups, -1, d.n_coeffs, 3)[:, :, -1]
    b1 = u.reshape(d.n_groups, -1, d.n_coeffs, 3)[:, :, -1]
    np.testing.assert_allclose(m @ b1.reshape(d.n_groups, -1), m @ b0.reshape(d.n_groups, -1),
                               atol=1e-12)
    # the change of each kernel is constant over the taps of one channel (minimum norm)
    delta = (u - k).reshape(d.n_groups, -1, d.n_coeffs, 3)
    for g in range(d.n_groups):
        lay = d.cfa.neighbourhood(int(np.flatnonzero(d.position_group == g)[0]), 5).ravel()
        for c in range(nch):
            dc = delta[g][:, :-1][:, lay == c]
            np.testing.assert_allclose(dc, dc[:, :1].repeat(dc.shape[1], axis=1), atol=1e-12)
    with pytest.raises(ConfigError, match="uniformity target"):
        make_uniform(k, t.counts, d, target="median")


@pytest.mark.parametrize("spec", ["RGGB", RGBW, "R G/NIR B"])
def test_flat_field_renders_uniform_after_smoothing(spec):
    from l3cli.render import render_mosaic

    t = plausible_table(spec, seed=8)
    s = smooth_table(t)
    cfa = t.cfa
    rng = np.random.default_rng(2)
    worst_raw = 0.0
    for scale in (0.004, 0.02, 0.1, 0.5):
        vals = {c: scale * (0.5 + rng.random()) for c in cfa.channels}
        m = flat_field(cfa, vals)
        for table, bound in ((s, 1e-3), (t, None)):
            spread = _rel_spread(render_mosaic(table, m), border=t.patch)
            if bound is None:
                worst_raw = max(worst_raw, float(spread.max()))
            else:
                assert spread.max() < bound, (scale, spread)
        # the smoothed table is uniform right up to the border too (phase-keeping mirror)
        full = render_mosaic(s, m).reshape(-1, 3)
        assert (full.std(axis=0) / np.abs(full.mean(axis=0))).max() < 1e-3
    assert worst_raw > 1e-2  # without the prior the flat field is not flat


def test_flat_field_with_a_saturated_channel_renders_uniform():
    from l3cli.render import render_mosaic

    t = plausible_table("RGGB", seed=9, empty_fraction=0.0)
    s = smooth_table(t)
    m = flat_field(t.cfa, {"R": 0.99, "G": 0.4, "B": 0.2})
    assert _rel_spread(render_mosaic(s, m), border=5).max() < 1e-3


def test_a_series_untrained_at_one_position_is_filled_by_uniformity():
    """Saturated-red classes trained at three positions but never at the fourth: a
    red-clipped flat field must still render flat."""
    from l3cli.render import render_mosaic
    from l3cli.train.fit import fallback_sources

    t = plausible_table("RGGB", seed=17, empty_fraction=0.0)
    d = t.definition
    g, sat, _, _ = (np.asarray(a) for a in d.class_tuple(np.arange(d.n_classes)))
    hole = (g == 3) & (sat == 0b001)  # B sites, red saturated
    empty = hole.copy()
    src = fallback_sources(d, ~empty)
    t = TransformTable(definition=d, kernels=t.kernels[src], counts=np.where(empty, 0, t.counts),
                       lambdas=t.lambdas, empty=empty, source_class=src)
    m = flat_field(d.cfa, {"R": 0.99, "G": 0.3, "B": 0.2})
    for kw in ({}, {"symmetry": False, "spline": False}):
        s = smooth_table(t, **kw)
        assert not s.empty.any()
        assert filled_classes(s)["uniformity"] == np.flatnonzero(hole).tolist()
        assert _rel_spread(render_mosaic(s, m), border=5).max() < 1e-3
    s = smooth_table(t, uniformity=False)
    assert _rel_spread(render_mosaic(s, m), border=5).max() > 1e-3


# ------------------------------------------------------------ smooth_table API
def test_provenance_records_priors_settings_and_filled_classes(tmp_path):
    t = plausible_table("RGGB", seed=10)
    s = smooth_table(t, spline_strength=0.5)
    rec = s.provenance["smoothing"]
    assert rec["priors"] == ["symmetry", "spline", "uniformity"]
    assert rec["spline"]["strength"] == 0.5
    assert rec["symmetry"]["orbits"] == [[0], [1, 2], [3]]
    assert rec["uniformity"]["spread_after"] < 1e-5 < rec["uniformity"]["spread_before"]
    assert rec["uniformity"]["target"] == "period-mean"
    filled = rec["filled_classes"]
    assert filled and filled == np.flatnonzero(t.empty & ~s.empty).tolist()
    assert np.all(s.source_class[filled] == filled)
    # counts, λ and the class definition are kept; the original table is untouched
    np.testing.assert_array_equal(s.counts, t.counts)
    np.testing.assert_array_equal(s.lambdas, t.lambdas)
    assert "smoothing" not in t.provenance
    u = load_table(save_table(tmp_path / "s.npz", s))
    assert u.provenance["smoothing"] == json.loads(json.dumps(rec))
    np.testing.assert_array_equal(u.kernels, s.kernels)
    # smoothing twice keeps the first record in a history
    s2 = smooth_table(s, symmetry=False)
    assert s2.provenance["smoothing"]["priors"] == ["spline", "uniformity"]
    assert s2.provenance["smoothing_history"][0]["priors"] == rec["priors"]


def test_each_prior_can_be_switched_off():
    t = plausible_table("RGGB", seed=11)
    none = smooth_table(t, symmetry=False, spline=False, uniformity=False)
    np.testing.assert_array_equal(none.kernels, t.kernels)
    assert none.provenance["smoothing"]["priors"] == []
    only_u = smooth_table(t, symmetry=False, spline=False)
    assert only_u.provenance["smoothing"]["priors"] == ["uniformity"]
    assert set(filled_classes(only_u)) == {"uniformity"}
    assert filled_classes(only_u)["uniformity"] == np.flatnonzero(t.empty & ~only_u.empty).tolist()


@pytest.mark.parametrize("bad", [-1.0, float("nan"), "smooth"])
def test_bad_spline_strength(bad):
    with pytest.raises(ConfigError, match="spline strength"):
        smooth_table(plausible_table(), spline_strength=bad)


def test_auto_strength_runs_and_is_recorded():
    s = smooth_table(plausible_table(seed=12), spline_strength="auto")
    assert s.provenance["smoothing"]["spline"]["strength"].startswith("auto")
    assert s.provenance["smoothing"]["spline"]["lambda_median"] > 0


def test_empty_middle_levels_are_filled_and_render_like_the_truth():
    """A table trained only at low and high levels: smoothing interpolates the middle."""
    from l3cli.render import render_mosaic
    from l3cli.train.fit import fallback_sources

    t = plausible_table("RGGB", seed=13, empty_fraction=0.0, noise=0.0)
    d = t.definition
    x = level_abscissa(d)
    ng, ns, nl, nc = d.shape
    k = t.kernels.reshape(ng, ns, nl, nc, d.n_coeffs, 3).astype(np.float64)
    k = k * (1.0 + 0.1 * (x - x[0]))[None, None, :, None, None, None]  # linear in ln level
    k[..., -1, :] = 0.01 * (x - x[0])[None, None, :, None, None]
    truth = TransformTable(definition=d, kernels=k.reshape(t.kernels.shape),
                           counts=t.counts, lambdas=t.lambdas, empty=t.empty,
                           source_class=t.source_class)
    lev = np.asarray(d.class_tuple(np.arange(d.n_classes))[2])
    empty = (lev >= 3) & (lev <= 6)
    src = fallback_sources(d, ~empty)
    holey = TransformTable(definition=d, kernels=truth.kernels[src], counts=np.where(
        empty, 0, t.counts), lambdas=t.lambdas, empty=empty, source_class=src)
    s = smooth_table(holey, symmetry=False, uniformity=False)
    assert not s.empty.any()
    assert set(filled_classes(s)["spline"]) == set(np.flatnonzero(empty).tolist())
    np.testing.assert_allclose(s.kernels, truth.kernels, atol=2e-6)
    m = flat_field(d.cfa, {"R": 0.05, "G": 0.07, "B": 0.04})
    m = m * (1 + 0.2 * np.random.default_rng(0).random(m.shape)).astype(np.float32)
    np.testing.assert_allclose(render_mosaic(s, m), render_mosaic(truth, m), atol=1e-5)
    assert np.abs(render_mosaic(holey, m) - render_mosaic(truth, m)).max() > 1e-3


# ------------------------------------------------------------------------ CLI
def test_cli_smooth(tmp_path, runner):
    from l3cli.cli.main import cli

    src = save_table(tmp_path / "t.npz", plausible_table(seed=14))
    r = runner.invoke(cli, ["smooth", str(src), "-o", str(tmp_path / "s.npz")])
    assert r.exit_code == 0, r.output
    s = load_table(tmp_path / "s.npz")
    assert s.provenance["smoothing"]["priors"] == ["symmetry", "spline", "uniformity"]
    assert s.provenance["smoothing"]["input"] == str(src)
    r = runner.invoke(cli, ["smooth", str(src), "-o", str(tmp_path / "n.npz"), "--no-symmetry",
                            "--no-uniformity", "--spline-strength", "2"])
    assert r.exit_code == 0, r.output
    rec = load_table(tmp_path / "n.npz").provenance["smoothing"]
    assert rec["priors"] == ["spline"] and rec["spline"]["strength"] == 2.0
    r = runner.invoke(cli, ["smooth", str(src), "-o", str(tmp_path / "l.npz"),
                            "--uniformity-target", "least-squares"])
    assert r.exit_code == 0, r.output
    rec = load_table(tmp_path / "l.npz").provenance["smoothing"]
    assert rec["uniformity"]["target"] == "least-squares" and rec["spline"]["strength"] == 0.02
    r = runner.invoke(cli, ["smooth", str(src), "-o", str(tmp_path / "a.npz"),
                            "--spline-strength", "auto"])
    assert r.exit_code == 0, r.output


def test_cli_smooth_errors(tmp_path, runner):
    from l3cli.cli.main import cli

    src = save_table(tmp_path / "t.npz", plausible_table(seed=15))
    r = runner.invoke(cli, ["smooth", str(src), "-o", str(tmp_path / "s.npz"),
                            "--spline-strength", "-3"])
    assert r.exit_code == 2 and "--spline-strength" in r.output
    r = runner.invoke(cli, ["smooth", str(tmp_path / "missing.npz"), "-o",
                            str(tmp_path / "s.npz")])
    assert r.exit_code == 1 and "missing.npz" in r.output and "Error" in r.output
    (tmp_path / "junk.npz").write_text("not a table")
    r = runner.invoke(cli, ["smooth", str(tmp_path / "junk.npz"), "-o", str(tmp_path / "s.npz")])
    assert r.exit_code == 1 and "junk.npz" in r.output
    assert not (tmp_path / "s.npz").exists()


# ------------------------------------------------- end to end (simulate, train)
BAYER = "sample_configs/bayer.toml"


def _run(runner, args):
    from l3cli.cli.main import cli

    r = runner.invoke(cli, ["-q", *args])
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def scarce(tmp_path_factory):
    """One small natural image at five light levels (training), and a Macbeth chart
    at two other light levels (held out)."""
    from click.testing import CliRunner

    from tests.builders import REPO

    runner = CliRunner()
    root = tmp_path_factory.mktemp("scarce")
    cam = str(REPO / BAYER)
    _run(runner, ["simulate", cam, "-o", str(root / "train"), "--scene", "natural:astronaut",
                  "--size", "96x72", "--seed", "1",
                  *[a for lux in (3, 10, 30, 100, 300) for a in ("--lux", str(lux))]])
    _run(runner, ["simulate", cam, "-o", str(root / "held"), "--scene", "macbeth",
                  "--size", "240x160", "--seed", "2", "--lux", "20", "--lux", "200"])
    _run(runner, ["train", str(root / "train"), "-o", str(root / "raw.npz"), *LAYOUT])
    _run(runner, ["smooth", str(root / "raw.npz"), "-o", str(root / "smooth.npz")])
    return root


def _macbeth_de(runner, root, table, held, name):
    import json as _json

    out = root / f"render_{name}"
    _run(runner, ["render", str(table), *sorted(str(p) for p in held.glob("*.dng")),
                  "-o", str(out)])
    _run(runner, ["evaluate", str(out), "--reference", str(held), "--json",
                  str(root / f"{name}.json")])
    rep = _json.loads((root / f"{name}.json").read_text())
    return rep["summary"]["macbeth_de_mean"]


def _flat_values(held):
    """Per-channel raw values of a uniform grey surface: the noise-free response inside
    the chart's grey patches (a uniform spectral scene seen by the camera)."""
    import json as _json

    from l3cli.cfa import CFA
    from l3cli.io.image import read_image

    man = _json.loads((held / "manifest.json").read_text())
    cap = man["captures"][-1]
    cfa = CFA.from_spec(man["camera"]["cfa"])
    nf = read_image(held / cap["noise_free"])[0][..., 0]
    cmap = cfa.channel_map(*nf.shape)
    out = []
    for k in range(19, 24):  # the neutral row, light to dark
        x0, y0, x1, y1 = cap["chart"]["patches"][k]
        box = (slice(y0 + 6, y1 - 6), slice(x0 + 6, x1 - 6))
        out.append({c: float(nf[box][cmap[box] == i].mean()) for i, c in enumerate(cfa.channels)})
    return cfa, out


def test_trained_table_renders_a_flat_field_uniform_after_smoothing(scarce):
    from l3cli.render import render_mosaic
    from l3cli.table import load_table

    raw, sm = load_table(scarce / "raw.npz"), load_table(scarce / "smooth.npz")
    cfa, greys = _flat_values(scarce / "held")
    worst_raw = 0.0
    for vals in greys:
        for f in (0.25, 1.0, 1.5):
            v = {c: f * x for c, x in vals.items()}
            if max(v.values()) >= 0.9 * sm.definition.saturation_threshold:
                continue
            m = flat_field(cfa, v, h=48, w=52)
            spread = _rel_spread(render_mosaic(sm, m), border=sm.patch)
            assert spread.max() < 1e-3, (v, spread)
            worst_raw = max(worst_raw, float(_rel_spread(render_mosaic(raw, m), 5).max()))
    assert worst_raw > 1e-3  # the trained table alone is not uniform


def test_scarce_data_smoothing_lowers_macbeth_error(scarce):
    from click.testing import CliRunner

    runner = CliRunner()
    de_raw = _macbeth_de(runner, scarce, scarce / "raw.npz", scarce / "held", "raw")
    de_sm = _macbeth_de(runner, scarce, scarce / "smooth.npz", scarce / "held", "smooth")
    print(f"scarce data: mean Macbeth dE*ab raw {de_raw:.3f}, smoothed {de_sm:.3f}")
    assert de_sm < de_raw


def test_empty_classes_render_without_holes_and_inspect_lists_them(scarce):
    from click.testing import CliRunner

    from l3cli.classify import classify
    from l3cli.io.raw import read_raw
    from l3cli.render import render_raw
    from l3cli.table import load_table

    raw, sm = load_table(scarce / "raw.npz"), load_table(scarce / "smooth.npz")
    assert raw.empty.any()
    filled = np.flatnonzero(raw.empty & ~sm.empty)
    assert filled.size
    used_filled = set()
    for p in sorted((scarce / "held").glob("*.dng")):
        r = read_raw(p)
        cls = classify(r.mosaic, sm.definition)
        used_filled |= set(np.intersect1d(cls, filled).tolist())
        img = render_raw(sm, r)
        assert np.isfinite(img).all()
        # no holes: no black pixels where the raw image is not black
        lum = img[..., 1]
        assert (lum[r.mosaic > 0.01] > 0).all()
    assert used_filled  # the chart really uses classes that had no trained kernel
    runner = CliRunner()
    from l3cli.cli.main import cli

    res = runner.invoke(cli, ["inspect", str(scarce / "smooth.npz")])
    assert res.exit_code == 0, res.output
    assert "filled classes (by prior):" in res.output
    # the lines "  <prior>: <count> [<ranges>]" under that heading name exactly the
    # classes that were empty before and are not after
    listed: set[int] = set()
    section = res.output.split("filled classes (by prior):")[1].splitlines()[1:]
    for line in section:
        if not line.startswith("  "):
            break
        prior, rest = line.strip().split(": ", 1)
        assert prior in ("symmetry", "spline", "uniformity"), line
        count, ranges = rest.split(" ", 1)
        got = set()
        for part in ranges.strip("[]").split(", "):
            lo, _, hi = part.partition("-")
            got |= set(range(int(lo), int(hi or lo) + 1))
        assert len(got) == int(count) and not got & listed, line
        listed |= got
    assert listed == set(filled.tolist())


def test_plentiful_data_smoothing_costs_at_most_two_percent(tmp_path):
    from click.testing import CliRunner

    from tests.builders import REPO

    runner = CliRunner()
    cam = str(REPO / BAYER)
    _run(runner, ["simulate", cam, "-o", str(tmp_path / "train"), "--scene", "natural",
                  "--scene", "macbeth", "--size", "240x160", "--seed", "3",
                  *[a for lux in (3, 30, 300) for a in ("--lux", str(lux))]])
    _run(runner, ["simulate", cam, "-o", str(tmp_path / "held"), "--scene", "macbeth",
                  "--size", "240x160", "--seed", "4", "--lux", "20", "--lux", "200"])
    _run(runner, ["train", str(tmp_path / "train"), "-o", str(tmp_path / "raw.npz"), *LAYOUT])
    _run(runner, ["smooth", str(tmp_path / "raw.npz"), "-o", str(tmp_path / "smooth.npz")])
    de_raw = _macbeth_de(runner, tmp_path, tmp_path / "raw.npz", tmp_path / "held", "raw")
    de_sm = _macbeth_de(runner, tmp_path, tmp_path / "smooth.npz", tmp_path / "held", "smooth")
    print(f"plentiful data: mean Macbeth dE*ab raw {de_raw:.3f}, smoothed {de_sm:.3f}")
    assert de_sm <= 1.02 * de_raw


def test_rgbw_trained_table_renders_a_flat_field_uniform_after_smoothing(tmp_path):
    """The same on the 4x4 interleaved RGBW camera (TIFF mosaics, W/R see near IR)."""
    from click.testing import CliRunner

    from l3cli.render import render_mosaic
    from l3cli.table import load_table
    from tests.builders import REPO

    runner = CliRunner()
    cam = str(REPO / "sample_configs/rgbw-4x4.toml")
    _run(runner, ["simulate", cam, "-o", str(tmp_path / "train"), "--scene", "natural:astronaut",
                  "--size", "96x72", "--seed", "1", "--lux", "10", "--lux", "100"])
    _run(runner, ["simulate", cam, "-o", str(tmp_path / "held"), "--scene", "macbeth",
                  "--size", "240x160", "--seed", "2", "--lux", "50"])
    _run(runner, ["train", str(tmp_path / "train"), "-o", str(tmp_path / "raw.npz"), *LAYOUT])
    _run(runner, ["smooth", str(tmp_path / "raw.npz"), "-o", str(tmp_path / "smooth.npz")])
    sm = load_table(tmp_path / "smooth.npz")
    cfa, greys = _flat_values(tmp_path / "held")
    assert cfa.spec == sm.cfa.spec and cfa.n_positions == 16
    assert any(len(o) > 1 for o in sm.provenance["smoothing"]["symmetry"]["orbits"])
    for vals in greys:
        if max(vals.values()) >= 0.9 * sm.definition.saturation_threshold:
            continue
        m = flat_field(cfa, vals, h=48, w=52)
        assert _rel_spread(render_mosaic(sm, m), border=sm.patch).max() < 1e-3, vals


def test_uniformity_leaves_channels_missing_from_tiny_patches_alone():
    t = plausible_table("RGGB", patch=1, seed=18, empty_fraction=0.0)
    s = smooth_table(t, symmetry=False, spline=False)
    assert s.provenance["smoothing"]["uniformity"]["channels_left_alone"] == ["R", "G", "B"]
    np.testing.assert_array_equal(s.kernels[:, 0], t.kernels[:, 0])  # weights untouched
    b = s.kernels[:, -1].reshape(t.definition.n_groups, -1, 3)  # G sites share a group
    np.testing.assert_allclose(b, np.broadcast_to(b[:1], b.shape), atol=1e-7)  # offsets agree
    full = plausible_table(RGBW, patch=5, seed=19)
    assert smooth_table(full).provenance["smoothing"]["uniformity"]["channels_left_alone"] == []
