"""Issue 29's hostile cases: bad table fields, absurd options, special files, long names.

Each case must end with a clear one-line error naming the right cause (or, for
a table, render finite values), never hang, never write a non-finite output
silently, and never print a stray library line or a numpy warning.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.errors import ConfigError, TableError
from l3cli.io.raw import write_raw
from l3cli.table import load_table, save_table
from l3cli.train import TrainOptions
from tests.builders import assert_one_line_error, make_table, sim_dir

L3 = [sys.executable, "-c", "from l3cli.cli.main import main; main()"]


@pytest.fixture
def work(tmp_path: Path) -> Path:
    """A valid table and a valid DNG in a folder."""
    save_table(tmp_path / "table.npz", make_table("RGGB"))
    dn = np.random.default_rng(0).integers(64, 4000, (40, 48)).astype(np.uint16)
    write_raw(tmp_path / "good.dng", dn, "RGGB", black_level=64, white_level=4095)
    return tmp_path


def npz_arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _with(path: Path, out: Path, **changes) -> Path:
    """A copy of the table at ``path`` with some keys replaced (raw NPZ arrays)."""
    arrs = npz_arrays(path)
    for k, v in changes.items():
        arrs[k] = v
    np.savez(out, **arrs)
    return out


# ---------------------------------------------------------------- table fields
def _first(path: Path, key: str, value: float) -> np.ndarray:
    a = npz_arrays(path)[key].astype(np.float64).copy()
    a.flat[0] = value
    return a


BAD_FIELDS = {
    "contrast_eps nan": ("contrast_eps", lambda p: np.array(np.nan), "contrast eps"),
    "contrast_eps inf": ("contrast_eps", lambda p: np.array(np.inf), "contrast eps"),
    "contrast_eps negative": ("contrast_eps", lambda p: np.array(-1e-4), "contrast eps"),
    "contrast_eps zero": ("contrast_eps", lambda p: np.array(0.0), "contrast eps"),
    "saturation beyond float32": ("saturation_threshold", lambda p: np.array(1e39),
                                  "saturation threshold"),
    "saturation nan": ("saturation_threshold", lambda p: np.array(np.nan),
                       "saturation threshold"),
    "contrast cut negative": ("contrast_cuts", lambda p: _first(p, "contrast_cuts", -0.5),
                              "contrast cut points"),
    "contrast cut nan": ("contrast_cuts", lambda p: _first(p, "contrast_cuts", np.nan),
                         "contrast cut points"),
    "level cut inf": ("level_cuts", lambda p: _first(p, "level_cuts", np.inf),
                      "level cut points"),
    "kernels that overflow float32": (
        "kernels", lambda p: (npz_arrays(p)["kernels"] * np.float32(1e37)).astype(np.float32),
        "overflow float32"),
    "negative counts": ("counts", lambda p: _first(p, "counts", -5).astype(np.int64),
                        "negative"),
    "lambda inf": ("lambdas", lambda p: _first(p, "lambdas", np.inf), "lambdas"),
    # sizes the class definition would allocate from: checked before it does
    "patch 2**31+1": ("patch", lambda p: np.array(2**31 + 1), "does not fit kernels"),
    "position group 2**62": ("position_group", lambda p: np.array([0, 1, 2**62, 1]),
                             "position groups"),
}


@pytest.mark.parametrize("case", list(BAD_FIELDS))
def test_bad_table_field_is_refused(work: Path, case: str) -> None:
    key, make, words = BAD_FIELDS[case]
    bad = _with(work / "table.npz", work / "bad.npz", **{key: make(work / "table.npz")})
    with pytest.raises(TableError, match=words) as exc:
        load_table(bad)
    assert str(exc.value).startswith(str(bad))


def _wb_record(**changes) -> str:
    rec = {"input": "as-shot", "feature": "log-b/r-v1", "space": "xyz", "center": [0.0],
           "coef": np.eye(3).reshape(1, 9).tolist() + [[0.0] * 9],
           "whites": [[2.0, 1.0, 1.5], [1.5, 1.0, 2.0]]}
    rec.update(changes)
    return json.dumps(rec)


@pytest.mark.parametrize("change", [{"center": [float("nan")]}, {"whites": [[2.0, 1.0, -1.0]]},
                                    {"whites": [[float("inf"), 1.0, 1.0]]},
                                    {"space": "sepia"}],
                         ids=["centre nan", "white negative", "white inf", "space"])
def test_bad_white_balance_record_is_refused(work: Path, change) -> None:
    from l3cli.whitebalance.model import WB_FEATURE

    good = _wb_record(feature=WB_FEATURE)
    ok = _with(work / "table.npz", work / "ok.npz", white_balance=np.array(good))
    load_table(ok)  # the record itself is valid
    bad = _with(work / "table.npz", work / "bad.npz",
                white_balance=np.array(_wb_record(feature=WB_FEATURE, **change)))
    with pytest.raises(TableError, match="white_balance"):
        load_table(bad)


def test_contrast_eps_nan_table_is_refused_by_render(runner, work: Path) -> None:
    """The reported case: it rendered with exit 0."""
    bad = _with(work / "table.npz", work / "bad.npz", contrast_eps=np.array(np.nan))
    res = runner.invoke(cli, ["render", str(bad), str(work / "good.dng"), "-o",
                              str(work / "out.exr")])
    assert_one_line_error(res, "bad.npz", "contrast eps")
    assert not (work / "out.exr").exists()


def test_half_overflow_is_refused(runner, work: Path) -> None:
    """A finite table whose output overflows half floats: an error, not +inf in the file;
    full floats write the same render."""
    arrs = npz_arrays(work / "table.npz")
    big = _with(work / "table.npz", work / "big.npz",
                kernels=(arrs["kernels"] * np.float32(1e6)).astype(np.float32))
    load_table(big)  # valid: finite and far from float32's range
    res = runner.invoke(cli, ["render", str(big), str(work / "good.dng"), "-o",
                              str(work / "half.exr"), "--half"])
    assert_one_line_error(res, "half.exr", "overflow half floats")
    assert not (work / "half.exr").exists()
    assert not list(work.glob(".l3-tmp*"))
    res = runner.invoke(cli, ["render", str(big), str(work / "good.dng"), "-o",
                              str(work / "full.exr")])
    assert res.exit_code == 0, res.output
    from l3cli.io.image import read_image

    img, _ = read_image(work / "full.exr")
    assert np.all(np.isfinite(img)) and np.abs(img).max() > 65520


def test_non_finite_float_image_is_not_written(tmp_path: Path) -> None:
    from l3cli.errors import OutputError
    from l3cli.io.image import write_image

    img = np.ones((4, 5, 3), np.float32)
    img[1, 2, 0] = np.nan
    with pytest.raises(OutputError, match="NaN or infinite"):
        write_image(tmp_path / "x.exr", img, space="xyz")
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------- options
NON_FINITE = [
    (["train", "IN", "-o", "t.npz", "--min-samples", "nan"], "--min-samples"),
    (["train", "IN", "-o", "t.npz", "--sample-fraction", "nan"], "--sample-fraction"),
    (["train", "IN", "-o", "t.npz", "--level-range", "0.01", "inf"], "--level-range"),
    (["train", "IN", "-o", "t.npz", "--level-range", "nan", "0.5"], "--level-range"),
    (["train", "IN", "-o", "t.npz", "--saturation", "nan"], "--saturation"),
    (["train", "IN", "-o", "t.npz", "--coherence", "nan"], "--coherence"),
    (["train", "IN", "-o", "t.npz", "--highlight-fraction", "nan"], "--highlight-fraction"),
    (["train", "IN", "-o", "t.npz", "--contrast-threshold", "inf"], "--contrast-threshold"),
    (["simulate", "CAM", "-o", "sim", "--lux", "nan"], "--lux"),
    (["simulate", "CAM", "-o", "sim", "--exposure", "inf"], "--exposure"),
    (["evaluate", "IMG", "--reference", "IMG", "--chart", "nan,0.1,0.9,0.1,0.9,0.9,0.1,0.9"],
     "--chart"),
    (["evaluate", "IMG", "--reference", "IMG", "--dpi", "nan"], "--dpi"),
    (["evaluate", "IMG", "--reference", "IMG", "--distance", "inf"], "--distance"),
]


@pytest.mark.parametrize("args,option", NON_FINITE, ids=[" ".join(a[-2:]) for a, _ in NON_FINITE])
def test_non_finite_option_is_refused(runner, tmp_path: Path, args, option) -> None:
    """NaN and infinity are refused for every float option, naming it (a usage error)."""
    cam = Path(__file__).parents[2] / "sample_configs" / "bayer.toml"
    img = tmp_path / "a.exr"
    img.write_bytes(b"")
    subs = {"IN": str(tmp_path), "CAM": str(cam), "IMG": str(img)}
    res = runner.invoke(cli, [subs.get(a, a) for a in args])
    assert res.exit_code == 2, res.output
    assert option in res.output and ("finite" in res.output), res.output
    assert "Traceback" not in res.output


def test_train_options_refuse_non_finite_values() -> None:
    """The library's own checks (a --config file or a caller) hold NaN too."""
    for bad in ({"min_samples_factor": float("nan")}, {"level_range": (0.01, float("inf"))},
                {"level_range": (float("nan"), 0.5)}, {"level_range": (0.5, 0.1)},
                {"sample_fraction": float("nan")}, {"saturation": float("nan")}):
        with pytest.raises(ConfigError):
            TrainOptions(**bad)


@pytest.fixture
def sim(tmp_path: Path) -> Path:
    return sim_dir(tmp_path, n=2, shape=(40, 48), seed=3)


def test_absurd_levels_are_refused_before_any_work(runner, sim: Path, monkeypatch) -> None:
    """--levels 100000000: refused at once, naming --levels, before any input is read."""
    import l3cli.train.fit as fit

    def no_work(*a, **k):
        raise AssertionError("pass 1 started")

    monkeypatch.setattr(fit, "define_classes", no_work)
    res = runner.invoke(cli, ["-q", "train", str(sim), "-o", str(sim.parent / "t.npz"),
                              "--levels", "100000000"])
    assert_one_line_error(res, "--levels 100000000", "memory")


def test_levels_beyond_memory_name_the_option(runner, sim: Path, monkeypatch) -> None:
    """A count that passes the first bound but whose exact statistics do not fit: the
    error names --levels, not "out of memory"."""
    import l3cli.train.options as options

    monkeypatch.setattr(options, "available_memory", lambda: 200 << 20)
    res = runner.invoke(cli, ["-q", "train", str(sim), "-o", str(sim.parent / "t.npz"),
                              "--levels", "3000"])
    assert_one_line_error(res, "--levels 3000", "GiB")


@pytest.mark.parametrize("fraction,words", [("1e-9", "--sample-fraction"),
                                            ("1e-4", "--sample-fraction")])
def test_tiny_sample_fraction_is_named(runner, sim: Path, fraction, words) -> None:
    res = runner.invoke(cli, ["-q", "train", str(sim), "-o", str(sim.parent / "t.npz"),
                              "--sample-fraction", fraction, "--levels", "4", "--patch", "3"])
    assert_one_line_error(res, words)


# ---------------------------------------------------------------- inputs and outputs
@pytest.mark.parametrize("command", ["render", "train", "info"])
def test_fifo_input_is_refused_not_read(work: Path, command: str) -> None:
    """A FIFO given as an input: one line, at once (it used to block forever)."""
    fifo = work / "pipe.dng"
    os.mkfifo(fifo)
    args = {"render": ["render", str(work / "table.npz"), str(fifo), "-o", str(work / "o.exr")],
            "train": ["train", str(fifo), "-o", str(work / "t2.npz")],
            "info": ["info", str(fifo)]}[command]
    res = subprocess.run([*L3, *args], capture_output=True, text=True, timeout=60)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 1 and len(lines) == 1, res.stderr
    assert "pipe.dng" in lines[0] and "FIFO" in lines[0]


def test_fifo_table_is_refused(runner, work: Path) -> None:
    fifo = work / "pipe.npz"
    os.mkfifo(fifo)
    for cmd in (["inspect", str(fifo)], ["smooth", str(fifo), "-o", str(work / "s.npz")]):
        res = runner.invoke(cli, cmd)
        assert_one_line_error(res, "pipe.npz", "FIFO")


def test_same_folder_twice_is_refused_by_train_as_by_render(runner, sim: Path,
                                                            monkeypatch) -> None:
    monkeypatch.chdir(sim.parent)
    res = runner.invoke(cli, ["-q", "train", sim.name, sim.name + "/", "-o", "t.npz"])
    assert_one_line_error(res, "given twice", sim.name)
    res = runner.invoke(cli, ["-q", "train", sim.name, str(sim), "-o", "t.npz"])
    assert_one_line_error(res, "given twice")
    assert not (sim.parent / "t.npz").exists()


def test_same_raw_twice_is_refused_by_render_and_info(runner, work: Path, monkeypatch) -> None:
    monkeypatch.chdir(work)
    res = runner.invoke(cli, ["render", "table.npz", "good.dng", "./good.dng", "-o", "out"])
    assert_one_line_error(res, "given twice", "good.dng")
    os.symlink("good.dng", "alias.dng")
    res = runner.invoke(cli, ["info", "good.dng", "alias.dng", "--planes", "planes"])
    assert_one_line_error(res, "given twice", "alias.dng")
    assert not (work / "planes").exists()


def test_same_render_twice_is_refused_by_evaluate(runner, work: Path, monkeypatch) -> None:
    """A rendered image given twice would count twice in the summary; one reference
    for two renders is allowed (two tables' renders of one raw)."""
    import numpy as np

    from l3cli.io.image import write_image

    monkeypatch.chdir(work)
    img = np.full((32, 32, 3), 0.5, np.float32)
    write_image("a.png", img)
    write_image("b.png", img)
    res = runner.invoke(cli, ["evaluate", "a.png", "./a.png", "--reference", "b.png", "b.png"])
    assert_one_line_error(res, "given twice", "a.png")
    res = runner.invoke(cli, ["evaluate", "a.png", "b.png", "--reference", "b.png", "b.png"])
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize("command", ["render", "smooth", "train"])
def test_output_name_too_long(runner, work: Path, sim: Path, command: str) -> None:
    """A name longer than the filesystem allows: one clear line, no "internal error"."""
    long = "n" * 300
    args = {"render": ["render", str(work / "table.npz"), str(work / "good.dng"), "-o",
                       str(work / f"{long}.exr")],
            "smooth": ["smooth", str(work / "table.npz"), "-o", str(work / f"{long}.npz")],
            "train": ["train", str(sim), "-o", str(work / f"{long}.npz")]}[command]
    res = runner.invoke(cli, args)
    line = assert_one_line_error(res, "-o", "bytes long")
    assert "internal error" not in line and len(line) < 300


def test_damaged_png_prints_no_library_line(runner, work: Path, capfd) -> None:
    """libpng's own "libpng error: ..." line stays off the terminal."""
    from l3cli.io.image import write_image

    write_image(work / "ok.png", np.random.default_rng(1).random((32, 40, 3)).astype(np.float32))
    data = bytearray((work / "ok.png").read_bytes())
    for i in range(120, len(data) - 40, 53):
        data[i] ^= 0x5A
    (work / "bad.png").write_bytes(bytes(data))
    capfd.readouterr()
    res = runner.invoke(cli, ["evaluate", str(work / "bad.png"), "--reference",
                              str(work / "ok.png")])
    assert_one_line_error(res, "bad.png")
    assert "libpng" not in capfd.readouterr().err


def test_numpy_warnings_do_not_reach_the_terminal(tmp_path: Path) -> None:
    """A numpy warning inside a command is a debug log record, not a terminal line."""
    code = ("import numpy as np, click\n"
            "from l3cli.cli.main import cli\n"
            "@cli.command('warns')\n"
            "def warns():\n"
            "    np.log(np.array([-1.0, 0.0]))\n"
            "    click.echo('done')\n"
            "cli()\n")
    res = subprocess.run([sys.executable, "-c", code, "warns"], capture_output=True, text=True,
                         timeout=60, env={**os.environ, "PYTHONWARNINGS": "default"})
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "done" and res.stderr.strip() == "", res.stderr
    res = subprocess.run([sys.executable, "-c", code, "-vv", "warns"], capture_output=True,
                         text=True, timeout=60)
    assert "RuntimeWarning" in res.stderr  # still there for whoever asks


def test_simulate_size_beyond_memory_is_refused(runner, tmp_path: Path, monkeypatch) -> None:
    """A capture size whose simulation cannot fit: refused before any work, naming --size
    (it used to end in "out of memory")."""
    import l3cli.buffers as buffers

    monkeypatch.setattr(buffers, "available_memory", lambda: 1 << 30)
    cam = Path(__file__).parents[2] / "sample_configs" / "bayer.toml"
    res = runner.invoke(cli, ["simulate", str(cam), "-o", str(tmp_path / "sim"),
                              "--size", "4000x3000", "--scene", "macbeth", "--lux", "100"])
    assert_one_line_error(res, "--size 4000x3000", "GiB")
    assert not (tmp_path / "sim").exists()


def test_absurd_worker_count_is_refused_before_starting_any(runner, sim: Path) -> None:
    """--workers 100000 would start a process per worker: refused, naming the option."""
    import psutil

    before = {p.pid for p in psutil.Process().children(recursive=True)}
    res = runner.invoke(cli, ["-q", "train", str(sim), "-o", str(sim.parent / "t.npz"),
                              "--levels", "4", "--workers", "100000"])
    assert_one_line_error(res, "--workers 100000", "memory")
    assert {p.pid for p in psutil.Process().children(recursive=True)} <= before


def test_negative_seed_is_a_usage_error(runner, sim: Path) -> None:
    """It was "internal error: ValueError" from numpy's generator."""
    res = runner.invoke(cli, ["-q", "train", str(sim), "-o", str(sim.parent / "t.npz"),
                              "--seed", "-1"])
    assert res.exit_code == 2 and "--seed" in res.output and "Traceback" not in res.output


def test_white_balance_coefficients_are_bounded(work: Path) -> None:
    from l3cli.whitebalance.model import WB_FEATURE

    coef = (np.eye(3).reshape(1, 9) * 1e7).tolist() + [[0.0] * 9]
    bad = _with(work / "table.npz", work / "bad.npz",
                white_balance=np.array(_wb_record(feature=WB_FEATURE, coef=coef)))
    with pytest.raises(TableError, match="white_balance"):
        load_table(bad)
