"""Shared fixtures: the CLI runner, paths to bundled/shared test data, a small table
file and a pairs folder (the builders themselves are in ``tests/builders.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from l3cli.colourspace import srgb_encode
from l3cli.io.image import write_image
from l3cli.io.raw import write_raw
from l3cli.table import save_table
from tests.builders import (  # noqa: F401 - REPO, for the tests' use
    DATA,
    REPO,
    SHARED,
    H,
    W,
    make_table,
    mosaic_dn,
    scene,
    write_headerless,
)


@pytest.fixture
def runner() -> CliRunner:
    """A click CliRunner (stderr kept apart from stdout)."""
    return CliRunner()


@pytest.fixture
def data_dir() -> Path:
    return DATA


@pytest.fixture
def shared_data() -> Path:
    """The project's shared real data; tests needing it skip where it is absent."""
    if not SHARED.exists():
        pytest.skip(f"shared data folder {SHARED} is absent")
    return SHARED


@pytest.fixture
def table_path(tmp_path):
    t = make_table("RGGB", patch=5, seed=4)
    t.kernels *= np.float32(0.05)  # values mostly inside [0, 1] once encoded
    return save_table(tmp_path / "t.npz", t)


@pytest.fixture
def pairs_dir(tmp_path: Path) -> Path:
    d = tmp_path / "pairs"
    d.mkdir()
    lin_a = scene(H, W, seed=11)
    write_headerless(d, "a", lin_a)
    write_image(d / "a.png", srgb_encode(lin_a), space="srgb")
    lin_b = scene(H, W, seed=12)
    write_raw(d / "b.dng", mosaic_dn(lin_b, "RGGB", 4095), "RGGB", white_level=4095)
    # RawTherapee-like: raw minus 4 pixels each side, 16-bit TIFF
    write_image(d / "b.tif", srgb_encode(lin_b)[4:-4, 4:-4], space="srgb")
    return d


@pytest.fixture(scope="session")
def cluster():
    """Address of a two-worker local dask cluster (one thread each), shared by the tests
    of one pytest process that reach it with ``--scheduler`` / ``scheduler=``."""
    import logging

    from distributed import LocalCluster

    # this scheduler lives in the test process, where the CLI's log handler is:
    # keep its INFO chatter (it outlives each command's client) out of the output
    dlog = logging.getLogger("distributed")
    old = dlog.level
    dlog.setLevel(logging.ERROR)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0", silence_logs=logging.ERROR,
                      env={"NUMBA_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}) as c:
        yield c.scheduler_address
    dlog.setLevel(old)


@pytest.fixture(scope="session", autouse=True)
def one_blas_thread():
    """One BLAS thread per pytest process: ``make test`` runs a worker per core, and a
    second BLAS thread would only wait for a core (a spinning OpenBLAS thread made a
    lens-shading fit's small solves 10x slower). Results do not depend on it."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
