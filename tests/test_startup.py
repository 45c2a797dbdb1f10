"""Start-up trims (l3cli.startup) and the buffer pool of a folder render (l3cli.buffers)."""

from __future__ import annotations

import gc
import os
import subprocess
import sys

import numpy as np

from l3cli import buffers, startup
from l3cli.cli.main import cli
from tests.builders import REPO, write_raws


# ------------------------------------------------------------------ buffers
def test_pool_reuses_a_released_array_of_the_same_shape_and_dtype():
    with buffers.recycling(keep=2):
        a = buffers.empty((4, 6), np.float32)
        a_id = id(a)
        buffers.release(a)
        b = buffers.empty((4, 6), np.float32)
        assert id(b) == a_id  # the same array back, no new allocation
        c = buffers.empty((4, 6), np.uint16)  # another dtype: a new one
        assert c.dtype == np.uint16 and id(c) != a_id
        d = buffers.empty((4, 6), np.float32)  # b is still lent: a new one
        assert d is not b


def test_pool_takes_back_only_what_it_lent_and_keeps_at_most_keep():
    with buffers.recycling(keep=1):
        outside = np.empty((3, 3), np.float32)
        buffers.release(outside)  # not lent: ignored
        assert buffers.empty((3, 3), np.float32) is not outside
        x, y = buffers.empty((2, 2), np.uint8), buffers.empty((2, 2), np.uint8)
        buffers.release(x)
        buffers.release(y)  # over keep=1: dropped
        buffers.release(x)  # twice: the second is ignored
        got = [buffers.empty((2, 2), np.uint8) for _ in range(2)]
        assert sum(g is x or g is y for g in got) == 1


def test_pool_drops_the_oldest_beyond_its_count_and_byte_bounds(monkeypatch):
    with buffers.recycling(keep=2):
        a, b, c = (buffers.empty((4,), np.float32), buffers.empty((5,), np.float32),
                   buffers.empty((6,), np.float32))
        for arr in (a, b, c):  # mixed sizes: only the 2 most recent stay
            buffers.release(arr)
        assert [x.shape for x in buffers._free] == [(5,), (6,)]
        monkeypatch.setattr(buffers, "MAX_FREE_BYTES", 30)  # 24 + 20 bytes > 30
        d = buffers.empty((6,), np.float32)
        assert d is c
        buffers.release(d)
        assert [x.shape for x in buffers._free] == [(6,)]


def test_without_a_pool_empty_is_numpy_empty_and_release_ignores():
    a = buffers.empty((2, 3), np.float32)
    assert a.shape == (2, 3) and a.dtype == np.float32 and a.flags.c_contiguous
    buffers.release(a)
    assert buffers.empty((2, 3), np.float32) is not a
    with buffers.recycling():
        pass
    with buffers.recycling():  # a pool does not outlive its block
        b = buffers.empty((2, 3), np.float32)
    buffers.release(b)
    assert buffers._free is None and not buffers._lent


def test_a_lent_array_that_dies_is_forgotten():
    with buffers.recycling():
        a = buffers.empty((5,), np.float32)
        assert len(buffers._lent) == 1
        del a
        gc.collect()
        assert not buffers._lent


def test_folder_render_recycles_and_equals_one_by_one(runner, tmp_path, table_path):  # noqa: F811
    """Five files through three in flight: buffers come back, outputs are unchanged."""
    from l3cli.io.image import read_image

    raws = write_raws(tmp_path, 5, seed=3)
    calls = {"new": 0, "reused": 0}
    real = buffers.empty

    def counting(shape, dtype):
        if buffers._free is not None:
            free = any(a.shape == tuple(shape) and a.dtype == dtype for a in buffers._free)
            calls["reused" if free else "new"] += 1
        return real(shape, dtype)

    buffers.empty = counting
    try:
        res = runner.invoke(cli, ["render", str(table_path), *map(str, raws), "-o",
                                  str(tmp_path / "out"), "--format", "tiff"])
    finally:
        buffers.empty = real
    assert res.exit_code == 0, res.output
    assert calls["reused"] > 0 and calls["new"] + calls["reused"] >= 10
    for r in raws:
        solo = tmp_path / f"{r.stem}.tif"
        assert runner.invoke(cli, ["render", str(table_path), str(r), "-o",
                                   str(solo)]).exit_code == 0
        np.testing.assert_array_equal(read_image(tmp_path / "out" / f"{r.stem}.tif")[0],
                                      read_image(solo)[0])


# ------------------------------------------------------------------ startup
def test_gc_is_on_again_after_render_and_after_a_failed_render(runner, tmp_path,
                                                              table_path):  # noqa: F811
    raw = write_raws(tmp_path, 1)[0]
    assert gc.isenabled()
    res = runner.invoke(cli, ["render", str(table_path), str(raw), "-o", str(tmp_path / "a.png")])
    assert res.exit_code == 0 and gc.isenabled()
    res = runner.invoke(cli, ["render", str(table_path), str(tmp_path / "missing.dng"), "-o",
                              str(tmp_path / "b.png")])
    assert res.exit_code != 0 and gc.isenabled()
    res = runner.invoke(cli, ["render", "--no-such-option"])
    assert res.exit_code == 2 and gc.isenabled()


def test_gc_pause_leaves_a_caller_disabled_collector_alone():
    gc.disable()
    try:
        startup.pause_gc()
        assert not gc.isenabled()
        startup.resume_gc()
        assert not gc.isenabled()  # not ours to turn on
    finally:
        gc.enable()
    startup.pause_gc()
    assert not gc.isenabled()
    startup.resume_gc()
    assert gc.isenabled()


def test_gc_resume_freezes_only_when_the_pause_asked_for_it():
    """The console entry point pauses with ``freeze``: the objects made until the
    resume go to the permanent generation (a later full collection skips them);
    a plain pause (the in-process CLI, tests) freezes nothing."""
    before = gc.get_freeze_count()
    try:
        startup.pause_gc()
        made = [[i] for i in range(1000)]
        startup.resume_gc()
        # frozen objects another thread frees lower the count: "froze nothing" is "did not
        # rise by the objects made while paused"
        assert gc.isenabled() and gc.get_freeze_count() < before + len(made)
        startup.pause_gc(freeze=True)
        kept = [[i] for i in range(1000)]  # made while paused
        startup.resume_gc()
        assert gc.isenabled() and gc.get_freeze_count() >= before + len(kept)
        frozen = gc.get_freeze_count()
        startup.pause_gc(freeze=True)
        made = [[i] for i in range(1000)]
        startup.resume_gc(freeze=False)  # declined (a command with a teardown)
        assert gc.isenabled() and gc.get_freeze_count() < frozen + len(made)
        startup.pause_gc()  # the freeze was for that one resume: none here
        made = [[i] for i in range(1000)]
        startup.resume_gc()
        assert gc.get_freeze_count() < frozen + len(made)
    finally:
        gc.unfreeze()
        gc.enable()


def _child(code: str, env: dict | None = None) -> str:
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                         env={**os.environ, **(env or {})}, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip().splitlines()[-1]


def test_render_and_info_run_one_openblas_thread_unless_the_user_says_otherwise():
    code = ("import sys; from l3cli.cli.main import cli\n"
            "cli.get_command(None, 'render'); import numpy\n"
            "from threadpoolctl import threadpool_info\n"
            "print(max(i['num_threads'] for i in threadpool_info() "
            "if i['internal_api'] == 'openblas'))")
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                         env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.split()[-1]) == 1
    assert int(_child(code, {"OPENBLAS_NUM_THREADS": "2"})) == 2


def test_lean_cache_leaves_other_numba_functions_alone():
    import numba

    def f(x):  # pragma: no cover - compiled
        return x + 1

    plain = numba.njit(cache=True)(f)
    assert plain._cache.load_overload.__qualname__.endswith("Cache.load_overload")
    uncached = startup.lean_cache(numba.njit(f))  # no cache: nothing to change
    assert uncached(1) == 2
    lean = startup.lean_cache(numba.njit(cache=True)(f))
    assert lean._cache.load_overload.__qualname__.startswith("lean_cache")
    assert plain._cache.load_overload.__qualname__.endswith("Cache.load_overload")


# ------------------------------------------------------------------ exit
_TEARDOWN_PROBE = (
    "import atexit, sys\n"
    "class Probe:\n"
    "    def __del__(self):\n"
    "        print('teardown ran', flush=True)\n"
    "probe = Probe()  # a module global: its __del__ runs only in the interpreter's teardown\n"
    "atexit.register(lambda: print('exit handlers ran', flush=True))\n"
)


def _main_child(argv: list[str], extra: str = "") -> subprocess.CompletedProcess:
    code = (_TEARDOWN_PROBE + extra + f"sys.argv = ['l3', *{argv!r}]\n"
            "from l3cli.cli.main import main\nmain()\n")
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                          text=True, timeout=300)


def test_a_finished_render_skips_the_teardown_but_runs_exit_handlers(tmp_path,
                                                                    table_path):  # noqa: F811
    raw = write_raws(tmp_path, 1)[0]
    out = tmp_path / "a.png"
    res = _main_child(["render", str(table_path), str(raw), "-o", str(out)])
    assert res.returncode == 0, res.stderr
    assert "exit handlers ran" in res.stdout and "teardown ran" not in res.stdout
    assert out.stat().st_size > 0
    # an error and a usage error keep their exit status and their message
    res = _main_child(["info", str(tmp_path / "missing.dng")])
    assert res.returncode == 1 and "missing.dng: no such file" in res.stderr
    assert "exit handlers ran" in res.stdout and "teardown ran" not in res.stdout
    res = _main_child(["render", "--no-such-option"])
    assert res.returncode == 2 and "no-such-option" in res.stderr


def test_other_commands_and_live_threads_get_the_normal_exit(tmp_path):
    res = _main_child(["smooth", "--help"])  # not a lean command: never armed
    assert res.returncode == 0 and "teardown ran" in res.stdout
    # a non-daemon thread still working: exit_now waits for it like sys.exit
    flag = tmp_path / "thread-done"
    extra = ("import threading, time\n"
             "from l3cli import startup\n"
             "startup.arm_exit_now()\n"
             "def work():\n"
             "    time.sleep(0.3)\n"
             f"    open({str(flag)!r}, 'w').close()\n"
             "threading.Thread(target=work).start()\n"
             "startup.exit_now(3)\n")
    res = subprocess.run([sys.executable, "-c", _TEARDOWN_PROBE + extra], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 3 and flag.exists() and "teardown ran" in res.stdout
