"""One signal policy for every command: SIGINT, SIGTERM and SIGHUP end a run alike.

Each case runs ``l3`` as a process, sends it a signal at a given moment and
checks what the policy (:func:`l3cli.startup.handle_signals`) promises: exit
status ``128 + n``, "Aborted." and no traceback, no temporary file, no folder
that the run created, the previous output byte for byte, and no process
started by the run still alive afterwards (found by a marker in their
environment, which every descendant inherits, wherever it was re-parented).

Moments: ``start`` (the command is resolved, before it runs), ``work`` (the
run has read an input or created its temporary or output folder), ``workers``
(``--workers 2``: the local dask cluster is up; slow). Each is a test point
in l3 (:func:`l3cli.startup.test_point`, named by ``L3_TEST_PAUSE_AT``) where
the run stops until the signal arrives, so no moment can pass unseen at any
speed or load.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import pytest

from l3cli.cli.main import cli

REPO = Path(__file__).resolve().parents[2]
CFG = REPO / "sample_configs" / "bayer.toml"
L3 = [sys.executable, "-c", "from l3cli.cli.main import main; main()"]
SIGNALS = ["SIGINT", "SIGTERM", "SIGHUP"]
PREVIOUS = b"the previous output, kept byte for byte\n"


def marked(mark: str) -> list[tuple[int, str]]:
    """Live processes whose environment carries ``L3_TEST_MARK=mark``."""
    found = []
    needle = f"L3_TEST_MARK={mark}".encode()
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            env = Path(f"/proc/{d}/environ").read_bytes()
            if needle in env.split(b"\0"):
                stat = Path(f"/proc/{d}/stat").read_text()
                if stat.rsplit(")", 1)[1].split()[0] != "Z":
                    found.append((int(d), Path(f"/proc/{d}/cmdline").read_bytes()[:80].decode(
                        errors="replace")))
        except OSError:
            continue
    return found


def no_survivors(mark: str, wait: float = 5.0) -> list[tuple[int, str]]:
    """The marked processes still alive after ``wait`` s (multiprocessing's resource
    tracker ends itself once its parent is gone)."""
    deadline = time.monotonic() + wait
    left = marked(mark)
    while left and time.monotonic() < deadline:
        time.sleep(0.05)
        left = marked(mark)
    return left


def run_signalled(args: list[str], sig: str, point: str, *, cwd: Path, group: bool = False,
                  timeout: float = 120.0):
    """Run ``l3 args`` stopped at the test point ``point`` (``L3_TEST_PAUSE_AT``,
    :func:`l3cli.startup.test_point`), send ``sig`` once it says it is there; return
    (status, stderr, mark).

    The run waits at its point until the signal comes, so the moment cannot pass
    whatever the machine's speed or load: the test reads the point's line from a pipe
    of its own (``L3_TEST_PAUSE_FD``; a blocking read, immune to the run redirecting
    its stderr for a moment). Fails the test if the command ends before it.
    """
    from l3cli.startup import TEST_PAUSE_ENV, TEST_PAUSE_FD_ENV, TEST_PAUSE_MARK

    mark = uuid.uuid4().hex
    read_end, write_end = os.pipe()  # the run says where it stopped on its own pipe
    env = {**os.environ, "L3_TEST_MARK": mark, "PYTHONWARNINGS": "ignore",
           TEST_PAUSE_ENV: point, TEST_PAUSE_FD_ENV: str(write_end)}
    try:
        p = subprocess.Popen([*L3, *args], cwd=cwd, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, start_new_session=True,
                             pass_fds=(write_end,))
    finally:
        os.close(write_end)  # the run holds the only write end: its end is an end of file
    # stderr drained as the run writes it (a full pipe would stop the run before its point)
    chunks: list[bytes] = []
    drain = threading.Thread(target=lambda: chunks.append(p.stderr.read()), daemon=True)
    drain.start()
    signum = getattr(signal, sig)
    want = f"{TEST_PAUSE_MARK}{point}".encode()
    try:
        with os.fdopen(read_end, "rb") as said:
            line = said.readline()  # blocks until the run stops at its point, or ends
        if line.strip() != want:
            p.wait(timeout=timeout)
            drain.join(timeout)
            pytest.fail(f"l3 {args} ended ({p.returncode}) before reaching {point!r}: "
                        f"{b''.join(chunks).decode(errors='replace')[-500:]}")
        if group:
            os.killpg(p.pid, signum)
        else:
            p.send_signal(signum)
        p.wait(timeout=timeout)
        drain.join(timeout)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    return p.returncode, b"".join(chunks).decode(errors="replace"), mark


def check_ended_cleanly(status: int, err: str, mark: str, sig: str, folder: Path) -> None:
    assert status == 128 + getattr(signal, sig), (status, err)
    assert "Traceback" not in err, err
    assert "Aborted" in err, err
    assert not [p for p in folder.rglob(".l3-tmp*")], list(folder.rglob("*"))
    assert no_survivors(mark) == []


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A simulation (12 raws), a table trained on it; built once, in process."""
    from click.testing import CliRunner

    r = CliRunner()
    root = tmp_path_factory.mktemp("signals")
    res = r.invoke(cli, ["-q", "simulate", str(CFG), "-o", str(root / "sim"),
                         "--scene", "macbeth", "--scene", "natural:coffee",
                         "--lux", "30", "--lux", "300", "--lux", "3000",
                         "--size", "160x120", "--seed", "1"])
    assert res.exit_code == 0, res.output
    res = r.invoke(cli, ["-q", "train", str(root / "sim"), "-o", str(root / "t.npz"),
                         "--levels", "4", "--patch", "3"])
    assert res.exit_code == 0, res.output
    return root


def _commands(w: Path) -> dict[str, tuple[list[str], Path | None]]:
    """command -> (arguments, the output it would write: a file that exists before, a
    folder that does not)."""
    raws = sorted(str(p) for p in (w / "sim").glob("*.dng"))
    return {
        "simulate": (["simulate", str(CFG), "-o", str(w / "out" / "sim"), "--scene", "macbeth",
                      "--lux", "10", "--lux", "100", "--lux", "1000", "--size", "320x240"],
                     w / "out" / "sim"),
        "train": (["train", str(w / "sim"), "-o", str(w / "out" / "t.npz"), "--levels", "4"],
                  w / "out" / "t.npz"),
        "render": (["render", str(w / "t.npz"), *raws, "-o", str(w / "out" / "r")],
                   w / "out" / "r"),
        "smooth": (["smooth", str(w / "t.npz"), "-o", str(w / "out" / "s.npz")],
                   w / "out" / "s.npz"),
        "baseline": (["baseline", raws[0], "--train", str(w / "sim"), "-o",
                      str(w / "out" / "b.tif")], w / "out" / "b.tif"),
        "info": (["info", raws[0]], None),
        "inspect": (["inspect", str(w / "t.npz"), "--plots", str(w / "out" / "plots")],
                    w / "out" / "plots"),
        "evaluate": (["evaluate", str(w / "sim" / "macbeth_D65_0300lux.target.exr"),
                      "--reference", str(w / "sim" / "macbeth_D65_0300lux.target.exr"),
                      "--json", str(w / "out" / "e.json")], w / "out" / "e.json"),
    }


def _prepare(w: Path, output: Path | None) -> None:
    out = w / "out"
    if out.exists():
        import shutil

        shutil.rmtree(out)
    out.mkdir()
    if output is not None and output.suffix:  # a file output: a previous one to keep
        output.write_bytes(PREVIOUS)


def _check_output(output: Path | None) -> None:
    if output is None:
        return
    if output.suffix:
        assert output.read_bytes() == PREVIOUS
    else:
        assert not output.exists(), sorted(output.rglob("*"))


@pytest.mark.parametrize("sig", SIGNALS)
@pytest.mark.parametrize("command", ["simulate", "train", "render", "smooth", "baseline",
                                     "info", "inspect", "evaluate"])
def test_signal_at_start(work: Path, command: str, sig: str) -> None:
    """Every command, each signal, while it loads: the same clean end."""
    args, output = _commands(work)[command]
    _prepare(work, output)
    status, err, mark = run_signalled(args, sig, "start", cwd=work)
    check_ended_cleanly(status, err, mark, sig, work / "out")
    _check_output(output)


#: The moment each command is at work (:func:`l3cli.startup.test_point`): simulate's
#: temporary folder made, render's output folder made, train's first raw read.
WORKING = {"simulate": "temporary", "render": "output-folder", "train": "raw-read"}


@pytest.mark.parametrize("sig", SIGNALS)
@pytest.mark.parametrize("command", ["simulate", "render", "train"])
def test_signal_at_work(work: Path, command: str, sig: str) -> None:
    """Mid-run: temporaries removed, a folder the run created removed with what it
    wrote, the previous output intact."""
    args, output = _commands(work)[command]
    _prepare(work, output)
    status, err, mark = run_signalled(args, sig, WORKING[command], cwd=work)
    check_ended_cleanly(status, err, mark, sig, work / "out")
    _check_output(output)


def _interrupted_render(work: Path, args: list[str], patch: str) -> str:
    """Run ``l3 args`` in a Python whose code ``patch`` ran first (it sends the SIGINT);
    check the run ended as an interrupted one does; its stderr."""
    code = (patch + f"import sys\nsys.argv = ['l3', *{args!r}]\n"
            "from l3cli.cli.main import main\nmain()\n")
    p = subprocess.run([sys.executable, "-c", code], cwd=work, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 128 + signal.SIGINT, p.stderr
    assert "Traceback" not in p.stderr and "Aborted" in p.stderr, p.stderr
    return p.stderr


def test_signal_right_after_the_output_folder_is_made(work: Path) -> None:
    """A signal between the output folder's mkdir and its record (the moment
    test_signal_at_work can hit on a loaded machine): the folder still goes."""
    args, output = _commands(work)["render"]
    _prepare(work, output)
    _interrupted_render(work, args, (
        "import os, pathlib, signal\n"
        "real = pathlib.Path.mkdir\n"
        "def mkdir(self, *a, **k):\n"
        "    real(self, *a, **k)\n"
        f"    if self == pathlib.Path({str(output)!r}):\n"
        "        os.kill(os.getpid(), signal.SIGINT)  # handled before the next line\n"
        "pathlib.Path.mkdir = mkdir\n"))
    _check_output(output)


@pytest.mark.parametrize("thread", ["l3-render_0", "l3-render_1"])
def test_signal_while_a_render_thread_starts(work: Path, thread: str) -> None:
    """A signal just after a render worker thread started, before its pool recorded
    it (inside ``pool.submit``): the pool still waits for that thread, so no render
    thread is alive when the interrupted run's clean-up removes its outputs (one
    that was once wrote its file after the clean-up)."""
    args, output = _commands(work)["render"]
    _prepare(work, output)
    err = _interrupted_render(work, args, (
        "import os, pathlib, signal, sys, threading\n"
        "real = threading.Thread.start\n"
        "def start(self):\n"
        "    real(self)\n"
        f"    if self.name == {thread!r}:\n"
        "        os.kill(os.getpid(), signal.SIGINT)  # handled before start returns\n"
        "threading.Thread.start = start\n"
        "rmdir = pathlib.Path.rmdir\n"
        "def cleanup(self):\n"
        "    alive = [t.name for t in threading.enumerate()\n"
        "             if t.name.startswith('l3-render') and t.is_alive()]\n"
        "    print('render threads at clean-up:', alive, file=sys.stderr)\n"
        "    rmdir(self)\n"
        "pathlib.Path.rmdir = cleanup\n"))
    assert "render threads at clean-up: []" in err, err
    _check_output(output)


@pytest.mark.slow
@pytest.mark.parametrize("group", [False, True], ids=["process", "group"])
@pytest.mark.parametrize("sig", SIGNALS)
def test_signal_to_train_with_workers(work: Path, sig: str, group: bool) -> None:
    """``train --workers 2``: the cluster and every process it started end with l3,
    whether the signal reaches l3 alone or its whole process group (a Ctrl-C in a
    terminal): no worker prints its own KeyboardInterrupt."""
    args, output = _commands(work)["train"]
    _prepare(work, output)
    status, err, mark = run_signalled([*args, "--workers", "2"], sig, "cluster", cwd=work,
                                      group=group)
    check_ended_cleanly(status, err, mark, sig, work / "out")
    assert "KeyboardInterrupt" not in err
    _check_output(output)


@pytest.mark.slow
def test_train_with_workers_leaves_no_process(work: Path) -> None:
    """A finished ``train --workers 2`` leaves no process behind either."""
    args, output = _commands(work)["train"]
    _prepare(work, output)
    mark = uuid.uuid4().hex
    env = {**os.environ, "L3_TEST_MARK": mark}
    res = subprocess.run([*L3, "-q", *args, "--workers", "2"], cwd=work, env=env,
                         capture_output=True, timeout=120)
    assert res.returncode == 0, res.stderr.decode()
    assert no_survivors(mark) == []
    assert output.read_bytes() != PREVIOUS


def test_interrupted_status_follows_the_signal() -> None:
    """In process: the exit status of an interrupted command is 128 + the signal."""
    from l3cli import startup

    assert startup.interrupt_status(startup.Interrupted(signal.SIGTERM)) == 143
    assert startup.interrupt_status(startup.Interrupted(signal.SIGHUP)) == 129
    assert startup.interrupt_status(KeyboardInterrupt()) == 130
    assert isinstance(startup.Interrupted(signal.SIGTERM), KeyboardInterrupt)


@pytest.mark.parametrize("maker", ["dir", "file"])
def test_a_signal_while_a_temporary_is_made_still_removes_it(tmp_path: Path, monkeypatch,
                                                             maker: str) -> None:
    """The signal lands just after the temporary exists, before its maker returns (the
    window the signal matrix hit once in a while): it is raised only once the temporary
    is recorded, and an interrupted run's exit removes it."""
    import tempfile

    from l3cli import startup
    from l3cli.io import atomic

    monkeypatch.setattr(startup, "_first_signal", [])
    name = "mkdtemp" if maker == "dir" else "mkstemp"
    real = getattr(tempfile, name)

    def make_then_signal(*a, **k):
        made = real(*a, **k)
        os.kill(os.getpid(), signal.SIGTERM)  # handled at the next bytecode: here
        return made

    monkeypatch.setattr(tempfile, name, make_then_signal)
    old = signal.signal(signal.SIGTERM, startup._on_signal)
    try:
        with pytest.raises(startup.Interrupted):
            if maker == "dir":
                atomic.make_temp_dir(tmp_path, "sim")
            else:
                with atomic.atomic_path(tmp_path / "out.exr"):
                    pass
    finally:
        signal.signal(signal.SIGTERM, old)
    if maker == "dir":  # its caller never saw it: the exit path removes it
        assert [p.name[:8] for p in tmp_path.iterdir()] == [".l3-tmp-"]
    atomic.remove_live_temporaries()
    assert list(tmp_path.iterdir()) == []


_SWALLOWED = """
import os, signal, sys, time, weakref
from l3cli import startup
startup.handle_signals()
class A: pass
def callback(_):
    os.kill(os.getpid(), signal.{sig})
    for _ in range(100000):  # the handler runs in here, inside the callback
        pass
a = A(); r = weakref.ref(a, callback)
try:
    del a
    time.sleep(5)
except startup.Interrupted as e:
    sys.exit(e.signum)
sys.exit(1)
"""


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_signal_inside_a_callback_is_not_lost(sig: str) -> None:
    """A signal whose handler runs inside a weakref callback (as at start-up, in the
    import lock's clean-up) still ends the run, with no "Exception ignored" traceback."""
    proc = subprocess.run([sys.executable, "-c", _SWALLOWED.format(sig=sig)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == getattr(signal, sig), proc.stderr
    assert "Traceback" not in proc.stderr and "ignored" not in proc.stderr
