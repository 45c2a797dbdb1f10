"""`l3 evaluate` never scores the wrong thing: which file is the reference, one
white scale for every output format, PSNR's domain named, a wrong reference warned."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.io.image import write_image

ROOT = Path(__file__).parents[2]


def _scene(h=64, w=80, seed=0):
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    return np.clip(gaussian_filter(rng.random((h, w, 3)), (2, 2, 0)) * 1.6 - 0.3, 0, 1).astype(np.float32)


def _raw_with_sidecar(path: Path, h=64, w=80):
    """A headerless-style TIFF mosaic with its ``.tif.toml`` sidecar: a raw, not a render."""
    import tifffile

    rng = np.random.default_rng(1)
    tifffile.imwrite(path, (rng.random((h, w)) * 4000).astype(np.uint16))
    Path(f"{path}.toml").write_text(
        f'width = {w}\nheight = {h}\ndtype = "uint16"\ncfa = "RGGB"\nblack_level = 0\nwhite_level = 4095\n')


def test_reference_folder_skips_raw_with_sidecar(runner, tmp_path):
    """A folder holding X.tif + X.tif.toml (a raw) and X.png (the render): the PNG is the reference."""
    ref_dir = tmp_path / "holdout"
    ref_dir.mkdir()
    img = _scene()
    _raw_with_sidecar(ref_dir / "X.tif")
    write_image(ref_dir / "X.png", img, space="srgb")
    out = tmp_path / "renders"
    out.mkdir()
    write_image(out / "X.png", img, space="srgb")
    rep = tmp_path / "r.json"
    res = runner.invoke(cli, ["evaluate", str(out), "--reference", str(ref_dir), "--json", str(rep)])
    assert res.exit_code == 0, res.output
    d = json.loads(rep.read_text())["images"][0]
    assert d["scielab_mean"] == 0.0  # against the PNG itself; the raw would score tens


def test_reference_folder_with_only_the_raw_says_so(runner, tmp_path):
    ref_dir = tmp_path / "holdout"
    ref_dir.mkdir()
    _raw_with_sidecar(ref_dir / "X.tif")
    out = tmp_path / "X.png"
    write_image(out, _scene(), space="srgb")
    res = runner.invoke(cli, ["evaluate", str(out), "--reference", str(ref_dir)])
    assert res.exit_code == 1
    assert "X.tif is a raw" in res.output and "Traceback" not in res.output


def test_ambiguous_reference_stem_is_refused(runner, tmp_path):
    ref_dir = tmp_path / "refs"
    ref_dir.mkdir()
    img = _scene()
    write_image(ref_dir / "X.png", img, space="srgb")
    write_image(ref_dir / "X.jpg", img, space="srgb")
    out = tmp_path / "X.png"
    write_image(out, img, space="srgb")
    res = runner.invoke(cli, ["evaluate", str(out), "--reference", str(ref_dir)])
    assert res.exit_code == 1
    msg = res.output.strip().splitlines()
    assert len(msg) == 1 and "X.jpg, X.png" in msg[0] and "refs" in msg[0]


def test_wrong_reference_of_the_same_size_is_warned(runner, tmp_path):
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    write_image(a, _scene(seed=0), space="srgb")
    write_image(b, _scene(seed=7), space="srgb")
    res = runner.invoke(cli, ["evaluate", str(a), "--reference", str(b)])
    assert res.exit_code == 0, res.output
    assert "hardly resembles" in res.output and "b.png" in res.output
    noisy = tmp_path / "noisy.png"
    rng = np.random.default_rng(3)
    write_image(noisy, np.clip(_scene(seed=0) + rng.normal(0, 0.03, (64, 80, 3)), 0, 1).astype(np.float32),
                space="srgb")
    res = runner.invoke(cli, ["evaluate", str(noisy), "--reference", str(a)])
    assert res.exit_code == 0, res.output
    assert "hardly resembles" not in res.output


def test_psnr_domain_is_the_references(runner, tmp_path):
    """A linear EXR and the 16-bit TIFF of the same image get the same PSNR against a
    display reference (both compared as sRGB codes), and the report names the domain."""
    from l3cli.colourspace import srgb_decode

    enc = _scene()
    ref = tmp_path / "ref.png"
    write_image(ref, enc, space="srgb")
    rng = np.random.default_rng(4)
    noisy = np.clip(enc + rng.normal(0, 0.02, enc.shape), 0, 1).astype(np.float32)
    write_image(tmp_path / "n.exr", srgb_decode(noisy), space="linear-srgb")
    write_image(tmp_path / "n.tif", noisy, space="srgb", bits=16)
    got = {}
    for name in ("n.exr", "n.tif"):
        rep = tmp_path / f"{name}.json"
        res = runner.invoke(cli, ["evaluate", str(tmp_path / name), "--reference", str(ref), "--json", str(rep)])
        assert res.exit_code == 0, res.output
        d = json.loads(rep.read_text())["images"][0]
        assert d["psnr_domain"] == "srgb-encoded"
        got[name] = d["psnr_db"]
    assert got["n.exr"] == pytest.approx(got["n.tif"], abs=0.05)
    # 0.02 rms noise on codes clipped to [0, 1]: PSNR = -20 log10(rms), a little above 34 dB
    assert 33.5 < got["n.tif"] < 36.0


# --------------------------------------------------------------- one white scale

#: How far a display render's score may move from the EXR render's of the same
#: table (S-CIELAB mean ΔE*ab against a simulate folder): the quantisation of the
#: format. 16-bit TIFF: steps of 1/65535 in sRGB code, nothing visible; 8-bit PNG:
#: steps of 1/255, about 0.2-0.4 ΔE*ab per pixel in dark colours, averaging to under
#: a hundredth after the S-CIELAB filters; JPEG q95 4:4:4 adds its compression.
#: (Measured: 0.0004, 0.002, 0.018. Before one white scale, PNG scored 2.5 above EXR.)
FORMAT_BOUNDS = {"tiff": 0.005, "png": 0.02, "jpg": 0.06}
#: The same for PSNR in dB (linear XYZ, the reference's domain); measured 0.01, 0.1, 0.98.
PSNR_BOUNDS = {"tiff": 0.1, "png": 0.4, "jpg": 2.0}


@pytest.fixture(scope="module")
def sim_renders(tmp_path_factory):
    """A small Bayer simulation, a table trained on it, and its renders in every format."""
    from click.testing import CliRunner

    run = CliRunner()
    base = tmp_path_factory.mktemp("white")
    cam = ROOT / "sample_configs" / "bayer.toml"
    common = ["--size", "160x120", "--seed", "1"]
    r = run.invoke(cli, ["simulate", str(cam), "-o", str(base / "train"), "--scene", "macbeth",
                         "--scene", "natural", "--lux", "60", "--lux", "400", *common])
    assert r.exit_code == 0, r.output
    r = run.invoke(cli, ["simulate", str(cam), "-o", str(base / "test"), "--scene", "macbeth",
                         "--scene", "slanted-edge", "--lux", "150", "--size", "160x120", "--seed", "2"])
    assert r.exit_code == 0, r.output
    table = base / "t.npz"
    r = run.invoke(cli, ["train", str(base / "train"), "-o", str(table), "--levels", "8", "--seed", "1"])
    assert r.exit_code == 0, r.output
    raws = sorted(str(p) for p in (base / "test").glob("*.dng"))
    assert raws
    out = {"_base": str(base)}
    for fmt in ("exr", *FORMAT_BOUNDS):
        r = run.invoke(cli, ["render", str(table), *raws, "-o", str(base / fmt), "--format", fmt])
        assert r.exit_code == 0, r.output
        rep = base / f"{fmt}.json"
        r = run.invoke(cli, ["evaluate", str(base / fmt), "--reference", str(base / "test"), "--json", str(rep)])
        assert r.exit_code == 0, r.output
        out[fmt] = {i["name"]: i for i in json.loads(rep.read_text())["images"]}
    return out


@pytest.mark.parametrize("fmt", sorted(FORMAT_BOUNDS))
def test_every_format_scores_on_one_white_scale(sim_renders, fmt):
    assert sim_renders[fmt]
    exr = sim_renders["exr"]
    for name, d in sim_renders[fmt].items():
        assert d["scielab_mean"] == pytest.approx(exr[name]["scielab_mean"], abs=FORMAT_BOUNDS[fmt]), name
        assert d["psnr_db"] == pytest.approx(exr[name]["psnr_db"], abs=PSNR_BOUNDS[fmt]), name
        assert d["psnr_domain"] == "linear-xyz"
    assert exr.keys() == sim_renders[fmt].keys()


def test_display_white_is_linear_y_one(tmp_path):
    """A display-encoded render of the reference's own XYZ, encoded with Y = 1 as white,
    scores ~0 against a linear reference whose white Y is not 1."""
    from l3cli.colourspace import convert
    from l3cli.evaluate import EvalItem, evaluate_item

    xyz = np.asarray(convert(_scene(), "srgb", "xyz"), dtype=np.float32) * 0.9
    write_image(tmp_path / "ref.exr", xyz, space="xyz")
    write_image(tmp_path / "r.tif", np.asarray(convert(xyz, "xyz", "srgb"), np.float32), space="srgb", bits=16)
    cap = {"white_xyz": [1.04, 1.1, 1.2]}  # the manifest's white on the target scale
    rep = evaluate_item(EvalItem("r", tmp_path / "r.tif", tmp_path / "ref.exr", cap, {}, "xyz"))
    assert rep.values["scielab_mean"] < 0.02


def test_render_takes_a_simulate_folder(runner, sim_renders, tmp_path):
    """`l3 render TABLE SIM_DIR` renders the captures of the folder into a folder."""
    base = Path(sim_renders["_base"])
    out = tmp_path / "out"
    res = runner.invoke(cli, ["render", str(base / "t.npz"), str(base / "test"), "-o", str(out),
                              "--format", "tiff"])
    assert res.exit_code == 0, res.output
    got = sorted(p.name for p in out.iterdir())
    assert got == sorted(f"{n}.tif" for n in sim_renders["exr"])
    from l3cli.io.image import read_image

    for p in out.iterdir():  # the same pixels as rendering the files by name
        np.testing.assert_array_equal(read_image(p)[0], read_image(base / "tiff" / p.name)[0])
    res = runner.invoke(cli, ["render", str(base / "t.npz"), str(tmp_path), "-o", str(tmp_path / "o2")])
    assert res.exit_code == 1 and "no raw files in the folder" in res.output
