"""`l3 render` over many files: pipeline order, failures, bands, options, start-up imports."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.io.image import read_image
from l3cli.io.raw import read_raw
from tests.builders import REPO, write_raws


def test_folder_outputs_in_input_order_equal_one_file_renders(runner, tmp_path, table_path):
    from l3cli.pipeline import render_pipeline
    from l3cli.render import render_mosaic, table_for_task

    raws = write_raws(tmp_path, 5)
    table = table_for_task(table_path)
    # different content per file, so a mix-up of order shows
    jobs = [(r, tmp_path / "out" / f"{r.stem}.png") for r in raws[::-1]]
    (tmp_path / "out").mkdir()
    done = render_pipeline(table, jobs, table_name="t.npz", in_flight=3)
    assert done == [o for _, o in jobs]
    for raw, out in jobs:
        img, _ = read_image(out)
        solo = tmp_path / f"solo-{raw.stem}.png"
        res = runner.invoke(cli, ["render", str(table_path), str(raw), "-o", str(solo)])
        assert res.exit_code == 0, res.output
        np.testing.assert_array_equal(img, read_image(solo)[0])
        exr = tmp_path / f"solo-{raw.stem}.exr"
        runner.invoke(cli, ["render", str(table_path), str(raw), "-o", str(exr)])
        np.testing.assert_array_equal(read_image(exr)[0],
                                      render_mosaic(table, read_raw(raw).mosaic))


@pytest.mark.parametrize("decoded_by", ["prefetch", "job"])
def test_a_failing_file_in_the_middle(runner, tmp_path, table_path, monkeypatch, decoded_by):
    # The bad file is decoded either by the prefetch (LibRaw alone) or by its
    # pipeline job (read_raw: l3's lossy-DNG probe first, tifffile, then LibRaw);
    # which one depends on thread timing in a real run (the job decodes it
    # itself when the prefetch has not begun it: a loaded machine, a cold numba
    # cache). Both are forced here: the message must be the same one line.
    from l3cli import pipeline

    if decoded_by == "prefetch":  # every prefetched decode done before the jobs start
        start = pipeline.Prefetch.__init__

        def init_and_wait(self, *args, **kwargs):
            start(self, *args, **kwargs)
            self._thread.join()

        monkeypatch.setattr(pipeline.Prefetch, "__init__", init_and_wait)
        monkeypatch.setattr(pipeline, "IN_FLIGHT", 4)
    else:  # no decode handed over: each job reads its file
        monkeypatch.setattr(pipeline.Prefetch, "take", lambda self, path: None)
    raws = write_raws(tmp_path, 4)
    bad = tmp_path / "r1.dng"
    bad.write_bytes(b"II*\x00 not really a raw file")
    out = tmp_path / "out"
    res = runner.invoke(cli, ["render", str(table_path), *map(str, raws), "-o", str(out),
                              "--format", "jpg"])
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and "r1.dng" in lines[0] and lines[0].startswith("Error:")
    assert sorted(p.name for p in out.iterdir()) == ["r0.jpg", "r2.jpg", "r3.jpg"]


def test_format_accepts_the_other_suffix_spellings(runner, tmp_path, table_path):
    raws = write_raws(tmp_path, 2)
    for given, suffix in (("TIF", ".tif"), ("jpeg", ".jpg"), ("tiff", ".tif")):
        out = tmp_path / f"out-{given}"
        res = runner.invoke(cli, ["render", str(table_path), *map(str, raws), "-o", str(out),
                                  "--format", given])
        assert res.exit_code == 0, res.output
        assert sorted(p.name for p in out.iterdir()) == [f"r0{suffix}", f"r1{suffix}"]
    res = runner.invoke(cli, ["render", str(table_path), str(raws[0]), "-o",
                              str(tmp_path / "x.jpg"), "--format", "tif"])
    assert res.exit_code != 0 and "--format tiff" in res.output  # the suffix disagrees
    res = runner.invoke(cli, ["render", str(table_path), str(raws[0]), "-o",
                              str(tmp_path / "x.bmp"), "--format", "bmp"])
    assert res.exit_code == 2


def test_display_render_equals_render_then_encode(table_path):
    from l3cli.io.encode import display_encode
    from l3cli.prepared import plain
    from l3cli.render import render_mosaic, table_for_task

    table = table_for_task(table_path)
    m = np.random.default_rng(2).random((53, 40)).astype(np.float32)
    for bits in (8, 16):
        got = plain(table, m).render(bits)
        want = display_encode(render_mosaic(table, m), table.output_space, bits)
        np.testing.assert_array_equal(got, want)


def test_compression_and_half_options(runner, tmp_path, table_path):
    import OpenImageIO as oiio

    (raw,) = write_raws(tmp_path, 1)

    def spec(path):
        inp = oiio.ImageInput.open(str(path))
        s = inp.spec()
        inp.close()
        return s

    for args, name, compression, fmt in (
            ([], "a.tif", "none", "uint16"), (["--compression", "zip"], "b.tif", "zip", "uint16"),
            ([], "c.exr", "none", "float"), (["--half"], "d.exr", "zips", "half"),
            (["--half", "--compression", "piz"], "e.exr", "piz", "half")):
        res = runner.invoke(cli, ["render", str(table_path), str(raw), "-o",
                                  str(tmp_path / name), *args])
        assert res.exit_code == 0, res.output
        s = spec(tmp_path / name)
        assert s.getattribute("compression") == compression and str(s.format) == fmt
    a, _ = read_image(tmp_path / "a.tif")
    np.testing.assert_array_equal(a, read_image(tmp_path / "b.tif")[0])
    for args in (["--compression", "zip"], ["--half"], ["--compression", "b44"]):
        out = "x.jpg" if args[0] != "--compression" or args[1] != "b44" else "x.exr"
        res = runner.invoke(cli, ["render", str(table_path), str(raw), "-o",
                                  str(tmp_path / out), *args])
        assert res.exit_code == 2, res.output
        assert not (tmp_path / out).exists()


_PROBE = """
import sys
from l3cli.cli.main import cli
try:
    cli(sys.argv[1:], standalone_mode=False)
finally:
    heavy = ("colour", "matplotlib", "dask", "distributed", "scipy.linalg", "scipy.interpolate",
             "scipy.ndimage")
    print(" ".join(sorted(m for m in heavy if m in sys.modules)) or "-")
"""


def _imports(args):
    res = subprocess.run([sys.executable, "-c", _PROBE, *args], cwd=REPO, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return res.stdout.strip().splitlines()[-1]


def test_render_and_info_import_only_what_they_use(tmp_path, table_path):
    (raw,) = write_raws(tmp_path, 1)
    assert _imports(["-q", "render", str(table_path), str(raw), "-o",
                     str(tmp_path / "o.jpg")]) == "-"
    assert _imports(["-q", "render", str(table_path), str(raw), "-o",
                     str(tmp_path / "o.exr")]) == "-"
    assert _imports(["info", str(raw)]) == "-"
    assert (tmp_path / "o.jpg").exists() and (tmp_path / "o.exr").exists()


def test_help_imports_no_numerical_library():
    probe = ("import sys\nfrom l3cli.cli.main import cli\ntry:\n    cli(['--help'])\n"
             "except SystemExit:\n    pass\nprint(sorted(m for m in ('numpy', 'numba', 'click')"
             " if m in sys.modules))")
    res = subprocess.run([sys.executable, "-c", probe], cwd=REPO, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().splitlines()[-1] == "['click']"


def test_prefetched_first_raw_is_used_once_and_its_error_raised(tmp_path, table_path):
    from l3cli.errors import InputError
    from l3cli.pipeline import Prefetch, render_pipeline
    from l3cli.render import table_for_task

    raws = write_raws(tmp_path, 2)
    with Prefetch(raws[0]) as pre:
        assert pre.take(raws[1]) is None  # another file: not this decode
        raw = pre.take(raws[0])
        np.testing.assert_array_equal(raw.mosaic, read_raw(raws[0]).mosaic)
        assert pre.take(raws[0]) is None  # once only
    cut = tmp_path / "cut.dng"
    cut.write_bytes(raws[0].read_bytes()[:200])
    table = table_for_task(table_path)
    (tmp_path / "out").mkdir()
    jobs = [(cut, tmp_path / "out" / "cut.png"), (raws[1], tmp_path / "out" / "r1.png")]
    with Prefetch(cut) as pre, pytest.raises(InputError, match="cut.dng"):
        render_pipeline(table, jobs, table_name="t.npz", prefetch=pre)
    assert (tmp_path / "out" / "r1.png").exists() and not (tmp_path / "out" / "cut.png").exists()


def test_prefetch_of_several_raws_in_order_each_once(tmp_path):
    from l3cli.pipeline import Prefetch

    raws = write_raws(tmp_path, 4)
    with Prefetch(raws, count=3) as pre:
        assert pre.paths == [str(r) for r in raws[:3]]
        np.testing.assert_array_equal(pre.take(raws[0]).mosaic, read_raw(raws[0]).mosaic)
        pre._thread.join(10)  # all decoded: any order of taking
        for r in reversed(raws[:3]):
            if r != raws[0]:
                np.testing.assert_array_equal(pre.take(r).mosaic, read_raw(r).mosaic)
            assert pre.take(r) is None
        assert pre.take(raws[3]) is None  # beyond the count: the job decodes it


def test_prefetch_leaves_a_file_not_yet_begun_to_its_job(tmp_path, monkeypatch):
    """A job that comes before its file's decode began gets None at once (it decodes
    itself) and the prefetch skips that file; leaving stops the queue."""
    import threading

    import l3cli.io.raw as raw_io
    from l3cli.pipeline import Prefetch

    raws = write_raws(tmp_path, 3)
    gate, calls = threading.Event(), []
    real = raw_io.read_raw

    def slow(path, **kw):
        calls.append(str(path))
        gate.wait(10)
        return real(path, **kw)

    monkeypatch.setattr(raw_io, "read_raw", slow)
    with Prefetch(raws, count=3) as pre:
        for _ in range(1000):  # the first decode is running (10 s at most)
            if calls:
                break
            threading.Event().wait(0.01)
        assert pre.take(raws[1]) is None  # not begun: handed back at once
        gate.set()
        assert pre.take(raws[0]) is not None
        pre._thread.join(10)
    assert calls == [str(raws[0]), str(raws[2])]  # raws[1] was left to its job
    gate.clear()
    calls.clear()
    with Prefetch(raws, count=3) as pre:
        for _ in range(1000):
            if calls:
                break
            threading.Event().wait(0.01)
        threading.Timer(0.2, gate.set).start()
    assert calls == [str(raws[0])]  # leaving stopped the files not yet begun


def test_display_tables_are_built_once_beside_the_warm_up(tmp_path, table_path, monkeypatch):
    """The first file's first band waits for the warm-up's encoder tables instead of
    building them a second time in its own thread."""
    import functools
    import time

    import l3cli.io.encode as encode
    from l3cli.pipeline import render_pipeline
    from l3cli.render import table_for_task

    built = []
    real = encode.srgb_thresholds.__wrapped__

    @functools.cache
    def slow(bits, encode_=True):
        built.append((bits, encode_))
        time.sleep(0.3)  # long enough for the first band to come for the tables
        return real(bits, encode_)

    monkeypatch.setattr(encode, "srgb_thresholds", slow)
    raws = write_raws(tmp_path, 1)
    (tmp_path / "out").mkdir()
    render_pipeline(table_for_task(table_path), [(raws[0], tmp_path / "out" / "a.png")],
                    table_name="t.npz")
    assert sorted(set(built)) == sorted(built) and built  # each table built once


def test_render_turns_go_in_input_order_and_a_skipped_file_passes_its_turn():
    """Files ready in reverse order still render 0, 1, 2, ...; a file that never reaches
    its render (decode failed) calls done() and the next one is not left waiting."""
    import threading
    import time

    from l3cli.pipeline import RenderTurns

    turns = RenderTurns()
    entered: list[int] = []

    def job(i: int) -> None:
        try:
            if i == 2:
                return  # fails before its render
            with turns.turn(i):
                entered.append(i)
                time.sleep(0.01)
        finally:
            turns.done(i)

    threads = [threading.Thread(target=job, args=(i,)) for i in reversed(range(5))]
    for t in threads:
        t.start()
        time.sleep(0.01)  # later files ask first
    for t in threads:
        t.join(timeout=10)
    assert not any(t.is_alive() for t in threads)
    assert entered == [0, 1, 3, 4]


def test_folder_renders_take_their_turns_in_input_order(tmp_path, table_path, monkeypatch):
    """In a folder render the render stage runs file by file in input order (whichever
    decode finishes first), each file's render alone."""
    import time

    import l3cli.io.raw as rawmod
    from l3cli import pipeline
    from l3cli.table import load_table

    raws = write_raws(tmp_path, 5)

    orig = rawmod.read_raw

    def slow_first(path, **kw):
        if str(path).endswith("r0.dng"):
            time.sleep(0.3)  # the first file decodes last
        return orig(path, **kw)

    monkeypatch.setattr(rawmod, "read_raw", slow_first)
    active: list[int] = []
    most: list[int] = []
    from l3cli.prepared import Prepared

    orig_render = Prepared.render

    def record(self, bits=None, **kw):
        active.append(1)
        most.append(len(active))
        try:
            return orig_render(self, bits, **kw)
        finally:
            active.pop()

    monkeypatch.setattr(Prepared, "render", record)
    seen: list[str] = []
    orig_one = pipeline.render_one

    def track(table, name, raw, out, *a, turn=None, **k):
        class Spy:
            def __enter__(self):
                r = turn.__enter__()
                seen.append(str(raw))
                return r

            def __exit__(self, *exc):
                return turn.__exit__(*exc)

        return orig_one(table, name, raw, out, *a, turn=Spy(), **k)

    monkeypatch.setattr(pipeline, "render_one", track)
    jobs = [(r, tmp_path / f"o{i}.jpg") for i, r in enumerate(raws)]
    pipeline.render_pipeline(load_table(table_path), jobs, in_flight=3)
    assert seen == [str(r) for r in raws]
    assert max(most) == 1  # one file's render at a time
    assert all((tmp_path / f"o{i}.jpg").exists() for i in range(5))
