"""map_reduce: in process, on a local dask cluster, and with a worker killed mid-task."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from l3cli.errors import InputError
from l3cli.parallel import ParallelError, map_reduce


def _square_sum(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((1000, 4))
    return x.T @ x


def _add(acc, r):
    return r if acc is None else acc + r


def _die_once(arg: tuple[str, int]) -> int:
    marker, value = arg
    m = Path(marker)
    if value == 3 and not m.exists():
        m.write_text("killed")
        os._exit(1)  # the worker process dies mid-task
    return value * value


def _slow_first(x: int) -> int:
    import time

    if x == 0:
        time.sleep(1.0)  # every later task finishes first
    return x


def _append(acc, r):
    return [r] if acc is None else [*acc, r]


def _always_die(_: int) -> int:
    os._exit(1)


def _bad_input(x: int) -> int:
    raise InputError(f"input{x}.raw: damaged")


def test_in_process_matches_plain_loop():
    expect = sum(_square_sum(s) for s in range(5))
    got = map_reduce(_square_sum, list(range(5)), reduce=_add)
    np.testing.assert_array_equal(got, expect)
    assert map_reduce(lambda v: v + 1, [1, 2, 3]) == [2, 3, 4]


@pytest.mark.slow
def test_local_cluster_equals_in_process_bit_for_bit():
    seq = map_reduce(_square_sum, list(range(6)), reduce=_add)
    dist = map_reduce(_square_sum, list(range(6)), reduce=_add, workers=2)
    np.testing.assert_array_equal(seq, dist)  # folded in input order: identical


@pytest.mark.slow
def test_results_fold_in_input_order_beyond_the_window():
    # 30 items > the in-flight window (8 on a small cluster); item 0 finishes last
    assert map_reduce(_slow_first, list(range(30)), reduce=_append, workers=2) == list(range(30))


@pytest.mark.slow
def test_single_worker_cluster_works():
    assert map_reduce(_square_sum, [1], workers=1)[0].shape == (4, 4)


@pytest.mark.slow
def test_worker_killed_mid_task_is_retried(tmp_path):
    marker = str(tmp_path / "killed")
    items = [(marker, v) for v in range(6)]
    out = map_reduce(_die_once, items, workers=2)
    assert out == [v * v for v in range(6)]
    assert Path(marker).exists()  # the kill really happened


@pytest.mark.slow
def test_task_that_always_kills_its_worker_fails_cleanly():
    with pytest.raises(ParallelError, match="workers kept dying"):
        map_reduce(_always_die, [0], workers=2)


@pytest.mark.slow
def test_l3_errors_pass_through_unchanged():
    with pytest.raises(InputError, match="input1.raw: damaged"):
        map_reduce(_bad_input, [1, 2], workers=1)


def test_unreachable_scheduler():
    with pytest.raises(ParallelError, match="cannot reach dask scheduler"):
        map_reduce(_square_sum, [1], scheduler="tcp://127.0.0.1:1")
