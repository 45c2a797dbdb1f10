"""The shared classifier: padding, features and classes against a numpy reference."""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.cfa import CFA
from l3cli.classify import (
    ClassDefinition,
    ContrastHistogram,
    classify,
    level_cuts_between,
    level_lookup,
    mirror_indices,
    pad_mosaic,
    patch_features,
    position_groups,
)
from l3cli.errors import ConfigError, InputError
from tests.l3ref import classify_reference, features_reference, pad_reference

CFAS = ["RGGB", "GRBG", "RGBW/GWRB/BRWG/WBGR", "R G/NIR B"]


@pytest.mark.parametrize("n,r,period", [(10, 2, 2), (10, 3, 2), (17, 4, 4), (9, 6, 3), (6, 4, 3)])
def test_mirror_keeps_phase(n, r, period):
    idx = mirror_indices(n, r, period)
    assert idx.shape == (n + 2 * r,)
    assert np.all((idx >= 0) & (idx < n))
    np.testing.assert_array_equal(idx % period, np.arange(-r, n + r) % period)
    np.testing.assert_array_equal(idx[r : r + n], np.arange(n))


def test_mirror_is_numpy_reflect_for_period_two():
    idx = mirror_indices(12, 4, 2)
    np.testing.assert_array_equal(idx, np.pad(np.arange(12), 4, mode="reflect"))


@pytest.mark.parametrize("spec", CFAS)
def test_padding_matches_reference(spec):
    cfa = CFA.from_spec(spec)
    rng = np.random.default_rng(1)
    m = rng.random((13, 18)).astype(np.float32)
    np.testing.assert_array_equal(pad_mosaic(m, 3, cfa.period), pad_reference(m, 3, cfa))
    band = pad_mosaic(m, 3, cfa.period, rows=(4, 9))
    np.testing.assert_array_equal(band, pad_reference(m, 3, cfa)[4 : 9 + 6])


@pytest.mark.parametrize(("spec", "patch"), [
    (spec, patch) for spec in CFAS for patch in (3, 5)
    # each (patch, CFA period width) is a kernel compile of its own (10-20 s on a fresh
    # machine): the 4-wide CFA at patch 5 only
    if not (patch == 3 and CFA.from_spec(spec).period[1] == 4)])
def test_features_match_reference(spec, patch):
    cfa = CFA.from_spec(spec)
    rng = np.random.default_rng(2)
    m = (rng.random((15, 21)) ** 2).astype(np.float32)
    lev, con, sat = patch_features(m, cfa, patch=patch, saturation_threshold=0.9)
    rlev, rcon, rsat, _ = features_reference(m, cfa, patch, 0.9, 1e-4)
    # the kernel works in float32 (the reference in float64): the level to a few
    # ulps; the contrast to ~1e-4 (E[x²] - m² cancels where a channel is nearly flat)
    np.testing.assert_allclose(lev, rlev, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(con, rcon, rtol=1e-4, atol=5e-4)
    np.testing.assert_array_equal(sat, rsat)


def test_level_of_flat_patch_is_its_value_and_contrast_zero():
    cfa = CFA.from_spec("RGGB")
    m = np.full((12, 12), 0.3, dtype=np.float32)
    lev, con, sat = patch_features(m, cfa)
    np.testing.assert_allclose(lev, 0.3, rtol=1e-6)
    # float32 E[x²] - m² leaves a rounding floor: sd ~ 1e-4 of the level at most
    np.testing.assert_allclose(con, 0.0, atol=1e-3)
    assert not sat.any()


def test_level_is_mean_of_channel_means_not_pixel_mean():
    # Bayer planes: R = 0.1, G = 0.4, B = 0.7 -> mean of channel means = 0.4, while
    # the 5x5 pixel mean at an R site weights R 9/25, G 12/25, B 4/25.
    cfa = CFA.from_spec("RGGB")
    vals = np.array([0.1, 0.4, 0.7])
    m = vals[cfa.channel_map(10, 10)].astype(np.float32)
    lev, con, _ = patch_features(m, cfa)
    np.testing.assert_allclose(lev, 0.4, rtol=1e-6)
    np.testing.assert_allclose(con, 0.0, atol=1e-3)  # colour is not texture (float32 floor)


def test_saturation_bits_per_channel():
    cfa = CFA.from_spec("RGGB")
    m = np.full((20, 20), 0.2, dtype=np.float32)
    m[10, 10] = 1.0  # an R pixel (even, even)
    _, _, sat = patch_features(m, cfa, saturation_threshold=0.95)
    r_bit = 1 << cfa.channels.index("R")
    assert sat[10, 10] == r_bit and sat[8, 8] == r_bit and sat[12, 12] == r_bit
    assert sat[7, 10] == 0 and sat[10, 13] == 0


@pytest.mark.parametrize("spec", CFAS)
def test_classes_match_reference(spec):
    cfa = CFA.from_spec(spec)
    rng = np.random.default_rng(3)
    m = (rng.random((19, 24)) ** 3).astype(np.float32)
    m[5, 5] = 1.0
    d = ClassDefinition.build(cfa, patch=5, level_cuts=level_cuts_between(0.01, 0.8, 12),
                              contrast_cuts=[0.2, 0.6], saturation_threshold=0.97)
    got = classify(m, d)
    want = classify_reference(m, d)
    # the kernel's float32 features may fall on the other side of a cut where the
    # float64 reference is within float32 rounding of it: only there may they differ
    rlev, rcon, _, _ = features_reference(m, cfa, 5, 0.97, d.contrast_eps)
    near = np.any(np.abs(rlev[..., None] - d.level_cuts) <= 1e-6 * d.level_cuts, axis=-1)
    near |= np.any(np.abs(rcon[..., None] - d.contrast_cuts[0]) <= 5e-4, axis=-1)
    np.testing.assert_array_equal(got[~near], want[~near])
    assert near.sum() <= 2
    assert got.min() >= 0 and got.max() < d.n_classes


@pytest.mark.parametrize("spacing,n", [("log", 40), ("linear", 40), ("log", 400), ("log", 2)])
def test_level_lookup_bins_like_searchsorted(spacing, n):
    cuts = level_cuts_between(1e-4, 0.95, n, spacing)
    d = ClassDefinition.build("RGGB", level_cuts=cuts)
    lut, shift, base, inside = level_lookup(d.level_cuts)
    c32 = cuts.astype(np.float32)
    rng = np.random.default_rng(7)
    v = np.concatenate([
        c32, np.nextafter(c32, np.float32(0)), np.nextafter(c32, np.float32(2)),
        np.exp(rng.uniform(np.log(1e-7), np.log(4.0), 20000)).astype(np.float32),
        np.array([0.0, -0.0, -1e-3, -5.0, 1e-38, 1.0, 3e38, np.inf], np.float32)]).astype(np.float32)
    k = np.clip((v.view(np.int32).astype(np.int64) >> shift) - base, 0, lut.size - 1)
    # as the kernel: cuts below the bucket + the bucket's cuts <= v (NaN where none)
    b = lut[k].astype(np.int64) + (inside[k, 0] <= v) + (inside[k, 1] <= v)
    np.testing.assert_array_equal(b, np.searchsorted(c32, v, side="right"))
    assert lut.size <= 4096


@pytest.mark.parametrize("spec", ["GRBG", "RGBW/GWRB/BRWG/WBGR"])
def test_class_depends_on_the_patch_only_not_on_tiles(spec):
    # a mosaic spanning several parallel tiles, and the same pixels inside a
    # larger mosaic at an offset (a multiple of the CFA period): same classes
    cfa = CFA.from_spec(spec)
    rng = np.random.default_rng(8)
    big = (rng.random((100, 1200)) ** 2).astype(np.float32)
    d = ClassDefinition.build(cfa, patch=5, level_cuts=level_cuts_between(0.01, 0.8, 20),
                              contrast_cuts=0.5)
    full = classify(big, d)
    oy, ox = 12, 4 * 67
    crop = classify(big[oy:oy + 70, ox:ox + 700], d)
    np.testing.assert_array_equal(crop[2:-2, 2:-2], full[oy + 2:oy + 68, ox + 2:ox + 698])
    rows = classify(big, d, rows=(33, 71))
    np.testing.assert_array_equal(rows, full[33:71])


def test_class_index_layout():
    d = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.1, 0.2], contrast_cuts=0.5)
    assert d.shape == (4, 8, 3, 2)
    assert d.n_classes == 4 * 8 * 3 * 2
    assert d.class_index(1, 2, 0, 1) == ((1 * 8 + 2) * 3 + 0) * 2 + 1
    assert tuple(int(v) for v in d.class_tuple(d.class_index(3, 7, 2, 1))) == (3, 7, 2, 1)


def test_equivalent_positions_merge():
    # horizontal stripes RGB/GBR... : build a CFA whose two rows are the same layout shifted
    cfa = CFA.from_spec("RG/RG")
    grp = position_groups(cfa, 5)
    assert grp.tolist() == [0, 1, 0, 1]
    assert position_groups(cfa, 5, merge=False).tolist() == [0, 1, 2, 3]
    bayer = position_groups(CFA.from_spec("RGGB"), 5)
    assert bayer.tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize("spec,n_pos", [("RGGB", 4), ("WGWR/BWGW/WRWG/GWBW", 16),
                                         ("RGBW/GWRB/BRWG/WBGR", 16)])
def test_position_is_the_place_in_the_cfa_repeat_and_equal_layouts_share(spec, n_pos):
    """Positions = the CFA repeat (Bayer 4, a 4x4 RGBW 16); positions share a group
    exactly when their 5x5 channel layouts coincide (found here from a tiled
    pattern, independently of CFA.neighbourhood)."""
    cfa = CFA.from_spec(spec)
    assert cfa.n_positions == n_pos
    ph, pw = cfa.period
    tiled = np.tile(np.array(cfa.pattern), (3, 3))
    lay = [tiled[ph + y - 2: ph + y + 3, pw + x - 2: pw + x + 3].tobytes()
           for y in range(ph) for x in range(pw)]
    grp = position_groups(cfa, 5)
    for a in range(n_pos):
        for b in range(n_pos):
            assert (grp[a] == grp[b]) == (lay[a] == lay[b]), (a, b)
    # the class of a pixel uses its position: same patch values, different positions
    # (other layouts) give different classes
    m = np.full((4 * ph, 4 * pw), 0.3, np.float32)
    d = ClassDefinition.build(cfa, patch=5, level_cuts=[0.1])
    g_map = np.asarray(d.class_tuple(classify(m, d))[0])
    np.testing.assert_array_equal(g_map, grp[cfa.position_map(*m.shape)])


def test_level_cuts():
    c = level_cuts_between(0.001, 0.9, 25)
    assert c.size == 24 and c[0] == pytest.approx(0.001) and c[-1] == pytest.approx(0.9)
    np.testing.assert_allclose(np.diff(np.log(c)), np.log(900) / 23)
    lin = level_cuts_between(0.1, 0.9, 5, "linear")
    np.testing.assert_allclose(lin, [0.1, 0.3666666, 0.6333333, 0.9], rtol=1e-6)
    with pytest.raises(ConfigError, match="spacing"):
        level_cuts_between(0.1, 0.9, 5, "cubic")


def test_histogram_places_cuts_in_data_and_median_contrast():
    cfa = CFA.from_spec("RGGB")
    rng = np.random.default_rng(4)
    base = np.exp(rng.uniform(np.log(0.01), np.log(0.5), (60, 80)))
    m = (base * (1 + 0.1 * rng.standard_normal((60, 80)))).astype(np.float32)
    h = ContrastHistogram.empty()
    h.add_mosaic(m, cfa, patch=5, saturation_threshold=0.95)
    h2 = ContrastHistogram.empty()
    h2.add_mosaic(m, cfa, patch=5, saturation_threshold=0.95)
    assert (h + h2).total == 2 * h.total == 2 * m.size
    lo, hi = h.level_range(low_quantile=0.0, high_quantile=1.0)
    lev, con, _ = patch_features(m, cfa)
    assert lo == pytest.approx(lev.min(), rel=0.03) and hi == pytest.approx(lev.max(), rel=0.03)
    cuts = level_cuts_between(lo, hi, 2)
    cc = h.contrast_cuts(cuts, 2)
    for b in range(2):
        sel = np.searchsorted(cuts, lev, side="right") == b
        assert cc[b, 0] == pytest.approx(np.median(con[sel]), rel=0.06)


def test_bad_definitions():
    with pytest.raises(ConfigError, match="patch size 4"):
        ClassDefinition.build("RGGB", patch=4, level_cuts=[0.1])
    with pytest.raises(ConfigError, match="increasing"):
        ClassDefinition.build("RGGB", level_cuts=[0.2, 0.1])
    with pytest.raises(ConfigError, match="must be > 0"):
        ClassDefinition.build("RGGB", level_cuts=[0.0, 0.1])
    with pytest.raises(InputError, match="too small"):
        classify(np.zeros((1, 1), np.float32), ClassDefinition.build("RGGB", level_cuts=[0.1]))


def test_kernel_tables_follow_the_kernel_arguments():
    """KernelTables, ContextGuide and the gains are the documented layouts of the tuples
    the kernel's entry points unpack, in their order; every entry point takes the same
    arguments but its outputs."""
    import inspect
    import re

    from l3cli.classify.features import ContextGuide
    from l3cli.classify.kernel import KernelTables, kernel_tables
    from l3cli.classify.tile_kernel import ENTRIES, tile_kernel
    from l3cli.lens.gainmaps import NO_GAINS

    src = inspect.getsource(tile_kernel)

    def unpacked(name: str) -> list[str]:
        m = re.search(r"^\s*\(?([\w,\s]+?)\)?\s*=\s*" + name + r"$", src, re.M)
        assert m is not None, name
        return [v.strip() for v in m.group(1).split(",")]

    assert unpacked("tables") == list(KernelTables._fields)
    assert len(unpacked("guide")) == len(ContextGuide._fields)
    assert len(unpacked("gains")) == len(NO_GAINS)
    for entry in ENTRIES:
        names = list(inspect.signature(tile_kernel(5, 2, entry).py_func).parameters)
        assert names == ["mosaic", "yi", "xi", "y0", "nrows", "tc", "tables", "guide",
                         "gains", "outs", "t_lo", "t_hi"]
    t = kernel_tables(ClassDefinition.build("RGGB", level_cuts=[0.01, 0.1]))
    assert t.n_sat == 8 and t.group.tolist() == [0, 1, 2, 3] and t.idx_pattern.shape == (2, 2)


def test_a_replaced_definition_builds_its_own_tables():
    """``dataclasses.replace`` (another patch, CFA phase or cuts) gives a definition whose
    kernel tables are its own: a copy that kept the cached tables of the original (built
    for patch 7) once sent the kernel out of its arrays."""
    import dataclasses

    d7 = ClassDefinition.build("RGGB", patch=7, level_cuts=[0.02, 0.1, 0.4], contrast_cuts=0.2)
    rng = np.random.default_rng(2)
    m = rng.uniform(0, 1, (40, 52)).astype(np.float32)
    classify(m, d7)  # caches its tables
    d5 = dataclasses.replace(d7, patch=5)
    fresh = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.02, 0.1, 0.4],
                                  contrast_cuts=0.2)
    np.testing.assert_array_equal(classify(m, d5), classify(m, fresh))
    assert d5._tables is not d7._tables
