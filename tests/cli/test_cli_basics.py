"""The l3 command group: help, version, error handling, and `l3 info`."""

from __future__ import annotations

import json

import numpy as np
import pytest

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


# ----------------------------------------------------------- global options
SIM_ARGS = ["--scene", "macbeth", "--lux", "100", "--size", "64x48"]


def _bayer() -> str:
    from pathlib import Path

    return str(Path(__file__).resolve().parents[2] / "sample_configs" / "bayer.toml")


def test_version_names_the_program(runner):
    res = runner.invoke(cli, ["--version"])
    assert res.exit_code == 0 and res.output.strip() == f"l3, version {__version__}"


def test_verbose_shows_info_logs_quiet_hides_them(runner, tmp_path):
    import logging

    res = runner.invoke(cli, ["simulate", _bayer(), "-o", str(tmp_path / "a"), *SIM_ARGS])
    assert res.exit_code == 0 and "INFO" not in res.output
    res = runner.invoke(cli, ["-v", "simulate", _bayer(), "-o", str(tmp_path / "b"), *SIM_ARGS])
    assert res.exit_code == 0
    assert "INFO l3cli.simulate.run: simulated macbeth_D65_0100lux" in res.output
    assert logging.getLogger().level == logging.INFO
    res = runner.invoke(cli, ["-vv", "simulate", _bayer(), "-o", str(tmp_path / "c"), *SIM_ARGS])
    assert res.exit_code == 0 and logging.getLogger().level == logging.DEBUG
    res = runner.invoke(cli, ["-q", "simulate", _bayer(), "-o", str(tmp_path / "d"), *SIM_ARGS])
    assert res.exit_code == 0 and res.output == ""
    assert logging.getLogger().level == logging.ERROR


def test_quiet_hides_warnings(runner, tmp_path):
    """A warning (here: a featureless render whose alignment cannot be checked) shows by
    default, not under -q."""
    from l3cli.io.raw import write_raw

    pairs = tmp_path / "pairs"
    pairs.mkdir()
    write_raw(pairs / "a.dng", np.full((48, 64), 500, np.uint16), "RGGB", white_level=4095)
    from l3cli.io.image import write_image

    write_image(pairs / "a.png", np.full((48, 64, 3), 0.5, np.float32))
    res = runner.invoke(cli, ["train", str(pairs), "-o", str(tmp_path / "t.npz"), "--no-tune"])
    assert res.exit_code == 0, res.output
    assert "WARNING" in res.output and "featureless" in res.output
    res = runner.invoke(cli, ["-q", "train", str(pairs), "-o", str(tmp_path / "t2.npz"),
                              "--no-tune"])
    assert res.exit_code == 0 and "WARNING" not in res.output


def test_debug_reraises_the_library_error(runner, tmp_path):
    from l3cli.errors import InputError

    res = runner.invoke(cli, ["--debug", "info", str(tmp_path / "missing.dng")])
    assert res.exit_code != 0 and isinstance(res.exception, InputError)
    res = runner.invoke(cli, ["info", str(tmp_path / "missing.dng")])
    assert res.exit_code == 1 and not isinstance(res.exception, InputError)


# ------------------------------------------------------------------ layout
def test_one_module_per_subcommand():
    """Each registered subcommand lives in its own module l3cli/cli/<name>.py."""
    import importlib

    from l3cli.cli.main import _COMMANDS

    for name, target in _COMMANDS.items():
        mod_name, attr = target.split(":")
        assert mod_name == f"l3cli.cli.{name}", (name, mod_name)
        cmd = getattr(importlib.import_module(mod_name), attr)
        assert cmd.name == name


def test_library_core_does_not_import_click():
    """Only l3cli/cli/ may use click: the library core stays usable without it."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2] / "l3cli"
    offenders = []
    for path in root.rglob("*.py"):
        if path.relative_to(root).parts[0] == "cli":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(n == "click" or n.startswith("click.") for n in names):
                offenders.append(str(path.relative_to(root)))
    assert offenders == []


def test_progress_draws_through_the_installed_factory():
    import contextlib

    from l3cli import progress

    seen = []

    @contextlib.contextmanager
    def fake(items, *, label, length=None):
        seen.append((label, length))
        yield items

    previous = progress.set_bar_factory(fake)
    try:
        assert list(progress.progress(range(3), label="x", length=3, enabled=True)) == [0, 1, 2]
        assert list(progress.progress(range(2), label="y", enabled=False)) == [0, 1]
        assert seen == [("x", 3)]
        progress.set_bar_factory(None)
        assert list(progress.progress(range(2), label="z", enabled=True)) == [0, 1]
        assert seen == [("x", 3)]
    finally:
        progress.set_bar_factory(previous)


def test_quiet_silences_every_summary_line(runner, tmp_path):
    """``-q``: smooth and export print nothing on success (their summary lines too)."""
    import importlib.util

    from l3cli.table import save_table
    from tests.builders import plausible_table

    t = save_table(tmp_path / "t.npz", plausible_table())
    res = runner.invoke(cli, ["-q", "smooth", str(t), "-o", str(tmp_path / "s.npz")])
    assert res.exit_code == 0 and res.output == "", res.output
    res = runner.invoke(cli, ["smooth", str(t), "-o", str(tmp_path / "s2.npz")])
    assert res.exit_code == 0 and "priors" in res.output  # without -q, the summary
    if importlib.util.find_spec("onnx") is not None:
        res = runner.invoke(cli, ["-q", "export", str(t), "-o", str(tmp_path / "t.onnx")])
        assert res.exit_code == 0 and res.output == "", res.output


@pytest.mark.parametrize("command", ["simulate", "train", "render", "smooth", "evaluate",
                                     "export", "inspect", "baseline", "info"])
def test_help_shows_no_empty_range(runner, command):
    """A float option without bounds shows no ``[x<=None]`` in --help."""
    res = runner.invoke(cli, [command, "--help"])
    assert res.exit_code == 0, res.output
    assert "None]" not in res.output and "<=None" not in res.output
