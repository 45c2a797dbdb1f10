"""Property-based fuzzing of l3's readers of external files and of the CLI's path handling.

Property: any input gives a result or an :class:`~l3cli.errors.L3Error` (a
one-line error for the user), never another exception. ``make test`` runs a
small budget (profile ``ci``); ``make fuzz`` a large one (``L3_FUZZ_PROFILE=fuzz``)
and prints how many inputs were generated.
"""

from __future__ import annotations

import copy
import json
import math
import os
import tomllib
from pathlib import Path

import click
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from l3cli.errors import L3Error

REPO = Path(__file__).parents[2]
_COMMON = {"deadline": None, "database": None,
           "suppress_health_check": [HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                     HealthCheck.data_too_large, HealthCheck.filter_too_much]}
settings.register_profile("ci", max_examples=30, derandomize=True, **_COMMON)
settings.register_profile("fuzz", max_examples=2500, **_COMMON)
settings.load_profile(os.environ.get("L3_FUZZ_PROFILE", "ci"))

#: Inputs generated in this session, per reader (``make fuzz`` reports them).
COUNTS: dict[str, int] = {}


@pytest.fixture(scope="module", autouse=True)
def _report_counts():
    yield
    total = sum(COUNTS.values())
    line = f"fuzz: {total} generated inputs ({', '.join(f'{k} {v}' for k, v in sorted(COUNTS.items()))})"
    print("\n" + line)
    out = os.environ.get("L3_FUZZ_COUNT_FILE")
    if out:
        with open(out, "a") as fh:
            fh.write(line + "\n")


def _count(name: str) -> None:
    COUNTS[name] = COUNTS.get(name, 0) + 1


def _either_result_or_l3error(fn, *args, one_line: bool = True, **kwargs):
    try:
        return fn(*args, **kwargs)
    except L3Error as exc:
        msg = str(exc)
        assert msg and (not one_line or "\n" not in msg.strip()), f"not one line: {msg!r}"
        return None


# ----------------------------------------------------------------------------- values
_text = st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=12)
_floats = st.floats(allow_nan=True, allow_infinity=True)
_ints = st.one_of(st.integers(-3, 70000), st.integers(-(2**63), 2**63 - 1))
_scalar = st.one_of(_ints, _floats, _text, st.booleans(),
                    st.sampled_from(["RGGB", "GRBG", "uint8", "uint16", "uint16be", "RGBW"]))
_toml_value = st.recursive(_scalar, lambda inner: st.lists(inner, max_size=5), max_leaves=12)
_json_value = st.recursive(
    st.one_of(st.none(), _ints, st.floats(allow_nan=False, allow_infinity=False), _text,
              st.booleans()),
    lambda inner: st.one_of(st.lists(inner, max_size=4),
                            st.dictionaries(_text, inner, max_size=4)),
    max_leaves=10)


def _toml_scalar(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=True)
    return "[" + ", ".join(_toml_scalar(x) for x in v) + "]"


def _toml_dump(d: dict, prefix: str = "") -> str:
    flat = [f"{json.dumps(k)} = {_toml_scalar(v)}\n" for k, v in d.items() if not isinstance(v, dict)]
    out = "".join(flat)
    for k, v in d.items():
        if isinstance(v, dict):
            name = f"{prefix}.{json.dumps(k)}" if prefix else json.dumps(k)
            out += f"[{name}]\n" + _toml_dump(v, name)
    return out


# ----------------------------------------------------------------------------- sidecars
_SIDECAR_KEYS = ["width", "height", "dtype", "cfa", "black_level", "white_level", "offset",
                 "bit_depth", "description", "bogus"]


@st.composite
def _sidecars(draw):
    good = {"width": 8, "height": 6, "dtype": "uint16", "cfa": "RGGB", "black_level": 64,
            "white_level": 4095}
    side = dict(good)
    for key in draw(st.lists(st.sampled_from(_SIDECAR_KEYS), max_size=4)):
        if draw(st.booleans()):
            side[key] = draw(_toml_value)
        else:
            side.pop(key, None)
    return side


@given(side=_sidecars(), kind=st.sampled_from(["raw", "png8", "png16", "tif"]),
       nbytes=st.one_of(st.none(), st.integers(0, 200)), garbage=st.one_of(st.none(), st.binary(max_size=40)))
def test_fuzz_raw_sidecar(tmp_path_factory, side, kind, nbytes, garbage):
    from l3cli.io.raw import read_raw

    _count("sidecar")
    d = tmp_path_factory.mktemp("side")
    if kind == "raw":
        raw = d / "a.raw"
        w, h = side.get("width"), side.get("height")
        size = nbytes
        if size is None:
            ok = isinstance(w, int) and isinstance(h, int) and 0 < w * h < 10000
            size = (w * h * 2) if ok and not isinstance(w, bool) and not isinstance(h, bool) else 16
        raw.write_bytes(np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes())
    else:
        import tifffile
        from PIL import Image

        dt = np.uint8 if kind == "png8" else np.uint16
        arr = np.random.default_rng(0).integers(0, np.iinfo(dt).max, (6, 8)).astype(dt)
        raw = d / ("a.png" if kind != "tif" else "a.tif")
        if kind == "tif":
            tifffile.imwrite(raw, arr)
        else:
            Image.fromarray(arr).save(raw)
    sc = raw.with_name(raw.name + ".toml")
    if garbage is not None:
        sc.write_bytes(garbage)
    else:
        sc.write_text(_toml_dump(side))
    res = _either_result_or_l3error(read_raw, raw)
    if res is not None:
        assert np.isfinite(res.white_level) and np.all(np.isfinite(res.black_level))
        assert res.mosaic.dtype == np.float32 and res.mosaic.ndim == 2
        assert np.all(np.isfinite(res.mosaic))


def test_sidecar_folder_and_8bit_png_scale(tmp_path):
    """Regression facts found by the campaign: a folder sidecar; an 8-bit PNG's scale."""
    from PIL import Image

    from l3cli.io.raw import read_raw

    arr = np.full((6, 8), 200, np.uint8)
    Image.fromarray(arr).save(tmp_path / "m.png")
    (tmp_path / "m.png.toml").write_text('cfa = "RGGB"\nblack_level = 0\nwhite_level = 255\n')
    raw = read_raw(tmp_path / "m.png")
    np.testing.assert_allclose(raw.mosaic, 200 / 255, rtol=1e-6)  # not 257x brighter
    (tmp_path / "f.raw").write_bytes(b"\0" * 96)
    (tmp_path / "f.raw.toml").mkdir()
    with pytest.raises(L3Error, match="not a file"):
        read_raw(tmp_path / "f.raw")


# ----------------------------------------------------------------------------- camera TOML
_CAMERA = tomllib.loads((REPO / "sample_configs" / "bayer.toml").read_text())
_PATHS = [(sec, key) for sec, v in _CAMERA.items() if isinstance(v, dict) for key in v] + \
         [(None, k) for k, v in _CAMERA.items() if not isinstance(v, dict)]


@given(edits=st.lists(st.tuples(st.sampled_from(_PATHS + [("exposure", "bogus"), (None, "x")]),
                                st.one_of(st.none(), _toml_value)), min_size=1, max_size=4),
       garbage=st.one_of(st.none(), st.binary(max_size=60)))
def test_fuzz_camera_toml(tmp_path_factory, edits, garbage):
    from l3cli.camera import load_camera

    _count("camera")
    data = copy.deepcopy(_CAMERA)
    for (sec, key), value in edits:
        tgt = data if sec is None else data.setdefault(sec, {})
        if value is None:
            tgt.pop(key, None)
        else:
            tgt[key] = value
    path = tmp_path_factory.mktemp("cam") / "cam.toml"
    if garbage is not None:
        path.write_bytes(garbage)
    else:
        path.write_text(_toml_dump(data))
    cam = _either_result_or_l3error(load_camera, path)
    if cam is not None:
        json.dumps(cam.to_dict())  # the manifest record is plain JSON


# ----------------------------------------------------------------------------- tables
def _make_table_arrays() -> dict[str, np.ndarray]:
    from l3cli.classify import ClassDefinition
    from l3cli.table import TransformTable

    d = ClassDefinition.build("RGGB", patch=3, level_cuts=[0.05, 0.2], contrast_cuts=0.3)
    nc, q = d.n_classes, d.n_coeffs
    t = TransformTable(definition=d, kernels=np.ones((nc, q, 3), np.float32),
                       counts=np.full(nc, 10), lambdas=np.full((nc, 3), 1e-3),
                       empty=np.zeros(nc, bool), source_class=np.arange(nc),
                       provenance={"seed": 1})
    return t.to_arrays()


_TABLE = _make_table_arrays()


def _filled(shape, kind, fill):
    with np.errstate(all="ignore"):
        return np.full(shape, fill).astype(kind)


npz_arrays = st.one_of(
    _json_value.map(lambda v: np.array(json.dumps(v))),
    st.builds(_filled,
              st.lists(st.integers(0, 4), max_size=3).map(tuple),
              st.sampled_from(["f4", "f8", "i8", "u1", "?", "U3"]),
              st.one_of(st.integers(-5, 5), st.floats(allow_nan=True, allow_infinity=True))),
)


@given(edits=st.lists(st.tuples(st.sampled_from(sorted(_TABLE) + ["extra"]),
                                 st.one_of(st.none(), npz_arrays)), max_size=3),
       cut=st.one_of(st.none(), st.integers(0, 3000)))
def test_fuzz_table(tmp_path_factory, edits, cut):
    from l3cli.table import load_table

    _count("table")
    arrays = dict(_TABLE)
    for key, value in edits:
        if value is None:
            arrays.pop(key, None)
        else:
            arrays[key] = value
    path = tmp_path_factory.mktemp("tab") / "t.npz"
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    if cut is not None:
        data = path.read_bytes()
        path.write_bytes(data[:cut])
    t = _either_result_or_l3error(load_table, path)
    if t is not None:
        assert np.all(t.counts >= 0) and isinstance(t.provenance, dict)
        assert np.all(np.isfinite(t.kernels))


def test_table_negative_counts_and_provenance_refused(tmp_path):
    from l3cli.table import load_table

    for key, value in (("counts", np.full(_TABLE["counts"].shape, -3)),
                       ("provenance", np.array("[1, 2]"))):
        path = tmp_path / f"{key}.npz"
        with open(path, "wb") as fh:
            np.savez(fh, **{**_TABLE, key: value})
        with pytest.raises(L3Error, match=key):
            load_table(path)


# ----------------------------------------------------------------------------- manifests
_MANIFEST = {
    "format": "l3-simulation", "version": 1, "camera": {"name": "c", "pixel_pitch_um": 2.2},
    "target": {"space": "xyz"}, "options": {},
    "captures": [{"stem": "a", "raw": "a.dng", "target": "a.target.exr",
                  "noise_free": "a.noisefree.exr", "lux": 100.0, "exposure_s": 0.01,
                  "width": 48, "height": 32, "white_xyz": [0.95, 1.0, 1.09],
                  "chart": {"patches": [[0, 0, 4, 4]] * 24,
                            "reference_xyz": [[0.1, 0.1, 0.1]] * 24, "white_index": 18},
                  "edge": {"roi": [0, 0, 10, 10]}}],
}


def _paths_of(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths_of(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj[:2]):
            yield from _paths_of(v, (*prefix, i))


_MPATHS = [p for p in _paths_of(_MANIFEST) if p]


@given(edits=st.lists(st.tuples(st.sampled_from(_MPATHS), st.one_of(st.none(), _json_value,
                                                                    st.sampled_from([float("nan"), float("inf"), -1, 0, "../x"]))),
                      max_size=3),
       garbage=st.one_of(st.none(), st.binary(max_size=40)))
def test_fuzz_manifest(tmp_path_factory, edits, garbage):
    from l3cli.io.manifest import read_manifest
    from l3cli.pairs import find_pairs

    _count("manifest")
    m = copy.deepcopy(_MANIFEST)
    for path, value in edits:
        tgt = m
        try:
            for k in path[:-1]:
                tgt = tgt[k]
            if value is None and isinstance(tgt, dict):
                tgt.pop(path[-1], None)
            else:
                tgt[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            continue
    d = tmp_path_factory.mktemp("sim")
    mp = d / "manifest.json"
    if garbage is not None:
        mp.write_bytes(garbage)
    else:
        mp.write_text(json.dumps(m))
    got = _either_result_or_l3error(read_manifest, d)
    if got is not None:
        pairs = _either_result_or_l3error(find_pairs, [d]) or []
        assert all(p.raw.parent == d and p.target.parent == d for p in pairs)


# ----------------------------------------------------------------------------- CLI paths
@given(n_inputs=st.integers(1, 3),
       out_kind=st.sampled_from(["new", "input", "symlink", "hardlink", "folder", "folder-of-inputs",
                                 "sidecar", "file-in-missing", "existing-file"]),
       suffix=st.sampled_from(["", ".exr", ".tif", ".tiff", ".png", ".jpg", ".jpeg", ".dng", ".txt"]),
       fmt=st.one_of(st.none(), st.sampled_from(["exr", "tiff", "png", "jpg"])),
       in_suffix=st.sampled_from([".dng", ".exr", ".tif", ".png"]))
def test_fuzz_output_planning(tmp_path_factory, n_inputs, out_kind, suffix, fmt, in_suffix):
    from l3cli.cli.paths import plan_outputs
    from l3cli.io.paths import same_file

    _count("paths")
    d = tmp_path_factory.mktemp("paths")
    ins = []
    for i in range(n_inputs):
        p = d / f"in{i}{in_suffix}"
        p.write_bytes(b"x" * (i + 1))
        ins.append(p)
    (d / f"in0{in_suffix}.toml").write_text("cfa = 'RGGB'\n")
    out = {"new": d / f"out{suffix}", "input": ins[0], "symlink": d / f"link{suffix}",
           "hardlink": d / f"hard{suffix}", "folder": d / "outdir", "folder-of-inputs": d,
           "sidecar": d / f"in0{in_suffix}.toml", "file-in-missing": d / "no" / f"x{suffix}",
           "existing-file": d / f"exists{suffix}"}[out_kind]
    if out_kind == "symlink":
        out.symlink_to(ins[0])
    elif out_kind == "hardlink":
        os.link(ins[0], out)
    elif out_kind == "folder":
        out.mkdir()
    elif out_kind == "existing-file":
        out.write_text("old")
    try:
        plan = plan_outputs(ins, out, fmt)
    except (L3Error, click.BadParameter):
        return
    protected = [*ins, d / f"in0{in_suffix}.toml"]
    for _, o in plan.targets:
        assert not any(same_file(o, p) for p in protected), (o, out_kind)


_path_text = st.lists(st.one_of(st.sampled_from(["..", ".", "", "a", "a.dng", "a.dng.toml",
                                                 "manifest.json", "sub", "\0", "ä ☃"]), _text),
                      min_size=1, max_size=4).map("/".join)


@given(out=_path_text, ins=st.lists(_path_text, max_size=3), absolute=st.booleans())
def test_fuzz_check_outputs(tmp_path_factory, out, ins, absolute):
    from l3cli.cli.paths import check_outputs

    _count("paths")
    d = tmp_path_factory.mktemp("chk")
    (d / "a.dng").write_bytes(b"x")
    (d / "sub").mkdir()
    base = d if absolute else Path(os.path.relpath(d))
    # a file name may itself hold a line break (the CLI escapes it: test_paths)
    _either_result_or_l3error(check_outputs, [(base / out, "-o")], [base / i for i in ins],
                              one_line=not any("\n" in p or "\r" in p for p in (out, *ins)))


# ----------------------------------------------------------------------------- table fields
def _feature_table_arrays() -> dict[str, np.ndarray]:
    """A table with every optional feature whose fields are numbers (orientation,
    context, highlights, a tone curve)."""
    from l3cli.classify import ClassDefinition
    from l3cli.table import TransformTable

    d = ClassDefinition.build("RGGB", patch=5, level_cuts=[0.05, 0.2], contrast_cuts=0.3,
                              orientation_bins=2, coherence_threshold=0.3, context_block=4,
                              context_cuts=[0.1], highlight_bins=2, highlight_fraction=0.5)
    nc, q = d.n_classes, d.n_coeffs
    k = np.zeros((nc, q, 3), np.float32)
    k[:, q // 2, :] = 1.0  # the centre pixel
    lut = np.linspace(0.0, 1.0, 16, dtype=np.float32)[:, None].repeat(3, axis=1)
    rng = np.array([[0.0] * 3, [1.0] * 3], np.float32)
    t = TransformTable(definition=d, kernels=k, counts=np.full(nc, 10),
                       lambdas=np.full((nc, 3), 1e-3), empty=np.zeros(nc, bool),
                       source_class=np.arange(nc), provenance={"seed": 1}, tone_lut=(lut, rng))
    return t.to_arrays()


_FTABLE = _feature_table_arrays()
_NUMERIC_KEYS = sorted(k for k, v in _FTABLE.items() if v.dtype.kind in "fiu" and k != "version")
_field_values = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, -1e-4, 1e-45, 1e-38, 3.4e38, 3.5e38, 1e39, 1e300, 65504.0,
                     65520.0, -1.0, 0.5, 1.0, 1.5, 2.0, 1e30, 1e31]),
    st.integers(-(2**63), 2**63 - 1))
_MOSAIC = np.random.default_rng(5).random((24, 28)).astype(np.float32)


@given(edits=st.lists(st.tuples(st.sampled_from(_NUMERIC_KEYS), st.integers(0, 10**6),
                                _field_values, st.booleans()), min_size=1, max_size=3))
def test_fuzz_table_fields(tmp_path_factory, edits):
    """Any numeric table field set to any value (NaN, inf, negative, beyond float32 or
    half range), one element or all: the table is refused with an L3Error, or it
    renders finite values."""
    from l3cli.render import render_mosaic
    from l3cli.table import load_table

    _count("table fields")
    arrays = {k: v.copy() for k, v in _FTABLE.items()}
    for key, index, value, whole in edits:
        a = arrays[key]
        with np.errstate(all="ignore"):
            if whole or a.ndim == 0:
                arrays[key] = np.full(a.shape, value).astype(a.dtype) if a.dtype.kind != "f" \
                    else np.full(a.shape, value, dtype=np.float64).astype(a.dtype)
            elif a.size:
                a.flat[index % a.size] = (value if a.dtype.kind == "f"
                                          else np.array(value).astype(a.dtype))
    path = tmp_path_factory.mktemp("tabf") / "t.npz"
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    t = _either_result_or_l3error(load_table, path)
    if t is not None:
        out = render_mosaic(t, _MOSAIC)
        assert np.all(np.isfinite(out)), edits


# ----------------------------------------------------------------------------- numeric options
_option_values = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["nan", "NaN", "inf", "-inf", "+inf", "infinity", "1e-9", "1e-300",
                     "1e300", "0", "-0", "-1", "1", "2", "0.5", "1.5", "100000000",
                     "1e8", "9" * 30, "", "x", "0x10", "1_000"]),
    st.integers(-(2**63), 2**63).map(str))
_TRAIN_FLOATS = ["--saturation", "--sample-fraction", "--min-samples", "--coherence",
                 "--highlight-fraction", "--contrast-threshold"]
_TRAIN_INTS = ["--levels", "--contrast-bins", "--patch", "--orientation-bins",
               "--context-block", "--context-bins", "--seed"]


@given(opts=st.lists(st.tuples(st.sampled_from(_TRAIN_FLOATS + _TRAIN_INTS + ["--level-range"]),
                               _option_values, _option_values), min_size=1, max_size=3))
def test_fuzz_train_options(tmp_path_factory, opts):
    """Any value of ``l3 train``'s numeric options: a usage error or an L3Error naming
    the problem, or options that are finite and in range (no work is started)."""
    from l3cli.cli.train import train
    from l3cli.train import TrainOptions

    _count("train options")
    args = ["IN", "-o", "t.npz"]
    for name, a, b in opts:
        args += [name, a, b] if name == "--level-range" else [name, a]
    try:
        ctx = train.make_context("train", args)
    except click.ClickException:
        return
    p = ctx.params
    kw = {k: p[k] for k in ("saturation", "sample_fraction", "min_samples_factor", "seed",
                            "coherence", "highlight_fraction", "context_block", "context_bins")}
    for k in ("patch", "levels", "contrast_bins"):
        if p[k] is not None:
            kw[k] = p[k]
    kw["orientation_bins"] = p["orientation_bins"]
    if p["level_range"] is not None:
        kw["level_range"] = tuple(p["level_range"])
    if p["contrast_threshold"] not in (None, "quantile"):
        kw["contrast_threshold"] = p["contrast_threshold"]
    o = _either_result_or_l3error(TrainOptions, **kw)
    if o is not None:
        for v in (o.saturation, o.sample_fraction, o.min_samples_factor, o.coherence,
                  o.highlight_fraction, *(o.level_range or ()), o.contrast_threshold or 1.0):
            assert math.isfinite(v), opts
        assert 0 < o.sample_fraction <= 1 and o.min_samples_factor > 1


_OTHER = [("simulate", ["CAM", "-o", "out"], ["--lux", "--exposure", "--oversample"]),
          ("evaluate", ["R", "--reference", "R"], ["--dpi", "--distance", "--pixel-pitch",
                                                   "--exclude-border"]),
          ("render", ["T", "R", "-o", "o"], ["--quality"])]


@given(which=st.integers(0, len(_OTHER) - 1), picks=st.lists(
    st.tuples(st.integers(0, 3), _option_values), min_size=1, max_size=3))
def test_fuzz_other_numeric_options(which, picks):
    """The numeric options of simulate, evaluate and render: NaN and infinity never
    pass (a usage error), whatever else is given."""
    import importlib

    _count("options")
    name, base, names = _OTHER[which]
    cmd = getattr(importlib.import_module(f"l3cli.cli.{name}"), name)
    args = list(base)
    for i, v in picks:
        args += [names[i % len(names)], v]
    try:
        ctx = cmd.make_context(name, args)
    except click.ClickException:
        return
    for k, v in ctx.params.items():
        for x in (v if isinstance(v, (tuple, list)) else [v]):
            if isinstance(x, float):
                assert math.isfinite(x), (k, x, args)


# ----------------------------------------------------------------------------- optional groups
def _group_table_arrays() -> dict[str, np.ndarray]:
    """A table with both optional groups: a lens-shading gain field and a multi-scale
    stage (both valid)."""
    from l3cli.classify import ClassDefinition
    from l3cli.lens.field import GainField
    from l3cli.multiscale.stage import Multiscale
    from l3cli.table import TransformTable

    d = ClassDefinition.build("RGGB", patch=3, level_cuts=[0.05, 0.2], contrast_cuts=0.3)
    nc, q = d.n_classes, d.n_coeffs
    k = np.zeros((nc, q, 3), np.float32)
    k[:, q // 2, :] = 1.0  # the centre pixel
    stage = Multiscale.identity(3, sigmas=(1.0, 3.0), level_cuts=[0.3],
                                energy_cuts=np.array([[0.01], [0.02]]))
    field = GainField(np.array([0.05, -0.1]), np.array([[1.0, 0.3, 0.05]] * 4), (24, 28))
    t = TransformTable(definition=d, kernels=k, counts=np.full(nc, 10),
                       lambdas=np.full((nc, 3), 1e-3), empty=np.zeros(nc, bool),
                       source_class=np.arange(nc), provenance={"seed": 1},
                       multiscale=stage, shading=field)
    return t.to_arrays()


_GTABLE = _group_table_arrays()
_GROUP_KEYS = sorted(k for k, v in _GTABLE.items()
                     if k.startswith(("shading_", "multiscale_")) and v.dtype.kind in "fiu")


@given(edits=st.lists(st.tuples(st.sampled_from(_GROUP_KEYS), st.integers(0, 10**6),
                                _field_values, st.booleans(),
                                st.sampled_from([None, "f4", "f8", "i8", "u8"])),
                      min_size=1, max_size=3))
def test_fuzz_table_groups(tmp_path_factory, edits):
    """Any numeric field of the optional groups (``shading_*``, ``multiscale_*``) set to
    any value, one element or all, in any numeric dtype: the table is refused with an
    L3Error, or it renders finite values (shading corrected, multi-scale stage applied)."""
    from l3cli.cfa import CFA
    from l3cli.io.raw import RawImage
    from l3cli.render import render_raw
    from l3cli.table import load_table

    _count("table groups")
    arrays = {k: v.copy() for k, v in _GTABLE.items()}
    for key, index, value, whole, dtype in edits:
        with np.errstate(all="ignore"):
            a = arrays[key] if dtype is None else arrays[key].astype(dtype)
            v = np.array(value).astype(a.dtype)  # ints wrap, NaN becomes some integer
            if whole or a.ndim == 0:
                a = np.full(a.shape, v, dtype=a.dtype)
            elif a.size:
                a.flat[index % a.size] = v
        arrays[key] = a
    path = tmp_path_factory.mktemp("tabg") / "t.npz"
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    t = _either_result_or_l3error(load_table, path)
    if t is not None:
        cfa = CFA.from_spec("RGGB")
        raw = RawImage(mosaic=_MOSAIC.copy(), cfa=cfa, black_level=np.zeros(4), white_level=1.0)
        out = render_raw(t, raw)
        assert np.all(np.isfinite(out)), edits


# ----------------------------------------------------------------------------- DNG opcodes
_U32 = st.one_of(st.integers(0, 12), st.sampled_from([20, 23, 24, 25, 28, 29, 255, 65535,
                                                       2**31 - 1, 2**31, 2**32 - 1]),
                 st.integers(0, 2**32 - 1))
_F64 = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                 st.sampled_from([0.0, -0.0, 1e-300, 0.25, 0.5, 1.0, 1e300, -1.0]))
_GAINS = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32),
                   st.sampled_from([0.0, 1.0, 1.5, 2.0, 4096.0, 4097.0, 3e38, -1.0, 1e-30]))


@st.composite
def _opcode_lists(draw):
    """An opcode list's bytes: GainMaps with sane or hostile fields, other opcodes, a
    count that may lie, a tail that may be cut."""
    import struct

    from l3cli.io.dng_opcodes import _HEAD

    ops = []
    for _ in range(draw(st.integers(0, 4))):
        if draw(st.integers(0, 5)) == 0:  # another opcode (skipped by l3)
            body = draw(st.binary(max_size=24))
            ops.append(struct.pack(">I4sII", draw(st.integers(1, 14)), bytes((1, 3, 0, 0)),
                                   draw(st.integers(0, 3)), len(body)) + body)
            continue
        sane = draw(st.booleans())
        f = {"top": draw(st.integers(0, 1)) if sane else draw(_U32),
             "left": draw(st.integers(0, 1)) if sane else draw(_U32),
             "bottom": 24 if sane else draw(_U32), "right": 28 if sane else draw(_U32),
             "plane": draw(st.integers(0, 2)) if sane else draw(_U32),
             "planes": draw(st.integers(1, 3)) if sane else draw(_U32),
             "row_pitch": draw(st.integers(1, 2)) if sane else draw(_U32),
             "col_pitch": draw(st.integers(1, 2)) if sane else draw(_U32),
             "pv": draw(st.integers(1, 4)) if sane else draw(st.one_of(st.integers(0, 40), _U32)),
             "ph": draw(st.integers(1, 4)) if sane else draw(st.one_of(st.integers(0, 40), _U32)),
             "sv": 0.5 if sane else draw(_F64), "sh": 0.5 if sane else draw(_F64),
             "ov": 0.0 if sane else draw(_F64), "oh": 0.0 if sane else draw(_F64),
             "mp": draw(st.integers(1, 3)) if sane else draw(st.one_of(st.integers(0, 4), _U32))}
        n = f["pv"] * f["ph"] * f["mp"]
        n_gains = n if n <= 4096 and draw(st.integers(0, 6)) else draw(st.integers(0, 64))
        gains = np.array(draw(st.lists(_GAINS, min_size=n_gains, max_size=n_gains))
                         if n_gains <= 64 else np.full(n_gains, draw(_GAINS)), ">f4")
        body = _HEAD.pack(*f.values()) + gains.tobytes()
        ops.append(struct.pack(">I4sII", 9, bytes((1, 3, 0, 0)), 0, len(body)) + body)
    count = len(ops) if draw(st.integers(0, 5)) else draw(_U32)
    data = struct.pack(">I", count) + b"".join(ops)
    cut = draw(st.one_of(st.none(), st.integers(0, max(0, len(data) - 1))))
    return data if cut is None else data[:cut]


_DN = np.random.default_rng(9).integers(64, 4000, (24, 28)).astype(np.uint16)


@given(list2=st.one_of(st.none(), _opcode_lists()), list3=st.one_of(st.none(), _opcode_lists()))
def test_fuzz_dng_opcodes(tmp_path_factory, list2, list3):
    """A DNG with any OpcodeList2/3 (GainMaps whose fields are any uint32, doubles and
    gains any value, lists cut short or whose count lies): read as a finite mosaic with
    the maps applied, or an L3Error; the work is bounded by the image (no loop of a
    file's field: a run of this test would not end otherwise)."""
    from l3cli.io.raw import read_raw
    from tests.dngmake import make_dng

    _count("dng opcodes")
    lists = {n: d for n, d in ((2, list2), (3, list3)) if d is not None}
    path = make_dng(tmp_path_factory.mktemp("op") / "o.dng", _DN, bits=16, black=64,
                    white=4095, opcode_lists=lists)
    raw = _either_result_or_l3error(read_raw, path)
    if raw is not None:
        assert raw.mosaic.shape == _DN.shape and np.all(np.isfinite(raw.mosaic)), lists
