"""A raw's gains folded into the tile kernel's band copy (:mod:`l3cli.lens.gainmaps`, issue 40).

A DNG's GainMap opcodes, a table's learned lens shading and its white balance
are applied by the tile kernel as it copies each tile's band, not as passes
over the mosaic. The references here are independent of that code:

* the DNG GainMap as the DNG specification defines it, written out with
  scipy's ``RegularGridInterpolator`` (bilinear on the map's grid at the
  pixel centre relative to the whole image, clamped at the grid's edges,
  clipped at 1 after each map), in float64;
* the lens-shading field as its polynomial in r² evaluated by numpy's
  ``polyval`` on coordinates computed here, with the clipping rules of
  ``docs/training.md``; the white balance as gains per channel.

Bounds: the kernel computes in float32 what the reference computes in
float64. Each of the three stages rounds its gain and its product once
(2 x 2^-24 relative each), so a pixel is within 6 x 2^-24 ≈ 3.6e-7 relative of
the reference: 1e-6 relative is the bound used. A render whose kernels are
the same for every class cannot move by a class flip, so it is within the
kernel's sum of absolute taps times that bound of the render of the
corrected mosaic.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from l3cli.classify import ClassDefinition
from l3cli.io.dng_opcodes import GainMap, encode_gain_maps
from l3cli.io.raw import read_raw
from l3cli.kernelset import KernelSet, prepare_kernels
from l3cli.lens.field import GainField
from l3cli.lens.gainmaps import apply_dng_gains, apply_maps
from l3cli.render import render_file, render_mosaic
from l3cli.table import TransformTable
from l3cli.whitebalance.model import WhiteBalanceModel
from tests.dngmake import make_dng, phone_gain_maps

H, W = 48, 72
SAT = 0.95


def _dn(seed=3):
    rng = np.random.default_rng(seed)
    dn = rng.integers(64, 4096, (H, W)).astype(np.uint16)
    dn[5:9, 10:30] = 4095  # above the white level (4000): values > 1, clipping rules
    dn[20:24, 40:60] = 3900  # just under it
    return dn


def _dng(tmp_path, name, *, list2=None, list3=None, seed=3):
    return make_dng(tmp_path / name, _dn(seed), black=64, white=4000,
                    opcode_list2=None if list2 is None else encode_gain_maps(list2),
                    opcode_list3=None if list3 is None else encode_gain_maps(list3))


def _table(kernel: np.ndarray | None = None, *, patch=5, wb=False, field=None, **features):
    """A table whose classes all hold the same kernel (default: the centre tap, so the
    render is the mosaic the classes see, on each output)."""
    d = ClassDefinition.build("RGGB", patch=patch, level_cuts=[0.02, 0.08, 0.3],
                              contrast_cuts=0.2, saturation_threshold=SAT, **features)
    nc, q = d.n_classes, d.n_coeffs
    if kernel is None:
        kernel = np.zeros((q, 3), np.float32)
        kernel[(patch // 2) * patch + patch // 2, :] = 1.0
    k = np.broadcast_to(kernel.astype(np.float32), (nc, q, 3)).copy()
    t = TransformTable(definition=d, kernels=k, counts=np.full(nc, 500),
                       lambdas=np.full((nc, 3), 1e-3), empty=np.zeros(nc, bool),
                       source_class=np.arange(nc), output_space="linear-srgb")
    if wb:  # one training white: the gains only, no adaptation
        t.white_balance = WhiteBalanceModel("linear-srgb", [], [np.eye(3).ravel()],
                                            [[2.0, 1.0, 1.5]]).as_dict()
    t.shading = field
    return t


# ------------------------------------------------------------ the references
def _ref_dng(m: np.ndarray, maps, planes=None) -> np.ndarray:
    """The DNG GainMap opcode, by the specification (float64)."""
    from scipy.interpolate import RegularGridInterpolator

    m = m.astype(np.float64).copy()
    h, w = m.shape
    for gm in maps:
        ys = np.arange(gm.top, min(gm.bottom, h), gm.row_pitch)
        xs = np.arange(gm.left, min(gm.right, w), gm.col_pitch)
        gv = gm.origin_v + gm.spacing_v * np.arange(gm.points_v)
        gh = gm.origin_h + gm.spacing_h * np.arange(gm.points_h)
        pv = np.clip((ys + 0.5) / h, gv[0], gv[-1])
        ph = np.clip((xs + 0.5) / w, gh[0], gh[-1])
        pts = np.stack(np.meshgrid(pv, ph, indexing="ij"), axis=-1)
        for plane in range(gm.plane, gm.plane + gm.planes):
            f = RegularGridInterpolator(
                (gv, gh), gm.gains[:, :, min(plane, gm.map_planes - 1)].astype(np.float64))
            g = f(pts)
            block = m[np.ix_(ys, xs)]
            sel = np.ones(block.shape, bool) if planes is None else (
                planes[np.ix_(ys, xs)] == plane)
            if planes is None and plane != 0:
                continue
            m[np.ix_(ys, xs)] = np.where(sel, np.minimum(block * g, 1.0), block)
    return m


def _ref_field(m: np.ndarray, field: GainField) -> np.ndarray:
    h, w = m.shape
    half = 0.5 * np.hypot(h, w)
    v = (np.arange(h) + 0.5 - h / 2) / half - field.centre[0]
    u = (np.arange(w) + 0.5 - w / 2) / half - field.centre[1]
    r2 = v[:, None] ** 2 + u[None, :] ** 2
    pos = (np.arange(h)[:, None] % 2) * 2 + np.arange(w)[None, :] % 2
    g = np.empty_like(m)
    for p in range(4):
        g[pos == p] = np.polynomial.polynomial.polyval(r2[pos == p], field.coeffs[p])
    if g.min() >= 1:
        return np.minimum(m * g, np.maximum(m, 1.0))
    return np.where((m < SAT) | (g >= 1), m * g, m)


def _ref_wb(m: np.ndarray, gains) -> np.ndarray:
    chan = np.array([[0, 1], [1, 2]])[np.arange(m.shape[0])[:, None] % 2,
                                       np.arange(m.shape[1])[None, :] % 2]
    g = np.asarray(gains, np.float64)[chan]
    return np.where((g > 1) | (m < SAT), m * g, m)


FIELDS = {
    "none": None,
    "gains >= 1": GainField([0.05, -0.03], [[1.0, 0.3, 0.1], [1.0, 0.25, 0.05],
                                            [1.0, 0.28, 0.0], [1.0, 0.4, 0.2]], (H, W)),
    "gains < 1 near the centre": GainField([0.0, 0.1], [[0.9, 0.4], [0.92, 0.3],
                                                         [0.95, 0.3], [0.88, 0.5]], (H, W)),
}


def _list3_maps():
    """OpcodeList3: one map of three colour planes, every pixel (pitch 1), 4x5 points."""
    rng = np.random.default_rng(11)
    g = (1.0 + 0.6 * rng.random((4, 5, 3))).astype(np.float32)
    return [GainMap(0, 0, H, W, 0, 3, 1, 1, 4, 5, 1 / 3, 0.25, 0.0, 0.0, g)]


@pytest.mark.parametrize("field", list(FIELDS))
@pytest.mark.parametrize("lists", ["list2", "list2+list3"])
@pytest.mark.parametrize("wb", [None, (0.8, 1.0, 1.6)])
def test_folded_gains_are_the_specification(tmp_path, field, lists, wb):
    """Centre-tap kernels render the mosaic the classes see: the kernel's band copy with
    the gains folded in equals the DNG GainMap, the field and the white balance written
    out independently, to 1e-6 relative (float32 rounding, see the module notes)."""
    maps2 = phone_gain_maps(H, W, points=(5, 7))
    maps3 = _list3_maps() if "list3" in lists else None
    path = _dng(tmp_path, "gm.dng", list2=maps2, list3=maps3)
    raw = read_raw(path)
    plain = read_raw(_dng(tmp_path, "plain.dng"))
    np.testing.assert_array_equal(raw.mosaic, plain.mosaic)  # read: not applied yet
    assert raw.gain_maps is not None
    t = _table(wb=True, field=FIELDS[field])
    wb_gains = None if wb is None else np.array(wb)
    ks = prepare_kernels(t, raw, white_balance=wb_gains)
    assert ks.folded
    mosaic = ks.prepare_mosaic(raw.mosaic)
    assert mosaic is raw.mosaic  # no pass over the mosaic
    got = render_mosaic(ks, mosaic)

    want = _ref_dng(plain.mosaic, maps2)
    if maps3 is not None:
        want = _ref_dng(want, maps3, planes=np.array([[0, 1], [1, 2]])[
            np.arange(H)[:, None] % 2, np.arange(W)[None, :] % 2])
    if FIELDS[field] is not None:
        want = _ref_field(want, FIELDS[field])
    want = _ref_wb(want, wb_gains if wb is not None else 1 / np.array([0.5, 1.0, 0.7]))
    assert np.abs(want - plain.mosaic).max() > 0.05  # the gains do something
    for c in range(3):
        np.testing.assert_allclose(got[:, :, c], want, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(raw.mosaic, plain.mosaic)  # the raw is not changed


def test_fold_equals_the_gains_applied_first(tmp_path):
    """A 5x5 kernel (the same in every class) sees mirrored neighbours with their gains:
    the folded render equals the render of the mosaic corrected first (numpy passes) by a
    plain kernel set, within sum |taps| x 1e-6."""
    rng = np.random.default_rng(5)
    kernel = np.abs(rng.normal(size=(26, 3))).astype(np.float32) / 10
    t = _table(kernel, wb=True, field=FIELDS["gains >= 1"])
    raw = read_raw(_dng(tmp_path, "gm.dng", list2=phone_gain_maps(H, W, points=(5, 7))))
    ks = prepare_kernels(t, raw)
    corrected = ks.corrected_mosaic(raw.mosaic)
    assert not np.array_equal(corrected, raw.mosaic)
    plain = KernelSet.plain(t)
    want = render_mosaic(plain, corrected)
    got = render_mosaic(ks, ks.prepare_mosaic(raw.mosaic))
    np.testing.assert_allclose(got, want, rtol=0, atol=float(np.abs(kernel).sum(0).max()) * 1e-6)
    for rows in ((0, 7), (13, 40)):  # bands of rows: the gains follow the image rows
        part = render_mosaic(ks, raw.mosaic, rows=rows)
        np.testing.assert_array_equal(part, got[rows[0]:rows[1]])


def test_maps_of_different_vertical_grids_fold_as_the_specification(tmp_path):
    """A raw three tiles tall whose per-position maps have different vertical grids
    (points, origin, spacing; two of them on the same row phase): each tile's band is
    interpolated between the grid rows its rows lie between, so the folded render equals
    the DNG GainMap written out independently, to 1e-6 relative."""
    h, w = 150, 72
    rng = np.random.default_rng(9)
    dn = rng.integers(64, 4000, (h, w)).astype(np.uint16)
    maps = []
    for (top, left), (pv, p_h, ov) in zip([(0, 0), (0, 1), (1, 0), (1, 1)],
                                         [(9, 5, 0.0), (4, 5, 0.1), (2, 3, 0.0), (6, 7, -0.05)],
                                         strict=True):
        g = (1.0 + 0.8 * rng.random((pv, p_h, 1))).astype(np.float32)
        maps.append(GainMap(top, left, h, w, 0, 1, 2, 2, pv, p_h, 0.9 / (pv - 1),
                            1 / (p_h - 1), ov, 0.0, g))
    path = make_dng(tmp_path / "gm.dng", dn, black=64, white=4000,
                    opcode_list2=encode_gain_maps(maps))
    raw = read_raw(path)
    plain = read_raw(make_dng(tmp_path / "plain.dng", dn, black=64, white=4000))
    ks = prepare_kernels(_table(), raw)
    assert ks.folded
    got = render_mosaic(ks, ks.prepare_mosaic(raw.mosaic))
    want = _ref_dng(plain.mosaic, maps)
    assert np.abs(want - plain.mosaic).max() > 0.05
    np.testing.assert_allclose(got[:, :, 1], want, rtol=1e-6, atol=1e-7)


def test_unusual_maps_and_context_tables_take_the_mosaic_pass(tmp_path):
    """A map the kernel cannot fold (every third row; a part of the image) and a table
    with a context guide (its block means read the corrected mosaic) multiply the mosaic
    first, with the same result."""
    g = np.linspace(1.2, 1.6, 12, dtype=np.float32).reshape(3, 4, 1)
    odd = [GainMap(0, 0, H, W, 0, 1, 3, 1, 3, 4, 0.5, 1 / 3, 0.0, 0.0, g),
           GainMap(4, 6, 30, 50, 0, 1, 1, 1, 3, 4, 0.5, 1 / 3, 0.0, 0.0, g)]
    raw = read_raw(_dng(tmp_path, "odd.dng", list2=odd))
    plain = read_raw(_dng(tmp_path, "plain.dng"))
    t = _table()
    ks = prepare_kernels(t, raw)
    assert not ks.folded
    got = render_mosaic(ks, ks.prepare_mosaic(raw.mosaic))[:, :, 0]
    np.testing.assert_allclose(got, _ref_dng(plain.mosaic, odd), rtol=1e-6, atol=1e-7)
    raw = read_raw(_dng(tmp_path, "gm.dng", list2=phone_gain_maps(H, W, points=(5, 7))))
    tc = _table(context_block=16, context_cuts=np.array([0.1, 0.3]))
    ks = prepare_kernels(tc, raw)
    assert ks.gains is not None and not ks.folded
    got = render_mosaic(ks, ks.prepare_mosaic(raw.mosaic))[:, :, 0]
    want = _ref_dng(plain.mosaic, phone_gain_maps(H, W, points=(5, 7)))
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)


def test_read_raw_parses_and_the_model_applies(tmp_path):
    """``read_raw`` leaves the maps pending; :func:`apply_dng_gains` applies them once (the
    specification's values) and a crop of a raw with pending maps is refused."""
    maps = phone_gain_maps(H, W, points=(5, 7))
    raw = read_raw(_dng(tmp_path, "gm.dng", list2=maps))
    plain = read_raw(_dng(tmp_path, "plain.dng"))
    assert raw.metadata["gain_maps"] == {"OpcodeList2": 4, "OpcodeList3": 0}
    with pytest.raises(ValueError, match="apply the DNG gain maps before cropping"):
        raw.crop(0, 0, 8, 8)
    assert apply_dng_gains(raw) is raw and raw.gain_maps is None
    np.testing.assert_allclose(raw.mosaic, _ref_dng(plain.mosaic, maps), rtol=1e-6, atol=1e-7)
    again = raw.mosaic.copy()
    apply_dng_gains(raw)
    np.testing.assert_array_equal(raw.mosaic, again)  # corrected once
    # a raw whose maps are applied renders as one whose maps are folded
    t = _table()
    folded = read_raw(_dng(tmp_path, "gm.dng", list2=maps))
    np.testing.assert_allclose(render_mosaic(prepare_kernels(t, folded), folded.mosaic),
                               render_mosaic(prepare_kernels(t, raw), raw.mosaic),
                               rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(apply_maps(plain.mosaic.copy(), []), plain.mosaic)


def test_file_render_folds_the_dng_gains(tmp_path):
    """``l3 render``'s path (pipeline.render_one) folds the maps and the field: its EXR is
    the reference, and the decoded raw is not multiplied before the kernel."""
    from l3cli.io.image import read_image

    maps = phone_gain_maps(H, W, points=(5, 7))
    field = FIELDS["gains >= 1"]
    path = _dng(tmp_path, "gm.dng", list2=maps)
    plain = read_raw(_dng(tmp_path, "plain.dng"))
    t = dataclasses.replace(_table(field=field))
    got, _ = read_image(render_file(t, path, tmp_path / "gm.exr"))
    want = _ref_field(_ref_dng(plain.mosaic, maps), field)
    np.testing.assert_allclose(got[:, :, 1], want, rtol=1e-6, atol=1e-7)


def test_shading_pass_in_place_clips_as_a_copy():
    """``correct_mosaic`` in place (``l3 render``'s old path) keeps the rule that a
    corrected pixel is not lifted above max(pixel, 1): it used to compare with the
    product it had just written, and left brightened pixels unclipped."""
    from l3cli.cfa import CFA
    from l3cli.lens.field import correct_mosaic

    m = np.random.default_rng(2).random((H, W), dtype=np.float32) * 1.1
    field = FIELDS["gains >= 1"]
    copy = correct_mosaic(m, field, CFA.from_spec("RGGB"), SAT)
    assert copy.max() <= max(1.0, float(m.max()))
    np.testing.assert_allclose(copy, _ref_field(m.astype(np.float64), field), rtol=1e-6)
    inplace = correct_mosaic(m, field, CFA.from_spec("RGGB"), SAT, out=m)
    assert inplace is m
    np.testing.assert_array_equal(inplace, copy)


@pytest.mark.parametrize("field", ["gains >= 1", "gains < 1 near the centre"])
def test_field_on_a_crop_is_placed_on_its_full_raw(tmp_path, field):
    """A cropped raw (``metadata`` crop and full size, odd offsets: the CFA phase moves)
    takes the field of its window of the full raw: the folded render equals the
    reference computed on the full raw, then cropped."""
    plain = read_raw(_dng(tmp_path, "plain.dng"))
    want = _ref_field(plain.mosaic.astype(np.float64), FIELDS[field])[5:5 + 30, 3:3 + 40]
    crop = plain.crop(5, 3, 30, 40)
    t = _table(field=FIELDS[field])
    t = dataclasses.replace(t, definition=ClassDefinition.build(
        crop.cfa, patch=5, level_cuts=[0.02, 0.08, 0.3], contrast_cuts=0.2,
        saturation_threshold=SAT))
    ks = prepare_kernels(t, crop)
    assert ks.folded
    got = render_mosaic(ks, ks.prepare_mosaic(np.ascontiguousarray(crop.mosaic)))[:, :, 0]
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("lift", [True, False])
def test_spline_field_folds_as_its_pass(tmp_path, lift):
    """A spline-grid field (l3cli.lens.grid) is folded into the band copy as its gain
    map: a 5x5 kernel (the same in every class) renders a GainMap DNG, and a crop of a
    plain one (placed on its full raw), as the mosaic corrected first by the passes (DNG
    maps, the field's correct_mosaic, white balance) through a plain kernel set, within
    sum |taps| x 1e-6, for both of the field's clipping rules (every gain >= 1; some
    below 1)."""
    from l3cli.lens.grid import SplineField

    rng = np.random.default_rng(4)
    kernel = np.abs(rng.normal(size=(26, 3))).astype(np.float32) / 10
    grid = 1 + 0.5 * rng.random((4, 5, 6)) if lift else 0.7 + 0.6 * rng.random((4, 5, 6))
    t = _table(kernel, wb=True)
    t.shading = SplineField(grid, (H, W))
    gm = read_raw(_dng(tmp_path, "gm.dng", list2=phone_gain_maps(H, W, points=(5, 7))))
    crop = read_raw(_dng(tmp_path, "plain.dng")).crop(2, 4, H - 6, W - 10)
    for raw in (gm, crop):
        ks = prepare_kernels(t, raw)
        assert ks.folded and ks.gains.field is t.shading
        assert ks.gains.kernel_args()[11] == lift  # which of the field's rules it takes
        mosaic = np.ascontiguousarray(raw.mosaic)
        want = render_mosaic(KernelSet.plain(t), ks.corrected_mosaic(mosaic))
        got = render_mosaic(ks, ks.prepare_mosaic(mosaic))
        np.testing.assert_allclose(got, want, rtol=0,
                                   atol=float(np.abs(kernel).sum(0).max()) * 1e-6)
