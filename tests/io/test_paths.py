"""Output planning (cli/paths.py) and alias detection (io/paths.py)."""

from __future__ import annotations

import os

import click
import pytest

from l3cli.cli.paths import plan_folder, plan_outputs
from l3cli.errors import OutputError
from l3cli.io.paths import refuse_overwrite, same_file


def _files(tmp_path, *names):
    out = []
    for n in names:
        p = tmp_path / n
        p.write_bytes(b"x")
        out.append(p)
    return out


def test_same_file_sees_symlinks_and_hard_links(tmp_path):
    (a,) = _files(tmp_path, "a.dng")
    (tmp_path / "s.dng").symlink_to(a)
    os.link(a, tmp_path / "h.dng")
    (sub := tmp_path / "sub").symlink_to(tmp_path, target_is_directory=True)
    assert same_file(a, tmp_path / "s.dng") and same_file(a, tmp_path / "h.dng")
    assert same_file(a, sub / "a.dng") and same_file(a, tmp_path / "." / "a.dng")
    assert not same_file(a, tmp_path / "b.dng")


def test_one_input_gives_a_file_with_the_format_suffix(tmp_path):
    (a,) = _files(tmp_path, "a.dng")
    plan = plan_outputs([a], tmp_path / "out", "png")
    assert plan.targets == [(a, tmp_path / "out.png")] and plan.folders == []
    with pytest.raises(click.BadParameter, match="does not end in .exr"):
        plan_outputs([a], tmp_path / "out.png", "exr")
    assert plan_outputs([a], tmp_path / "o.JPEG", "jpg").targets[0][1].name == "o.JPEG"


def test_several_inputs_give_a_folder_created_only_when_writing(tmp_path):
    a, b = _files(tmp_path, "a.dng", "b.raw")
    out = tmp_path / "new" / "deeper"
    plan = plan_outputs([a, b], out, None)
    assert [o for _, o in plan.targets] == [out / "a.exr", out / "b.exr"]
    assert not out.exists()
    with pytest.raises(RuntimeError), plan.writing():
        assert out.is_dir()
        raise RuntimeError("work failed")
    assert not (tmp_path / "new").exists()  # both created levels removed again
    with plan.writing():
        (out / "a.exr").write_bytes(b"1")
    assert (out / "a.exr").exists()
    with pytest.raises(click.BadParameter, match="share the stem"):
        plan_outputs([a, tmp_path / "a.tif"], out, None)
    with pytest.raises(OutputError, match="several inputs need an output folder"):
        plan_outputs([a, b], a, None)


def test_a_failed_run_keeps_a_folder_that_already_existed(tmp_path):
    folder = tmp_path / "plots"
    folder.mkdir()
    with pytest.raises(RuntimeError), plan_folder(folder, "--plots").writing():
        raise RuntimeError
    assert folder.is_dir()


@pytest.mark.parametrize("how", ["same", "symlink", "hardlink", "folder", "sidecar"])
def test_outputs_aliasing_inputs_are_refused(tmp_path, how):
    a, b = _files(tmp_path, "a.tif", "b.dng")
    (tmp_path / "a.tif.toml").write_text("x")
    if how == "symlink":
        (tmp_path / "l.tif").symlink_to(a)
    if how == "hardlink":
        os.link(a, tmp_path / "h.tif")
    cases = {"same": ([a], a, None), "symlink": ([a], tmp_path / "l.tif", None),
             "hardlink": ([b], tmp_path / "h.tif", None, [a]),
             "folder": ([a, b], tmp_path, "tiff"),  # tmp/a.tif is the input a.tif
             "sidecar": ([b], tmp_path / "a.tif.toml", None, [a])}
    ins, out, fmt, *protect = cases[how]
    with pytest.raises(OutputError, match="would overwrite the input"):
        plan_outputs(ins, out, fmt, protect=protect[0] if protect else ())


def test_two_outputs_that_are_one_file(tmp_path):
    with pytest.raises(OutputError, match="would both write"):
        refuse_overwrite([(tmp_path / "x.json", "-o"), (tmp_path / "." / "x.json", "--json")],
                         [])


def test_atomic_write_refuses_a_pipe_or_a_folder(tmp_path):
    from l3cli.io.atomic import atomic_path

    fifo = tmp_path / "p.json"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match="not a regular file"), atomic_path(fifo) as tmp:
        tmp.write_text("{}")
    with pytest.raises(OutputError, match="is a folder"), atomic_path(tmp_path) as tmp:
        tmp.write_text("{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.json"]


def test_cli_error_is_one_line_even_for_a_file_name_with_a_line_break(runner, tmp_path):
    from l3cli.cli.main import cli

    res = runner.invoke(cli, ["smooth", str(tmp_path / "a\nb.npz"), "-o", str(tmp_path / "o.npz")])
    assert res.exit_code == 1
    assert res.output.count("\n") == 1 and "a\\nb.npz" in res.output, res.output
