"""The top-level Python API: ``l3cli.train``, ``l3cli.load_table(...).render``,
``l3cli.evaluate`` (README, "From Python"), and ``l3 train`` as a thin mapping
of its flags onto it."""

from __future__ import annotations

import dataclasses
import doctest
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import l3cli
from l3cli.cli.main import cli
from l3cli.errors import OptionError
from l3cli.train import TrainOptions
from tests.builders import sim_dir, tune_pairs

ROOT = Path(__file__).resolve().parents[1]
TINY = ["--levels", "4", "--contrast-bins", "1", "--level-range", "0.02", "0.6", "--patch", "5",
        "--no-multiscale"]
TINY_KW = dict(levels=4, contrast_bins=1, level_range=(0.02, 0.6), patch=5, multiscale=False)


def _arrays_equal(path: Path, table, *, ignore: tuple[str, ...] = ()) -> None:
    """Every array of the table file equals the table's own (``table.to_arrays()``);
    the provenance compared as JSON without the keys ``ignore`` (``tune.seconds``)."""
    want = table.to_arrays()
    with np.load(path, allow_pickle=False) as z:
        assert sorted(z.files) == sorted(want)
        for k in z.files:
            if k == "provenance":
                a, b = json.loads(str(z[k])), json.loads(str(want[k]))
                for key in ignore:
                    outer, inner = key.split(".")
                    a[outer].pop(inner), b[outer].pop(inner)
                assert a == b
            else:
                np.testing.assert_array_equal(z[k], want[k], err_msg=k)


def test_import_is_light_and_names_resolve_lazily():
    code = ("import sys, l3cli; print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('l3cli', 'numpy', 'click')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT).stdout
    assert out.strip() == "['l3cli']"
    import l3cli.evaluate.metrics
    import l3cli.model
    import l3cli.train.api

    assert callable(l3cli.train) and l3cli.train.TrainOptions is TrainOptions  # the package
    assert l3cli.load_table is l3cli.model.load_table
    assert callable(l3cli.evaluate)
    with pytest.raises(AttributeError):
        l3cli.no_such_name  # noqa: B018


def test_options_are_frozen_and_hold_no_fitted_state():
    opts = TrainOptions(levels=4)
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.levels = 5
    assert not {"shading_field", "tone_model", "target_adapt"} & set(vars(opts))
    assert dataclasses.replace(opts, patch=7).patch == 7 and opts.patch == 5


def test_library_errors_name_parameters_the_cli_its_flags(tmp_path, runner):
    sim = sim_dir(tmp_path)
    with pytest.raises(OptionError, match=r"^orientation_bins 3 is not allowed"):
        l3cli.train(sim, orientation_bins=3)
    with pytest.raises(OptionError, match=r"^min_samples is not an option of l3cli.train"):
        l3cli.train(sim, min_samples=2)  # the flag's spelling is not a parameter
    with pytest.raises(OptionError, match=r"^white_balance: must be 3 finite positive numbers"):
        l3cli.train(sim, white_balance=(1, 2))
    res = runner.invoke(cli, ["train", str(sim), "-o", str(tmp_path / "t.npz"),
                              "--orientation-bins", "3"])
    assert res.exit_code == 1
    assert "Error: --orientation-bins 3 is not allowed" in res.output
    assert not (tmp_path / "t.npz").exists()


def test_python_train_equals_l3_train_simulate_folder(tmp_path, runner):
    sim = sim_dir(tmp_path, n=3)
    out = tmp_path / "cli.npz"
    res = runner.invoke(cli, ["-q", "train", str(sim), "-o", str(out), "--seed", "1",
                              "--levels", "4"])
    assert res.exit_code == 0, res.output
    table = l3cli.train(sim, seed=1, levels=4)
    assert table.tuning is None
    _arrays_equal(out, table)
    back = l3cli.load_table(out)
    raw = sim / "cap0.dng"
    np.testing.assert_array_equal(back.render(raw), table.render(str(raw)))


def test_python_train_equals_l3_train_tuned_pairs_folder(tmp_path, runner):
    """The default path of a pairs folder (self-tuning, as-shot white balance off: the
    raws carry none): the same table from the command and from Python, every array
    (the provenance too, but for the search's wall time)."""
    folder = tune_pairs(tmp_path / "p", {"a": (5, 1.0), "b": (6, 1.0), "c": (7, 1.0)})
    out = tmp_path / "cli.npz"
    res = runner.invoke(cli, ["-q", "train", str(folder), "-o", str(out), "--seed", "1",
                              *TINY])
    assert res.exit_code == 0, res.output
    table = l3cli.train(folder, seed=1, **TINY_KW)
    assert table.tuning is not None and {c["patch"] for c in table.tuning["candidates"]} == {5}
    _arrays_equal(out, table, ignore=("tune.seconds",))


def test_evaluate_files_and_arrays(tmp_path):
    from l3cli.colourspace import srgb_encode
    from l3cli.io.image import read_image, write_image
    from tests.builders import scene

    ref = tmp_path / "ref.png"
    write_image(ref, srgb_encode(scene(64, 80, seed=3)), space="srgb")
    same = l3cli.evaluate(ref, ref)
    assert same["scielab_mean"] == 0.0 and same["psnr_db"] == np.inf
    values, space = read_image(ref)
    assert l3cli.evaluate(values, ref, space=space)["scielab_mean"] == 0.0
    worse = l3cli.evaluate(np.clip(values * 0.8, 0, 1), ref, space="srgb")
    assert worse["scielab_mean"] > 1.0
    with pytest.raises(OptionError, match="^space is needed with an array"):
        l3cli.evaluate(values, ref)


@pytest.mark.slow
def test_readme_from_python_session_runs(monkeypatch):
    """The README's "From Python" section, run as a doctest from the repository root."""
    monkeypatch.chdir(ROOT)
    res = doctest.testfile(str(ROOT / "README.md"), module_relative=False,
                           optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert res.attempted >= 8 and res.failed == 0, res


def test_every_train_flag_is_a_parameter_of_the_library():
    """``l3 train`` maps flags only: each of its options is a keyword of ``l3cli.train``
    (the run's own: the output, the config file, the cluster), under the same name."""
    from l3cli.cli.train import train
    from l3cli.train.api import TrainRequest

    fields = {f.name for f in dataclasses.fields(TrainRequest)}
    flags = {p.name for p in train.params if p.expose_value} - {"inputs", "output",
                                                                 "workers", "scheduler"}
    assert flags <= fields, flags - fields
    assert fields - flags == {"tune_grid"}  # the CLI's --config [train.tune] table


def test_an_asked_for_lens_field_that_is_not_kept_is_said(tmp_path, runner):
    """``shading=True`` on unshaded pairs: the field does not help and is not kept; the
    user who asked for it is told (Python: a note naming the parameter; the command
    line: its flag), and the table is written without one."""
    folder = tune_pairs(tmp_path / "p", {"a": (5, 1.0), "b": (6, 1.0)})
    notes = []
    table = l3cli.train(folder, shading=True, tune=False, patch=3, levels=4,
                        note=notes.append)
    assert table.shading is None
    said = [n for n in notes if n.parameter == "shading"]
    assert len(said) == 1 and "no lens-shading field kept" in said[0].named("shading")
    res = runner.invoke(cli, ["train", str(folder), "-o", str(tmp_path / "t.npz"), "--shading",
                              "--no-tune", "--patch", "3", "--levels", "4"])
    assert res.exit_code == 0, res.output
    assert "--shading: no lens-shading field kept" in res.output
