"""`l3 evaluate` through the command line: image pairs, simulation folders, the
JSON contract, plots and bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import colour
import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.io.image import write_image

CONTRACT_KEYS = {"name", "scielab_mean", "scielab_median", "scielab_p90", "psnr_db"}


def _smooth_image(h=96, w=128, seed=0):
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    return np.clip(gaussian_filter(rng.random((h, w, 3)), (3, 3, 0)) * 1.4 - 0.2, 0, 1).astype(np.float32)


@pytest.fixture
def pngs(tmp_path):
    ref = _smooth_image()
    rng = np.random.default_rng(5)
    noisy = np.clip(ref + rng.normal(0, 0.03, ref.shape), 0, 1).astype(np.float32)
    write_image(tmp_path / "ref.png", ref, space="srgb")
    write_image(tmp_path / "same.png", ref, space="srgb")
    write_image(tmp_path / "noisy.png", noisy, space="srgb")
    return tmp_path


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory):
    """A small simulated capture set (macbeth + slanted edge), noise-free."""
    from click.testing import CliRunner

    out = tmp_path_factory.mktemp("sim") / "sim"
    cfg = Path(__file__).parents[2] / "sample_configs" / "bayer.toml"
    res = CliRunner().invoke(cli, ["simulate", str(cfg), "-o", str(out), "--scene", "macbeth",
                                   "--scene", "slanted-edge", "--lux", "200", "--size", "192x128",
                                   "--no-noise", "--seed", "3"])
    assert res.exit_code == 0, res.output
    return out


def test_identical_pngs_score_zero(runner, pngs):
    rep = pngs / "rep.json"
    res = runner.invoke(cli, ["evaluate", str(pngs / "same.png"), "--reference", str(pngs / "ref.png"),
                              "--json", str(rep)])
    assert res.exit_code == 0, res.output
    assert "S-CIELAB" in res.output and "same.png" in res.output
    d = json.loads(rep.read_text())
    img = d["images"][0]
    assert CONTRACT_KEYS <= set(img)
    assert img["scielab_mean"] == 0.0 and img["scielab_p90"] == 0.0
    assert img["psnr_db"] is None  # infinite PSNR is written as null
    assert d["summary"]["scielab_mean"] == 0.0


def test_several_pairs_and_greedy_reference(runner, pngs, tmp_path):
    rep = tmp_path / "r.json"
    res = runner.invoke(cli, ["evaluate", str(pngs / "same.png"), str(pngs / "noisy.png"),
                              "--reference", str(pngs / "ref.png"), str(pngs / "ref.png"),
                              "--json", str(rep), "--dpi", "96", "--distance", "1.0"])
    assert res.exit_code == 0, res.output
    d = json.loads(rep.read_text())
    names = [i["name"] for i in d["images"]]
    assert names == ["same.png", "noisy.png"]
    noisy = d["images"][1]
    assert 0 < noisy["scielab_mean"] < noisy["scielab_p90"]
    assert noisy["scielab_de2000_mean"] > 0
    # PSNR on 8-bit codes: noise of 0.03 (clipped) gives about 30 dB
    assert 28 < noisy["psnr_db"] < 33
    assert d["summary"]["scielab_mean"] == pytest.approx(noisy["scielab_mean"] / 2)
    assert d["summary"]["psnr_db"] == pytest.approx(noisy["psnr_db"])  # inf is left out
    assert d["settings"]["samples_per_degree"] == 66


def test_matches_library_scielab(runner, pngs, tmp_path):
    from l3cli.colourspace import convert
    from l3cli.io.image import read_image
    from l3cli.metrics.scielab import scielab

    rep = tmp_path / "r.json"
    res = runner.invoke(cli, ["evaluate", str(pngs / "noisy.png"), "--reference", str(pngs / "ref.png"),
                              "--json", str(rep), "--filters", "original", "--dpi", "150"])
    assert res.exit_code == 0, res.output
    a = convert(read_image(pngs / "ref.png")[0], "srgb", "xyz") * 100
    b = convert(read_image(pngs / "noisy.png")[0], "srgb", "xyz") * 100
    lib = scielab(a, b, dpi=150, distance=1.0, version="original")
    assert json.loads(rep.read_text())["images"][0]["scielab_mean"] == pytest.approx(lib.mean, rel=1e-5)


def test_exclude_border_ignores_corrupted_margin(runner, pngs, tmp_path):
    from l3cli.io.image import read_image

    img = read_image(pngs / "ref.png")[0].copy()
    img[:4] = 0
    img[-4:] = 1
    img[:, :4] = [1, 0, 0]
    img[:, -4:] = [0, 0, 1]
    write_image(tmp_path / "bad_border.png", img, space="srgb")
    args = ["evaluate", str(tmp_path / "bad_border.png"), "--reference", str(pngs / "ref.png"),
            "--json", str(tmp_path / "r.json")]
    res = runner.invoke(cli, args)
    assert json.loads((tmp_path / "r.json").read_text())["images"][0]["scielab_mean"] > 0.5
    res = runner.invoke(cli, args + ["--exclude-border", "4"])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "r.json").read_text())["images"][0]["scielab_mean"] == 0.0


def test_chart_corners_on_real_images(runner, tmp_path):
    cc = colour.CCS_COLOURCHECKERS["ColorChecker24 - After November 2014"]
    xyz = colour.xyY_to_XYZ(np.array(list(cc.data.values())))
    lin = np.clip(colour.XYZ_to_sRGB(xyz, apply_cctf_encoding=False), 0, 1)

    def chart(colours):
        img = np.full((100, 140, 3), 0.05, dtype=np.float32)
        for i, c in enumerate(colours):
            r, q = divmod(i, 6)
            img[10 + r * 20 + 2:10 + r * 20 + 18, 10 + q * 20 + 2:10 + q * 20 + 18] = c
        return colour.cctf_encoding(img, function="sRGB").astype(np.float32)

    # a rendered chart whose greys are right but every other patch is 10 % darker
    shifted = lin.copy()
    shifted[:18] *= 0.9
    write_image(tmp_path / "ref.png", chart(lin), space="srgb")
    write_image(tmp_path / "out.png", chart(shifted), space="srgb")
    corners = "10,10,130,10,130,90,10,90"
    res = runner.invoke(cli, ["evaluate", str(tmp_path / "out.png"), "--reference", str(tmp_path / "ref.png"),
                              "--chart", corners, "--json", str(tmp_path / "r.json")])
    assert res.exit_code == 0, res.output
    got = json.loads((tmp_path / "r.json").read_text())["images"][0]["macbeth_de_mean"]
    # expected: ΔE*ab between the 8-bit colours' CIELAB (white = the white patch)
    from l3cli.io.image import read_image
    from l3cli.metrics.macbeth import chart_patches_from_corners, macbeth_delta_e, patch_means

    a = colour.sRGB_to_XYZ(read_image(tmp_path / "ref.png")[0], chromatic_adaptation_transform=None)
    b = colour.sRGB_to_XYZ(read_image(tmp_path / "out.png")[0], chromatic_adaptation_transform=None)
    boxes = chart_patches_from_corners([float(v) for v in corners.split(",")], image_shape=a.shape)
    exp = macbeth_delta_e(patch_means(b, boxes), patch_means(a, boxes))
    assert got == pytest.approx(exp.mean_ab, rel=1e-3)
    assert exp.delta_e_ab[18:].max() < 0.05 and exp.delta_e_ab[:18].min() > 1.0


def test_simulation_folder_ideal_target(runner, sim_dir, tmp_path):
    renders = tmp_path / "renders"
    renders.mkdir()
    man = json.loads((sim_dir / "manifest.json").read_text())
    for cap in man["captures"]:
        shutil.copy(sim_dir / cap["target"], renders / f"{cap['stem']}.exr")
    rep = tmp_path / "r.json"
    plots = tmp_path / "plots"
    res = runner.invoke(cli, ["evaluate", str(renders), "--reference", str(sim_dir), "--json", str(rep),
                              "--plots", str(plots)])
    assert res.exit_code == 0, res.output
    d = json.loads(rep.read_text())
    by = {i["name"]: i for i in d["images"]}
    mac = next(v for k, v in by.items() if k.startswith("macbeth"))
    edge = next(v for k, v in by.items() if k.startswith("slanted"))
    assert mac["macbeth_de_mean"] < 0.5  # the ideal target of a simulated chart
    assert mac["scielab_mean"] == 0.0
    assert "mtf50_cy_per_mm" in edge and "macbeth_de_mean" not in edge
    pitch = man["camera"]["pixel_pitch_um"]
    assert edge["mtf50_cy_per_mm"] == pytest.approx(edge["mtf50_cy_per_px"] / (pitch * 1e-3))
    assert 0.05 < edge["mtf50_cy_per_px"] < 1.0
    assert {"scielab_mean", "macbeth_de_mean", "mtf50_cy_per_mm"} <= set(d["summary"])
    names = {p.name for p in plots.iterdir()}
    assert any(n.endswith("_macbeth.png") for n in names)
    assert any(n.endswith("_mtf.png") for n in names)
    assert any(n.endswith("_scielab.png") for n in names)
    assert any(n.endswith("_crops.png") for n in names)
    import matplotlib

    assert matplotlib.get_backend().lower() == "agg"


def test_simulation_known_colour_shift(runner, sim_dir, tmp_path):
    """Scaling a render's X and Z by known factors shifts every patch by a computable ΔE."""
    from l3cli.io.image import read_image
    from l3cli.metrics.macbeth import macbeth_delta_e

    man = json.loads((sim_dir / "manifest.json").read_text())
    cap = next(c for c in man["captures"] if c["chart"])
    img, _ = read_image(sim_dir / cap["target"])
    gain = np.array([1.05, 1.0, 0.9], dtype=np.float32)
    write_image(tmp_path / f"{cap['stem']}.exr", img * gain, space="xyz")
    rep = tmp_path / "r.json"
    res = runner.invoke(cli, ["evaluate", str(tmp_path / f"{cap['stem']}.exr"), "--reference", str(sim_dir),
                              "--json", str(rep)])
    assert res.exit_code == 0, res.output
    ideal = np.asarray(cap["chart"]["reference_xyz"])
    expected = macbeth_delta_e(ideal * gain, ideal).mean_ab
    assert expected > 2
    got = json.loads(rep.read_text())["images"][0]["macbeth_de_mean"]
    assert got == pytest.approx(expected, abs=0.1)


def test_different_sizes_names_both(runner, pngs, tmp_path):
    write_image(tmp_path / "small.png", _smooth_image(90, 120), space="srgb")
    res = runner.invoke(cli, ["evaluate", str(tmp_path / "small.png"), "--reference", str(pngs / "ref.png")])
    assert res.exit_code == 1
    assert "120x90" in res.output and "128x96" in res.output


def test_unknown_encoding(runner, pngs, tmp_path):
    import OpenImageIO as oiio

    path = tmp_path / "odd.exr"
    spec = oiio.ImageSpec(128, 96, 3, "float")
    spec.attribute("l3:space", "gamma22")
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    out.write_image(np.zeros((96, 128, 3), np.float32))
    out.close()
    res = runner.invoke(cli, ["evaluate", str(path), "--reference", str(pngs / "ref.png")])
    assert res.exit_code == 1
    assert "unknown encoding" in res.output and "gamma22" in res.output


def test_chart_corners_outside_image(runner, pngs):
    res = runner.invoke(cli, ["evaluate", str(pngs / "same.png"), "--reference", str(pngs / "ref.png"),
                              "--chart", "10,10,500,10,500,90,10,90"])
    assert res.exit_code == 1
    assert "outside the 128x96 image" in res.output


def test_no_edge_found(runner, tmp_path):
    flat = np.full((64, 64, 3), 0.5, dtype=np.float32)
    write_image(tmp_path / "a.png", flat, space="srgb")
    res = runner.invoke(cli, ["evaluate", str(tmp_path / "a.png"), "--reference", str(tmp_path / "a.png"),
                              "--edge", "8,8,56,56", "--json", str(tmp_path / "r.json")])
    assert res.exit_code == 1
    assert "no edge found" in res.output
    assert not (tmp_path / "r.json").exists()


def test_usage_errors(runner, pngs):
    res = runner.invoke(cli, ["evaluate", str(pngs / "same.png"), "--reference", str(pngs / "ref.png"),
                              "--chart", "1,2,3"])
    assert res.exit_code == 2 and "8 comma-separated numbers" in res.output
    res = runner.invoke(cli, ["evaluate", str(pngs / "same.png"), "--reference", str(pngs / "ref.png"),
                              str(pngs / "ref.png")])
    assert res.exit_code == 1 and "1 rendered image(s) but 2 reference(s)" in res.output
    res = runner.invoke(cli, ["evaluate", str(pngs / "same.png"), "--reference", str(pngs / "ref.png"),
                              "--dpi", "0"])
    assert res.exit_code == 2


def test_render_not_in_simulation(runner, sim_dir, pngs):
    res = runner.invoke(cli, ["evaluate", str(pngs / "same.png"), "--reference", str(sim_dir)])
    assert res.exit_code == 1 and "is not a capture of" in res.output


def test_exposure_error_counts_in_scielab_not_in_macbeth(runner, sim_dir, tmp_path):
    """S-CIELAB uses the capture's fixed white (manifest white_xyz); the Macbeth ΔE
    normalises the white patch, so a pure exposure error only shows in S-CIELAB."""
    from l3cli.io.image import read_image

    man = json.loads((sim_dir / "manifest.json").read_text())
    cap = next(c for c in man["captures"] if c["chart"])
    img, _ = read_image(sim_dir / cap["target"])
    write_image(tmp_path / f"{cap['stem']}.exr", img * 0.7, space="xyz")
    rep = tmp_path / "r.json"
    res = runner.invoke(cli, ["evaluate", str(tmp_path / f"{cap['stem']}.exr"), "--reference", str(sim_dir),
                              "--json", str(rep)])
    assert res.exit_code == 0, res.output
    d = json.loads(rep.read_text())["images"][0]
    assert d["macbeth_de_mean"] < 0.5
    assert d["scielab_mean"] > 3


def test_load_xyz_scales(tmp_path):
    from l3cli.evaluate import load_xyz

    write_image(tmp_path / "white.png", np.ones((4, 4, 3), np.float32), space="srgb")
    xyz, space = load_xyz(tmp_path / "white.png")
    assert space == "srgb"
    np.testing.assert_allclose(xyz[0, 0], [95.047, 100.0, 108.883], rtol=2e-3)
    write_image(tmp_path / "lin.exr", np.full((4, 4, 3), 0.5, np.float32), space="linear-srgb")
    xyz, space = load_xyz(tmp_path / "lin.exr")
    assert space == "linear-srgb"
    np.testing.assert_allclose(xyz[0, 0], 0.5 * np.array([0.95047, 1.0, 1.08883]), rtol=2e-3)


def test_linear_render_against_display_reference(runner, pngs, tmp_path):
    """An EXR in linear sRGB equal to the decoded PNG scores ~0 against the PNG."""
    from l3cli.colourspace import srgb_decode
    from l3cli.io.image import read_image

    enc = read_image(pngs / "ref.png")[0]
    write_image(tmp_path / "lin.exr", srgb_decode(enc), space="linear-srgb")
    rep = tmp_path / "r.json"
    res = runner.invoke(cli, ["evaluate", str(tmp_path / "lin.exr"), "--reference", str(pngs / "ref.png"),
                              "--json", str(rep)])
    assert res.exit_code == 0, res.output
    assert json.loads(rep.read_text())["images"][0]["scielab_mean"] < 0.01


def test_json_has_patch_errors_and_mtf_curve(runner, sim_dir, tmp_path):
    renders = tmp_path / "renders"
    renders.mkdir()
    man = json.loads((sim_dir / "manifest.json").read_text())
    for cap in man["captures"]:
        shutil.copy(sim_dir / cap["target"], renders / f"{cap['stem']}.exr")
    rep = tmp_path / "r.json"
    res = runner.invoke(cli, ["evaluate", str(renders), "--reference", str(sim_dir), "--json", str(rep)])
    assert res.exit_code == 0, res.output
    imgs = json.loads(rep.read_text())["images"]
    mac = next(i for i in imgs if "macbeth_patches" in i)
    assert len(mac["macbeth_patches"]["de_ab"]) == 24
    assert np.mean(mac["macbeth_patches"]["de_ab"]) == pytest.approx(mac["macbeth_de_mean"], abs=1e-3)
    edge = next(i for i in imgs if "mtf_curve" in i)
    f, m = np.array(edge["mtf_curve"]["cy_per_px"]), np.array(edge["mtf_curve"]["mtf"])
    assert f[0] == 0 and m[0] == pytest.approx(1.0)
    assert np.interp(edge["mtf50_cy_per_px"], f, m) == pytest.approx(0.5, abs=0.01)


def test_align_reference_undoes_crops_and_flips():
    from scipy.ndimage import gaussian_filter

    from l3cli.align import FLIPS, apply_flip
    from l3cli.evaluate import align_reference

    rng = np.random.default_rng(8)
    full = gaussian_filter(rng.random((96, 128, 3)), (1.5, 1.5, 0)) * 100
    window = full[5:85, 3:83]  # square: every orientation fits
    for flip in FLIPS:
        ref = np.ascontiguousarray(apply_flip(window, flip))
        (y0, x0, h, w), back = align_reference(full, ref)
        assert (y0, x0, h, w) == (5, 3, 80, 80)
        np.testing.assert_array_equal(apply_flip(full[y0:y0 + h, x0:x0 + w], back), ref)


def test_align_option_scores_a_cropped_mirrored_reference(runner, pngs, tmp_path):
    from l3cli.io.image import read_image

    img = read_image(pngs / "ref.png")[0]
    write_image(tmp_path / "cam.png", img[4:-4, 6:-2][:, ::-1], space="srgb")
    args = ["evaluate", str(pngs / "same.png"), "--reference", str(tmp_path / "cam.png"),
            "--json", str(tmp_path / "r.json")]
    res = runner.invoke(cli, args)
    assert res.exit_code == 1 and "use --align" in res.output and "120x88" in res.output
    res = runner.invoke(cli, args + ["--align"])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "r.json").read_text())["images"][0]["scielab_mean"] == 0.0
    other = tmp_path / "other.png"
    write_image(other, _smooth_image(80, 100, seed=9), space="srgb")
    res = runner.invoke(cli, ["evaluate", str(pngs / "same.png"), "--reference", str(other), "--align"])
    assert res.exit_code == 1 and "does not align with rendered" in res.output
