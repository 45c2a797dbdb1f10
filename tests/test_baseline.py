"""The conventional baseline: matrix recovery, Menon 2007 beats bilinear on a
noise-free simulated Bayer capture, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from l3cli.baseline import BaselineModel, bayer_pattern, demosaic, fit_baseline, render_baseline
from l3cli.cfa import CFA
from l3cli.cli.main import cli
from l3cli.errors import ConfigError, InputError
from l3cli.io.image import write_image
from l3cli.io.raw import RawImage, read_raw, write_raw


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory):
    """A noise-free simulated Bayer capture set: the Macbeth chart and a natural scene."""
    from click.testing import CliRunner

    out = tmp_path_factory.mktemp("simb") / "sim"
    cfg = Path(__file__).parents[1] / "sample_configs" / "bayer.toml"
    res = CliRunner().invoke(cli, ["simulate", str(cfg), "-o", str(out), "--scene", "macbeth",
                                   "--scene", "natural", "--lux", "200", "--size", "192x128",
                                   "--no-noise", "--seed", "2"])
    assert res.exit_code == 0, res.output
    return out


def _raw(mosaic, spec="RGGB"):
    return RawImage(mosaic=np.asarray(mosaic, np.float32), cfa=CFA.from_spec(spec),
                    black_level=np.zeros(4), white_level=1.0)


def test_bayer_patterns():
    for spec in ("RGGB", "BGGR", "GRBG", "GBRG"):
        assert bayer_pattern(CFA.from_spec(spec)) == spec
    with pytest.raises(InputError, match="not a Bayer pattern"):
        bayer_pattern(CFA.from_spec("R G/NIR B"))


def test_uniform_grey_demosaics_to_itself():
    rgb = demosaic(_raw(np.full((16, 16), 0.3)), method="menon2007")
    np.testing.assert_allclose(rgb, 0.3, atol=1e-6)


def test_unknown_method():
    with pytest.raises(ConfigError, match="bilinear, malvar2004, menon2007"):
        demosaic(_raw(np.zeros((8, 8))), method="ahd")


def test_matrix_is_recovered_from_exact_pairs(tmp_path):
    """Targets made as demosaicked camera RGB @ M are fitted back to M."""
    rng = np.random.default_rng(0)
    from scipy.ndimage import gaussian_filter

    m_true = np.array([[0.6, 0.3, 0.05], [0.25, 0.8, 0.1], [0.1, -0.1, 0.9]])
    folder = tmp_path / "pairs"
    folder.mkdir()
    for i in range(2):
        rgb = gaussian_filter(rng.random((48, 64, 3)), (2, 2, 0)) * 0.8
        mosaic = np.zeros((48, 64))
        mosaic[0::2, 0::2] = rgb[0::2, 0::2, 0]
        mosaic[0::2, 1::2] = rgb[0::2, 1::2, 1]
        mosaic[1::2, 0::2] = rgb[1::2, 0::2, 1]
        mosaic[1::2, 1::2] = rgb[1::2, 1::2, 2]
        dn = np.round(mosaic * 4000).astype(np.uint16)
        write_raw(folder / f"c{i}.dng", dn, CFA.from_spec("RGGB"), black_level=0, white_level=4000)
        cam = demosaic(read_raw(folder / f"c{i}.dng"), method="bilinear")
        write_image(folder / f"c{i}.exr", cam @ m_true, space="xyz")
    model = fit_baseline([folder], method="bilinear", target_space="xyz")
    np.testing.assert_allclose(model.matrix, m_true, atol=1e-4)
    assert max(model.provenance["rms_residual"]) < 1e-5
    again = BaselineModel.from_json(model.to_json())
    np.testing.assert_allclose(again.matrix, model.matrix)


def test_menon_beats_bilinear_on_noise_free_capture(sim_dir, tmp_path):
    from l3cli.evaluate import evaluate

    man = json.loads((sim_dir / "manifest.json").read_text())
    scores = {}
    for method in ("bilinear", "menon2007"):
        model = fit_baseline([sim_dir], method=method, target_space="xyz")
        out = tmp_path / method
        out.mkdir()
        for cap in man["captures"]:
            img = render_baseline(model, read_raw(sim_dir / cap["raw"]))
            write_image(out / f"{cap['stem']}.exr", img, space="xyz")
        _, summary = evaluate([out], [sim_dir])
        scores[method] = summary["scielab_mean"]
    assert scores["menon2007"] < scores["bilinear"]


def test_cli_renders_simulation(runner, sim_dir, tmp_path):
    out = tmp_path / "base"
    model_path = tmp_path / "model.json"
    res = runner.invoke(cli, ["baseline", str(sim_dir), "--train", str(sim_dir), "-o", str(out),
                              "--demosaic", "malvar2004", "--format", "png", "--save-model", str(model_path)])
    assert res.exit_code == 0, res.output
    man = json.loads((sim_dir / "manifest.json").read_text())
    from l3cli.io.image import read_image

    for cap in man["captures"]:
        img, space = read_image(out / f"{cap['stem']}.png")
        assert img.shape == (cap["height"], cap["width"], 3) and space == "srgb"
    model = BaselineModel.from_json(model_path.read_text())
    assert model.method == "malvar2004" and model.matrix.shape == (3, 3)


def test_cli_rejects_non_bayer(runner, tmp_path, sim_dir):
    dn = np.full((16, 16), 1000, np.uint16)
    raw_path = write_raw(tmp_path / "rgbn.dng", dn, CFA.from_spec("R G/NIR B"), black_level=0,
                         white_level=4095)
    res = runner.invoke(cli, ["baseline", str(raw_path), "--train", str(sim_dir), "-o", str(tmp_path / "o.exr")])
    assert res.exit_code == 1
    assert "not a Bayer pattern" in res.output
