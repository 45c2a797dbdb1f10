"""`l3 train` and `l3 render` through click's CliRunner."""

from __future__ import annotations

import numpy as np

from l3cli.cli.main import cli
from l3cli.io.image import read_image
from l3cli.table import load_table
from tests.test_train import _sim_dir


def test_train_then_render(runner, tmp_path):
    sim = _sim_dir(tmp_path, n=2, shape=(48, 64), seed=11)
    table = tmp_path / "t.npz"
    res = runner.invoke(cli, ["-q", "train", str(sim), "-o", str(table), "--levels", "4",
                              "--seed", "3", "--min-samples", "2"])
    assert res.exit_code == 0, res.output
    t = load_table(table)
    assert t.definition.n_levels == 4 and t.output_space == "xyz" and t.patch == 5
    assert t.provenance["seed"] == 3 and len(t.provenance["inputs"]) == 2
    raws = sorted(sim.glob("*.dng"))
    out = tmp_path / "one.exr"
    res = runner.invoke(cli, ["render", str(table), str(raws[0]), "-o", str(out)])
    assert res.exit_code == 0, res.output
    img, space = read_image(out)
    assert img.shape == (48, 64, 3) and space == "xyz"
    folder = tmp_path / "renders"
    res = runner.invoke(cli, ["render", str(table), *map(str, raws), "-o", str(folder),
                              "--format", "png"])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in folder.iterdir()) == ["cap0.png", "cap1.png"]
    png, _ = read_image(folder / "cap0.png")
    assert png.shape == (48, 64, 3) and 0 <= png.min() and png.max() <= 1


def test_cli_errors(runner, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    res = runner.invoke(cli, ["train", str(empty), "-o", str(tmp_path / "t.npz")])
    assert res.exit_code == 1 and "no training pairs" in res.output
    assert not (tmp_path / "t.npz").exists()
    res = runner.invoke(cli, ["train", str(empty), "-o", "x.npz", "--patch", "4"])
    assert res.exit_code == 2
    bad = tmp_path / "bad.npz"
    bad.write_text("not a table")
    res = runner.invoke(cli, ["render", str(bad), str(tmp_path / "x.dng"), "-o",
                              str(tmp_path / "o.exr")])
    assert res.exit_code == 1 and "not an NPZ table" in res.output


def test_render_rejects_table_for_other_cfa(runner, tmp_path):
    from l3cli.io.raw import write_raw
    from l3cli.table import save_table
    from tests.test_table import make_table

    table = save_table(tmp_path / "t.npz", make_table("GRBG"))
    raw = write_raw(tmp_path / "r.dng", np.full((40, 48), 100, np.uint16), "RGGB",
                    white_level=4095)
    res = runner.invoke(cli, ["render", str(table), str(raw), "-o", str(tmp_path / "o.exr")])
    assert res.exit_code == 1
    assert "t.npz is for CFA GR/BG" in res.output and "has CFA RG/GB" in res.output
    assert not (tmp_path / "o.exr").exists()
