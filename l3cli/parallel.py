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

import logging
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from l3cli.errors import L3Error
from l3cli.progress import progress as _progress

__all__ = ["map_reduce", "ParallelError"]

log = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")
A = TypeVar("A")


class ParallelError(L3Error):
    """A distributed job could not finish."""


def _describe(item: Any) -> str:
    s = str(item)
    return s if len(s) < 120 else s[:117] + "..."


def map_reduce(
    func: Callable[[T], R],
    items: Sequence[T],
    *,
    reduce: Callable[[A | None, R], A] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
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

    Raises
    ------
    ParallelError
        The cluster cannot be reached, or a task failed on every attempt.
    L3Error
        Re-raised from a task (bad input file), unchanged.
    """
    items = list(items)
    acc: Any = None
    results: list[R] = []

    def fold(r: R) -> None:
        nonlocal acc
        if reduce is None:
            results.append(r)
        else:
            acc = reduce(acc, r)

    if workers is None and scheduler is None:
        for item in _progress(items, label=label, enabled=show_progress):
            fold(func(item))
        return acc if reduce is not None else results

    from distributed import Client, LocalCluster, as_completed
    from distributed.client import FutureCancelledError
    from distributed.scheduler import KilledWorker

    cluster = None
    try:
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout="5s")
            except (OSError, TimeoutError) as exc:
                raise ParallelError(f"cannot reach dask scheduler {scheduler}: {exc}") from exc
        else:
            cluster = LocalCluster(
                n_workers=int(workers), threads_per_worker=1, processes=True,
                dashboard_address=None, silence_logs=logging.ERROR,
            )
            client = Client(cluster)
        with client:
            log.info("dask: %s", client)
            futures = client.map(func, items, retries=retries, pure=False)
            index = {f.key: i for i, f in enumerate(futures)}
            done: dict[int, R] = {}
            next_i = 0
            it = as_completed(futures)
            for fut in _progress(it, label=label, length=len(futures), enabled=show_progress):
                i = index[fut.key]
                try:
                    done[i] = fut.result()
                except L3Error:
                    client.cancel(futures)
                    raise
                except KilledWorker as exc:
                    client.cancel(futures)
                    raise ParallelError(
                        f"{_describe(items[i])}: workers kept dying on this input; job abandoned"
                    ) from exc
                except FutureCancelledError as exc:
                    raise ParallelError(f"{_describe(items[i])}: task was cancelled") from exc
                except Exception as exc:  # noqa: BLE001 - task errors become one line
                    client.cancel(futures)
                    raise ParallelError(
                        f"{_describe(items[i])}: task failed after {retries + 1} attempts: "
                        f"{type(exc).__name__}: {exc}"
                    ) from exc
                while next_i in done:
                    fold(done.pop(next_i))
                    next_i += 1
    finally:
        if cluster is not None:
            cluster.close()
    return acc if reduce is not None else results
