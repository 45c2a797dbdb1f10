"""Map-reduce over files, in process or on a dask.distributed cluster.

Every l3 job that scales (training statistics, rendering, simulation) is a map
over inputs whose results are small or written by the task itself. This module
runs that map

* in the current process (the default: no cluster, no overhead),
* on a local cluster started for the job (``workers=N``: N worker processes,
  one thread each), or
* on a running scheduler (``scheduler="tcp://host:8786"``), e.g. a user's
  cluster started with ``dask scheduler`` / ``dask worker``.

Tasks receive *paths or small descriptions*, never pixel data: workers read
their inputs themselves. Results are handed to ``reduce`` in input order, so a
sum of float64 statistics is the same whatever the completion order, and the
same as in process (bit-identical for deterministic tasks).

Faults: dask retries a task whose worker died on another worker (its
``allowed-failures`` mechanism) and ``retries`` re-runs tasks that raised; a
task that still cannot finish fails the whole job with an
:class:`~l3cli.errors.L3Error` naming the input, so callers that write their
output only after the reduce leave nothing partial behind.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

from l3cli.errors import L3Error
from l3cli.progress import progress as _progress

__all__ = ["map_reduce", "dask_client", "cpu_count", "ParallelError"]

log = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")
A = TypeVar("A")

#: Tasks in flight (submitted, not yet folded) per worker thread: enough to keep
#: every worker busy while bounding the results held out of order.
WINDOW_PER_THREAD = 4


#: dask's default worker environment sets glibc's trim threshold, which also
#: turns off glibc's dynamic mmap threshold: every large array of a task is then
#: mapped and zero-filled anew (measured on 16 training captures: worker system
#: time 1.6 s instead of 0.2 s). Local clusters leave it unset.
#: Seconds a scheduler address has to answer as a dask scheduler (connect + handshake).
SCHEDULER_TIMEOUT_S = 20.0

_SPAWN_ENV = "distributed.nanny.pre-spawn-environ"
_TRIM = _SPAWN_ENV + ".MALLOC_TRIM_THRESHOLD_"


class ParallelError(L3Error):
    """A distributed job could not finish."""


def _describe(item: Any) -> str:
    s = str(item)
    return s if len(s) < 120 else s[:117] + "..."


def cpu_count() -> int:
    """The CPUs this process may run on (its affinity mask; os.cpu_count elsewhere)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def check_scheduler(address: str, timeout: float | None = None) -> None:
    """Check that ``address`` answers as a dask.distributed scheduler, within ``timeout`` s.

    dask's own connect waits forever for a server that accepts the connection
    and never answers, and reads the first bytes of any other server (a web
    server) as a message length (then "out of memory"). Here the address is
    parsed, connected to, and asked for its identity under one deadline.

    Raises
    ------
    ParallelError
        A malformed address, nothing listening, no answer in time, or a server
        that is not a dask scheduler: one line naming the address.
    """
    import asyncio

    from distributed.comm import connect
    from distributed.comm.addressing import parse_address

    timeout = SCHEDULER_TIMEOUT_S if timeout is None else timeout
    try:
        parse_address(address)
    except (ValueError, TypeError) as exc:
        raise ParallelError(f"{address!r} is not a scheduler address (e.g. "
                            f"tcp://host:8786): {exc}") from None

    scheme, loc = parse_address(address)
    if scheme == "tcp":  # a refused connection fails now, not after dask's retries
        import socket

        from distributed.comm.addressing import parse_host_port

        try:
            host, port = parse_host_port(loc)
            socket.create_connection((host, port), timeout=timeout).close()
        except (OSError, ValueError, TypeError) as exc:
            raise ParallelError(f"cannot reach dask scheduler {address}: "
                                f"{getattr(exc, 'strerror', None) or exc}") from None

    async def identity() -> Any:
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    async def bounded() -> Any:
        return await asyncio.wait_for(identity(), timeout)

    try:
        reply = asyncio.run(bounded())
    except TimeoutError:
        raise ParallelError(f"cannot reach dask scheduler {address}: no answer within {timeout:g} s "
                            "(nothing listening, or not a dask scheduler)") from None
    except (OSError, ValueError) as exc:
        raise ParallelError(f"cannot reach dask scheduler {address}: {exc}") from None
    except (MemoryError, Exception) as exc:  # noqa: BLE001 - any garbage a non-scheduler sends
        raise ParallelError(f"{address} is not a dask scheduler ({type(exc).__name__} "
                            "while talking to it)") from None
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        raise ParallelError(f"{address} is not a dask scheduler (it answered "
                            f"{str(reply)[:60]!r})")


#: Memory of one local worker process once it has imported l3 (numpy, numba,
#: OpenImageIO, LibRaw) and holds one input: measured RSS ~200 MiB, rounded up.
WORKER_BYTES = 256 << 20


def check_worker_count(n: int) -> None:
    """Refuse ``--workers n`` when n worker processes cannot fit in the available memory.

    Raises
    ------
    ParallelError
        Naming the option and the most workers that fit.
    """
    from l3cli.buffers import available_memory

    most = max(1, available_memory() // WORKER_BYTES)
    if n > most:
        raise ParallelError(f"--workers {n} is too many: each worker process needs about "
                            f"{WORKER_BYTES >> 20} MiB, and the available memory holds at most "
                            f"{most}; use --workers {min(most, cpu_count())} or fewer")


def _children() -> set[int]:
    """Process ids of this process's live descendants."""
    import psutil

    try:
        return {p.pid for p in psutil.Process().children(recursive=True)}
    except psutil.Error:  # pragma: no cover - /proc unreadable
        return set()


@contextlib.contextmanager
def _terminal_signals_held() -> Iterator[None]:
    """Hold SIGINT and SIGHUP back from this thread while a local cluster starts.

    The threads dask starts meanwhile inherit the mask, and so do the worker
    processes they spawn: a Ctrl-C or a hang-up sent to the whole process group
    reaches only l3, which closes the cluster (l3cli.startup.handle_signals),
    instead of every worker printing its own KeyboardInterrupt. A signal sent
    meanwhile is delivered when the start is over. SIGTERM stays as it is
    (the nannies end their workers with it).
    """
    import signal
    import threading

    held = {signal.SIGINT, getattr(signal, "SIGHUP", signal.SIGINT)}
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    from multiprocessing import resource_tracker

    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    # multiprocessing's resource tracker (started here, with the mask, if not yet
    # running) unblocks SIGINT in the thread that starts it: block again after
    resource_tracker.ensure_running()
    signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _close_half_made(before: set) -> None:
    """Close local clusters made since ``before`` whose start was cut short (their
    object never reached l3), and keep dask's exit hook from closing them again
    (with an assertion's traceback)."""
    from distributed.deploy.spec import SpecCluster

    for c in list(SpecCluster._instances):
        if c in before:
            continue
        if getattr(c, "status", None) is not None and c.status.name not in ("closed",):
            with contextlib.suppress(Exception):
                c.close(timeout=5)
        SpecCluster._instances.discard(c)


def _end_children(before: set[int], timeout: float = 5.0) -> list[int]:
    """End the descendants started since ``before`` (a local cluster's nannies and
    workers) that are still alive: SIGTERM, then SIGKILL after ``timeout`` s.

    multiprocessing's resource tracker is left to end itself when this process
    exits (it then releases what the workers left). Returns the ids ended.
    """
    import psutil

    procs = []
    try:
        kids = psutil.Process().children(recursive=True)
    except psutil.Error:  # pragma: no cover
        return []
    for p in kids:
        if p.pid in before:
            continue
        try:
            if "resource_tracker" in " ".join(p.cmdline()):
                continue
            p.terminate()
            procs.append(p)
        except psutil.Error:
            continue
    if procs:
        log.debug("dask: ending %d leftover processes", len(procs))
        for p in _wait_ended(procs, timeout):
            with contextlib.suppress(psutil.Error):
                p.kill()
        _wait_ended(procs, timeout)
    return [p.pid for p in procs]


def _wait_ended(procs: list, timeout: float) -> list:
    """Wait up to ``timeout`` s for ``procs`` to end; return those still running.

    Ended children are left as zombies for their owner (multiprocessing)
    to reap: reaping them here would take their exit status from it.
    """
    import time

    import psutil

    def running(p) -> bool:
        try:
            return p.status() != psutil.STATUS_ZOMBIE
        except psutil.Error:
            return False

    deadline = time.monotonic() + timeout
    alive = [p for p in procs if running(p)]
    while alive and time.monotonic() < deadline:
        time.sleep(0.05)
        alive = [p for p in alive if running(p)]
    return alive


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """A dask.distributed client for a job, or ``None`` to run in process.

    Parameters
    ----------
    workers
        Start a local cluster of this many single-threaded worker processes
        (closed when the block ends). Each worker's numba kernels get
        ``cpus // workers`` threads (``NUMBA_NUM_THREADS``), so the workers do
        not oversubscribe the machine.
    scheduler
        Address of a running scheduler (takes precedence over ``workers``).

    Yields
    ------
    distributed.Client or None
        ``None`` when neither is given (the in-process path).

    Raises
    ------
    ParallelError
        The scheduler cannot be reached or the local cluster cannot start.
    """
    if workers is None and scheduler is None:
        yield None
        return
    import dask
    from distributed import Client, LocalCluster

    # The nannies of a local cluster run in this process and set dask's
    # "pre-spawn" variables (thread counts) in its environment: put it back.
    saved_env = {k: os.environ.get(k)
                 for k in [*dask.config.get(_SPAWN_ENV, {}), "PYTHONHASHSEED"]}
    # dask logs its own life (workers starting, closing) at INFO: show it only
    # with -vv (debug); warnings (a worker died and restarts) with the default.
    root = logging.getLogger().getEffectiveLevel()
    dlog = logging.getLogger("distributed")
    old_level = dlog.level
    dlog.setLevel(root if root <= logging.DEBUG else max(root, logging.WARNING))
    # a local cluster's worker processes log a task's error with its traceback
    # ("Compute Failed"); the client reports it as one line: show those logs
    # only with --debug / -vv
    worker_logs = logging.DEBUG if root <= logging.DEBUG else logging.CRITICAL
    cluster = None
    before = _children()
    from distributed.deploy.spec import SpecCluster

    clusters_before = set(SpecCluster._instances)
    try:
        if scheduler is not None:
            check_scheduler(scheduler)
            try:
                client = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s")
            except (OSError, TimeoutError, ValueError, MemoryError) as exc:
                raise ParallelError(f"cannot reach dask scheduler {scheduler}: {exc}") from exc
        else:
            n = int(workers)  # type: ignore[arg-type]
            check_worker_count(n)
            threads = max(1, cpu_count() // n)
            try:
                with dask.config.set({_TRIM: None}), _terminal_signals_held():
                    cluster = LocalCluster(
                        n_workers=n, threads_per_worker=1, processes=True,
                        dashboard_address=":0", silence_logs=worker_logs,
                        env={"NUMBA_NUM_THREADS": str(threads)},
                    )
            except (OSError, TimeoutError, RuntimeError) as exc:
                raise ParallelError(f"cannot start a local dask cluster of {n} workers: "
                                    f"{exc}") from exc
            client = Client(cluster)
        with client:
            log.info("dask: %s", client)
            from l3cli.startup import test_point

            test_point("cluster")  # test-only: tests/cli/test_signals.py
            yield client
    finally:
        if isinstance(sys.exc_info()[1], KeyboardInterrupt) and root > logging.DEBUG:
            # interrupted: the process is ending; dask's reports of the workers it
            # loses on the way (and of a start cut short) are not news either
            for name in ("distributed", "asyncio"):
                logging.getLogger(name).setLevel(logging.CRITICAL + 1)
            old_level = logging.CRITICAL + 1
        try:
            if cluster is not None:
                # closing is l3's own decision: a busy worker that the nanny must
                # kill to close ("still alive after 4 s") is not news for the user
                if root > logging.DEBUG:
                    dlog.setLevel(max(dlog.level, logging.ERROR))
                cluster.close()
        finally:
            if workers is not None and scheduler is None:
                _close_half_made(clusters_before)  # a start cut short (a signal)
                _end_children(before)  # whatever the close (or a half-made cluster) left
            for k, v in saved_env.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
            dlog.setLevel(old_level)


def map_reduce(
    func: Callable[[T], R],
    items: Sequence[T],
    *,
    reduce: Callable[[A | None, R], A] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    label: str = "working",
    show_progress: bool | None = None,
    retries: int = 1,
) -> A | list[R] | None:
    """Apply ``func`` to every item and fold the results in input order.

    Parameters
    ----------
    func
        A picklable top-level function of one item (a path or small tuple).
    items
        The inputs.
    reduce
        ``reduce(acc, result) -> acc`` with ``acc`` starting as ``None``. If not
        given, the list of results is returned.
    workers
        Start a local cluster with this many single-threaded worker processes.
    scheduler
        Address of a running dask.distributed scheduler (takes precedence).
    client
        An open client (:func:`dask_client`) to reuse across several maps;
        takes precedence over ``workers`` and ``scheduler``.
    label
        Progress-bar label.
    show_progress
        Show a progress bar on stderr (default: when stderr is a TTY).
    retries
        Extra attempts for a task that raised (a worker that died is handled by
        dask itself).

    Returns
    -------
    The folded value, or the list of results.

    Notes
    -----
    On a cluster at most ``WINDOW_PER_THREAD`` tasks per worker thread (at
    least 8) are in flight: submitted and not yet folded. A result that
    finishes before its turn stays on its worker; the client fetches results
    in input order, so it holds one at a time whatever the number of items.

    Raises
    ------
    ParallelError
        The cluster cannot be reached, or a task failed on every attempt.
    L3Error
        Re-raised from a task (bad input file), unchanged.
    """
    items = list(items)
    if client is None and (workers is not None or scheduler is not None):
        with dask_client(workers, scheduler) as c:
            return map_reduce(func, items, reduce=reduce, client=c, label=label,
                              show_progress=show_progress, retries=retries)

    acc: Any = None
    results: list[R] = []

    def fold(r: R) -> None:
        nonlocal acc
        if reduce is None:
            results.append(r)
        else:
            acc = reduce(acc, r)

    if client is None:
        for item in _progress(items, label=label, enabled=show_progress):
            fold(func(item))
        return acc if reduce is not None else results

    from distributed import as_completed
    from distributed.client import FutureCancelledError
    from distributed.scheduler import KilledWorker

    n = len(items)
    index: dict[str, int] = {}
    live: dict[int, Any] = {}  # submitted, not yet folded
    finished: set[int] = set()
    ac = as_completed()
    state = {"submitted": 0, "next": 0, "window": 0, "refresh": 0}

    def window() -> int:
        if state["refresh"] <= 0:
            threads = sum(client.nthreads().values())
            state["window"] = max(8, WINDOW_PER_THREAD * threads)
            state["refresh"] = 16
        state["refresh"] -= 1
        return state["window"]

    def top_up() -> None:
        while state["submitted"] < n and state["submitted"] - state["next"] < window():
            k = state["submitted"]
            fut = client.submit(func, items[k], retries=retries, pure=False)
            index[fut.key] = k
            live[k] = fut
            ac.add(fut)
            state["submitted"] += 1

    def step(fut: Any) -> None:
        """A task finished: check it; fetch and fold every result now in order.

        Results that finish early stay on their workers until their turn, so
        the client holds one result at a time."""
        i = index.pop(fut.key)
        state["current"] = i
        if fut.status != "finished":
            fut.result()  # raises the task's error
        finished.add(i)
        while state["next"] in finished:
            k = state["next"]
            state["current"] = k
            f = live.pop(k)
            r = f.result()
            f.release()
            finished.discard(k)
            fold(r)
            state["next"] += 1

    top_up()
    try:
        for fut in _progress(ac, label=label, length=n, enabled=show_progress):
            step(fut)
            top_up()
    except BaseException as exc:
        client.cancel(list(live.values()))
        what = _describe(items[state.get("current", state["next"])])
        if isinstance(exc, (L3Error, KeyboardInterrupt)) or not isinstance(exc, Exception):
            raise
        if isinstance(exc, KilledWorker):
            raise ParallelError(f"{what}: workers kept dying on this input; job abandoned") \
                from exc
        if isinstance(exc, FutureCancelledError):
            raise ParallelError(f"{what}: task was cancelled") from exc
        raise ParallelError(  # a task's own error becomes one line
            f"{what}: task failed after {retries + 1} attempts: {type(exc).__name__}: {exc}"
        ) from exc
    return acc if reduce is not None else results
