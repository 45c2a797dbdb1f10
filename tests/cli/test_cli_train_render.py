"""`l3 train` and `l3 render` through click's CliRunner."""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.io.image import read_image, write_image
from l3cli.table import load_table
from tests.builders import make_table, plausible_table, sim_dir


def test_train_then_render(runner, tmp_path):
    sim = sim_dir(tmp_path, n=2, shape=(48, 64), seed=11)
    table = tmp_path / "t.npz"
    res = runner.invoke(cli, ["-q", "train", str(sim), "-o", str(table), "--levels", "4",
                              "--seed", "3", "--min-samples", "2"])
    assert res.exit_code == 0, res.output
    t = load_table(table)
    assert t.definition.n_levels == 4 and t.output_space == "xyz"
    assert t.patch == 5  # the simulation layout's patch (tests/test_defaults.py)
    assert t.provenance["seed"] == 3 and len(t.provenance["inputs"]) == 2
    # empty classes exist and carry the kernel of the trained class they fall back to
    assert t.empty.any() and not t.empty[t.source_class].any()
    np.testing.assert_array_equal(t.source_class[~t.empty], np.flatnonzero(~t.empty))
    np.testing.assert_array_equal(t.kernels[t.empty], t.kernels[t.source_class[t.empty]])
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

    table = save_table(tmp_path / "t.npz", make_table("GRBG"))
    raw = write_raw(tmp_path / "r.dng", np.full((40, 48), 100, np.uint16), "RGGB",
                    white_level=4095)
    res = runner.invoke(cli, ["render", str(table), str(raw), "-o", str(tmp_path / "o.exr")])
    assert res.exit_code == 1
    assert "t.npz is for CFA GR/BG" in res.output and "has CFA RG/GB" in res.output
    assert not (tmp_path / "o.exr").exists()


def _one_line_error(res, *fragments):
    """Exit 1, a single ``Error: ...`` line on stderr holding every fragment, no traceback."""
    assert res.exit_code == 1, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), res.stderr
    assert "Traceback" not in res.output
    for f in fragments:
        assert f in lines[0], (f, lines[0])


@pytest.mark.parametrize("case", ["empty-folder", "nan-target", "inf-target", "size-mismatch",
                                  "zero-trained-classes"])
def test_train_bad_input_is_one_line_and_writes_nothing(runner, tmp_path, case):
    table = tmp_path / "t.npz"
    extra: list[str] = []
    if case == "empty-folder":
        folder = tmp_path / "empty"
        folder.mkdir()
        expect = [str(folder), "no training pairs"]
    elif case in ("nan-target", "inf-target"):
        folder = sim_dir(tmp_path, n=2, seed=21, nan=True)
        if case == "inf-target":  # the same pixel, +Inf instead of NaN
            img, space = read_image(folder / "cap1.target.exr")
            img[3, 4, 1] = np.inf
            write_image(folder / "cap1.target.exr", img, space=space, allow_nonfinite=True)
        expect = ["cap1.target.exr", "NaN or Inf", "x=4, y=3"]
    elif case == "size-mismatch":
        folder = sim_dir(tmp_path, n=2, seed=22, bad_size=True)
        expect = ["cap1.target.exr", "target is 48x38 but raw cap1.dng is 48x40"]
    else:
        folder = sim_dir(tmp_path, n=1, seed=23)
        extra = ["--levels", "40", "--min-samples", "50"]
        expect = ["no class has enough training samples"]
    res = runner.invoke(cli, ["train", str(folder), "-o", str(table), "--levels", "3", *extra])
    _one_line_error(res, *expect)
    assert not table.exists()


def test_render_bad_input_is_one_line_and_writes_nothing(runner, tmp_path):
    """A table for another CFA or a patch larger than the raw: say which."""
    from l3cli.io.raw import write_raw
    from l3cli.table import save_table

    table = save_table(tmp_path / "t.npz", make_table("RGGB", patch=5))
    rgbw = write_raw(tmp_path / "w.dng", np.full((16, 16), 100, np.uint16),
                     "RGBW/GWRB/BRWG/WBGR", white_level=4095)
    res = runner.invoke(cli, ["render", str(table), str(rgbw), "-o", str(tmp_path / "o.exr")])
    _one_line_error(res, "t.npz is for CFA RG/GB", f"{rgbw.name} has CFA RGBW/GWRB/BRWG/WBGR")
    tiny = tmp_path / "tiny.raw"  # headerless 4x4 dump (LibRaw refuses tiny DNGs)
    np.full((4, 4), 100, "<u2").tofile(tiny)
    (tmp_path / "tiny.raw.toml").write_text('width = 4\nheight = 4\ndtype = "uint16"\n'
                                            'cfa = "RGGB"\nblack_level = 0\n'
                                            'white_level = 4095\n')
    res = runner.invoke(cli, ["render", str(table), str(tiny), "-o", str(tmp_path / "o.exr")])
    _one_line_error(res, "t.npz uses 5x5 patches", "tiny.raw is only 4x4 pixels")
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.parametrize("space", ["xyz", "linear-srgb"])
def test_render_exr_keeps_the_table_space_and_tiff_png_jpeg_get_display_srgb(
        runner, tmp_path, space):
    """EXR holds the rendered values in the table's space; TIFF/PNG/JPEG hold them
    converted to display sRGB (colour-science's XYZ -> sRGB and sRGB transfer
    function as the reference)."""
    import colour

    from l3cli.io.raw import read_raw, write_raw
    from l3cli.render import render_mosaic
    from l3cli.table import save_table

    t = plausible_table("RGGB", seed=30)
    t.output_space = space
    table = save_table(tmp_path / "t.npz", t)
    rng = np.random.default_rng(4)
    raw = write_raw(tmp_path / "r.dng", rng.integers(200, 3500, (36, 44)).astype(np.uint16),
                    "RGGB", white_level=4095)
    outs = {}
    for suffix in (".exr", ".tif", ".png", ".jpg"):
        res = runner.invoke(cli, ["render", str(table), str(raw), "-o",
                                  str(tmp_path / f"o{suffix}")])
        assert res.exit_code == 0, res.output
        outs[suffix], file_space = read_image(tmp_path / f"o{suffix}")
        assert outs[suffix].shape == (36, 44, 3)
        assert file_space == (space if suffix == ".exr" else "srgb")
    np.testing.assert_array_equal(outs[".exr"], render_mosaic(t, read_raw(raw).mosaic))
    lin = outs[".exr"].astype(np.float64)
    if space == "xyz":
        lin = colour.XYZ_to_sRGB(lin, apply_cctf_encoding=False)
    ref = colour.cctf_encoding(np.clip(lin, 0, 1), function="sRGB")
    assert 0.05 < ref.mean() < 0.95  # a real image, not clipped flat
    np.testing.assert_allclose(outs[".tif"], ref, atol=1e-4)  # 16 bit
    np.testing.assert_allclose(outs[".png"], ref, atol=0.5 / 255 + 1e-4)  # 8 bit
    assert np.abs(outs[".jpg"] - ref).mean() < 0.01  # lossy
