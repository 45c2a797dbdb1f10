"""The l3 command group: help, version, error handling, and `l3 info`."""

from __future__ import annotations

import json

import numpy as np

from l3cli import __version__
from l3cli.cli.main import cli
from l3cli.io.image import read_image


def test_help_and_version(runner):
    res = runner.invoke(cli, ["--help"])
    assert res.exit_code == 0 and "info" in res.output
    res = runner.invoke(cli, ["--version"])
    assert res.exit_code == 0 and __version__ in res.output


def test_every_registered_command_has_help(runner):
    from l3cli.cli.main import _COMMANDS

    for name in _COMMANDS:
        res = runner.invoke(cli, [name, "--help"])
        assert res.exit_code == 0, (name, res.output)
        assert "Usage:" in res.output


def test_unknown_command_is_usage_error(runner):
    res = runner.invoke(cli, ["frobnicate"])
    assert res.exit_code == 2


def test_info_json(runner, data_dir):
    res = runner.invoke(cli, ["info", "--json", str(data_dir / "DSC_1339_768x512_rggb_14bit.raw")])
    assert res.exit_code == 0, res.output
    d = json.loads(res.output)
    assert d["width"] == 768 and d["height"] == 512 and d["cfa"] == "RG/GB"
    raw = np.fromfile(data_dir / "DSC_1339_768x512_rggb_14bit.raw", "<u2").reshape(512, 768)
    r_mean = ((raw[0::2, 0::2] - 600.0) / (15520 - 600)).mean()
    assert abs(d["channels"]["R"]["mean"] - r_mean) < 1e-5


def test_info_preview_and_planes(runner, data_dir, tmp_path):
    src = data_dir / "halide_bayer_small.png"
    res = runner.invoke(cli, ["info", str(src), "--preview", str(tmp_path / "p.png"),
                              "--planes", str(tmp_path / "planes")])
    assert res.exit_code == 0, res.output
    prev, space = read_image(tmp_path / "p.png")
    assert prev.shape == (172, 128, 3) and space == "srgb"
    names = sorted(p.name for p in (tmp_path / "planes").iterdir())
    assert names == [f"halide_bayer_small_plane{k}.tif" for k in ("0_G", "1_R", "2_B", "3_G")]


def test_bad_input_is_one_line_exit_1(runner, tmp_path):
    bad = tmp_path / "bad.dng"
    bad.write_bytes(b"nope" * 100)
    res = runner.invoke(cli, ["info", str(bad)])
    assert res.exit_code == 1
    assert "Traceback" not in res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error:") and "bad.dng" in lines[0]


def test_debug_shows_traceback(runner, tmp_path):
    bad = tmp_path / "bad.dng"
    bad.write_bytes(b"nope" * 100)
    res = runner.invoke(cli, ["--debug", "info", str(bad)])
    assert res.exit_code != 0
    assert res.exception is not None and "bad.dng" in str(res.exception)


def test_preview_with_several_inputs_is_usage_error(runner, data_dir, tmp_path):
    src = str(data_dir / "halide_bayer_small.png")
    res = runner.invoke(cli, ["info", src, src, "--preview", str(tmp_path / "p.png")])
    assert res.exit_code == 2 and "--preview" in res.output
