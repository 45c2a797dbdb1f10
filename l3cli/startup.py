"""Process start-up and exit: what a short ``l3 render`` spends around its pixels.

A one-file render is mostly start-up (``docs/performance.md``). Four costs
here are not l3's own work, and each has one switch here:

* **OpenBLAS threads.** numpy and scipy each load an OpenBLAS that starts a
  thread per core; the threads spin for a while after start-up, stealing a
  core from the decode and the imports (``perf``: 3 % of an eight-file
  render, ~0.15 s of CPU). The render path calls no BLAS routine, so
  :func:`single_threaded_blas` asks for one thread before numpy loads.
* **The cyclic garbage collector** walks the growing heap again and again
  while numba's modules import and register (~0.08 s of a one-file
  render); the ``l3`` entry point turns it off (:func:`pause_gc`) until
  the command is known, ``l3 render`` keeps it off until its kernels are
  loaded (:func:`resume_gc`), and the objects made by then are frozen
  (:func:`gc.freeze`: later full collections skip them; ~0.1 s of an
  eight-file render, measured).
* **Interpreter teardown.** After the last file is written, Python's
  finalisation collects and tears down every module (numba, LLVM,
  OpenImageIO): ~0.1 s of a one-file render, with nothing left to
  do. :func:`exit_now` ends a finished ``l3 render`` / ``l3 info``
  after running the exit handlers and flushing the standard streams.
* **numba itself.** Importing numba (~0.35 s: its typing and lowering of
  all of Python and numpy) and loading a kernel from its cache (~0.2 s) is
  what compiling needs, not running machine code. The render kernel and the
  lossy DNG decoder come from :mod:`l3cli.kernel_store` instead (their
  stored object code, loaded in milliseconds without numba);
  :func:`lean_cache` makes l3's other cached numba functions load with only
  what running them needs (numba's runtime library), and
  :func:`preload_scipy_blas` spares numba's first use ``scipy.linalg``'s
  import.

Signals have one policy here too (:func:`handle_signals`): SIGINT, SIGTERM
and SIGHUP each raise :class:`Interrupted` (a ``KeyboardInterrupt``) in the
main thread, so every run unwinds the way Ctrl-C always did: temporaries
removed (:mod:`l3cli.io.atomic`), folders l3 created and left empty removed
(:class:`l3cli.cli.paths.OutputPlan`), a local dask cluster closed
(:func:`l3cli.parallel.dask_client`), and the previous output untouched. The
command then exits ``128 + n`` (:func:`interrupt_status`).
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import logging
import os
import signal
import sys
import threading
import time
from typing import Any, NoReturn

__all__ = ["Interrupted", "arm_exit_now", "exit_now", "extension_module", "handle_signals",
           "interrupt_status", "lean_cache", "pause_gc", "preload_scipy_blas", "resume_gc",
           "signals_deferred", "single_threaded_blas", "stop_if_interrupted", "test_point"]

log = logging.getLogger(__name__)

_gc_lock = threading.Lock()
_gc_paused = False
_gc_freeze = False
_exit_now_armed = False

#: The signals that end a run cleanly (:func:`handle_signals`).
SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))
#: Seconds after the first signal during which repeats are ignored (the run is
#: cleaning up); a repeat after that ends the process at once.
REPEAT_GRACE_S = 10.0
_first_signal: list = []  # [time, signum] of the first


class Interrupted(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP arrived: the run unwinds as for Ctrl-C.

    A ``KeyboardInterrupt``, so every cleanup that handles Ctrl-C handles
    the other signals alike. ``signum`` is the signal's number.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


_deferred: list[int] = []  # depth of signals_deferred blocks in the main thread, signum
_defer_depth = [0]


@contextlib.contextmanager
def signals_deferred():
    """Hold a signal (:func:`handle_signals`) back until the block ends, then raise it.

    For the few lines that create a temporary and record it (:mod:`l3cli.io.atomic`):
    the :class:`Interrupted` comes after the record, so the cleanup finds it.
    Only in the main thread (elsewhere the block changes nothing).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _defer_depth[0] += 1
    try:
        yield
    finally:
        _defer_depth[0] -= 1
    if _defer_depth[0] == 0 and _deferred:
        signum = _deferred.pop()
        _first_signal.extend((time.monotonic(), signum))
        raise Interrupted(signum)


def _on_signal(signum: int, frame: Any) -> None:
    if _defer_depth[0] and not _first_signal:  # inside signals_deferred: at its end
        if not _deferred:
            _deferred.append(int(signum))
        return
    if _first_signal:  # already unwinding: let the cleanup finish
        if time.monotonic() - _first_signal[0] < REPEAT_GRACE_S:
            return
        signal.signal(signum, signal.SIG_DFL)  # asked again, long after: end now
        os.kill(os.getpid(), signum)
        return
    _first_signal.extend((time.monotonic(), int(signum)))
    raise Interrupted(signum)


_previous_unraisablehook: list = []


def _on_unraisable(unraisable: Any) -> None:
    """Deliver again a signal whose :class:`Interrupted` a callback swallowed.

    Python runs a signal handler wherever the main thread is, and an
    exception raised inside a weakref callback, a finaliser or the import
    lock's clean-up cannot propagate: Python reports it as "Exception
    ignored in ..." with a traceback, and the run would go on as if no
    signal had come. Here the report is dropped and the signal sent again a
    moment later from a helper thread, once the main thread has left the
    callback (and this hook): the handler runs again in ordinary code and
    the run unwinds.
    """
    exc = unraisable.exc_value
    if isinstance(exc, Interrupted) and _first_signal and _first_signal[1] == exc.signum:
        timer = threading.Timer(0.02, _redeliver, (exc.signum,))
        timer.daemon = True
        timer.start()
        return
    (_previous_unraisablehook[0] if _previous_unraisablehook else sys.__unraisablehook__)(unraisable)


def _redeliver(signum: int) -> None:
    _first_signal.clear()
    os.kill(os.getpid(), signum)


def handle_signals() -> None:
    """Make SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` (main thread only).

    A signal that the process inherited as ignored (``nohup``) stays ignored.
    One raised where Python cannot propagate it (a callback) is delivered
    again (:func:`_on_unraisable`).
    """
    if threading.current_thread() is not threading.main_thread():
        return
    if sys.unraisablehook is not _on_unraisable:
        _previous_unraisablehook[:] = [sys.unraisablehook]
        sys.unraisablehook = _on_unraisable
    for sig in SIGNALS:
        if sig != signal.SIGINT and signal.getsignal(sig) == signal.SIG_IGN:
            continue
        signal.signal(sig, _on_signal)


#: Test-only (``tests/cli/test_signals.py``): the environment variable naming the point
#: (:func:`test_point`) where a run stops until a signal arrives.
TEST_PAUSE_ENV = "L3_TEST_PAUSE_AT"
#: Test-only: the file descriptor :func:`test_point` writes its line to (default 2).
TEST_PAUSE_FD_ENV = "L3_TEST_PAUSE_FD"
#: What :func:`test_point` writes when it stops (then the point's name).
TEST_PAUSE_MARK = "l3-test-paused-at: "
#: Seconds a paused run waits for its signal before it goes on (a test that forgot it).
TEST_PAUSE_LIMIT_S = 300.0
_paused: set[str] = set()
_pause_lock = threading.Lock()


def test_point(name: str) -> None:
    """Test-only: stop at the point ``name`` until a signal arrives.

    Where the environment variable ``L3_TEST_PAUSE_AT`` (:data:`TEST_PAUSE_ENV`)
    names this point, the first thread to reach it writes
    ``l3-test-paused-at: NAME`` to the file descriptor ``L3_TEST_PAUSE_FD`` (a pipe
    of the test's; stderr by default) and waits until :func:`handle_signals`
    has caught a signal, so a test sends its signal at an exact moment of the
    run whatever the machine's speed or load (no polling for a moment that
    may pass). In the main thread the handler's :class:`Interrupted` ends the
    wait; another thread returns once the signal is caught and the run unwinds
    as it would. Points: ``start`` (the command is resolved, before it runs),
    ``raw-read`` (the first raw file read), ``temporary`` (the first temporary
    file or folder made), ``output-folder`` (the output folders made and recorded,
    :class:`l3cli.cli.paths.OutputPlan`), ``cluster`` (a dask cluster's client
    connected, :func:`l3cli.parallel.dask_client`). Otherwise a dictionary look-up, nothing more.

    Examples
    --------
    >>> test_point("start")  # no L3_TEST_PAUSE_AT: returns at once
    """
    if os.environ.get(TEST_PAUSE_ENV) != name:
        return
    with _pause_lock:  # one pause per point and process
        if name in _paused:
            return
        _paused.add(name)
    # to the test's own pipe when it gives one (stderr may be redirected for a moment
    # while LibRaw's messages are captured in another thread)
    fd = int(os.environ.get(TEST_PAUSE_FD_ENV) or 2)
    os.write(fd, f"{TEST_PAUSE_MARK}{name}\n".encode())
    deadline = time.monotonic() + TEST_PAUSE_LIMIT_S
    while not _first_signal and not _deferred and time.monotonic() < deadline:
        time.sleep(0.005)  # the handler raises here (main thread), or the loop sees it


def signal_received() -> int | None:
    """The first signal :func:`handle_signals` caught in this process, or None."""
    return _first_signal[1] if _first_signal else None


def stop_if_interrupted() -> None:
    """In a worker thread, raise :class:`Interrupted` once a signal has come.

    The handler raises in the main thread only; a long loop that runs in a
    worker (a decode, a render job) calls this between its steps, so the
    thread ends promptly and the main thread's clean-up does not wait for the
    rest of its work. In the main thread (already unwinding) it does nothing.
    """
    if _first_signal and threading.current_thread() is not threading.main_thread():
        raise Interrupted(_first_signal[1])


def interrupt_status(exc: BaseException | None = None) -> int:
    """The exit status of an interrupted run: ``128 + n`` (n from ``exc``, else the
    first signal caught, else SIGINT's 2)."""
    signum = getattr(exc, "signum", None) or signal_received() or signal.SIGINT
    return 128 + int(signum)


def single_threaded_blas() -> bool:
    """One OpenBLAS thread for this process, if numpy is not loaded yet.

    Leaves an ``OPENBLAS_NUM_THREADS`` the user set alone, and changes
    nothing once numpy is imported (OpenBLAS reads it when it loads).
    Returns whether the setting applies.
    """
    if "numpy" in sys.modules:
        return False
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    return True


def pause_gc(*, freeze: bool = False) -> None:
    """No cyclic garbage collection until :func:`resume_gc`.

    Does nothing when collection is already off (the caller's choice, which
    :func:`resume_gc` then leaves alone). With ``freeze`` (the console entry
    point, for the lean commands that end without a teardown) :func:`resume_gc`
    first moves the objects made until then (the imported modules, numba's type
    system: about 115 000 that the collector tracks) to the permanent generation
    (:func:`gc.freeze`), so later full collections do not walk them again;
    cyclic garbage made while paused is then never collected, which only a
    short-lived process can afford.
    """
    global _gc_paused, _gc_freeze
    with _gc_lock:
        if gc.isenabled() and not _gc_paused:
            gc.disable()
            _gc_paused = True
        _gc_freeze = _gc_freeze or (freeze and _gc_paused)


def resume_gc(*, freeze: bool = True) -> None:
    """Turn collection back on if :func:`pause_gc` turned it off (idempotent);
    ``freeze=False`` declines the freeze the pause asked for (a command that ends
    with the interpreter's teardown, whose finalisers must still run)."""
    global _gc_paused, _gc_freeze
    with _gc_lock:
        if _gc_paused:
            _gc_paused = False
            if _gc_freeze and freeze:
                gc.freeze()
            _gc_freeze = False
            gc.enable()


def arm_exit_now() -> None:
    """Let :func:`exit_now` skip the teardown (the command is one of the lean ones)."""
    global _exit_now_armed
    _exit_now_armed = True


def exit_now(code: Any) -> NoReturn:
    """End the process with ``code`` (a :class:`SystemExit` code), without its teardown.

    Only once armed (:func:`arm_exit_now`) and only when no other non-daemon
    thread is alive; otherwise (and when this Python lacks
    ``atexit._run_exitfuncs``) it is ``sys.exit(code)``. Before ``os._exit``
    it runs the exit handlers (logging's flush among them) and flushes
    stdout and stderr; a failed flush exits 120, as Python does. Every
    output is already complete and closed when a command returns (writes are
    atomic), so nothing is lost: only the module teardown and the final
    garbage collections are skipped.
    """
    run_exitfuncs = getattr(atexit, "_run_exitfuncs", None)
    others = [t for t in threading.enumerate()
              if t is not threading.main_thread() and not t.daemon and t.is_alive()]
    if not _exit_now_armed or others or run_exitfuncs is None:
        sys.exit(code)
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:  # sys.exit("message") prints the message and exits 1
        print(code, file=sys.stderr)
        status = 1
    run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):
            status = status or 120
    os._exit(status)


def lean_cache(dispatcher: Any) -> Any:
    """Let ``dispatcher`` (an ``njit(cache=True)`` function) load from numba's cache lean.

    numba's ``Cache.load_overload`` refreshes the target context before it
    reads a cached overload; a refresh imports and installs every typing and
    lowering registry, which compiling needs and running machine code does
    not. For this dispatcher only, the load becomes the runtime
    initialisation (the NRT symbols cached code links against) and the load
    itself. On a miss the dispatcher compiles, and numba's compiler
    refreshes the target first, as always. A numba without these internals
    is left as it is. Returns ``dispatcher`` (use it as a decorator, above
    ``@numba.njit``).
    """
    cache = getattr(dispatcher, "_cache", None)
    try:
        from numba.core import caching
        from numba.core.runtime import nrt

        needed = ("_load_overload", "_guard_against_spurious_io_errors", "load_overload")
        if (not isinstance(cache, caching.Cache) or not all(hasattr(cache, n) for n in needed)
                or not hasattr(nrt, "rtsys")):
            return dispatcher
        rtsys = nrt.rtsys

        def load_overload(sig, target_context):  # numba's Cache.load_overload, lean
            rtsys.initialize(target_context)
            with cache._guard_against_spurious_io_errors():
                return cache._load_overload(sig, target_context)
            return None  # the guard swallowed an I/O error: compile

        cache.load_overload = load_overload
    except Exception as exc:  # noqa: BLE001 - an optimisation only
        log.debug("lean cache loads not set up for %s: %s", dispatcher, exc)
    return dispatcher


def preload_scipy_blas() -> None:
    """Load scipy's BLAS/LAPACK capsule modules without the rest of ``scipy.linalg``.

    numba's CPU target, on its first use (also when loading cached kernels),
    imports ``scipy.linalg.cython_blas`` to check that BLAS exists; importing
    that submodule first runs ``scipy.linalg``'s ``__init__`` (and through it
    ``numpy.f2py`` and scipy's array-API layer): about a third of a second of
    a one-file ``l3 render`` that never calls BLAS. Loading the two extension
    modules by file and registering them under their names gives numba the
    same modules (a later ``import scipy.linalg`` reuses them). Any surprise
    (another scipy layout) leaves the normal import to happen.
    """
    if "scipy.linalg" in sys.modules:
        return
    with _preload_lock:  # two threads' first numba calls: one preload
        _preload_scipy_blas()


_preload_lock = threading.Lock()


def _preload_scipy_blas() -> None:
    try:
        import scipy

        folder = os.path.join(scipy.__path__[0], "linalg")
        for name in ("cython_blas", "cython_lapack"):
            if extension_module(f"scipy.linalg.{name}", folder) is None:
                return
    except Exception as exc:  # noqa: BLE001 - an optimisation only
        log.debug("scipy BLAS preload skipped: %s", exc)


def extension_module(full: str, folder: str | os.PathLike) -> Any:
    """The C extension module ``full`` loaded from its file in ``folder``, without its
    package's ``__init__``; None when no such file is there.

    Registered in ``sys.modules`` under ``full``, so a later import of the
    package uses this very module. An error in the module's own initialisation
    propagates (and leaves nothing registered).
    """
    import glob
    import importlib.machinery
    import importlib.util

    if full in sys.modules:
        return sys.modules[full]
    stem = full.rsplit(".", 1)[-1]
    files = [f for suffix in importlib.machinery.EXTENSION_SUFFIXES
             for f in glob.glob(os.path.join(os.fspath(folder), stem + suffix))]
    if not files:
        return None
    spec = importlib.util.spec_from_file_location(full, files[0])
    if spec is None or spec.loader is None:
        return None
    module = importlib.util.module_from_spec(spec)
    sys.modules[full] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[full]
        raise
    return module
