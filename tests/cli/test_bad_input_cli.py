"""Issue 2's bad-input list, through the command line.

Each case: a one-line ``Error: ...`` naming the file and the problem, a non-zero
exit status, no traceback, and no output file (nor temporary file) left behind.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.io.raw import sidecar_path, write_raw
from l3cli.table import save_table
from tests.builders import assert_one_line_error, make_table

REPO = Path(__file__).resolve().parents[2]
ROSE = "DSC_1339_768x512_rggb_14bit.raw"
BAYER_TOML = (REPO / "sample_configs" / "bayer.toml").read_text()




def assert_nothing_written(folder: Path, before: set[str]) -> None:
    """``folder`` holds exactly what it held before (no output, no .l3-tmp file)."""
    assert {p.name for p in folder.iterdir()} == before


@pytest.fixture
def work(tmp_path: Path, data_dir: Path) -> Path:
    """A folder with a valid table, a valid DNG and the rose crop (+ sidecar); ``out/`` is empty."""
    save_table(tmp_path / "table.npz", make_table("RGGB"))
    dn = np.random.default_rng(0).integers(64, 4000, (40, 48)).astype(np.uint16)
    write_raw(tmp_path / "good.dng", dn, "RGGB", black_level=64, white_level=4095)
    (tmp_path / ROSE).write_bytes((data_dir / ROSE).read_bytes())
    sidecar_path(tmp_path / ROSE).write_text(sidecar_path(data_dir / ROSE).read_text())
    (tmp_path / "out").mkdir()
    return tmp_path


# Each maker prepares a bad raw in the work folder and returns (raw path, words of the error).
def _truncated_dng(d: Path) -> tuple[Path, list[str]]:
    data = (d / "good.dng").read_bytes()
    (d / "cut.dng").write_bytes(data[: len(data) // 2])
    return d / "cut.dng", ["cut.dng", "Unexpected end of file"]


def _not_raw(d: Path) -> tuple[Path, list[str]]:
    (d / "notes.dng").write_text("these are my holiday notes\n" * 40)
    return d / "notes.dng", ["notes.dng", "not a raw file"]


def _truncated_headerless(d: Path) -> tuple[Path, list[str]]:
    p = d / ROSE
    p.write_bytes(p.read_bytes()[:-1000])
    return p, [ROSE, "785432 bytes", "768x512 uint16"]


def _sidecar_missing(d: Path) -> tuple[Path, list[str]]:
    sidecar_path(d / ROSE).unlink()
    return d / ROSE, [ROSE, f"sidecar {ROSE}.toml is missing"]


def _sidecar_size_mismatch(d: Path) -> tuple[Path, list[str]]:
    sc = sidecar_path(d / ROSE)
    sc.write_text(sc.read_text().replace("width = 768", "width = 760"))
    return d / ROSE, [ROSE, "786432 bytes", "760x512 uint16"]


def _unknown_cfa_letter(d: Path) -> tuple[Path, list[str]]:
    sc = sidecar_path(d / ROSE)
    sc.write_text(sc.read_text().replace('"RGGB"', '"RGXB"'))
    return d / ROSE, [f"{ROSE}.toml", "unknown channel 'X'", "allowed: R, G, B"]


def _sidecar_syntax_error(d: Path) -> tuple[Path, list[str]]:
    sc = sidecar_path(d / ROSE)
    sc.write_text(sc.read_text().replace("height = 512", "height = = 512"))
    lineno = next(i for i, ln in enumerate(sc.read_text().splitlines(), 1) if "= =" in ln)
    return d / ROSE, [f"{ROSE}.toml", "TOML syntax error", f"line {lineno}"]


BAD_RAWS: dict[str, Callable[[Path], tuple[Path, list[str]]]] = {
    "truncated-dng": _truncated_dng,
    "not-a-raw-file": _not_raw,
    "truncated-headerless": _truncated_headerless,
    "sidecar-missing": _sidecar_missing,
    "sidecar-size-mismatch": _sidecar_size_mismatch,
    "unknown-cfa-letter": _unknown_cfa_letter,
    "sidecar-toml-syntax": _sidecar_syntax_error,
}


@pytest.mark.parametrize("case", list(BAD_RAWS))
def test_bad_raw_render(runner, work: Path, case: str) -> None:
    raw, words = BAD_RAWS[case](work)
    res = runner.invoke(cli, ["render", str(work / "table.npz"), str(raw),
                              "-o", str(work / "out" / "r.exr")])
    assert_one_line_error(res, *words)
    assert_nothing_written(work / "out", set())


@pytest.mark.parametrize("case", list(BAD_RAWS))
def test_bad_raw_info_preview(runner, work: Path, case: str) -> None:
    raw, words = BAD_RAWS[case](work)
    res = runner.invoke(cli, ["info", str(raw), "--preview", str(work / "out" / "p.png"),
                              "--planes", str(work / "out" / "planes")])
    assert_one_line_error(res, *words)
    assert_nothing_written(work / "out", set())


def test_bad_raw_among_good_ones_leaves_no_render(runner, work: Path) -> None:
    raw, words = _truncated_dng(work)
    res = runner.invoke(cli, ["render", str(work / "table.npz"), str(work / "good.dng"), str(raw),
                              "-o", str(work / "out")])
    assert res.exit_code == 1 and "cut.dng" in res.output
    assert not list((work / "out").glob(".l3-tmp*"))
    assert not (work / "out" / "cut.exr").exists()


def test_libraw_message_is_folded_into_the_one_line(work: Path) -> None:
    """In a real process LibRaw writes to fd 2 itself; l3 folds that into its one line."""
    raw, _ = _truncated_dng(work)
    raw = raw.rename(raw.with_suffix(".nef"))  # LibRaw's to decode (l3 reads DNG pixels)
    proc = subprocess.run([sys.executable, "-m", "l3cli.cli.main", "info", str(raw)],
                          capture_output=True, text=True, cwd=work)
    assert proc.returncode == 1
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines == [f"Error: {raw}: cannot unpack raw data (Unexpected end of file)"]
    assert proc.stdout == ""


# ------------------------------------------------------------------- tables
def _wrong_version(d: Path) -> tuple[Path, list[str]]:
    p = d / "table.npz"
    with np.load(p, allow_pickle=False) as z:
        arrs = {k: z[k] for k in z.files}
    arrs["version"] = np.array(7)
    with open(p, "wb") as fh:
        np.savez(fh, **arrs)
    return p, ["table.npz", "table version 7 is not supported"]


def _not_npz(d: Path) -> tuple[Path, list[str]]:
    p = d / "table.npz"
    p.write_text("a text file, not a table")
    return p, ["table.npz", "not an NPZ table"]


def _damaged_npz(d: Path) -> tuple[Path, list[str]]:
    p = d / "table.npz"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 3])
    return p, ["table.npz", "damaged"]


BAD_TABLES = {"wrong-version": _wrong_version, "not-npz": _not_npz, "damaged": _damaged_npz}


@pytest.mark.parametrize("case", list(BAD_TABLES))
@pytest.mark.parametrize("command", ["render", "smooth", "inspect"])
def test_bad_table(runner, work: Path, case: str, command: str) -> None:
    table, words = BAD_TABLES[case](work)
    args = {
        "render": ["render", str(table), str(work / "good.dng"), "-o", str(work / "out" / "r.exr")],
        "smooth": ["smooth", str(table), "-o", str(work / "out" / "s.npz")],
        "inspect": ["inspect", str(table), "--plots", str(work / "out" / "plots")],
    }[command]
    assert_one_line_error(runner.invoke(cli, args), *words)
    assert_nothing_written(work / "out", set())


# ------------------------------------------------------------- camera TOML
@pytest.mark.parametrize(
    "change, words",
    [
        (("f_number = 4.0", "f_number = = 4.0"), ["cam.toml", "TOML syntax error", "line {line}"]),
        (('pattern = "RGGB"', 'pattern = "RGXB"'), ["cam.toml", "unknown channel 'X'"]),
        (("f_number = 4.0", "f_numbr = 4.0"), ["cam.toml", "optics.f_numbr", "f_number"]),
    ],
    ids=["toml-syntax", "unknown-cfa-letter", "unknown-key"],
)
def test_bad_camera_toml(runner, tmp_path: Path, change, words) -> None:
    old, new = change
    assert old in BAYER_TOML
    text = BAYER_TOML.replace(old, new)
    line = next(i for i, ln in enumerate(text.splitlines(), 1) if new in ln)
    (tmp_path / "cam.toml").write_text(text)
    res = runner.invoke(cli, ["simulate", str(tmp_path / "cam.toml"), "-o", str(tmp_path / "sim"),
                              "--size", "64x48"])
    assert_one_line_error(res, *(w.format(line=line) for w in words))
    assert_nothing_written(tmp_path, {"cam.toml"})


# --------------------------------------------------------- unwritable output
@pytest.fixture
def deny_writes(monkeypatch):
    """Make ``os.access`` deny writing to chosen folders (as root, chmod cannot)."""
    denied: set[str] = set()
    real = os.access

    def access(path, mode, *args, **kwargs):
        if mode & os.W_OK and str(Path(path).resolve()) in denied:
            return False
        return real(path, mode, *args, **kwargs)

    monkeypatch.setattr(os, "access", access)
    return lambda folder: denied.add(str(Path(folder).resolve()))


def test_render_into_unwritable_folder(runner, work: Path, deny_writes) -> None:
    deny_writes(work / "out")
    res = runner.invoke(cli, ["render", str(work / "table.npz"), str(work / "good.dng"),
                              "-o", str(work / "out" / "r.exr")])
    assert_one_line_error(res, "out", "not writable")
    assert_nothing_written(work / "out", set())


def test_info_preview_into_unwritable_folder(runner, work: Path, deny_writes) -> None:
    deny_writes(work / "out")
    res = runner.invoke(cli, ["info", str(work / "good.dng"), "--preview",
                              str(work / "out" / "p.png")])
    assert_one_line_error(res, "out", "not writable")
    assert_nothing_written(work / "out", set())


def test_smooth_into_unwritable_folder(runner, work: Path, deny_writes) -> None:
    deny_writes(work / "out")
    res = runner.invoke(cli, ["smooth", str(work / "table.npz"), "-o", str(work / "out" / "s.npz")])
    assert_one_line_error(res, "out", "not writable")
    assert_nothing_written(work / "out", set())


def test_simulate_into_unwritable_folder(runner, tmp_path: Path, deny_writes) -> None:
    (tmp_path / "ro").mkdir()
    deny_writes(tmp_path / "ro")
    res = runner.invoke(cli, ["simulate", str(REPO / "sample_configs" / "bayer.toml"),
                              "-o", str(tmp_path / "ro" / "sim"), "--scene", "macbeth",
                              "--lux", "100", "--size", "64x48"])
    assert_one_line_error(res, "sim", "not writable")
    assert_nothing_written(tmp_path / "ro", set())


def test_render_into_missing_folder(runner, work: Path) -> None:
    res = runner.invoke(cli, ["render", str(work / "table.npz"), str(work / "good.dng"),
                              "-o", str(work / "nowhere" / "r.exr")])
    assert_one_line_error(res, "nowhere", "does not exist")
    assert not (work / "nowhere").exists()
