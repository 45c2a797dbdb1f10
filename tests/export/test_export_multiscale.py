"""``l3 export`` of a table with the multi-scale stage (l3cli.export.multiscale): ONNX
Runtime's output against ``l3 render``'s (skipped without onnx and onnxruntime)."""

from __future__ import annotations

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

from l3cli.cfa import CFA  # noqa: E402
from l3cli.classify import ClassDefinition  # noqa: E402
from l3cli.io.encode import display_encode  # noqa: E402
from l3cli.io.raw import RawImage  # noqa: E402
from l3cli.kernelset import render_mosaic  # noqa: E402
from l3cli.multiscale.stage import Multiscale, encode, feature_maps  # noqa: E402
from l3cli.table import TransformTable  # noqa: E402


def _table(space: str, transfer: str, sigmas, seed: int = 0) -> tuple[TransformTable, np.ndarray]:
    """A random 5x5 table and a mosaic; its stage's cuts at quantiles of the render's own
    levels and energies (every class used), blends around the identity."""
    from l3cli.multiscale.fit import place_cuts

    d = ClassDefinition.build("RGGB", patch=5, level_cuts=np.geomspace(0.01, 0.6, 7),
                              contrast_cuts=[0.1, 0.3])
    rng = np.random.default_rng(seed)
    k = (0.15 * rng.normal(size=(d.n_classes, d.n_coeffs, 3))).astype(np.float32)
    k[:, -1, :] += np.float32(0.4)
    t = TransformTable(definition=d, kernels=k, counts=np.full(d.n_classes, 100),
                       lambdas=np.full((d.n_classes, 3), 1e-3), empty=np.zeros(d.n_classes, bool),
                       source_class=np.arange(d.n_classes), output_space=space,
                       provenance={"inputs": ["synthetic"], "seed": seed})
    h, w = 75, 93  # odd: the pyramid's last blocks are cut short
    level = np.geomspace(0.003, 1.1, w)[None, :]
    noise = np.geomspace(0.005, 0.4, h)[:, None] * rng.normal(size=(h, w))
    mosaic = (level * (1.0 + noise)).astype(np.float32)
    _, _, lev, en = feature_maps(encode(render_mosaic(t, mosaic), transfer), sigmas)
    lc, ec = place_cuts(lev, en, 3, 4)
    ns = len(sigmas)
    blend = np.tile(np.eye(3), (ns, 1))[None] + 0.3 * rng.normal(size=(12, 3 * ns, 3))
    t.multiscale = Multiscale(np.asarray(sigmas), lc, ec, blend, np.ones(12, np.int64),
                              transfer)
    return t, mosaic


def _near_a_cut(table, mosaic) -> np.ndarray:
    """Pixels whose coarse level or band energy lies within 1e-5 (relative) of one of the
    stage's cuts: where float32 sums in another order may give the other class."""
    stage = table.multiscale
    plain = render_mosaic(table, mosaic) if table.multiscale is None else None
    if plain is None:
        import copy

        t = copy.copy(table)
        t.multiscale = None
        plain = render_mosaic(t, mosaic)
    _, _, lev, en = feature_maps(encode(plain, stage.transfer), stage.sigmas)
    near = np.zeros(lev.shape, bool)
    for cut in stage.level_cuts:
        near |= np.abs(lev - cut) <= 1e-5 * max(1.0, abs(cut))
    for cut in np.unique(stage.energy_cuts):
        near |= np.abs(en - cut) <= 1e-5 * max(1.0, abs(cut))
    return near


def _ort(model, mosaic):
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {"mosaic": mosaic[None, None]})[0][0].transpose(1, 2, 0)


@pytest.mark.parametrize("space,transfer,sigmas", [
    ("linear-srgb", "srgb", (1.0, 3.0, 9.0)),  # the default stage of a pairs table
    ("xyz", "srgb", (1.0, 3.0, 6.0)),
    ("srgb", "none", (2.0, 6.0)),
])
def test_export_of_a_multiscale_table_matches_render(space, transfer, sigmas):
    from l3cli.export import build_model
    from l3cli.prepared import render_raw

    table, mosaic = _table(space, transfer, sigmas)
    cfa = CFA.from_spec("RGGB")
    raw = RawImage(mosaic, cfa, np.zeros(cfa.n_positions), 1.0, None, {})
    want = render_raw(table, raw)  # the float render with its stage
    got = _ort(build_model(table), mosaic)
    assert got.shape == want.shape and got.dtype == np.float32
    near = _near_a_cut(table, mosaic)
    assert near.mean() < 0.02
    ok = ~near
    np.testing.assert_allclose(got[ok], want[ok], rtol=0, atol=1e-5)
    changed = np.abs(want - render_mosaic(_without(table), mosaic)).max()
    assert changed > 1e-2  # the stage did change the render
    disp = _ort(build_model(table, output="display", bits=8), mosaic)
    ref = display_encode(want, space, 8).astype(np.int64)
    assert np.abs(disp.astype(np.int64) - ref)[ok].max() <= 1


def _without(table):
    import copy

    t = copy.copy(table)
    t.multiscale = None
    return t


def test_coding_in_the_graph_is_the_stages_table_bit_for_bit():
    """The sRGB coding and its inverse in ONNX (the table's bucket found by comparisons)
    give l3's values bit for bit, on values of both signs, at bucket starts, beyond the
    table and on the linear segment."""
    from onnx import TensorProto, helper

    from l3cli.export.graph import Graph
    from l3cli.export.multiscale import coding
    from l3cli.multiscale.stage import decode

    rng = np.random.default_rng(3)
    v = np.concatenate([rng.normal(0, 0.6, 20_000), rng.uniform(-70, 70, 2_000),
                        np.ldexp(1.0, np.arange(-12, 9)), [0.0, 0.0031308, 0.04045, 1.0, 64.0,
                                                           64.2, 200.0]]).astype(np.float32)
    from l3cli.multiscale.stage import encode as enc

    for inverse, ref in ((False, enc(v, "srgb")), (True, decode(v, "srgb"))):
        g = Graph()
        x = g.add_input("x", TensorProto.FLOAT, ["n"])
        g.add_output(coding(g, x, inverse), "y", TensorProto.FLOAT, ["n"])
        model = g.model(doc="coding", metadata={})
        sess = ort.InferenceSession(model.SerializeToString(),
                                    providers=["CPUExecutionProvider"])
        got = sess.run(None, {"x": v})[0]
        inside = np.abs(v) < 64.0  # beyond the table both evaluate the formula (powf)
        np.testing.assert_array_equal(got[inside].view(np.uint32), ref[inside].view(np.uint32))
        np.testing.assert_allclose(got, ref, rtol=1e-6)
        assert helper is not None
