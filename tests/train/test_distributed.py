"""`l3 train/render/simulate --workers/--scheduler`: same results as in process.

The cluster tests share one local dask cluster (module fixture) reached with
``--scheduler``; ``--workers`` (a cluster started by the command) is exercised
with one worker, as on a small machine.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.io.image import read_image, write_image
from l3cli.io.raw import write_raw
from l3cli.train import ClassStats, TrainOptions, accumulate, find_pairs, load_pair
from l3cli.train.fit import collect_stats, define_classes, sample_mask, stats_task
from tests.builders import H, W, mosaic_dn, scene, sim_dir

REPO = Path(__file__).resolve().parents[2]
BAYER = str(REPO / "sample_configs" / "bayer.toml")
SIM_ARGS = ["--scene", "macbeth", "--scene", "natural:coffee", "--lux", "40", "--lux", "400",
            "--size", "96x64", "--seed", "7"]


def no_leftovers(folder: Path) -> bool:
    return not any(p.name.startswith(".l3-tmp") for p in folder.iterdir())


def npz_equal(a: Path, b: Path) -> None:
    """Every array of two NPZ files is identical (provenance text included)."""
    with np.load(a, allow_pickle=False) as za, np.load(b, allow_pickle=False) as zb:
        assert sorted(za.files) == sorted(zb.files)
        for k in za.files:
            np.testing.assert_array_equal(za[k], zb[k], err_msg=k)


def npz_equal_but_tune_time(a: Path, b: Path) -> None:
    """:func:`npz_equal`, the provenance compared as JSON without the search's wall time
    (``tune.seconds``: two runs never take the same time)."""
    with np.load(a, allow_pickle=False) as za, np.load(b, allow_pickle=False) as zb:
        assert sorted(za.files) == sorted(zb.files)
        for k in za.files:
            if k != "provenance":
                assert za[k].tobytes() == zb[k].tobytes() and za[k].dtype == zb[k].dtype, k
        pa, pb = json.loads(str(za["provenance"])), json.loads(str(zb["provenance"]))
        assert pa["tune"].pop("seconds") >= 0 and pb["tune"].pop("seconds") >= 0
        assert pa == pb


def ran_on(address: str, task: str) -> bool:
    """Whether the scheduler at ``address`` has run tasks of the function ``task``."""
    from distributed import Client

    with Client(address, timeout="5s") as c:
        return c.run_on_scheduler(lambda dask_scheduler: task in dask_scheduler.task_prefixes)


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """Four simulated captures (macbeth, coffee x 40, 400 lux), made in process."""
    from click.testing import CliRunner

    out = tmp_path_factory.mktemp("dist") / "sim"
    r = CliRunner().invoke(cli, ["-q", "simulate", BAYER, "-o", str(out), *SIM_ARGS])
    assert r.exit_code == 0, r.output
    return out


def _train(runner, inputs, out, *extra):
    r = runner.invoke(cli, ["-q", "train", *map(str, inputs), "-o", str(out), "--levels", "6",
                            *extra])
    assert r.exit_code == 0, r.output
    return out


# ------------------------------------------------------------- in process
def test_statistics_are_the_ordered_sum_of_per_input_tasks(tmp_path):
    """collect_stats == the per-input statistics (full arrays) added in input order,
    bit for bit, although each task returns only its classes with samples; and
    it equals one running accumulation over all inputs to float64 rounding."""
    sim = sim_dir(tmp_path, n=3, shape=(40, 48), seed=4)
    pairs = find_pairs([sim])
    opts = TrainOptions(levels=4, sample_fraction=0.6, seed=9)
    d = define_classes(pairs, opts)
    got = collect_stats(pairs, d, opts)
    per_input, running = [], ClassStats.zeros(d, 3)
    for i, p in enumerate(pairs):
        loaded = load_pair(p)
        raw, target = loaded.raw, loaded.target
        mask = sample_mask(raw.mosaic.shape, 0.6, 9, i)
        one = ClassStats.zeros(d, 3)
        accumulate(one, raw.mosaic, target, mask=mask)
        per_input.append(one)
        accumulate(running, raw.mosaic, target, mask=mask)
        part = stats_task((i, p, d, opts))
        assert 0 < part.classes.size < d.n_classes  # only the classes this input reaches
        np.testing.assert_array_equal(part.classes, np.flatnonzero(one.n))
    dense = (per_input[0] + per_input[1]) + per_input[2]
    for k in ("n", "xtx", "xty", "yy"):
        np.testing.assert_array_equal(getattr(got, k), getattr(dense, k))
    np.testing.assert_array_equal(got.n, running.n)
    np.testing.assert_allclose(got.xtx, running.xtx, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got.xty, running.xty, rtol=1e-12, atol=1e-12)
    # and a split list with index_offset adds up to the whole
    part = collect_stats(pairs[:1], d, opts) + collect_stats(pairs[1:], d, opts, index_offset=1)
    np.testing.assert_array_equal(part.n, got.n)
    np.testing.assert_allclose(part.xtx, got.xtx, rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------- on a cluster
@pytest.mark.slow
def test_simulate_on_cluster_is_identical(runner, sim, cluster, tmp_path):
    out = tmp_path / "sim"
    r = runner.invoke(cli, ["-q", "simulate", BAYER, "-o", str(out), *SIM_ARGS,
                            "--scheduler", cluster])
    assert r.exit_code == 0, r.output
    assert ran_on(cluster, "capture_task")
    assert (out / "manifest.json").read_text() == (sim / "manifest.json").read_text()
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in sim.iterdir())
    caps = json.loads((sim / "manifest.json").read_text())["captures"]
    assert len(caps) == 4
    for f in sim.iterdir():  # every file (DNG, EXR targets, noise-free) byte for byte
        assert (out / f.name).read_bytes() == f.read_bytes(), f.name
    assert no_leftovers(tmp_path)


@pytest.mark.slow
def test_simulate_failure_on_cluster_leaves_nothing(runner, cluster, tmp_path):
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"not a png at all")
    out = tmp_path / "sim"
    r = runner.invoke(cli, ["simulate", BAYER, "-o", str(out), "--scene", "macbeth",
                            "--scene", str(bad), "--lux", "100", "--size", "64x48",
                            "--scheduler", cluster])
    assert r.exit_code == 1
    assert "broken.png" in r.output and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1
    assert not out.exists() and no_leftovers(tmp_path)


@pytest.mark.slow
def test_train_on_cluster_equals_in_process_simulate_folder(runner, sim, cluster, tmp_path):
    extra = ["--sample-fraction", "0.5", "--seed", "3"]  # histogram pass + sampled pixels
    local = _train(runner, [sim], tmp_path / "local.npz", *extra)
    dist = _train(runner, [sim], tmp_path / "dist.npz", *extra, "--scheduler", cluster)
    assert ran_on(cluster, "histogram_task") and ran_on(cluster, "stats_task")
    npz_equal(local, dist)


@pytest.mark.slow
def test_train_with_one_local_worker_equals_in_process_pairs_folder(runner, tmp_path):
    from l3cli.colourspace import srgb_encode

    d = tmp_path / "pairs"
    d.mkdir()
    for stem, seed, crop in (("x", 41, 0), ("y", 42, 4)):
        lin = scene(H, W, seed=seed)
        write_raw(d / f"{stem}.dng", mosaic_dn(lin, "RGGB", 4095), "RGGB", white_level=4095)
        write_image(d / f"{stem}.png", srgb_encode(lin)[crop:H - crop, crop:W - crop],
                    space="srgb")
    extra = ["--patch", "3", "--levels", "4", "--no-tune"]
    local = _train(runner, [d], tmp_path / "local.npz", *extra)
    dist = _train(runner, [d], tmp_path / "dist.npz", *extra, "--workers", "1")
    npz_equal(local, dist)


@pytest.mark.slow
def test_tuned_pairs_folder_on_cluster_equals_one_process(runner, cluster, tmp_path):
    """The default training of a pairs folder self-tunes on the cluster (the units'
    statistics and every candidate's folds are tasks there) and writes the table one
    process writes, every array byte for byte (the provenance but for the wall time)."""
    from tests.builders import tune_pairs

    folder = tune_pairs(tmp_path / "p", {"a": (5, 1.0), "b": (6, 1.0), "c": (7, 1.0)})
    extra = ["--levels", "4", "--contrast-bins", "1", "--level-range", "0.02", "0.6",
             "--patch", "5", "--seed", "1"]  # small: spaces, shading, multi-scale searched
    local = _train(runner, [folder], tmp_path / "a.npz", *extra)
    dist = _train(runner, [folder], tmp_path / "b.npz", *extra, "--scheduler", cluster)
    npz_equal_but_tune_time(local, dist)
    assert len(json.loads(str(np.load(dist)["provenance"]))["tune"]["candidates"]) >= 3
    assert ran_on(cluster, "score_fold_task") and ran_on(cluster, "unit_stats_task")
    assert ran_on(cluster, "multiscale_fold_task")


@pytest.mark.slow
def test_render_on_cluster_is_identical(runner, sim, cluster, tmp_path):
    table = _train(runner, [sim], tmp_path / "t.npz")
    raws = sorted(map(str, sim.glob("*.dng")))
    outs = {}
    for name, extra in (("local", []), ("dist", ["--scheduler", cluster])):
        r = runner.invoke(cli, ["-q", "render", str(table), *raws, "-o",
                                str(tmp_path / name), *extra])
        assert r.exit_code == 0, r.output
        outs[name] = tmp_path / name
    names = sorted(p.name for p in outs["local"].iterdir())
    assert names == sorted(p.name for p in outs["dist"].iterdir()) and len(names) == 4
    assert ran_on(cluster, "render_task")
    for n in names:
        assert read_image(outs["dist"] / n)[1] == "xyz"
        assert (outs["dist"] / n).read_bytes() == (outs["local"] / n).read_bytes(), n
    assert no_leftovers(outs["dist"])


@pytest.mark.slow
def test_failing_train_job_leaves_no_table(runner, cluster, tmp_path):
    sim = sim_dir(tmp_path, n=3, nan=True)  # the last target holds a NaN
    out = tmp_path / "t.npz"
    r = runner.invoke(cli, ["train", str(sim), "-o", str(out), "--levels", "4",
                            "--scheduler", cluster])
    assert r.exit_code == 1
    assert "cap2.target.exr" in r.output and "NaN" in r.output
    assert "Traceback" not in r.output and len(r.output.strip().splitlines()) == 1
    assert not out.exists() and no_leftovers(tmp_path)


@pytest.mark.slow
def test_unreachable_scheduler_leaves_no_table(runner, tmp_path):
    sim = sim_dir(tmp_path, n=1)
    out = tmp_path / "t.npz"
    r = runner.invoke(cli, ["train", str(sim), "-o", str(out), "--scheduler",
                            "tcp://127.0.0.1:1"])
    assert r.exit_code == 1 and "cannot reach dask scheduler tcp://127.0.0.1:1" in r.output
    assert not out.exists()


# ------------------------------------------------------------- faults
def _stats_or_die(arg):
    """stats_task, except that the worker running input 1 dies the first time."""
    marker, item = arg
    if item[0] == 1 and not Path(marker).exists():
        Path(marker).write_text("killed")
        os._exit(1)
    return stats_task(item)


@pytest.mark.slow
def test_training_statistics_survive_a_killed_worker(tmp_path):
    from l3cli.parallel import map_reduce

    sim = sim_dir(tmp_path, n=4, shape=(40, 48), seed=5)
    pairs = find_pairs([sim])
    opts = TrainOptions(levels=4)
    d = define_classes(pairs, opts)
    expect = collect_stats(pairs, d, opts)
    marker = str(tmp_path / "killed")
    items = [(marker, (i, p, d, opts)) for i, p in enumerate(pairs)]
    got = ClassStats.zeros(d, 3)
    map_reduce(_stats_or_die, items, reduce=lambda acc, part: part.add_to(got), workers=2)
    assert Path(marker).exists()  # a worker really died mid-task
    for k in ("n", "xtx", "xty", "yy"):
        np.testing.assert_array_equal(getattr(got, k), getattr(expect, k))


@pytest.mark.slow
def test_failing_job_on_local_workers_prints_one_line(tmp_path):
    """In a real process (the workers' stderr is the terminal too): a bad input
    stops `l3 train --workers 2` with one line and no traceback, and no table."""
    import subprocess
    import sys

    sim = sim_dir(tmp_path, n=3, nan=True)
    out = tmp_path / "t.npz"
    res = subprocess.run([sys.executable, "-m", "l3cli.cli.main", "train", str(sim), "-o",
                          str(out), "--levels", "4", "--workers", "2"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), res.stderr
    assert "cap2.target.exr" in lines[0] and "NaN" in lines[0]
    assert not out.exists() and no_leftovers(tmp_path)


def _fold_or_die(arg):
    """score_fold_task, except that the worker scoring fold 1 dies the first time."""
    from l3cli.train.cv import score_fold_task

    marker, item = arg
    if item[3] == [1] and not Path(marker).exists():
        Path(marker).write_text("killed")
        os._exit(1)
    return score_fold_task(item)


@pytest.mark.slow
def test_tuning_folds_survive_a_killed_worker(tmp_path):
    """A worker lost while it scores a fold: the fold is retried on the other worker,
    which holds the scattered images and statistics too; the scores are one process's."""
    from l3cli.parallel import dask_client, map_reduce
    from l3cli.train.cv import (
        fold_scores,
        histogram,
        layout_stats,
        load_cv_images,
        make_folds,
        make_units,
    )
    from tests.builders import tune_pairs

    folder = tune_pairs(tmp_path / "p", {"a": (5, 1.0), "b": (6, 1.0), "c": (7, 1.0)})
    opts = TrainOptions(target_space="linear-srgb", patch=5, levels=4, contrast_bins=1,
                        level_range=(0.02, 0.6))
    images = load_cv_images(find_pairs([folder]), opts)
    units = make_units(images)
    folds = make_folds(units, 3)
    lay = layout_stats(images, units, opts, histogram(images, opts))
    expect = fold_scores(images, units, folds, lay, opts)
    marker = str(tmp_path / "killed")
    with dask_client(workers=2) as client:
        imgs = client.scatter(images, broadcast=True, hash=False)
        remote = client.scatter(lay, broadcast=True, hash=False)
        items = [(marker, (imgs, units, remote, held, opts)) for held in folds]
        got = map_reduce(_fold_or_die, items, client=client)
    assert Path(marker).exists()  # a worker really died mid-task
    for held, sc in zip(folds, got, strict=True):
        np.testing.assert_array_equal(sc, expect[held])
