"""``l3 export``: the ONNX graph renders as ``l3 render`` does.

Every check runs the exported model in ONNX Runtime (CPU) and compares it
with l3's own render of the same raw (:func:`l3cli.render.render_raw`, or the
display integers :func:`l3cli.io.encode.display_encode` makes of it): within
1e-5 for float output, one code value for display output. The classes are
compared directly too (they must be identical: one pixel in another class
would differ by far more than 1e-5 with these kernels).
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

from click.testing import CliRunner  # noqa: E402

from l3cli.cfa import CFA  # noqa: E402
from l3cli.classify import ClassDefinition, classify, mirror_indices  # noqa: E402
from l3cli.cli.main import cli  # noqa: E402
from l3cli.conditions import Conditioned  # noqa: E402
from l3cli.export import build_model  # noqa: E402
from l3cli.io.encode import display_encode  # noqa: E402
from l3cli.io.raw import RawImage, read_raw  # noqa: E402
from l3cli.render import render_raw  # noqa: E402
from l3cli.table import TransformTable, load_table, save_table  # noqa: E402
from l3cli.whitebalance.model import WhiteBalanceModel  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
FRAMES = REPO / "examples" / "infinite_isp" / "frames"
HOLDOUT = REPO / "examples" / "infinite_isp" / "holdout"
GAINS = [1.9, 1.0, 1.4]


def _session(model):
    return ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])


def _run(sess, mosaic, gains=None, condition=None):
    """The model's output for one (H, W) mosaic, as (H, W, C)."""
    feeds = {"mosaic": np.asarray(mosaic, np.float32)[None, None]}
    names = {i.name for i in sess.get_inputs()}
    if "wb_gains" in names:
        feeds["wb_gains"] = np.asarray([gains], np.float32)
    if "condition" in names:
        feeds["condition"] = np.array([condition if condition is not None else 0.0])
    if "frame" in names:
        feeds["frame"] = np.zeros(4, np.int64)  # the mosaic is the whole raw
    return sess.run(None, feeds)[0][0].transpose(1, 2, 0)


def _table(spec="RGGB", patch=5, space="linear-srgb", n_out=3, *, tone=False, wb=False,
           cond=False, seed=0, **features) -> TransformTable:
    """A table with random kernels (outputs over about [-0.3, 1.3]) and the given features."""
    features.setdefault("contrast_cuts", [0.1, 0.3])
    d = ClassDefinition.build(spec, patch=patch, level_cuts=np.geomspace(0.01, 0.6, 7),
                              **features)
    rng = np.random.default_rng(seed)
    nc, q = d.n_classes, d.n_coeffs
    k = (0.15 * rng.normal(size=(nc, q, n_out))).astype(np.float32)
    k[:, -1, :] += np.float32(0.4)
    t = TransformTable(definition=d, kernels=k, counts=np.full(nc, 100),
                       lambdas=np.full((nc, n_out), 1e-3), empty=np.zeros(nc, bool),
                       source_class=np.arange(nc), output_space=space,
                       provenance={"inputs": ["synthetic"], "seed": seed})
    if tone:
        x = np.linspace(0, 1, 64)
        lut = np.stack([x ** 1.8, x ** 2.2, x ** 2.0][:n_out], axis=1).astype(np.float32)
        t.tone_lut = (lut, np.array([[-0.1, 0.0, 0.05][:n_out], [1.2, 1.1, 1.0][:n_out]],
                                    np.float32))
    if wb:
        coef = np.concatenate([np.eye(3).reshape(1, 9), 0.1 * rng.normal(size=(2, 9))])
        t.white_balance = WhiteBalanceModel(space, [0.3, -0.1], coef, [GAINS]).as_dict()
    if cond:
        bins = k[None] + (0.05 * rng.normal(size=(3, *k.shape))).astype(np.float32)
        counts = np.ones((3, nc), np.int64)
        counts[1, ::3] = 0  # the pooled kernels there
        t.conditions = Conditioned("iso", [100.0, 400.0, 1600.0], bins, counts)
    return t


def _mosaic(h, w, seed):
    """A gradient over every level with noise from faint to strong, clipped pixels and
    negative ones, and flat rows."""
    rng = np.random.default_rng(seed)
    level = np.geomspace(0.003, 1.2, w)[None, :]
    noise = np.geomspace(0.005, 0.6, h)[:, None] * rng.normal(size=(h, w))
    m = (level * (1.0 + noise)).astype(np.float32) - np.float32(0.004)
    m[h // 3:h // 3 + 2, :] = 0.2  # flat rows: contrast near 0
    return m


def _raw(mosaic, spec, *, gains=None, iso=None):
    meta = {}
    if gains is not None:
        meta["white_balance"] = list(gains)
    if iso is not None:
        meta["shot"] = {"iso": iso}
    cfa = CFA.from_spec(spec)
    return RawImage(mosaic, cfa, np.zeros(cfa.n_positions), 1.0, None, meta)


def _check(table, mosaic, *, gains=None, iso=None, bits=(8,)):
    """ONNX Runtime's float and display outputs against l3's render of the same raw."""
    want = render_raw(table, _raw(mosaic, table.cfa.spec, gains=gains, iso=iso))
    got = _run(_session(build_model(table)), mosaic, gains, iso)
    assert got.shape == want.shape and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)
    if table.n_out == 3 and table.output_space == "lab":
        return
    for b in bits:
        disp = _run(_session(build_model(table, output="display", bits=b)), mosaic, gains, iso)
        ref = display_encode(want, table.output_space, b)
        assert disp.dtype == ref.dtype
        assert np.abs(disp.astype(np.int64) - ref.astype(np.int64)).max() <= 1


FEATURES = {  # name: table keywords
    "plain": dict(space="xyz"),
    "patch7-contrast3": dict(patch=7),
    "1-contrast-bin": dict(contrast_cuts=None),
    "per-level-contrast": dict(contrast_cuts=np.stack([np.linspace(0.05, 0.2, 8),
                                                       np.linspace(0.2, 0.5, 8)], axis=1)),
    "no-merge": dict(merge_positions=False),
    "4x4-cfa": dict(spec="RGBW/GWRB/BRWG/WBGR", space="xyz"),
    "3x2-cfa": dict(spec="RGB/GBR", patch=3),
    "orientation": dict(orientation_bins=4),
    "orientation-highlight": dict(patch=7, orientation_bins=8, highlight_bins=2),
    "context-mean": dict(context_block=8, context_cuts=[0.05, 0.2]),
    "context-ratio-all": dict(patch=7, orientation_bins=4, context_block=6,
                              context_cuts=[0.8, 1.25], context_rule="ratio", highlight_bins=2),
    "tone-curve": dict(tone=True, patch=7),
    "white-balance": dict(wb=True),
    "white-balance-tone-xyz": dict(wb=True, tone=True, space="xyz", spec="GRBG"),
    "srgb": dict(space="srgb"),
    "1-output": dict(n_out=1, space="linear-srgb"),
    "4-outputs": dict(n_out=4, space="xyz"),
}


@pytest.mark.parametrize("name", list(FEATURES))
def test_export_matches_render(name):
    kw = FEATURES[name]
    t = _table(**kw)
    gains = GAINS if kw.get("wb") else None
    ph, pw = t.cfa.period
    # odd sizes (not multiples of the period), and the smallest l3 renders
    sizes = [(37, 45), (max(ph, t.patch), max(pw, t.patch))]
    if t.definition.context_block:  # l3's block_means fails where a last block holds
        sizes = [(38, 47), (23, 29)]  # fewer rows or columns than the period: not those
    for (h, w), seed in zip(sizes, (1, 2), strict=True):
        _check(t, _mosaic(h, w, seed), gains=gains, bits=(8, 16) if name == "plain" else (8,))


def test_condition_bins_match_render():
    t = _table(cond=True)
    m = _mosaic(29, 34, 3)
    for iso in (50.0, 100.0, 250.0, 400.0, 5000.0, None):  # clamped, on a bin, between, unknown
        _check(t, m, iso=iso)


@pytest.mark.parametrize("spec, patch, features", [
    ("RGGB", 5, {}), ("GRBG", 7, {"contrast_cuts": [0.1, 0.3]}),
    ("RGBW/GWRB/BRWG/WBGR", 5, {}), ("RGB/GBR", 3, {}),
    ("RGGB", 7, {"orientation_bins": 8, "highlight_bins": 2}),
    ("RGGB", 5, {"context_block": 8, "context_cuts": [0.05, 0.2]}),
    ("RGBW/GWRB/BRWG/WBGR", 5, {"context_block": 12, "context_cuts": [0.9, 1.1],
                                "context_rule": "ratio"}),
])
def test_classes_are_the_tile_kernels(spec, patch, features):
    """The graph's class index equals :func:`l3cli.classify.classify` at every pixel."""
    from onnx import TensorProto

    from l3cli.export.classify import classify_nodes
    from l3cli.export.graph import Graph

    features.setdefault("contrast_cuts", 0.2)
    d = ClassDefinition.build(spec, patch=patch, level_cuts=np.geomspace(0.01, 0.5, 9),
                              **features)
    g = Graph()
    x = g.add_input("mosaic", TensorProto.FLOAT, ["N", 1, "H", "W"])
    g.add_output(classify_nodes(g, d, x).index, "cls", TensorProto.INT64, ["N", 1, "H", "W"])
    sess = _session(g.model(doc="", metadata={}))
    # (not 1 row or column into a last context block: l3's block_means fails there)
    for h, w in ((40, 53), (64, 126)):
        m = _mosaic(h, w, h)
        want = classify(m, d)
        got = sess.run(None, {"mosaic": m[None, None]})[0][0, 0]
        np.testing.assert_array_equal(got, want)
        _, sat, lev, tex = d.class_tuple(want)
        assert len(np.unique(sat)) > 1 and len(np.unique(lev)) > 3 and len(np.unique(tex)) > 1


def test_mirror_indices_in_the_graph():
    from onnx import TensorProto

    from l3cli.export.graph import Graph

    for r, p in ((3, 2), (2, 2), (3, 4), (1, 3), (4, 3)):
        g = Graph()
        n = g.add_input("n", TensorProto.INT64, [])
        g.add_output(g.mirror_indices(n, r, p), "o", TensorProto.INT64, ["k"])
        sess = _session(g.model(doc="", metadata={}))
        for size in range(max(p, r + 1), 24):
            got = sess.run(None, {"n": np.array(size, np.int64)})[0]
            np.testing.assert_array_equal(got, mirror_indices(size, r, p))


def test_batch_of_two_with_their_own_gains():
    t = _table(wb=True)
    sess = _session(build_model(t))
    m = np.stack([_mosaic(20, 22, 5), _mosaic(20, 22, 6)])[:, None]
    gains = np.array([GAINS, [1.5, 1.0, 2.1]], np.float32)
    out = sess.run(None, {"mosaic": m, "wb_gains": gains})[0]
    for i in range(2):
        want = render_raw(t, _raw(m[i, 0], t.cfa.spec, gains=gains[i].astype(np.float64)))
        np.testing.assert_allclose(out[i].transpose(1, 2, 0), want, rtol=0, atol=1e-5)


def test_bands_with_and_without_saturated_pixels():
    """Bands without a saturated pixel skip the saturation pass (an ``If``): a frame whose
    top bands hold none and whose bottom bands do renders as l3 render does, every pixel
    in its class (one in another would differ by far more than 1e-5)."""
    m = _mosaic(75, 61, 5)
    m[:40] = np.minimum(m[:40], np.float32(0.5))  # the first bands: nothing saturated
    t = _table(patch=7, tone=True)
    _check(t, m)
    from l3cli.export.bands import BAND_ROWS

    assert 40 >= 2 * BAND_ROWS and (m[40:] >= t.definition.saturation_threshold).any()


def test_real_raw_with_a_synthetic_table(data_dir):
    """A real 14-bit Bayer raw (bundled test data), whole frame and an odd crop."""
    raw = read_raw(data_dir / "DSC_1339_768x512_rggb_14bit.raw")
    t = _table(spec=raw.cfa.spec, patch=7, tone=True)
    _check(t, raw.mosaic[:203, :301])


# ------------------------------------------------------- lens shading, DNG GainMaps
def _field(size, centre=(0.08, -0.12), coeffs=((1.0, 0.9, 0.5), (1.0, 0.7, 0.3),
                                              (1.0, 0.7, 0.3), (1.0, 1.2, 0.6))):
    from l3cli.lens.field import GainField

    return GainField(np.array(centre), np.array(coeffs, dtype=np.float64), size)


def _feeds(sess, mosaic, *, gains=None, frame=None):
    feeds = {"mosaic": np.asarray(mosaic, np.float32)[None, None]}
    if gains is not None:
        feeds["wb_gains"] = np.asarray([gains], np.float32)
    if "frame" in {i.name for i in sess.get_inputs()}:
        feeds["frame"] = np.asarray(frame if frame is not None else [0, 0, 0, 0], np.int64)
    return sess.run(None, feeds)[0][0].transpose(1, 2, 0)


@pytest.mark.parametrize("case", ["brighten", "below-one", "white-balance", "crop"])
def test_shading_table_matches_render(case):
    """A table with a lens shading gain field: the field evaluated in the graph from the
    input's size (or the placement fed as ``frame``) corrects the mosaic as l3 render's
    does, saturated pixels included (the mosaic reaches 1.2)."""
    h, w = 46, 61
    m = _mosaic(h, w, 11)
    t = _table(wb=case == "white-balance", patch=5)
    coeffs = ((0.8, 0.9, 0.5), (0.9, 0.7, 0.3), (0.9, 0.7, 0.3), (0.7, 1.2, 0.6))
    t.shading = _field((h, w), coeffs=coeffs if case == "below-one" else
                       ((1.0, 0.9, 0.5), (1.0, 0.7, 0.3), (1.0, 0.7, 0.3), (1.0, 1.2, 0.6)))
    raw, frame = _raw(m, "RGGB", gains=GAINS if case == "white-balance" else None), None
    if case == "crop":  # a crop of a larger raw: the field is placed on the full raw
        t.shading = _field((90, 120))
        frame = [90, 120, 30, 44]
        raw.metadata.update(crop=[30, 44], full_size=[90, 120])
    want = render_raw(t, raw)
    got = _feeds(_session(build_model(t)), m, frame=frame,
                 gains=GAINS if case == "white-balance" else None)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)
    plain = dataclasses.replace(t, shading=None)
    assert np.abs(render_raw(plain, raw) - want).max() > 0.05  # the field does something


def _spline(size, seed=0, intervals=(3, 4), low=0.8):
    """A spline-grid field: per position random control values from ``low`` to 1.6."""
    from l3cli.lens.grid import SplineField

    rng = np.random.default_rng(seed)
    ny, nx = intervals
    return SplineField(rng.uniform(low, 1.6, size=(4, ny + 3, nx + 3)), size)


@pytest.mark.parametrize("case", ["brighten", "below-one", "crop", "other-size"])
def test_spline_grid_table_matches_render(case):
    """A table with a spline-grid lens shading field (``SplineField``): the B-spline grid is
    evaluated in the graph from the input's size or the ``frame`` placement and corrects
    the mosaic as l3 render's does, every pixel in the same class."""
    from l3cli.lens.field import corrected

    h, w = 46, 61
    m = _mosaic(h, w, 12)
    t = _table(patch=5)
    raw, frame = _raw(m, "RGGB"), None
    t.shading = _spline((h, w), low=0.8 if case == "below-one" else 1.0)
    if case == "crop":  # a crop of a larger raw: the field is placed on the full raw
        t.shading = _spline((90, 120), seed=1)
        frame = [90, 120, 30, 44]
        raw.metadata.update(crop=[30, 44], full_size=[90, 120])
    if case == "other-size":  # learned on another size: frame-relative, clamped at edges
        t.shading = _spline((60, 50), seed=2)
    want = render_raw(t, raw)
    got = _feeds(_session(build_model(t)), m, frame=frame)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)
    cls = _shading_classes(t).run(None, {"mosaic": m[None, None],
                                         "frame": np.array(frame or [0] * 4, np.int64)})[0]
    np.testing.assert_array_equal(cls[0, 0], classify(corrected(t, raw).mosaic, t.definition))
    plain = dataclasses.replace(t, shading=None)
    assert np.abs(render_raw(plain, raw) - want).max() > 0.05  # the field does something


def test_spline_grid_reproduces_a_linear_ramp():
    """An independent fact of uniform cubic B-splines: control values linear in their index
    (``c_j = a + b (j - 1)``) give ``a + b s``, ``s`` the position in intervals. The graph's
    gains on a constant mosaic are that ramp along the columns (``s`` from the pixel
    centres' normalised coordinates), whatever the row and CFA position."""
    from onnx import TensorProto

    from l3cli.export import stages
    from l3cli.export.graph import Graph
    from l3cli.lens.grid import SplineField, frame_extent

    h, w, nx = 30, 40, 5
    a, b = 1.2, 0.15
    ramp = a + b * (np.arange(nx + 3) - 1.0)
    field = SplineField(np.broadcast_to(ramp, (4, 7, nx + 3)).copy(), (h, w))
    g = Graph()
    x = g.add_input("mosaic", TensorProto.FLOAT, ["N", 1, "H", "W"])
    frame = g.add_input("frame", TensorProto.INT64, [4])
    y = stages.shading(g, x, field, (2, 2), 0.95, frame)
    g.add_output(y, "out", TensorProto.FLOAT, ["N", 1, "H", "W"])
    sess = _session(g.model(doc="", metadata={}))
    level = np.float32(0.01)
    out = sess.run(None, {"mosaic": np.full((1, 1, h, w), level, np.float32),
                          "frame": np.zeros(4, np.int64)})[0][0, 0]
    half = 0.5 * np.hypot(h, w)
    u = (np.arange(w) + 0.5 - 0.5 * w) / half
    uh = frame_extent(h, w)[1]
    s = (u + uh) / (2 * uh) * nx
    np.testing.assert_allclose(out / level, np.broadcast_to(a + b * s, (h, w)), rtol=1e-6)


def test_gain_map_dng_is_fed_as_read(tmp_path):
    """A DNG with four GainMap opcodes (one per Bayer position, as phones write them): the
    caller feeds the mosaic with the maps applied (``apply_dng_gains(read_raw(...))``), and the model of
    a shading table renders it as ``l3 render`` renders the file."""
    from l3cli.io.dng_opcodes import encode_gain_maps
    from l3cli.io.image import read_image
    from l3cli.render import render_file
    from tests.builders import phone_gain_maps, write_dng_with_opcodes

    h, w = 40, 60
    dn = np.random.default_rng(3).integers(64, 4096, (h, w))
    path = write_dng_with_opcodes(tmp_path / "gm.dng", dn, encode_gain_maps(phone_gain_maps(h, w)))
    from l3cli.lens.gainmaps import apply_dng_gains

    raw = apply_dng_gains(read_raw(path))  # the caller applies the maps, as documented
    assert raw.metadata["gain_maps"] == {"OpcodeList2": 4, "OpcodeList3": 0}
    for shading in (None, _field((h, w))):
        t = _table(patch=5)
        t.shading = shading
        want = read_image(render_file(t, path, tmp_path / "gm.exr"))[0]
        got = _feeds(_session(build_model(t)), raw.mosaic)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)


@pytest.mark.parametrize("spec, kw", [("RGGB", {"patch": 7, "tone": True, "wb": True}),
                                      ("RGB/GBR", {"patch": 3}),
                                      ("RGBW/GWRB/BRWG/WBGR", {"space": "xyz"})])
def test_strips_render_as_the_whole_frame(spec, kw):
    """l3cli.export.runner: strips fed with their margins in parallel threads give the
    frame's render (a shading table placed on a larger raw, odd sizes)."""
    from l3cli.export.runner import run_strips, strip_rows, strip_session

    t = _table(spec=spec, **kw)
    h, w = 53, 41
    t.shading = _field((80, 70), coeffs=np.tile([[1.0, 0.8, 0.3]], (t.cfa.n_positions, 1)))
    m = _mosaic(h, w, 21)
    gains = GAINS if kw.get("wb") else None
    raw = _raw(m, spec, gains=gains)
    raw.metadata.update(crop=[14, 8], full_size=[80, 70])
    want = render_raw(t, raw)
    sess = strip_session(build_model(t).SerializeToString())
    feeds = {"wb_gains": np.asarray([gains], np.float32)} if gains else None
    parts = strip_rows(h, 4, t.patch, t.cfa.period[0])
    assert len(parts) >= 3 and parts[-1][1] == h
    got = run_strips(sess, m[None, None], threads=4, feeds=feeds, frame=[80, 70, 14, 8])
    np.testing.assert_allclose(got[0].transpose(1, 2, 0), want, rtol=0, atol=1e-5)


def test_runner_needs_numpy_and_onnxruntime_only():
    """The runner can be copied next to a model: it imports no l3 module."""
    import ast

    import l3cli.export.runner as runner

    tree = ast.parse(Path(runner.__file__).read_text())
    names = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import)
             for a in n.names}
    names |= {n.module.split(".")[0] for n in ast.walk(tree)
              if isinstance(n, ast.ImportFrom) and n.module}
    assert names <= {"__future__", "json", "os", "concurrent", "numpy", "onnxruntime"}, names


# ----------------------------------------------------------------- CLI, refusals
def _save(tmp_path, table, name="t.npz"):
    return str(save_table(tmp_path / name, table))


@pytest.mark.parametrize("table_kw, options, words", [
    (dict(space="srgb", wb=True), [], ["white-balance adaptation", "srgb"]),
    (dict(space="lab"), ["--display"], ["display output of a lab table"]),
])
def test_refused_features_give_one_line(tmp_path, table_kw, options, words):
    table = _save(tmp_path, _table(**table_kw))
    res = CliRunner().invoke(cli, ["export", table, "-o", str(tmp_path / "p.onnx"), *options])
    assert res.exit_code == 1, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error:"), lines
    assert all(w in lines[0] for w in words), lines[0]
    assert not (tmp_path / "p.onnx").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.npz"]


def test_cli_bad_arguments_give_one_line(tmp_path):
    table = _save(tmp_path, _table())
    r = CliRunner()
    for args, code, word in ((["export", str(tmp_path / "none.npz"), "-o", "p.onnx"], 1,
                               "no such table"),
                              (["export", table, "-o", str(tmp_path / "p.png")], 1, ".onnx"),
                              (["export", table, "-o", str(tmp_path / "p.onnx"), "--bits", "16"],
                               2, "--display")):
        res = r.invoke(cli, args)
        assert res.exit_code == code, res.output
        assert word in res.output and "Traceback" not in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.npz"]


def test_cli_export_and_inspect(tmp_path):
    table = _save(tmp_path, _table(tone=True, wb=True))
    out = tmp_path / "p.onnx"
    res = CliRunner().invoke(cli, ["export", table, "-o", str(out), "--display"])
    assert res.exit_code == 0, res.output
    model = onnx.load(str(out))
    onnx.checker.check_model(model)
    assert {o.domain for o in model.opset_import} <= {"", "ai.onnx"}  # standard ops only
    assert {i.name for i in model.graph.input} == {"mosaic", "wb_gains"}
    res = CliRunner().invoke(cli, ["inspect", str(out)])
    assert res.exit_code == 0, res.output
    assert "CFA RG/GB" in res.output and "wb_gains" in res.output and "tone curve" in res.output
    res = CliRunner().invoke(cli, ["inspect", "--json", str(out)])
    info = json.loads(res.output)
    assert info["output"] == "display" and info["bits"] == "8"
    assert info["provenance"] == {"inputs": ["synthetic"], "seed": 0}
    assert info["table"] == "t.npz" and len(info["table_sha256"]) == 64
    assert info["graph_outputs"]["image"] == "uint8 (N, 3, H, W)"


def test_inspect_refuses_a_model_l3_did_not_write(tmp_path):
    from onnx import TensorProto, helper

    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])
    g = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g", [x],
                          [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    onnx.save(helper.make_model(g), str(tmp_path / "other.onnx"))
    (tmp_path / "junk.onnx").write_bytes(b"not a model at all")
    for name, word in (("other.onnx", "not an l3 pipeline"), ("junk.onnx", "not an ONNX")):
        res = CliRunner().invoke(cli, ["inspect", str(tmp_path / name)])
        assert res.exit_code == 1, res.output
        assert word in res.output and len(res.output.strip().splitlines()) == 1


# ------------------------------------------------------ tables that l3 train makes
def test_default_table_from_simulate_folder(tmp_path):
    r = CliRunner()
    sim = tmp_path / "sim"
    res = r.invoke(cli, ["simulate", str(REPO / "sample_configs" / "bayer.toml"), "-o", str(sim),
                         "--scene", "macbeth", "--scene", "natural", "--lux", "200",
                         "--size", "96x64", "--seed", "2"])
    assert res.exit_code == 0, res.output
    res = r.invoke(cli, ["train", str(sim), "-o", str(tmp_path / "t.npz")])  # defaults
    assert res.exit_code == 0, res.output
    t = load_table(tmp_path / "t.npz")
    for raw_path in sorted(sim.glob("*.dng"))[:2]:
        raw = read_raw(raw_path)
        _check(t, raw.mosaic[:-3, :-1])  # bottom/right crop: phase kept, odd size


#: As-shot white balance written into copies of the bundled frames' sidecars (LibRaw-style
#: multipliers), so that ``l3 train``'s defaults include white balance and its adaptation.
_SHOT_GAINS = {"Indoor1_crop": "1.8, 1.0, 1.5", "Outdoor1_crop": "2.1, 1.0, 1.3",
               "Outdoor2_crop": "1.6, 1.0, 1.8", "Outdoor3_crop": "1.9, 1.0, 1.45",
               "Outdoor4_crop": "2.0, 1.0, 1.35"}


@pytest.fixture(scope="module")
def default_pairs_table(tmp_path_factory):
    """``l3 train`` with every default on the bundled Infinite-ISP pairs, given an as-shot
    white balance: patch 7, tone curve, white balance and its adaptation.

    Returns the table and the folder of the holdout raws (copies with that white balance).
    """
    import shutil

    work = tmp_path_factory.mktemp("pairs")
    for src in (FRAMES, HOLDOUT):
        dst = work / src.name
        shutil.copytree(src, dst)
        for toml in dst.glob("*.tif.toml"):
            stem = toml.name.removesuffix(".tif.toml")
            with open(toml, "a") as fh:
                fh.write(f"white_balance = [{_SHOT_GAINS[stem]}]\n")
    out = work / "default.npz"
    res = CliRunner().invoke(cli, ["train", str(work / "frames"), "-o", str(out), "--no-tune"])
    assert res.exit_code == 0, res.output
    return out, work / "holdout"


@pytest.mark.slow
def test_default_pairs_table_renders_holdout_frames(default_pairs_table):
    from l3cli.whitebalance.model import raw_gains

    path, holdout = default_pairs_table
    t = load_table(path)
    assert t.tone_lut is not None and t.white_balance is not None and t.patch == 7
    for raw_path in sorted(holdout.glob("*.tif")):
        raw = read_raw(raw_path)
        mosaic = raw.mosaic[:301, :203]
        _check(t, mosaic, gains=raw_gains(raw))


_FRESH = r"""
import sys, numpy as np, onnxruntime as ort
s = ort.InferenceSession(sys.argv[1], providers=["CPUExecutionProvider"])
for path in sys.argv[2:]:
    m = np.load(path)
    gains = np.load(path.replace(".npy", ".gains.npy"))
    out = s.run(None, {"mosaic": m[None, None], "wb_gains": gains[None]})[0]
    np.save(path.replace(".npy", ".out.npy"), out)
bad = sorted(m for m in sys.modules if m.split(".")[0] in ("l3cli", "numba", "onnx", "scipy"))
assert not bad, bad
"""


@pytest.mark.slow
def test_default_model_runs_in_a_fresh_process(default_pairs_table, tmp_path):
    """numpy and onnxruntime only: python -I (no PYTHONPATH, no user site), no l3 import;
    the holdout frames as ``l3 render`` writes them to PNG, within one code value."""
    import OpenImageIO as oiio

    from l3cli.whitebalance.model import raw_gains

    table, holdout = default_pairs_table
    model = tmp_path / "pipeline.onnx"
    res = CliRunner().invoke(cli, ["export", str(table), "-o", str(model), "--display"])
    assert res.exit_code == 0, res.output
    raws, inputs = [], []
    for path in sorted(holdout.glob("*.tif")):
        raws.append(read_raw(path))
        inputs.append(tmp_path / f"{path.stem}.npy")
        np.save(inputs[-1], raws[-1].mosaic)
        np.save(tmp_path / f"{path.stem}.gains.npy", raw_gains(raws[-1]).astype(np.float32))
    proc = subprocess.run([sys.executable, "-I", "-c", _FRESH, str(model), *map(str, inputs)],
                          capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr
    res = CliRunner().invoke(cli, ["render", str(table), *map(str, sorted(holdout.glob("*.tif"))),
                                   "-o", str(tmp_path / "png"), "--format", "png"])
    assert res.exit_code == 0, res.output
    t = load_table(table)
    for raw, path in zip(raws, inputs, strict=True):
        got = np.load(str(path).replace(".npy", ".out.npy"))[0].transpose(1, 2, 0)
        inp = oiio.ImageInput.open(str(tmp_path / "png" / f"{raw.path.stem}.png"))
        png = inp.read_image(0, 0, 0, 3, "uint8")
        inp.close()
        for want in (png, display_encode(render_raw(t, raw), t.output_space, 8)):
            assert got.shape == want.shape == (*raw.mosaic.shape, 3)
            assert np.abs(got.astype(np.int64) - want.astype(np.int64)).max() <= 1


def _shading_classes(table):
    """A model of the table's lens shading correction and classifier alone: the classes."""
    from onnx import TensorProto

    from l3cli.export import stages
    from l3cli.export.classify import classify_nodes
    from l3cli.export.graph import Graph

    g = Graph()
    x = g.add_input("mosaic", TensorProto.FLOAT, ["N", 1, "H", "W"])
    frame = g.add_input("frame", TensorProto.INT64, [4])
    d = table.definition
    x = stages.shading(g, x, table.shading, d.cfa.period, d.saturation_threshold, frame)
    g.add_output(classify_nodes(g, d, x).index, "cls", TensorProto.INT64, ["N", 1, "H", "W"])
    return _session(g.model(doc="", metadata={}))


@pytest.mark.slow
def test_default_table_of_shaded_frames(tmp_path):
    """The bundled frames with a known strong off-centre per-channel lens shading on the
    raws (scripts/make_shaded_examples.py), ``l3 train`` with the pairs defaults (the
    field is learned and kept): the exported model renders crops of the holdout frames as
    ``l3 render`` does, every pixel in the same class."""
    from l3cli.lens.field import corrected
    from tests.builders import shaded_examples_script

    shaded_examples_script().main(tmp_path / "shaded")
    table = tmp_path / "t.npz"
    res = CliRunner().invoke(cli, ["train", str(tmp_path / "shaded" / "frames"), "-o",
                                   str(table), "--no-tune"])
    assert res.exit_code == 0, res.output
    model = tmp_path / "p.onnx"
    res = CliRunner().invoke(cli, ["export", str(table), "-o", str(model)])
    assert res.exit_code == 0, res.output
    t = load_table(table)
    assert t.shading is not None and t.tone_lut is not None
    sess = _session(onnx.load(str(model)))
    classes = _shading_classes(t)
    for path in sorted((tmp_path / "shaded" / "holdout").glob("*.tif")):
        full = read_raw(path)
        h, w = full.mosaic.shape
        for top, left in ((0, 0), (h - 240, w - 302)):  # corners: the strongest shading
            raw = full.crop(top, left, 240, 302)
            frame = [h, w, top, left]
            want = render_raw(t, raw)
            got = _feeds(sess, raw.mosaic, frame=frame)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)
            cls = classes.run(None, {"mosaic": raw.mosaic[None, None],
                                     "frame": np.array(frame, np.int64)})[0][0, 0]
            np.testing.assert_array_equal(cls, classify(corrected(t, raw).mosaic, t.definition))


def test_stages_the_export_does_not_know_are_refused():
    """A table stage added to l3 after the export (e.g. multiscale, lens shading) is refused
    by name instead of being left out of the graph."""
    import dataclasses

    from l3cli.errors import ConfigError
    from l3cli.export import _KNOWN_TABLE, check_exportable

    others = [f.name for f in dataclasses.fields(TransformTable) if f.name not in _KNOWN_TABLE]
    if not others:
        pytest.skip("this l3's tables have no stage beyond the exported ones")
    for name in others:
        t = _table()
        setattr(t, name, object())
        with pytest.raises(ConfigError, match="cannot be exported"):
            check_exportable(t)


def test_without_onnx_the_error_says_what_to_install(monkeypatch, tmp_path):
    from l3cli.errors import ConfigError
    from l3cli.export import require_onnx

    monkeypatch.setitem(sys.modules, "onnx", None)  # import onnx raises ImportError
    with pytest.raises(ConfigError, match=r"pip install 'l3cli\[export\]'"):
        require_onnx()
    table = _save(tmp_path, _table())
    res = CliRunner().invoke(cli, ["export", table, "-o", str(tmp_path / "p.onnx")])
    assert res.exit_code == 1 and "l3cli[export]" in res.output
    assert not (tmp_path / "p.onnx").exists()
