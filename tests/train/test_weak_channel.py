"""`l3 simulate` warns about a CFA channel that hardly responds (issue 31)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from l3cli.camera import load_camera
from l3cli.cli.main import cli
from l3cli.simulate.core import prepare_camera
from l3cli.simulate.run import WEAK_CHANNEL, channel_responses, warn_weak_channels

CONFIGS = Path(__file__).parents[2] / "sample_configs"


def _rgbnir_like_bayer(tmp_path: Path) -> Path:
    """The RGB-NIR camera after copying a Bayer TOML's IR-cut filter and 400-730 nm spectrum."""
    text = (CONFIGS / "rgbnir.toml").read_text()
    bayer = (CONFIGS / "bayer.toml").read_text()
    ir = re.search(r'^ir_cut = "([^"]+)"', bayer, re.M).group(1)
    assert ir != "none"
    text = re.sub(r'^ir_cut = .*$', f'ir_cut = "{ir}"', text, flags=re.M)
    text = re.sub(r'^wavelength_nm = .*$', "wavelength_nm = [400, 730, 10]", text, flags=re.M)
    p = tmp_path / "rgbnir_ircut.toml"
    p.write_text(text)
    return p


def test_responses_are_relative_to_the_strongest_channel():
    model = prepare_camera(load_camera(CONFIGS / "bayer.toml"))
    rel = channel_responses(model, "D65")
    assert rel.max() == pytest.approx(1.0)
    # a Bayer camera under daylight: every channel well above the warning level, G strongest
    assert np.all(rel > 0.3)
    assert model.channels[int(np.argmax(rel))] == "G"


def test_nir_behind_an_ir_cut_filter_is_warned(tmp_path, caplog):
    model = prepare_camera(load_camera(_rgbnir_like_bayer(tmp_path)))
    with caplog.at_level("WARNING", logger="l3cli.simulate.run"):
        weak = warn_weak_channels(model, "D65")
    assert weak == ["NIR"]
    msg = caplog.records[0].getMessage()
    assert "NIR" in msg and "cfa.ir_cut" in msg and "730" in msg and "rgbnir_ircut.toml" in msg
    rel = channel_responses(model, "D65")
    assert rel[model.channels.index("NIR")] < WEAK_CHANNEL


def test_the_sample_rgbnir_camera_is_not_warned(caplog):
    model = prepare_camera(load_camera(CONFIGS / "rgbnir.toml"))
    with caplog.at_level("WARNING", logger="l3cli.simulate.run"):
        assert warn_weak_channels(model, "visir-DAY") == []


def test_simulate_prints_the_warning(runner, tmp_path):
    res = runner.invoke(cli, ["simulate", str(_rgbnir_like_bayer(tmp_path)), "-o", str(tmp_path / "s"),
                              "--scene", "macbeth", "--lux", "100", "--size", "64x48", "--seed", "1"])
    assert res.exit_code == 0, res.output
    assert "channel NIR responds at" in res.output
