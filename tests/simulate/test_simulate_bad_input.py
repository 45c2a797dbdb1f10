"""Issue 3's bad-input list through `l3 simulate`: a clear one-line error, exit 1,
and nothing half-written in SIM_DIR (absent SIM_DIR stays absent, an existing one
is left exactly as it was)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from l3cli.cli.main import cli
from tests.builders import assert_one_line_error

REPO = Path(__file__).resolve().parents[2]
BAYER = (REPO / "sample_configs" / "bayer.toml").read_text()
SMALL = ["--scene", "macbeth", "--lux", "100", "--size", "64x48"]


def snapshot(folder: Path) -> dict[str, str]:
    """File name -> sha256 of every file under ``folder`` (recursively)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def qe_csv(path: Path, rows) -> Path:
    path.write_text("wavelength_nm,R,G,B\n" + "".join(f"{w:g},{r:g},{g:g},{b:g}\n"
                                                       for w, r, g, b in rows))
    return path


def camera(tmp_path: Path, **replace: str) -> Path:
    text = BAYER
    for old, new in replace.items():
        old = old.replace("__", " = ")
        line = next(ln for ln in text.splitlines() if ln.startswith(old))
        text = text.replace(line, new)
    p = tmp_path / "cam.toml"
    p.write_text(text)
    return p


WL = np.arange(380, 1071, 10)
CASES = {
    # name: (camera edits, extra CSV rows or None, extra CLI args, words of the error)
    "unknown-qe-preset": ({"qe": 'qe = "nikon-d2000"'}, None, [],
                          ["cam.toml", "cfa.qe", "nikon-d2000", "bayer-rgb", "nikon-d200-ir",
                           "mt9v024-rgbw"]),
    "unknown-ir-filter": ({"ir_cut": 'ir_cut = "hot-mirror"'}, None, [],
                          ["cam.toml", "cfa.ir_cut", "hot-mirror", "ircf-public", "schott"]),
    "unknown-illuminant-option": ({}, None, ["--illuminant", "D66"],
                                  ["D66", "D65", "visir-A", "visir-CWF", "visir-DAY"]),
    "unknown-illuminant-toml": ({"illuminant": 'illuminant = "tungsten"'}, None, [],
                                ["cam.toml", "exposure.illuminant", "tungsten", "visir-CWF"]),
    "qe-csv-non-monotonic": ({"qe": 'qe = "qe.csv"'},
                             [(w, .3, .4, .5) for w in WL[:20]] + [(WL[10], .3, .4, .5)]
                             + [(w, .3, .4, .5) for w in WL[20:]], [],
                             ["qe.csv", "strictly increasing"]),
    "qe-csv-negative": ({"qe": 'qe = "qe.csv"'},
                        [(w, .3, -.1 if w == 550 else .4, .5) for w in WL], [],
                        ["qe.csv", "non-negative"]),
    "qe-csv-range-not-covered": ({"qe": 'qe = "qe.csv"'},
                                 [(w, .3, .4, .5) for w in WL if 420 <= w <= 680], [],
                                 ["qe.csv", "covers 420-680 nm", "380-730 nm"]),
    "illuminant-range-not-covered": ({"wavelength_nm": "wavelength_nm = [380, 1000, 10]",
                                      "ir_cut": 'ir_cut = "none"'}, None, ["--illuminant", "D65"],
                                     ["D65", "300-780 nm", "1000 nm"]),
    "lux-zero-toml": ({"light_levels_lux": "light_levels_lux = [10.0, 0.0]"}, None,
                      ["--scene", "macbeth"], ["cam.toml", "exposure.light_levels_lux", "(0, 1e6]"]),
    "lux-negative-toml": ({"light_levels_lux": "light_levels_lux = [-5.0]"}, None,
                          ["--scene", "macbeth"], ["cam.toml", "exposure.light_levels_lux"]),
}


@pytest.fixture(params=["absent", "existing"])
def sim_dir(request, runner, tmp_path: Path) -> tuple[Path, dict[str, str] | None]:
    """SIM_DIR either absent, or holding an earlier good simulation."""
    out = tmp_path / "sim"
    if request.param == "absent":
        return out, None
    res = runner.invoke(cli, ["-q", "simulate", str(REPO / "sample_configs" / "bayer.toml"),
                              "-o", str(out), *SMALL])
    assert res.exit_code == 0, res.output
    return out, snapshot(out)


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_leaves_sim_dir_alone(runner, tmp_path: Path, sim_dir, case: str) -> None:
    edits, rows, args, words = CASES[case]
    out, before = sim_dir
    if rows is not None:
        qe_csv(tmp_path / "qe.csv", rows)
    cam = camera(tmp_path, **edits)
    res = runner.invoke(cli, ["simulate", str(cam), "-o", str(out), "--size", "64x48",
                              *(args or SMALL)])
    assert_one_line_error(res, *words)
    if before is None:
        assert not out.exists()
    else:
        assert snapshot(out) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".l3-tmp")]


@pytest.mark.parametrize("lux", ["0", "-2", "nan"])
def test_lux_option_not_positive_is_usage_error(runner, tmp_path: Path, sim_dir, lux: str) -> None:
    out, before = sim_dir
    res = runner.invoke(cli, ["simulate", str(REPO / "sample_configs" / "bayer.toml"),
                              "-o", str(out), "--scene", "macbeth", "--lux", lux,
                              "--size", "64x48"])
    assert res.exit_code == 2 and "--lux" in res.output and "Traceback" not in res.output
    assert (not out.exists()) if before is None else snapshot(out) == before


@pytest.mark.parametrize("content", [b"", b"\x89PNG\r\n\x1a\n" + b"\0" * 40, b"GIF89a"])
def test_unreadable_scene_image(runner, tmp_path: Path, sim_dir, content: bytes) -> None:
    out, before = sim_dir
    bad = tmp_path / "scene.png"
    bad.write_bytes(content)
    res = runner.invoke(cli, ["simulate", str(REPO / "sample_configs" / "bayer.toml"),
                              "-o", str(out), "--scene", "macbeth", "--scene", str(bad),
                              "--lux", "100", "--size", "64x48"])
    assert_one_line_error(res, "scene.png")
    assert (not out.exists()) if before is None else snapshot(out) == before
