"""`l3 simulate` end to end: files, manifest, DNG rendering, bad input leaves nothing behind."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from l3cli.cli.main import cli

REPO = Path(__file__).resolve().parents[2]
BAYER = str(REPO / "sample_configs" / "bayer.toml")
RGBW = str(REPO / "sample_configs" / "rgbw.toml")
RGBNIR = str(REPO / "sample_configs" / "rgbnir.toml")


def no_leftovers(parent: Path) -> bool:
    return not any(p.name.startswith(".l3-tmp") for p in parent.iterdir())


def test_bayer_macbeth_and_edge(runner, tmp_path: Path) -> None:
    out = tmp_path / "sim"
    r = runner.invoke(cli, ["simulate", BAYER, "-o", str(out), "--scene", "macbeth",
                            "--scene", "slanted-edge", "--lux", "100", "--lux", "1000",
                            "--size", "192x128", "--seed", "4"])
    assert r.exit_code == 0, r.output
    m = json.loads((out / "manifest.json").read_text())
    assert m["format"] == "l3-simulation" and m["version"] == 1
    assert m["camera"]["cfa"] and m["camera"]["pixel_pitch_um"] == 2.2 and m["camera"]["f_number"] == 4.0
    assert m["target"]["space"] == "xyz" and "H_ref" in m["target"]["scale"]
    caps = {c["stem"]: c for c in m["captures"]}
    assert set(caps) == {"macbeth_D65_0100lux", "macbeth_D65_1000lux",
                         "slanted-edge_D65_0100lux", "slanted-edge_D65_1000lux"}
    from l3cli.io.image import read_image
    from l3cli.io.raw import read_raw

    for c in caps.values():
        for k in ("raw", "target", "noise_free"):
            assert (out / c[k]).is_file()
        assert c["width"] == 192 and c["height"] == 128 and c["exposure_s"] > 0
        raw = read_raw(out / c["raw"])
        assert raw.mosaic.shape == (128, 192) and raw.cfa.spec == m["camera"]["cfa"]
        tgt, space = read_image(out / c["target"])
        assert tgt.shape == (128, 192, 3) and tgt.dtype == np.float32 and space == "xyz"
        nf, _ = read_image(out / c["noise_free"])
        assert nf.shape[:2] == (128, 192)
        # Noise-free and raw share the normalisation.
        assert abs(float(nf.mean()) - float(raw.mosaic.mean())) < 0.02
    mc = caps["macbeth_D65_0100lux"]["chart"]
    assert mc["rows"] == 4 and mc["cols"] == 6 and mc["white_index"] == 18
    assert len(mc["patches"]) == 24 and len(mc["reference_xyz"]) == 24
    ref = np.array(mc["reference_xyz"])
    assert ref[18, 1] > ref[19, 1] > ref[20, 1] > ref[21, 1] > ref[22, 1] > ref[23, 1]
    assert caps["macbeth_D65_0100lux"]["edge"] is None
    e = caps["slanted-edge_D65_0100lux"]["edge"]
    assert e["angle_deg"] == 5.0 and len(e["roi"]) == 4
    assert caps["slanted-edge_D65_0100lux"]["chart"] is None
    # Target on a fixed scale: same exposure → ×10 light gives ×10 target where the exposure is equal.
    t100 = read_image(out / caps["macbeth_D65_0100lux"]["target"])[0]
    t1000 = read_image(out / caps["macbeth_D65_1000lux"]["target"])[0]
    e100, e1000 = caps["macbeth_D65_0100lux"]["exposure_s"], caps["macbeth_D65_1000lux"]["exposure_s"]
    ratio = float(t1000[..., 1].mean() / t100[..., 1].mean())
    assert ratio == pytest.approx(10 * e1000 / e100, rel=1e-3)
    assert no_leftovers(tmp_path)


def test_bayer_dng_renders_through_rawpy(runner, tmp_path: Path) -> None:
    """Must show: rawpy.postprocess() of the DNG orders Macbeth patch colours like the chart."""
    import rawpy

    out = tmp_path / "sim"
    r = runner.invoke(cli, ["simulate", BAYER, "-o", str(out), "--scene", "macbeth", "--lux", "300",
                            "--size", "240x160"])
    assert r.exit_code == 0, r.output
    cap = json.loads((out / "manifest.json").read_text())["captures"][0]
    with rawpy.imread(str(out / cap["raw"])) as raw:
        rgb = raw.postprocess(use_camera_wb=True, no_auto_bright=True, output_bps=16).astype(float)
    assert rgb.shape[:2] == (160, 240)

    def mean(i: int) -> np.ndarray:
        x0, y0, x1, y1 = cap["chart"]["patches"][i]
        dx, dy = (x1 - x0) // 4, (y1 - y0) // 4
        return rgb[y0 + dy:y1 - dy, x0 + dx:x1 - dx].reshape(-1, 3).mean(axis=0)

    red, green, blue, white, black = mean(14), mean(13), mean(12), mean(18), mean(23)
    assert red[0] > red[1] and red[0] > red[2]
    assert green[1] > green[0] and green[1] > green[2]
    assert blue[2] > blue[0] and blue[2] > blue[1]
    assert np.all(white > 2 * black)
    # White renders neutral-ish (camera white balance from AsShotNeutral).
    assert white.max() / white.min() < 1.25


@pytest.mark.parametrize(("config", "period"), [("rgbw.toml", (2, 2)), ("rgbw-4x4.toml", (4, 4))])
def test_rgbw_writes_tiff_and_sidecar(runner, tmp_path: Path, config: str, period: tuple) -> None:
    out = tmp_path / "sim"
    r = runner.invoke(cli, ["simulate", str(REPO / "sample_configs" / config), "-o", str(out),
                            "--scene", "natural:coffee",
                            "--lux", "50", "--size", "96x64"])
    assert r.exit_code == 0, r.output
    cap = json.loads((out / "manifest.json").read_text())["captures"][0]
    assert cap["raw"].endswith(".tif") and (out / (cap["raw"] + ".toml")).is_file()
    from l3cli.io.raw import read_raw

    raw = read_raw(out / cap["raw"])
    assert raw.cfa.period == period and "W" in raw.cfa.channels
    assert cap["illuminant"] == "visir-DAY"


def test_default_scenes_and_levels(runner, tmp_path: Path) -> None:
    out = tmp_path / "sim"
    r = runner.invoke(cli, ["simulate", BAYER, "-o", str(out), "--size", "64x48"])
    assert r.exit_code == 0, r.output
    m = json.loads((out / "manifest.json").read_text())
    scenes = {c["scene"] for c in m["captures"]}
    assert "macbeth" in scenes and {"coffee", "astronaut"} <= scenes
    assert {c["lux"] for c in m["captures"]} == {10.0, 100.0, 1000.0}


@pytest.mark.parametrize("camera", [BAYER, RGBW], ids=["bayer-dng", "rgbw-tiff"])
def test_seed_bit_identical(runner, tmp_path: Path, camera: str) -> None:
    """Every file of SIM_DIR (raw, sidecar, EXRs, manifest) is byte-identical for a seed."""
    import time

    outs = []
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        out = tmp_path / name
        r = runner.invoke(cli, ["simulate", camera, "-o", str(out), "--scene", "macbeth",
                                "--scene", "natural:coffee", "--lux", "20", "--size", "64x48",
                                "--seed", str(seed)])
        assert r.exit_code == 0, r.output
        outs.append({p.name: p.read_bytes() for p in sorted(out.iterdir())})
        time.sleep(1.1)  # a time stamp in any file would now differ
    assert len(outs[0]) >= 7 and outs[0] == outs[1]
    raws = [n for n in outs[0] if n.endswith((".dng", ".tif"))]
    assert raws and all(outs[0][n] != outs[2][n] for n in raws)


def test_user_rgb_image_and_spectral_cube(runner, tmp_path: Path) -> None:
    from l3cli.io.image import write_image

    img = np.zeros((40, 60, 3), np.float32)
    img[:, :30] = [0.8, 0.2, 0.1]
    img[:, 30:] = [0.1, 0.3, 0.9]
    write_image(tmp_path / "two.png", img, space="srgb")
    wl = np.arange(380, 1081, 20.0)
    cube = np.tile(np.linspace(0.2, 0.6, wl.size, dtype=np.float32), (30, 40, 1))
    np.savez(tmp_path / "cube.npz", wavelength=wl, reflectance=cube)
    out = tmp_path / "sim"
    r = runner.invoke(cli, ["simulate", BAYER, "-o", str(out), "--scene", str(tmp_path / "two.png"),
                            "--scene", str(tmp_path / "cube.npz"), "--lux", "100",
                            "--size", "60x40"])
    assert r.exit_code == 0, r.output
    m = json.loads((out / "manifest.json").read_text())
    assert [c["scene"] for c in m["captures"]] == ["two", "cube"]
    # A cube that does not cover the camera's wavelengths is refused.
    np.savez(tmp_path / "short.npz", wavelength=wl[1:-2], reflectance=cube[..., 1:-2])
    r2 = runner.invoke(cli, ["simulate", BAYER, "-o", str(tmp_path / "sim2"), "--scene",
                             str(tmp_path / "short.npz"), "--lux", "100", "--size", "60x40"])
    assert r2.exit_code == 1 and "covers 400-1040 nm" in r2.output and "needs 380-" in r2.output
    from l3cli.io.image import read_image

    tgt = read_image(out / m["captures"][0]["target"])[0]
    from l3cli.colourspace import convert

    rgb = convert(tgt, "xyz", "linear-srgb")
    left, right = rgb[:, 5:25].reshape(-1, 3).mean(0), rgb[:, 35:55].reshape(-1, 3).mean(0)
    assert left[0] > left[2] and right[2] > right[0]


def test_existing_sim_dir_is_updated(runner, tmp_path: Path) -> None:
    out = tmp_path / "sim"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    r = runner.invoke(cli, ["simulate", BAYER, "-o", str(out), "--scene", "macbeth",
                            "--lux", "100", "--size", "64x48"])
    assert r.exit_code == 0, r.output
    assert (out / "keep.txt").exists() and (out / "manifest.json").exists()
    assert no_leftovers(tmp_path) and no_leftovers(out)


@pytest.mark.parametrize(
    "args, code, words",
    [
        (["--illuminant", "D66"], 1, ["D66", "D65", "visir-DAY"]),
        (["--scene", "beach"], 1, ["beach", "macbeth", "slanted-edge", "natural"]),
        (["--lux", "0"], 2, ["--lux", "> 0"]),
        (["--lux", "-3"], 2, ["--lux"]),
        (["--size", "10x10"], 2, ["--size"]),
        (["--scene", "/nonexistent/x.png"], 1, ["does not exist"]),
    ],
)
def test_bad_options(runner, tmp_path: Path, args, code, words) -> None:
    out = tmp_path / "sim"
    r = runner.invoke(cli, ["simulate", BAYER, "-o", str(out), "--size", "64x48"] + args)
    assert r.exit_code == code, r.output
    for w in words:
        assert w in r.output
    assert not out.exists() and no_leftovers(tmp_path)


def test_illuminant_range_not_covered(runner, tmp_path: Path) -> None:
    out = tmp_path / "sim"
    r = runner.invoke(cli, ["simulate", RGBNIR, "-o", str(out), "--illuminant", "D65",
                            "--size", "64x48"])
    assert r.exit_code == 1
    assert "300-780 nm" in r.output and "1060 nm" in r.output
    assert not out.exists() and no_leftovers(tmp_path)


def test_unreadable_scene_after_good_one_leaves_nothing(runner, tmp_path: Path) -> None:
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"not a png at all")
    out = tmp_path / "sim"
    r = runner.invoke(cli, ["simulate", BAYER, "-o", str(out), "--scene", "macbeth",
                            "--scene", str(bad), "--lux", "100", "--size", "64x48"])
    assert r.exit_code == 1
    assert "broken.png" in r.output and "Traceback" not in r.output
    assert not out.exists() and no_leftovers(tmp_path)


def test_bad_camera_file(runner, tmp_path: Path) -> None:
    cam = tmp_path / "cam.toml"
    cam.write_text((REPO / "sample_configs" / "bayer.toml").read_text().replace("f_number = 4.0", "f_number = 0"))
    out = tmp_path / "sim"
    r = runner.invoke(cli, ["simulate", str(cam), "-o", str(out)])
    assert r.exit_code == 1 and "optics.f_number" in r.output and "cam.toml" in r.output
    assert not out.exists()


def test_list(runner) -> None:
    r = runner.invoke(cli, ["simulate", "--list"])
    assert r.exit_code == 0 and "visir-A" in r.output and "interleaved-rgbw" in r.output
