"""Stored machine code (l3cli.kernel_store): loaded without numba, the same results."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numba
import numpy as np
import pytest

from l3cli import kernel_store
from l3cli.kernel_store import Stored, typekey
from tests.builders import REPO, write_raws


def _values():
    a = np.arange(24, dtype=np.float32).reshape(4, 6)
    ro = a.copy()
    ro.flags.writeable = False
    return [a, np.asfortranarray(a), a[:, ::2], a[0], ro, a.astype(np.uint16),
            np.zeros((2, 3, 4), np.float32), 3, -(1 << 40), 2.5, True, False, np.float32(1.5),
            np.int32(7), np.uint8(3), (1, 2.0), (a, 1)]


def test_typekey_tells_apart_what_numba_tells_apart():
    """Two arguments get the same key exactly when numba gives them the same type (the
    stored code for one key is numba's code for that type)."""
    vals = _values()
    keys = [typekey(v) for v in vals]
    types = [numba.typeof(v) for v in vals]
    for i in range(len(vals)):
        for j in range(len(vals)):
            assert (keys[i] == keys[j]) == (types[i] == types[j]), (vals[i], vals[j])
    with pytest.raises(TypeError):
        typekey(object())


def _source(tmp_path, body: str):
    src = tmp_path / "kernel_src.py"
    src.write_text(textwrap.dedent(body))
    return src


def _add_kernel():
    def add(a, b, out):  # pragma: no cover - compiled
        for i in range(a.size):
            out[i] = a[i] * np.float32(2.0) + b
        return 0

    return numba.njit(nogil=True)(add)


def test_stored_code_loads_and_damage_falls_back_to_numba(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    src = _source(tmp_path, "x = 1\n")
    a = np.arange(5, dtype=np.float32)
    want = a * 2 + 1

    def run(stored):
        out = np.zeros(5, np.float32)
        assert stored(a, np.float32(1.0), out) == 0
        np.testing.assert_array_equal(out, want)
        return stored.function(a, np.float32(1.0), out)

    first = Stored("test-add", [src], _add_kernel)
    assert not first.stored()
    with caplog.at_level("INFO", logger="l3cli.kernel_store"):
        assert isinstance(run(first), numba.core.dispatcher.Dispatcher)  # compiled, stored
    assert "compiling test-add for this machine" in caplog.text  # what `l3 -v` shows
    assert first.stored()
    files = list((tmp_path / "cache" / "l3cli-kernels").glob("test-add-*.bin"))
    assert len(files) == 1
    loaded = run(Stored("test-add", [src], _add_kernel))
    assert not isinstance(loaded, numba.core.dispatcher.Dispatcher)  # the stored code

    for damage in (lambda b: b[:-100], lambda b: b[:-50] + bytes([b[-50] ^ 1]) + b[-49:]):
        files[0].write_bytes(damage(files[0].read_bytes()))  # truncated, one bit flipped
        assert isinstance(run(Stored("test-add", [src], _add_kernel)),
                          numba.core.dispatcher.Dispatcher)  # numba again, and stored again
        assert not isinstance(run(Stored("test-add", [src], _add_kernel)),
                              numba.core.dispatcher.Dispatcher)

    src.write_text("x = 2\n")  # a source changed: another key, nothing stored for it
    changed = Stored("test-add", [src], _add_kernel)
    assert not changed.stored()
    assert isinstance(run(changed), numba.core.dispatcher.Dispatcher)
    assert len(list((tmp_path / "cache" / "l3cli-kernels").glob("test-add-*.bin"))) == 2


def test_code_not_loaded_for_a_month_is_pruned_when_code_is_stored(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    folder = tmp_path / "cache" / "l3cli-kernels"
    folder.mkdir(parents=True)
    stale, recent = folder / "old-0-0.bin", folder / "new-0-0.bin"
    for f in (stale, recent):
        f.write_bytes(b"x")
    month = (kernel_store.PRUNE_DAYS + 1) * 86400
    os.utime(stale, (stale.stat().st_atime - month, stale.stat().st_mtime - month))
    a, out = np.ones(2, np.float32), np.zeros(2, np.float32)
    Stored("test-prune", [_source(tmp_path, "z = 1\n")], _add_kernel)(a, np.float32(0.0), out)
    assert not stale.exists() and recent.exists()
    assert len(list(folder.glob("test-prune-*.bin"))) == 1


def test_no_writable_folder_still_runs(tmp_path, monkeypatch, caplog):
    """Nowhere to store (a path under a file: not writable even for root): the function
    runs from numba, and one warning says that every run will compile."""
    import logging

    # the logger's own level: an earlier `l3 -q` in this process may have raised the root's
    caplog.set_level(logging.WARNING, logger="l3cli.kernel_store")
    monkeypatch.setitem(kernel_store._runtime, "warned", False)
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setattr(kernel_store, "store_dirs", lambda: [blocker / "kernels"])
    src = _source(tmp_path, "y = 1\n")
    out = np.zeros(3, np.float32)
    Stored("test-ro", [src], _add_kernel)(np.ones(3, np.float32), np.float32(0.5), out)
    np.testing.assert_array_equal(out, [2.5, 2.5, 2.5])
    assert "cannot be stored" in caplog.text


def test_a_fresh_process_renders_from_stored_code_without_numba(tmp_path, table_path):  # noqa: F811
    """The render kernel's stored code: a new process renders without importing numba,
    bit for bit what numba's kernel renders in this one."""
    from l3cli.io.raw import read_raw
    from l3cli.render import render_mosaic, table_for_task

    raw = write_raws(tmp_path, 1, seed=7)[0]
    want = render_mosaic(table_for_task(table_path), read_raw(raw).mosaic)  # stores if new
    code = ("import sys, json\n"
            "from l3cli.render import render_mosaic, table_for_task\n"
            "from l3cli.io.raw import read_raw\n"
            f"t = table_for_task({str(table_path)!r}); m = read_raw({str(raw)!r}).mosaic\n"
            "img = render_mosaic(t, m)\n"
            "print(json.dumps({'numba': 'numba' in sys.modules, 'img': img.ravel().tolist()}))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert not got["numba"]
    np.testing.assert_array_equal(np.asarray(got["img"], np.float32), want.ravel())


@pytest.mark.parametrize("threads", ["1", "3"])
def test_tile_threads_do_not_change_a_render(tmp_path, table_path, monkeypatch, threads):  # noqa: F811
    """Threads share an image's tiles: any number of them renders the same pixels."""
    from l3cli.render import render_mosaic, table_for_task
    from l3cli.threads import tile_threads

    mosaic = np.random.default_rng(2).random((150, 1100), dtype=np.float32)  # 3 x 3 tiles
    t = table_for_task(table_path)
    monkeypatch.setenv("NUMBA_NUM_THREADS", "2")
    want = render_mosaic(t, mosaic)
    monkeypatch.setenv("NUMBA_NUM_THREADS", threads)
    assert tile_threads() == int(threads)
    np.testing.assert_array_equal(render_mosaic(t, mosaic), want)


@pytest.mark.parametrize("fmt", ["jpg", "tiff"])
def test_l3_render_imports_no_numba(tmp_path, table_path, fmt):  # noqa: F811
    """The whole command: `l3 render` of raws to JPEG or TIFF runs without importing numba
    once the kernel's code is stored (the first run here stores it)."""
    raws = [str(r) for r in write_raws(tmp_path, 2, seed=5)]
    code = ("import atexit, sys\n"
            "atexit.register(lambda: print('NUMBA', 'numba' in sys.modules))\n"
            "from l3cli.cli.main import main\n"
            f"sys.argv = ['l3', '-q', 'render', {str(table_path)!r}, *{raws!r}, '-o', "
            f"{str(tmp_path / 'out')!r}, '--format', {fmt!r}]\n"
            "main()\n")
    lines = []
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                             text=True, timeout=300)
        assert out.returncode == 0, out.stderr[-2000:]
        lines.append(out.stdout.strip().splitlines()[-1])
    assert lines[-1] == "NUMBA False"
    assert len(list((tmp_path / "out").iterdir())) == 2


def test_one_process_compiles_a_kernel_at_a_time(tmp_path, monkeypatch):
    """While one process compiles kernel X for some types (holds ``compiling``), another
    cannot take the same lock (it would wait, then load the stored code); a different
    kernel's lock is free, and the lock is released on leaving."""
    import fcntl
    import os

    from l3cli import kernel_store

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    src = tmp_path / "k.py"
    src.write_text("x = 1\n")

    def held_elsewhere(name: str, types_: str) -> bool:
        lock = next((tmp_path / "l3cli-kernels").glob(".lock-*"), None)
        assert lock is not None
        key = kernel_store.hashlib.sha256(
            f"{name} {kernel_store._digest([src])} {types_}".encode()).hexdigest()[:24]
        fd = os.open(tmp_path / "l3cli-kernels" / f".lock-{key}", os.O_RDWR | os.O_CREAT)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        finally:
            os.close(fd)  # (a lock taken here is released with the descriptor)
        return False

    with kernel_store.compiling("k", [src], "f32"):
        assert held_elsewhere("k", "f32")
        assert not held_elsewhere("k", "f64")
    assert not held_elsewhere("k", "f32")
