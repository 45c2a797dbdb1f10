"""A newcomer's first hour (issue 31): summaries on success whatever stdout is,
help texts that read plainly, raw files accepted by `train`."""

from __future__ import annotations

import re
from pathlib import Path

from l3cli.cli.main import cli
from l3cli.defaults import PAIRS_LAYOUT, SIMULATION_LAYOUT

ROOT = Path(__file__).parents[2]
FRAME = ROOT / "examples" / "infinite_isp" / "frames" / "Indoor1_crop.tif"


def test_simulate_and_train_print_a_summary_off_a_terminal(runner, tmp_path):
    """CliRunner's stderr is not a terminal: the summary line is printed all the same (logs, CI)."""
    sim = tmp_path / "sim"
    res = runner.invoke(cli, ["simulate", str(ROOT / "sample_configs" / "bayer.toml"), "-o", str(sim),
                              "--scene", "macbeth", "--lux", "100", "--size", "64x48", "--seed", "1"])
    assert res.exit_code == 0, res.output
    assert f"{sim}: 1 captures" in res.output
    res = runner.invoke(cli, ["train", str(sim), "-o", str(tmp_path / "t.npz"), "--levels", "4"])
    assert res.exit_code == 0, res.output
    assert re.search(r"t\.npz: \d+ of \d+ classes trained from 1 captures", res.output)
    res = runner.invoke(cli, ["-q", "train", str(sim), "-o", str(tmp_path / "t2.npz"), "--levels", "4"])
    assert res.exit_code == 0 and res.output == ""


def test_train_takes_one_raw_file(runner, tmp_path):
    out = tmp_path / "t.npz"
    res = runner.invoke(cli, ["train", str(FRAME), "-o", str(out), "--levels", "6", "--no-tone-curve",
                              "--no-tune"])
    assert res.exit_code == 0, res.output
    assert out.is_file() and "Directory" not in res.output


def test_train_refuses_a_render_as_input_by_name(runner, tmp_path):
    png = FRAME.with_suffix(".png")
    res = runner.invoke(cli, ["train", str(png), "-o", str(tmp_path / "t.npz")])
    assert res.exit_code == 1
    assert f"{png}: not a simulate folder, a pairs folder or a raw file" in res.output


def test_train_help_names_shared_defaults_once(runner):
    text = " ".join(runner.invoke(cli, ["train", "--help"]).output.split())
    assert f"[default: {PAIRS_LAYOUT['levels']}]" in text  # the same for both input kinds
    assert not re.search(r"default: (\S+) for pairs folders, \1 for simulate folders", text)
    assert (f"[default: {PAIRS_LAYOUT['patch']} for pairs folders, {SIMULATION_LAYOUT['patch']} "
            "for simulate folders]") in text
