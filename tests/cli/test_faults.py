"""Fault injection: full disks, I/O errors, outputs that alias inputs, bad schedulers.

A "full disk" is the process's file-size limit (``RLIMIT_FSIZE``, with
``SIGXFSZ`` ignored): every write past the limit fails with ``EFBIG``, in
Python and in the C encoders (OpenImageIO, libtiff, libpng, libjpeg) alike,
with no mount and no privilege. An I/O error is ``os.fsync`` failing with
``EIO``. Under each, every writing subcommand must exit 1 with one line, leave
the previous output byte for byte, and leave no temporary file.
"""

from __future__ import annotations

import contextlib
import errno
import os
import resource
import signal
import socket
import threading
import time
from pathlib import Path

import pytest

from l3cli.cli.main import cli
from l3cli.errors import L3Error

CFG = Path(__file__).parents[2] / "sample_configs" / "bayer.toml"


@contextlib.contextmanager
def disk_full(limit: int = 64):
    """Writes past ``limit`` bytes of any file fail (EFBIG), as on a full disk."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    old = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, old)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A small simulation, a table trained on it, and renders of it (built once)."""
    from click.testing import CliRunner

    r = CliRunner()
    root = tmp_path_factory.mktemp("faults")
    sim = root / "sim"
    res = r.invoke(cli, ["simulate", str(CFG), "-o", str(sim), "--scene", "macbeth",
                         "--lux", "300", "--size", "64x48", "--no-blur", "--seed", "1"])
    assert res.exit_code == 0, res.output
    table = root / "t.npz"
    res = r.invoke(cli, ["-q", "train", str(sim), "-o", str(table), "--levels", "3",
                         "--min-samples", "2", "--patch", "3"])
    assert res.exit_code == 0, res.output
    renders = root / "renders"
    renders.mkdir()
    res = r.invoke(cli, ["render", str(table), *map(str, sorted(sim.glob("*.dng"))), "-o",
                         str(renders), "--format", "exr"])
    assert res.exit_code == 0, res.output
    return {"root": root, "sim": sim, "table": table, "renders": renders,
            "raw": next(sim.glob("*.dng"))}


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def _commands(w, out: Path) -> dict[str, tuple[list[str], Path]]:
    """name -> (arguments, the output they write) for every writing subcommand."""
    raw, table, sim, renders = map(str, (w["raw"], w["table"], w["sim"], w["renders"]))
    return {
        "simulate": (["simulate", str(CFG), "-o", str(out / "sim"), "--scene", "macbeth",
                      "--lux", "100", "--size", "48x32", "--no-blur"], out / "sim"),
        "train": (["-q", "train", sim, "-o", str(out / "t.npz"), "--levels", "2",
                   "--min-samples", "2", "--patch", "3"], out / "t.npz"),
        "smooth": (["smooth", table, "-o", str(out / "s.npz")], out / "s.npz"),
        "render-exr": (["render", table, raw, "-o", str(out / "r.exr")], out / "r.exr"),
        "render-png": (["render", table, raw, "-o", str(out / "r.png")], out / "r.png"),
        "render-tif": (["render", table, raw, "-o", str(out / "r.tif")], out / "r.tif"),
        "render-jpg": (["render", table, raw, "-o", str(out / "r.jpg")], out / "r.jpg"),
        "evaluate-json": (["evaluate", renders, "--reference", sim, "--json",
                           str(out / "e.json")], out / "e.json"),
        "evaluate-plots": (["evaluate", renders, "--reference", sim, "--plots",
                            str(out / "plots")], out / "plots"),
        "baseline": (["baseline", raw, "--train", sim, "-o", str(out / "b.exr")], out / "b.exr"),
        "baseline-model": (["baseline", raw, "--train", sim, "-o", str(out / "b2.exr"),
                            "--save-model", str(out / "m.json")], out / "m.json"),
        "inspect-plots": (["inspect", table, "--plots", str(out / "iplots")], out / "iplots"),
        "info-preview": (["info", raw, "--preview", str(out / "p.png")], out / "p.png"),
        "info-planes": (["info", raw, "--planes", str(out / "planes")], out / "planes"),
    }


_NAMES = list(_commands({"raw": "", "table": "", "sim": "", "renders": ""}, Path("/x")))


@pytest.mark.parametrize("name", _NAMES)
@pytest.mark.parametrize("fault", ["full", "eio", "enospc"])
def test_write_fault_keeps_previous_output(runner, work, tmp_path, monkeypatch, name, fault):
    args, target = _commands(work, tmp_path)[name]
    res = runner.invoke(cli, args)
    assert res.exit_code == 0, res.output
    before = _snapshot(tmp_path)
    assert any(k.startswith(target.name) for k in before), before.keys()
    if fault == "full":
        with disk_full():
            res = runner.invoke(cli, args)
    else:
        code = errno.EIO if fault == "eio" else errno.ENOSPC

        def broken_fsync(fd):
            raise OSError(code, os.strerror(code))

        monkeypatch.setattr(os, "fsync", broken_fsync)
        res = runner.invoke(cli, args)
        monkeypatch.undo()
    assert res.exit_code == 1, res.output
    last = res.output.strip().splitlines()[-1]
    assert last.startswith("Error:") and "internal error" not in last, res.output
    assert "cannot write" in last or "space" in last or "Input/output" in last, last
    assert _snapshot(tmp_path) == before  # byte for byte, and no temporary left


def test_full_disk_leaves_no_new_output_or_folder(runner, work, tmp_path):
    """A first run on a full disk creates nothing: no file, no empty folder."""
    for name, (args, _target) in _commands(work, tmp_path).items():
        with disk_full():
            res = runner.invoke(cli, args)
        assert res.exit_code == 1, (name, res.output)
        assert list(tmp_path.iterdir()) == [], (name, list(tmp_path.iterdir()))


# ----------------------------------------------------------------------------- aliasing
def _alias_cases(w, tmp: Path):
    raw, table, sim = w["raw"], w["table"], w["sim"]
    target = next(sim.glob("*.target.exr"))
    link = tmp / "link.npz"
    link.symlink_to(table)
    hard = tmp / "hard.npz"
    os.link(table, hard)
    rlink = tmp / "raw.dng"
    rlink.symlink_to(raw)
    return {
        "smooth-same": ["smooth", str(table), "-o", str(table)],
        "smooth-symlink": ["smooth", str(link), "-o", str(table)],
        "smooth-hardlink": ["smooth", str(table), "-o", str(hard)],
        "train-manifest": ["train", str(sim), "-o", str(sim / "manifest.json")],
        "train-raw": ["train", str(sim), "-o", str(raw)],
        "render-raw": ["render", str(table), str(raw), "-o", str(raw)],
        "render-table": ["render", str(table), str(raw), "-o", str(link)],
        "render-symlinked-raw": ["render", str(table), str(rlink), "-o", str(raw)],
        "render-folder": ["render", str(table), str(target), str(raw), "-o", str(sim)],
        "evaluate-json-ref": ["evaluate", str(w["renders"]), "--reference", str(sim), "--json",
                              str(sim / "manifest.json")],
        "evaluate-json-render": ["evaluate", str(next(w["renders"].iterdir())), "--reference",
                                 str(target), "--json", str(target)],
        "baseline-out": ["baseline", str(raw), "--train", str(sim), "-o", str(target)],
        "baseline-model": ["baseline", str(raw), "--train", str(sim), "-o", str(tmp / "o.exr"),
                           "--save-model", str(sim / "manifest.json")],
        "info-preview": ["info", str(raw), "--preview", str(rlink)],
        "simulate-camera": ["simulate", str(tmp / "cam.toml"), "-o", str(tmp)],
    }


def test_outputs_that_alias_inputs_are_refused(runner, work, tmp_path):
    (tmp_path / "cam.toml").write_bytes(CFG.read_bytes())
    sim_before = _snapshot(work["sim"])
    table_before = work["table"].read_bytes()
    for name, args in _alias_cases(work, tmp_path).items():
        if name == "simulate-camera":  # a capture named like the camera file
            (tmp_path / "cam.toml").rename(tmp_path / "manifest.json")
            args = ["simulate", str(tmp_path / "manifest.json"), "-o", str(tmp_path)]
        res = runner.invoke(cli, args)
        assert res.exit_code == 1, (name, res.output)
        assert "would overwrite the input" in res.output, (name, res.output)
    assert _snapshot(work["sim"]) == sim_before
    assert work["table"].read_bytes() == table_before


# ----------------------------------------------------------------------------- leftovers
def test_failed_render_leaves_no_empty_folder(runner, work, tmp_path):
    bad = tmp_path / "bad.dng"
    bad.write_bytes(b"II*\0garbage")
    bad2 = tmp_path / "bad2.dng"
    bad2.write_bytes(b"II*\0garbage too")
    out = tmp_path / "renders"
    res = runner.invoke(cli, ["render", str(work["table"]), str(bad), str(bad2), "-o", str(out)])
    assert res.exit_code == 1
    assert not out.exists()
    # with a good file among them, the good one is written (issue 16) and nothing else
    res = runner.invoke(cli, ["render", str(work["table"]), str(bad), str(work["raw"]),
                              "-o", str(out)])
    assert res.exit_code == 1
    assert "bad.dng" in res.output
    assert sorted(p.name for p in out.iterdir()) == [work["raw"].stem + ".exr"]


def test_failed_evaluate_leaves_no_report(runner, work, tmp_path, monkeypatch):
    import l3cli.evaluate.plots

    def boom(*a, **k):
        raise L3Error("plotting failed")

    monkeypatch.setattr(l3cli.evaluate.plots, "plot_report", boom)
    res = runner.invoke(cli, ["evaluate", str(work["renders"]), "--reference", str(work["sim"]),
                              "--json", str(tmp_path / "e.json"), "--plots",
                              str(tmp_path / "plots")])
    assert res.exit_code == 1
    assert list(tmp_path.iterdir()) == []


def test_stale_temporaries_of_killed_runs_are_removed(runner, work, tmp_path):
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    stale_dir = tmp_path / f".l3-tmp-{dead}-sim-abc"
    stale_dir.mkdir()
    (stale_dir / "x.dng").write_bytes(b"x")
    stale_file = tmp_path / f".l3-tmp-{dead}-t-xyz.npz"
    stale_file.write_bytes(b"x")
    alive = tmp_path / f".l3-tmp-{os.getpid()}-mine-1.npz"  # a live process's: kept
    alive.write_bytes(b"x")
    other = tmp_path / ".hidden-user-file"  # not l3's: kept
    other.write_bytes(b"x")
    import l3cli.io.atomic

    l3cli.io.atomic._CLEANED.clear()  # as in a new process
    res = runner.invoke(cli, ["smooth", str(work["table"]), "-o", str(tmp_path / "s.npz")])
    assert res.exit_code == 0, res.output
    assert not stale_dir.exists() and not stale_file.exists()
    assert alive.exists() and other.exists()


# ----------------------------------------------------------------------------- schedulers
@contextlib.contextmanager
def _server(reply: bytes | None):
    """A loopback TCP server that accepts and then stays silent or answers ``reply``."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(4)
    sock.settimeout(0.2)
    stop = threading.Event()
    conns = []

    def serve():
        while not stop.is_set():
            try:
                c, _ = sock.accept()
            except OSError:
                continue
            conns.append(c)
            if reply is not None:
                with contextlib.suppress(OSError):
                    c.recv(100)
                    c.sendall(reply)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        yield f"tcp://127.0.0.1:{sock.getsockname()[1]}"
    finally:
        stop.set()
        t.join(2)
        for c in conns:
            c.close()
        sock.close()


@pytest.mark.parametrize("reply", [None, b"HTTP/1.0 200 OK\r\n\r\n" + b"x" * 64])
def test_scheduler_that_is_not_dask_fails_fast(runner, work, tmp_path, monkeypatch, reply):
    import l3cli.parallel

    monkeypatch.setattr(l3cli.parallel, "SCHEDULER_TIMEOUT_S", 3.0)
    with _server(reply) as address:
        t0 = time.monotonic()
        res = runner.invoke(cli, ["train", str(work["sim"]), "-o", str(tmp_path / "t.npz"),
                                  "--scheduler", address])
        took = time.monotonic() - t0
    assert res.exit_code == 1, res.output
    assert took < 15, took
    last = res.output.strip().splitlines()[-1]
    assert address in last and "internal error" not in last and "memory" not in last, last
    assert not (tmp_path / "t.npz").exists()


def test_default_scheduler_deadline_is_within_30_s():
    import l3cli.parallel

    assert 0 < l3cli.parallel.SCHEDULER_TIMEOUT_S <= 25  # + Client's own start < 30 s


@pytest.mark.parametrize("address", ["tcp://foo:bar:baz", "::::", "nope://x",
                                     "tcp://127.0.0.1:notaport", "tcp://127.0.0.1:1"])
def test_malformed_or_refused_scheduler_is_one_line(runner, work, tmp_path, address):
    res = runner.invoke(cli, ["train", str(work["sim"]), "-o", str(tmp_path / "t.npz"),
                              "--scheduler", address])
    assert res.exit_code == 1, res.output
    last = res.output.strip().splitlines()[-1]
    assert "scheduler" in last and "internal error" not in last, last


def test_killed_simulate_temporary_folder_is_removed_by_the_next_simulate(runner, tmp_path):
    """A simulate killed mid-run (SIGKILL) leaves .l3-tmp-<pid>-sim-*; the next run removes it."""
    import subprocess
    import sys

    import l3cli.io.atomic

    code = ("import sys; from l3cli.cli.main import cli; "
            "sys.argv = ['l3', 'simulate', sys.argv[1], '-o', sys.argv[2], '--scene', 'macbeth', "
            "'--scene', 'natural', '--size', '480x320']; cli()")
    proc = subprocess.Popen([sys.executable, "-c", code, str(CFG), str(tmp_path / "sim")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not list(tmp_path.glob(".l3-tmp-*")):
        time.sleep(0.05)
    proc.kill()
    proc.wait()
    left = list(tmp_path.glob(".l3-tmp-*"))
    assert left and left[0].is_dir() and not (tmp_path / "sim").exists()
    l3cli.io.atomic._CLEANED.clear()  # as in a new process
    res = runner.invoke(cli, ["simulate", str(CFG), "-o", str(tmp_path / "sim2"), "--scene",
                              "macbeth", "--lux", "100", "--size", "48x32", "--no-blur"])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim2"]
