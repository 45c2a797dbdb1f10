"""Issue 42's hostile cases (round 3): what is new since round 2 holds bad input too.

Each case of the issue's table is a test here: `l3 export` onto its own input,
DNG GainMap opcodes that do not fit their image, signals during long steps and a
FIFO in the kernel store, a shading fit on small data, the optional table groups
(lens shading, multi-scale) with finite but absurd values, a lossy DNG without
its tiles, a `.npy` header claiming 2**40 values, and the image writers' last
line of defence against NaN. Files are tiny and made here.
"""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.errors import InputError, TableError
from l3cli.io.raw import write_raw
from l3cli.table import load_table, save_table
from tests.builders import REPO, assert_one_line_error, make_table

L3 = [sys.executable, "-c", "from l3cli.cli.main import main; main()"]


@pytest.fixture
def work(tmp_path: Path) -> Path:
    """A valid table and a valid DNG in a folder."""
    save_table(tmp_path / "t.npz", make_table("RGGB"))
    dn = np.random.default_rng(0).integers(64, 4000, (40, 48)).astype(np.uint16)
    write_raw(tmp_path / "good.dng", dn, "RGGB", black_level=64, white_level=4095)
    return tmp_path


def _run(args: list[str], *, code: str = "", cwd: Path | None = None,
         timeout: float = 120) -> subprocess.CompletedProcess:
    """``l3 args`` in a fresh Python (``code`` run first: a patch)."""
    prog = code + f"import sys\nsys.argv = ['l3', *{args!r}]\nfrom l3cli.cli.main import main\nmain()\n"
    return subprocess.run([sys.executable, "-c", prog], cwd=cwd or REPO, capture_output=True,
                          text=True, timeout=timeout)


# ---------------------------------------------------------------- l3 export onto its input
@pytest.mark.parametrize("kind", ["same file", "symbolic link", "hard link"])
def test_export_refuses_an_output_that_is_the_table(runner, work: Path, kind: str) -> None:
    """`l3 export t.onnx -o t.onnx` overwrote the table; a link to it was replaced. Now
    one line naming both, before any work (the table is not even loaded)."""
    table = work / "t.npz"
    before = table.read_bytes()
    if kind == "same file":
        table = work / "t.onnx"  # a table whose name ends in .onnx
        table.write_bytes(before)
        out = table
    elif kind == "symbolic link":
        out = work / "s.onnx"
        out.symlink_to(table)
    else:
        out = work / "h.onnx"
        os.link(table, out)
    res = runner.invoke(cli, ["export", str(table), "-o", str(out)])
    line = assert_one_line_error(res, str(out), "overwrite the input")
    assert str(table) in line
    assert table.read_bytes() == before
    assert out.is_symlink() == (kind == "symbolic link")
    assert not list(work.glob(".l3-tmp*"))


def test_export_refuses_a_fifo_table_at_once(runner, work: Path) -> None:
    """A FIFO as the table: one line, never opened for reading (it blocked forever)."""
    fifo = work / "pipe.npz"
    os.mkfifo(fifo)
    res = runner.invoke(cli, ["export", str(fifo), "-o", str(work / "x.onnx")])
    assert_one_line_error(res, "pipe.npz", "FIFO")
    with pytest.raises(TableError, match="not a regular file"):
        load_table(fifo)  # the library's own reader: opened non-blocking, refused


# ---------------------------------------------------------------- DNG GainMap opcodes
def _gain_map(**fields):
    from l3cli.io.dng_opcodes import GainMap

    f = dict(top=0, left=0, bottom=40, right=48, plane=0, planes=1, row_pitch=1, col_pitch=1,
             points_v=2, points_h=2, spacing_v=1.0, spacing_h=1.0, origin_v=0.0,
             origin_h=0.0, gains=np.full((2, 2, 1), 1.5, np.float32))
    f.update(fields)
    return GainMap(**f)


def _dng_with_opcodes(path: Path, list2: bytes | None = None, list3: bytes | None = None,
                      shape=(40, 48)) -> Path:
    """A 16-bit RGGB DNG (tests/dngmake.py) with OpcodeList2/3 tags."""
    from tests.dngmake import make_dng

    dn = np.random.default_rng(1).integers(64, 4000, shape).astype(np.uint16)
    lists = {n: d for n, d in ((2, list2), (3, list3)) if d is not None}
    return make_dng(path, dn, black=64, white=4095, opcode_lists=lists)


def _raw_opcodes(maps_params: list[dict], gains: np.ndarray | None = None) -> bytes:
    """An opcode list of GainMaps written field by field (any uint32, as a hostile file)."""
    from l3cli.io.dng_opcodes import _HEAD

    out = [struct.pack(">I", len(maps_params))]
    for p in maps_params:
        q = dict(top=0, left=0, bottom=40, right=48, plane=0, planes=1, row_pitch=1,
                 col_pitch=1, pv=2, ph=2, sv=1.0, sh=1.0, ov=0.0, oh=0.0, mp=1)
        q.update(p)
        g = np.full(q["pv"] * q["ph"] * q["mp"], 1.5, ">f4") if gains is None else gains
        body = _HEAD.pack(*q.values()) + np.asarray(g, ">f4").tobytes()
        out.append(struct.pack(">I4sII", 9, bytes((1, 3, 0, 0)), 0, len(body)) + body)
    return b"".join(out)


BAD_MAPS = {
    "planes 0xFFFFFFFF in OpcodeList2": ({"planes": 0xFFFFFFFF}, "list2", "planes"),
    "planes 0xFFFFFFFF in OpcodeList3": ({"planes": 0xFFFFFFFF}, "list3", "planes"),
    "plane beyond the image's": ({"plane": 7}, "list3", "planes 7"),
    "area beyond the image": ({"bottom": 4000}, "list2", "outside the 48x40 image"),
    "pitch beyond the area": ({"row_pitch": 100}, "list2", "pitch"),
    "map finer than the pixels": ({"pv": 300, "ph": 2}, "list2", "finer"),
    "map planes beyond the image's": ({"mp": 9}, "list2", "map planes"),
}


@pytest.mark.parametrize("case", list(BAD_MAPS))
def test_gain_map_that_does_not_fit_the_image_is_refused(runner, work: Path, case: str) -> None:
    """Validated against the image before any pixel: a map's planes among the image's,
    its area inside it, its grid no finer than the pixels. Planes = 0xFFFFFFFF ran for
    over 13 minutes (a loop per plane); now one line naming the DNG, at once."""
    params, where, words = BAD_MAPS[case]
    data = _raw_opcodes([params])
    dng = _dng_with_opcodes(work / "gm.dng", **{where: data})
    res = runner.invoke(cli, ["render", str(work / "t.npz"), str(dng), "-o",
                              str(work / "o.png")])
    assert_one_line_error(res, "gm.dng", f"OpcodeList{where[-1]}", words)
    assert not (work / "o.png").exists()


@pytest.mark.parametrize("gain", [3e38, 1e5, 0.0, -1.0])
def test_gain_map_gains_beyond_the_sdk_range_are_refused(runner, work: Path,
                                                         gain: float) -> None:
    """Two GainMaps of 3e38 rendered a PNG from NaN (negative pixels times 3e38 twice);
    gains outside the DNG SDK's 1/4096 .. 4096 are refused, naming the DNG."""
    g = np.full(4, gain, ">f4")
    dng = _dng_with_opcodes(work / "big.dng", list2=_raw_opcodes([{}, {}], gains=g))
    res = runner.invoke(cli, ["render", str(work / "t.npz"), str(dng), "-o",
                              str(work / "o.png")])
    assert_one_line_error(res, "big.dng", "OpcodeList2, opcode 1",
                          "outside the 0.000244141 .. 4096")
    assert not (work / "o.png").exists()


def test_gain_maps_within_range_still_apply(work: Path) -> None:
    """The checks leave a valid list alone: OpcodeList3's maps of gain 2 on R and B (a
    plane each) double those pixels below white (the DNG SDK's arithmetic, by hand)."""
    from l3cli.io.raw import read_raw
    from l3cli.lens.gainmaps import apply_dng_gains

    g = np.full(4, 2.0, ">f4")
    plain = read_raw(_dng_with_opcodes(work / "plain.dng"))
    dng = _dng_with_opcodes(work / "gm.dng",
                            list3=_raw_opcodes([{"plane": 0}, {"plane": 2}], gains=g))
    raw = apply_dng_gains(read_raw(dng))  # read_raw parses, the model applies
    assert raw.metadata["gain_maps"] == {"OpcodeList2": 0, "OpcodeList3": 2}
    want = plain.mosaic.astype(np.float64).copy()
    for sl in ((slice(0, None, 2), slice(0, None, 2)), (slice(1, None, 2), slice(1, None, 2))):
        want[sl] = np.minimum(want[sl] * 2.0, 1.0)  # R and B of RGGB
    np.testing.assert_allclose(raw.mosaic, want, rtol=0, atol=1e-6)


def test_gain_map_plane_loop_is_bounded_by_the_image() -> None:
    """apply_gain_maps alone (the checks skipped): Planes = 0xFFFFFFFF applies the map to
    the image's one plane (or three), as Planes = 1 (or 3) does; a loop per claimed
    plane would not end for hours."""
    from l3cli.lens.gainmaps import apply_maps as apply_gain_maps

    m = np.full((40, 48), 0.25, np.float32)
    want = apply_gain_maps(m.copy(), [_gain_map()])
    got = apply_gain_maps(m.copy(), [_gain_map(planes=0xFFFFFFFF)])
    np.testing.assert_array_equal(got, want)
    colour = np.indices((40, 48)).sum(axis=0) % 3  # three planes
    want = apply_gain_maps(m.copy(), [_gain_map(planes=3)], planes=colour)
    got = apply_gain_maps(m.copy(), [_gain_map(planes=0xFFFFFFFF)], planes=colour)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(got, 0.375)


def test_opcode_count_beyond_the_bytes_is_refused() -> None:
    from l3cli.io.dng_opcodes import parse_opcode_list

    with pytest.raises(InputError, match="claims 4294967295 opcodes"):
        parse_opcode_list(b"\xff\xff\xff\xff" + bytes(40), "x.dng: OpcodeList2")


def test_too_many_gain_maps_are_refused() -> None:
    from l3cli.io.dng_opcodes import MAX_GAIN_MAPS, parse_opcode_list

    data = _raw_opcodes([{}] * (MAX_GAIN_MAPS + 1))
    with pytest.raises(InputError, match=f"more than {MAX_GAIN_MAPS} GainMap"):
        parse_opcode_list(data, "x.dng: OpcodeList2")


def test_extreme_map_spacing_stays_on_the_grid() -> None:
    """Spacing 1e-300 (positions far beyond the grid): the gain of the grid's edge, not an
    integer overflow's garbage."""
    from l3cli.lens.gainmaps import apply_maps as apply_gain_maps

    gains = np.array([1.5, 1.5, 1.25, 1.25], np.float32).reshape(2, 2, 1)
    m = np.full((40, 48), 0.25, np.float32)
    apply_gain_maps(m, [_gain_map(spacing_v=1e-300, spacing_h=1e-300, gains=gains)])
    np.testing.assert_allclose(m, 0.25 * 1.25, rtol=1e-6)  # the last grid row everywhere


# ---------------------------------------------------------------- signals and the kernel store
def test_sigterm_ends_a_render_inside_a_long_opcode_loop(work: Path) -> None:
    """SIGTERM to a render busy applying GainMaps in a worker thread: "Aborted.", 143.

    Deterministic: the (patched) list of maps never ends once applied, and its start
    sends the signal; the loop must see it and stop (before, only SIGKILL ended the run).
    """
    patch = (
        "import os, signal, itertools\n"
        "import numpy as np\n"
        "import l3cli.io.dng_opcodes as ops\n"
        "from l3cli.io.dng_opcodes import GainMap\n"
        "gm = GainMap(0, 0, 40, 48, 0, 1, 1, 1, 2, 2, 1.0, 1.0, 0.0, 0.0,\n"
        "             np.ones((2, 2, 1), np.float32))\n"
        "class Maps(list):  # checked once (one map), then applied without end\n"
        "    checked = False\n"
        "    def __iter__(self):\n"
        "        if not self.checked:\n"
        "            self.checked = True\n"
        "            return iter([gm])\n"
        "        os.kill(os.getpid(), signal.SIGTERM)\n"
        "        return itertools.repeat(gm)\n"
        "ops.read_gain_maps = lambda path: (Maps([gm]), [])\n")
    res = _run(["render", str(work / "t.npz"), str(work / "good.dng"), "-o",
                str(work / "o.png")], code=patch, timeout=120)
    assert res.returncode == 128 + signal.SIGTERM, res.stderr[-2000:]
    assert "Aborted" in res.stderr and "Traceback" not in res.stderr
    assert not (work / "o.png").exists() and not list(work.glob(".l3-tmp*"))


def test_stop_if_interrupted_raises_in_workers_only(monkeypatch) -> None:
    import threading

    from l3cli import startup

    monkeypatch.setattr(startup, "_first_signal", [0.0, int(signal.SIGTERM)])
    startup.stop_if_interrupted()  # the main thread: its handler raised already
    seen: list[BaseException] = []

    def worker() -> None:
        try:
            startup.stop_if_interrupted()
        except BaseException as exc:  # noqa: BLE001 - recorded
            seen.append(exc)

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert len(seen) == 1 and isinstance(seen[0], startup.Interrupted)
    assert seen[0].signum == signal.SIGTERM


@pytest.mark.slow
def test_fifo_in_the_kernel_store_is_not_waited_on(tmp_path: Path, work: Path) -> None:
    """A FIFO in place of every stored kernel file: the render does not block on it
    (opened non-blocking, refused as not a regular file) and falls back to numba, as
    for a damaged file. Nothing writes to the FIFOs: a blocking open would never
    return, so completing is the test."""
    from l3cli.kernel_store import store_dirs

    real = [d for d in store_dirs() if d.is_dir() and any(d.glob("*.bin"))]
    fifos = tmp_path / "fifos"
    fifos.mkdir()
    names = {p.name for d in real for p in d.glob("*.bin")}
    for name in names:
        os.mkfifo(fifos / name)
    patch = ("import l3cli.kernel_store as ks\n"
             "real = ks.store_dirs\n"
             f"ks.store_dirs = lambda: [__import__('pathlib').Path({str(fifos)!r}), *real()]\n")
    res = _run(["render", str(work / "t.npz"), str(work / "good.dng"), "-o",
                str(work / "o.png")], code=patch, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    assert (work / "o.png").exists()


def test_kernel_store_refuses_a_fifo_as_damaged(tmp_path: Path, monkeypatch) -> None:
    from l3cli import kernel_store

    monkeypatch.setattr(kernel_store, "store_dirs", lambda: [tmp_path])
    monkeypatch.setattr(kernel_store, "_digest", lambda sources: "d")
    fifo = kernel_store._file(tmp_path, "k", "d", "t")
    os.mkfifo(fifo)
    assert kernel_store.load("k", [], "t") is None  # returns at once: nothing writes
    with pytest.raises(ValueError, match="not a regular file"):
        kernel_store._read_regular(fifo)


# ---------------------------------------------------------------- optional table groups
def _group_table(tmp_path: Path) -> Path:
    """A valid table with both optional groups: a shading gain field and a multi-scale
    stage (the identity blend on two low-passes, three coarse levels)."""
    from l3cli.lens.field import GainField
    from l3cli.multiscale.stage import Multiscale

    t = make_table("RGGB")
    coeffs = np.array([[1.0, 0.3, 0.05]] * 4)
    t.shading = GainField(np.array([0.05, -0.1]), coeffs, (40, 48))
    t.multiscale = Multiscale.identity(t.n_out, sigmas=(1.0, 3.0), level_cuts=[0.2, 0.5])
    return save_table(tmp_path / "groups.npz", t)


def _changed(path: Path, out: Path, key: str, change) -> Path:
    with np.load(path, allow_pickle=False) as z:
        arrs = {k: z[k] for k in z.files}
    arrs[key] = change(arrs[key].copy())
    np.savez(out, **arrs)
    return out


def _at(index, value, dtype=None):
    def change(a):
        a = a.astype(dtype or a.dtype)
        a[index] = value
        return a
    return change


BAD_GROUPS = {
    "shading constant 1e39": ("shading_coeffs", _at((0, 0), 1e39), "shading_coeffs"),
    "shading r2 term 1e300": ("shading_coeffs", _at((slice(None), 1), 1e300), "shading_coeffs"),
    "shading constant 3e38": ("shading_coeffs", _at((2, 0), 3e38), "shading_coeffs"),
    "shading gains beyond 4096": ("shading_coeffs", _at((1, 0), 5000.0), "shading_coeffs"),
    "shading gain negative far out": ("shading_coeffs", _at((3, 2), -2.0), "not positive"),
    "shading 20 terms": ("shading_coeffs", lambda a: np.pad(a, ((0, 0), (0, 17))),
                         "shading_coeffs"),
    "shading_size NaN": ("shading_size", lambda a: np.array([np.nan, 48.0]), "shading_size"),
    "shading_size 1e30": ("shading_size", lambda a: np.array([1e30, 48.0]), "shading_size"),
    "shading_size 2**62": ("shading_size", lambda a: np.array([2**62, 48]), "shading_size"),
    "multiscale blend 3e38": ("multiscale_blend", _at((0, 0, 0), 3e38), "multiscale_blend"),
    "multiscale blend 1e39": ("multiscale_blend", _at((1, 0, 0), 1e39, np.float64),
                              "multiscale_blend"),
    "multiscale blend 1e300": ("multiscale_blend", _at((2, 1, 1), 1e300, np.float64),
                               "multiscale_blend"),
    "multiscale blend 1e7": ("multiscale_blend", _at((0, 0, 0), 1e7), "multiscale_blend"),
    "multiscale_sigmas 1e-300": ("multiscale_sigmas", lambda a: np.array([1e-300, 3.0]),
                                 "multiscale_sigmas"),
    "multiscale_sigmas 1e12": ("multiscale_sigmas", lambda a: np.array([1.0, 1e12]),
                               "multiscale_sigmas"),
    "multiscale_sigmas 1e5": ("multiscale_sigmas", lambda a: np.array([1.0, 1e5]),
                              "multiscale_sigmas"),
    "multiscale level cut 1e300": ("multiscale_level_cuts", _at(1, 1e300),
                                   "multiscale_level_cuts"),
}


@pytest.mark.parametrize("case", list(BAD_GROUPS))
def test_absurd_optional_group_is_refused_at_load(tmp_path: Path, case: str) -> None:
    """Finite but absurd values in the optional groups loaded and rendered NaN (or ended
    in "internal error"): refused at load, one line naming the table and the field."""
    good = _group_table(tmp_path)
    load_table(good)  # the table itself is valid
    key, change, words = BAD_GROUPS[case]
    bad = _changed(good, tmp_path / "bad.npz", key, change)
    with pytest.raises(TableError) as exc:
        load_table(bad)
    msg = str(exc.value)
    assert msg.startswith(str(bad)) and words in msg and "\n" not in msg, msg


@pytest.mark.parametrize("case", ["multiscale_sigmas 1e-300", "shading_size NaN",
                                  "multiscale blend 3e38", "shading constant 1e39"])
def test_absurd_group_render_is_one_line(runner, work: Path, case: str) -> None:
    key, change, words = BAD_GROUPS[case]
    bad = _changed(_group_table(work), work / "bad.npz", key, change)
    res = runner.invoke(cli, ["render", str(bad), str(work / "good.dng"), "-o",
                              str(work / "o.png")])
    line = assert_one_line_error(res, "bad.npz", words)
    assert "internal error" not in line
    assert not (work / "o.png").exists()


def test_a_table_with_both_groups_renders_finite(runner, work: Path) -> None:
    from l3cli.io.image import read_image

    table = _group_table(work)
    for out in ("o.exr", "o.png"):
        res = runner.invoke(cli, ["render", str(table), str(work / "good.dng"), "-o",
                                  str(work / out)])
        assert res.exit_code == 0, res.output
    img, _ = read_image(work / "o.exr")
    assert img.shape == (40, 48, 3) and np.all(np.isfinite(img))


def test_shading_extremes_find_a_dip_between_grid_points() -> None:
    """A gain that dips below zero between the 257 grid points of r^2 (a narrow quadratic
    well at t = 0.5004) is found by the derivative's root: gain 1 - 1e8 (t - 0.5004)^2..."""
    from l3cli.lens.field import GainField

    # g(t) = a (t - t0)^2 - d: min -d at t0, positive one grid step away
    t0, a, d = 0.50037, 1e8, 1e-3
    coeffs = np.array([[a * t0 * t0 - d, -2 * a * t0, a]] * 4)
    with pytest.raises(TableError, match="not positive"):
        GainField(np.zeros(2), coeffs, (40, 48))


# ---------------------------------------------------------------- shading fit on small data
def _unusable_fit(monkeypatch) -> None:
    """A fit that passes the fit's own checks on the training area but whose gains turn
    negative before the farthest corner of any raw (an r^4 term of -0.3, centre (0.4, 0)):
    what small crops gave. The radial model is chosen (every candidate scores alike)."""
    import l3cli.lens.fit as shading_fit

    def fit(model, samples, size):
        a = np.zeros((samples[0].raw.shape[1], max(int(model[1]), 2)))
        a[:, 1] = -0.3
        return None, (a, np.array([0.4, 0.0]))

    monkeypatch.setattr(shading_fit, "_scores", lambda samples, model, size, n: (0.5, 1.0))
    monkeypatch.setattr(shading_fit, "_fit_model", fit)


def test_unusable_shading_fit_is_dropped(monkeypatch) -> None:
    from l3cli.cfa import CFA
    from l3cli.lens.fit import BlockSamples, fit_field

    _unusable_fit(monkeypatch)
    rng = np.random.default_rng(0)
    s = BlockSamples(rng.random(64), rng.random(64), rng.random((64, 3)), rng.random((64, 3)))
    field, record = fit_field([s, s], CFA.from_spec("GRBG"), (192, 256))
    assert field is None and record["unusable"]
    assert "not positive" in record["reason"]


def _crops(folder: Path, names=("Indoor1_crop", "Outdoor1_crop"), box=(200, 300, 192, 256)):
    """Two pairs cut from the bundled frames (mosaic TIFF + sidecar, its render)."""
    import shutil

    import tifffile
    from PIL import Image

    src = REPO / "examples" / "infinite_isp" / "frames"
    y0, x0, h, w = box
    folder.mkdir()
    for name in names:
        tifffile.imwrite(folder / f"{name}.tif",
                         tifffile.imread(src / f"{name}.tif")[y0:y0 + h, x0:x0 + w])
        shutil.copy(src / f"{name}.tif.toml", folder / f"{name}.tif.toml")
        Image.fromarray(np.asarray(Image.open(src / f"{name}.png"))[y0:y0 + h, x0:x0 + w]
                        ).save(folder / f"{name}.png")
    return folder


@pytest.mark.slow
def test_train_on_two_small_pairs_writes_the_table(runner, tmp_path: Path, monkeypatch) -> None:
    """`l3 train --no-tune` on two crops of the bundled frames ended in "bad shading gain
    field: gains are not positive over the sensor" (naming no file): the unusable fit is
    dropped with one note line, and the table is written without a gain field."""
    _unusable_fit(monkeypatch)
    pairs = _crops(tmp_path / "pairs")
    out = tmp_path / "t.npz"
    res = runner.invoke(cli, ["train", str(pairs), "--no-tune", "--shading", "--levels", "4",
                              "--patch", "3", "-o", str(out)])
    assert res.exit_code == 0, res.output
    notes = [ln for ln in res.output.splitlines() if "shading" in ln]
    assert len(notes) == 1 and "not usable" in notes[0], res.output
    assert load_table(out).shading is None


# ---------------------------------------------------------------- a lossy DNG cut short
@pytest.mark.parametrize("libraw_only", [False, True])
def test_lossy_dng_cut_after_its_header_is_refused(runner, work: Path,
                                                   libraw_only: bool) -> None:
    """LibRaw decodes what is there (a black or garbage image, exit 0); the tiles lie
    past the end: "Unexpected end of file", exit 1, whichever decoder would run."""
    from l3cli.io import dng_lossy
    from l3cli.io.raw import read_raw
    from tests.dngmake import make_dng

    dn = np.random.default_rng(0).integers(64, 4000, (32, 48)).astype(np.uint16)
    whole = make_dng(work / "lossy.dng", dn, bits=12, tile=(16, 16), lossy_jpeg=True)
    tiles = dng_lossy.probe(whole)
    assert tiles is not None  # the layout the lossy decoder takes
    data = whole.read_bytes()
    for name, size in (("cut.dng", min(tiles.offsets)), ("half.dng", tiles.offsets[2] + 10)):
        (work / name).write_bytes(data[:size])
        with pytest.raises(InputError, match="Unexpected end of file") as exc:
            read_raw(work / name, libraw_only=libraw_only)
        assert str(exc.value).startswith(str(work / name))
    res = runner.invoke(cli, ["render", str(work / "t.npz"), str(work / "cut.dng"), "-o",
                              str(work / "o.png")])
    assert_one_line_error(res, "cut.dng", "Unexpected end of file")


def test_real_lossy_dng_cut_after_its_header(shared_data: Path, tmp_path: Path) -> None:
    from l3cli.io import dng_lossy
    from l3cli.io.raw import read_raw

    data = (shared_data / "raw/misc/blackmagic_pocket4k_rggb.dng").read_bytes()
    cut = tmp_path / "cut.dng"
    cut.write_bytes(data[:min(dng_lossy.probe(data).offsets)])
    with pytest.raises(InputError, match="Unexpected end of file"):
        read_raw(cut)


# ---------------------------------------------------------------- .npy header of 2**40 values
def test_npy_header_claiming_2_40_values_names_file_and_key(runner, work: Path) -> None:
    """It ended in "Error: out of memory" naming no file."""
    import io
    import zipfile

    bad = work / "huge.npz"
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        head, {"descr": "<f8", "fortran_order": False, "shape": (2**40,)})
    with zipfile.ZipFile(work / "t.npz") as zin, zipfile.ZipFile(bad, "w") as zout:
        for info in zin.infolist():
            data = zin.read(info)
            if info.filename == "lambdas.npy":
                data = b"\x93NUMPY\x01\x00" + head.getvalue()[8:] + bytes(64)
            zout.writestr(info.filename, data)
    with pytest.raises(TableError, match="key 'lambdas' claims 1099511627776 values"):
        load_table(bad)
    res = runner.invoke(cli, ["render", str(bad), str(work / "good.dng"), "-o",
                              str(work / "o.png")])
    line = assert_one_line_error(res, "huge.npz", "lambdas")
    assert "memory" not in line


# ---------------------------------------------------------------- the writers' last defence
@pytest.mark.parametrize("suffix", [".png", ".jpg", ".tif"])
def test_display_writers_refuse_nan(tmp_path: Path, suffix: str) -> None:
    """PNG/JPEG/TIFF were encoded from NaN (some integer per NaN): refused as EXR is,
    naming the output and the input it was rendered from; nothing written."""
    from l3cli.errors import OutputError
    from l3cli.io.image import write_image

    for bad in (np.nan, np.inf, -np.inf):
        img = np.full((4, 5, 3), 0.5, np.float32)
        img[1, 2, 0] = bad
        with pytest.raises(OutputError, match="rendered from in.dng.*NaN or infinite") as exc:
            write_image(tmp_path / f"x{suffix}", img, space="srgb", source="in.dng")
        assert str(exc.value).startswith(str(tmp_path / f"x{suffix}"))
        assert list(tmp_path.iterdir()) == []
