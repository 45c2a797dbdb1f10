"""Every table feature through every path (issues 39 and 40: "a feature is done when it
travels").

The features are the product's own list (:data:`l3cli.features.FEATURES`); for each
this file builds a small table holding it (``BUILDERS``: a feature without a builder
fails :func:`test_every_feature_has_a_builder`, so a new one cannot be half supported)
and drives it through each path a user takes with a table: ``l3 render`` to EXR,
16-bit TIFF, 8-bit PNG and JPEG, ``l3 export`` run in ONNX Runtime, and ``l3 inspect``.
The reference is the in-process float render, :func:`l3cli.render.render_raw`:

- EXR: within float32 rounding of it (the file path prepares the mosaic in place);
- TIFF / PNG: within one code of its display encoding (the fused encoder);
- JPEG: decodes to the raw's size, within JPEG's error of the PNG;
- export: within 1e-5 (relative to the image's range) in ONNX Runtime, or refused with
  one line naming the feature (``EXPORT_REFUSED``);
- inspect: exits 0 and names the feature.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from l3cli.classify import ClassDefinition
from l3cli.features import FEATURES, table_features
from l3cli.io.encode import display_encode
from l3cli.io.image import read_image
from l3cli.io.raw import read_raw, write_raw
from l3cli.render import render_file, render_raw
from l3cli.table import TransformTable, save_table

SHAPE = (64, 96)
ISO = 400


def _definition(patch=5, **features):
    return ClassDefinition.build("RGGB", patch=patch, level_cuts=[0.02, 0.08, 0.3],
                                 contrast_cuts=0.2, **features)


def _table(d: ClassDefinition, *, seed: int = 0) -> TransformTable:
    """Kernels that render a photograph: a weighted mean of the patch, plus noise."""
    rng = np.random.default_rng(seed)
    nc, q = d.n_classes, d.n_coeffs
    k = rng.normal(scale=0.03, size=(nc, q, 3)).astype(np.float32)
    k[:, : q - 1, :] += np.float32(1.0 / (q - 1))
    k[:, -1, :] = rng.normal(scale=0.01, size=(nc, 3))
    return TransformTable(definition=d, kernels=k, counts=np.full(nc, 500),
                          lambdas=np.full((nc, 3), 1e-3), empty=np.zeros(nc, bool),
                          source_class=np.arange(nc), output_space="linear-srgb")


def _shading(t):
    from l3cli.lens.field import GainField

    t.shading = GainField(np.array([0.45, 0.55]), np.array([[1.0, 0.5], [1.0, 0.3],
                                                            [1.0, 0.3], [1.0, 0.6]]), SHAPE)
    return t


def _shading_grid(t):
    from l3cli.lens.grid import SplineField

    yy = np.linspace(-1, 1, 6)[:, None]
    xx = np.linspace(-1, 1, 6)[None, :]
    grid = np.stack([1.0 + k * (yy ** 2 + 0.5 * xx ** 2) for k in (0.5, 0.3, 0.3, 0.6)])
    t.shading = SplineField(grid, SHAPE)
    return t


def _conditions(t):
    from l3cli.conditions import Conditioned

    rng = np.random.default_rng(5)
    kb = np.stack([t.kernels, t.kernels * np.float32(1.2)
                   + rng.normal(scale=0.01, size=t.kernels.shape).astype(np.float32)])
    t.conditions = Conditioned(by="iso", values=np.array([100.0, 1600.0]), kernels=kb,
                               counts=np.full((2, t.definition.n_classes), 500))
    return t


def _white_balance(t):
    from l3cli.whitebalance.model import WhiteBalanceModel

    c0 = np.array([[1.05, 0.04, -0.02], [0.03, 0.97, 0.01], [-0.01, 0.05, 1.1]])
    c1 = np.array([[0.1, 0.0, 0.02], [0.0, 0.0, 0.0], [0.01, 0.0, -0.12]])
    t.white_balance = WhiteBalanceModel("linear-srgb", [0.2], [c0.ravel(), c1.ravel()],
                                        [[2.0, 1.0, 1.5], [1.6, 1.0, 2.1]]).as_dict()
    return t


def _tone_curve(t):
    from l3cli.tone.curve import ToneCurve

    x = np.linspace(0, 1, 33)[:, None]
    t.tone_lut = ToneCurve(np.hstack([x ** 2.0, x ** 2.2, x ** 1.9]), space="srgb").lut(
        t.output_space)
    return t


def _multiscale(t):
    from l3cli.multiscale.stage import Multiscale

    rng = np.random.default_rng(4)
    t.multiscale = Multiscale(np.array([1.0, 3.0, 9.0]), np.array([0.2, 0.5]),
                              np.array([[0.01, 0.05], [0.01, 0.05], [0.02, 0.08]]),
                              0.3 + 0.1 * rng.normal(size=(9, 9, 3)), np.full(9, 100),
                              "srgb")
    return t


#: feature name (l3cli.features) -> a small table that holds it
BUILDERS = {
    "lens shading": lambda: _shading(_table(_definition())),
    "lens shading grid": lambda: _shading_grid(_table(_definition())),
    "patch 9": lambda: _table(_definition(9)),
    "orientation bins": lambda: _table(_definition(orientation_bins=4)),
    "context bins": lambda: _table(_definition(context_block=16,
                                               context_cuts=np.array([0.1, 0.3]))),
    "highlight bins": lambda: _table(_definition(highlight_bins=2)),
    "condition bins": lambda: _conditions(_table(_definition())),
    "white balance": lambda: _white_balance(_table(_definition())),
    "tone curve": lambda: _tone_curve(_table(_definition())),
    "multiscale stage": lambda: _multiscale(_table(_definition())),
}
#: what ``l3 inspect`` prints for each
INSPECT_WORDS = {"lens shading": "lens shading", "lens shading grid": "lens shading",
                 "patch 9": "9x9",
                 "orientation bins": "orientation", "context bins": "context",
                 "highlight bins": "highlight", "condition bins": "condition bins",
                 "white balance": "white balance", "tone curve": "tone curve",
                 "multiscale stage": "multiscale"}
PATHS = ["exr", "tif", "png", "jpg", "export", "inspect"]
#: features the export refuses, with one line naming them (the rest must export)
EXPORT_REFUSED: dict[str, str] = {}


def _raw_file(tmp_path):
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[: SHAPE[0], : SHAPE[1]]
    m = 0.25 + 0.2 * np.sin(xx / 5.0) * np.cos(yy / 4.0)
    m = np.clip(m + rng.normal(scale=0.03, size=SHAPE), 0.001, 1.0)
    m[10:14, 30:50] = 1.0  # clipped: the saturation (and highlight) classes
    dn = (m * 3800 + 200).astype(np.uint16)
    return write_raw(tmp_path / "r.dng", dn, "RGGB", black_level=200, white_level=4000,
                     as_shot_neutral=np.array([0.45, 1.0, 0.7]), shot={"iso": ISO})


def test_every_feature_has_a_builder():
    assert sorted(BUILDERS) == sorted(f.name for f in FEATURES)
    assert sorted(INSPECT_WORDS) == sorted(BUILDERS)
    for name, build in BUILDERS.items():  # and each builder holds its feature (alone)
        if name == "patch 9":
            continue  # built in its (slow) case: a kernel compile
        assert [f.name for f in table_features(build())] == [name]


def _cases():
    for name in BUILDERS:
        for path in PATHS:
            slow = name == "patch 9" and path != "inspect"  # a kernel compile
            yield pytest.param(name, path, marks=[pytest.mark.slow] if slow else [],
                               id=f"{name}-{path}")


@pytest.mark.parametrize(("name", "path"), list(_cases()))
def test_feature_travels(tmp_path, runner, name, path):
    table = BUILDERS[name]()
    raw_path = _raw_file(tmp_path)
    t_path = save_table(tmp_path / "t.npz", table)
    if path == "inspect":
        from l3cli.cli.main import cli

        res = runner.invoke(cli, ["inspect", str(t_path)])
        assert res.exit_code == 0, res.output
        assert INSPECT_WORDS[name] in res.output.lower(), res.output
        return
    from l3cli.table import load_table

    table = load_table(t_path)  # as every path gets it: from the file
    want = render_raw(table, read_raw(raw_path))
    assert np.isfinite(want).all()
    scale = max(1.0, float(np.abs(want).max()))
    if path == "export":
        if name in EXPORT_REFUSED:
            from l3cli.errors import ConfigError
            from l3cli.export import build_model

            pytest.importorskip("onnx")
            with pytest.raises(ConfigError, match=EXPORT_REFUSED[name]) as exc:
                build_model(table)
            assert "\n" not in str(exc.value)
            return
        _check_export(table, raw_path, want, scale)
        return
    out = render_file(table, raw_path, tmp_path / f"out.{path}")
    img, _ = read_image(out)
    assert img.shape[:2] == SHAPE
    if path == "exr":
        np.testing.assert_allclose(img, want, rtol=0, atol=2e-5 * scale)
        return
    bits = 16 if path == "tif" else 8
    codes = display_encode(want, table.output_space, bits).astype(np.int64)
    mine = np.round(np.asarray(img, np.float64) * (2 ** bits - 1)).astype(np.int64)
    if path == "jpg":  # lossy: close to the exact codes on average
        assert np.abs(mine - codes).mean() < 4, np.abs(mine - codes).mean()
    else:
        assert np.abs(mine - codes).max() <= 1, np.abs(mine - codes).max()


def _check_export(table, raw_path, want, scale):
    if importlib.util.find_spec("onnx") is None or importlib.util.find_spec(
            "onnxruntime") is None:
        pytest.skip("the optional export extra (onnx, onnxruntime) is not installed")
    import onnxruntime as ort

    from l3cli.export import build_model

    model = build_model(table)
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    raw = read_raw(raw_path)
    feeds = {}
    for inp in sess.get_inputs():
        if inp.name == "mosaic":
            feeds["mosaic"] = raw.mosaic[None, None].astype(np.float32)
        elif inp.name == "wb_gains":
            from l3cli.whitebalance.model import gains_or_error

            feeds["wb_gains"] = np.asarray([gains_or_error(raw, None)], np.float32)
        elif inp.name == "condition":
            feeds["condition"] = np.array([float(ISO)], np.float64)
        elif inp.name == "frame":
            feeds["frame"] = np.zeros(4, np.int64)
        else:
            pytest.fail(f"the exported model asks for an input this test does not know: "
                        f"{inp.name}")
    feeds = {k: v.astype(_dtype(sess, k)) for k, v in feeds.items()}
    got = sess.run(None, feeds)[0][0].transpose(1, 2, 0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * scale)


def _dtype(sess, name):
    t = next(i.type for i in sess.get_inputs() if i.name == name)
    return {"tensor(float)": np.float32, "tensor(double)": np.float64,
            "tensor(int64)": np.int64}[t]
