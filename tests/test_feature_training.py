"""Every table feature through training's paths: self-tuning, and self-tuning on a
dask cluster (issues 39 and 40: "a feature is done when it travels").

The companion of ``test_feature_matrix.py`` (render to every format, export,
inspect). For each feature of the product's list (:data:`l3cli.features.FEATURES`)
``TRAIN`` names the options of :func:`l3cli.train` that learn it; the feature is
trained from one small pairs folder (three DNGs of three ISOs, an as-shot white,
colour lens shading) with self-tuning (the feature's option held fixed, the rest
of a small grid searched), once in this process and once on a two-worker dask
cluster (``scheduler=``, as ``l3 train --scheduler``). Each case checks:

- the table holds the feature (:func:`l3cli.features.table_features`), and the
  tuning record says it was tuned;
- the cluster's table is this process's, array for array (the provenance but for
  the search's wall time).

A feature added to the list without an entry here fails
:func:`test_every_feature_has_training_options`.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import l3cli
from l3cli.colourspace import srgb_encode
from l3cli.features import FEATURES, table_features
from l3cli.io.image import write_image
from l3cli.io.raw import write_raw
from l3cli.train.tune import TuneGrid
from tests.builders import mosaic_dn

#: feature name -> the options of l3cli.train (l3 train's flags) that learn it
TRAIN: dict[str, dict] = {
    "lens shading": dict(shading=True),
    "lens shading grid": None,  # the same training: the data chooses the field's kind
    "patch 9": dict(patch=9),
    "orientation bins": dict(orientation_bins=4),
    "context bins": dict(context_block=16),
    "highlight bins": dict(highlight_bins=2),
    "condition bins": dict(by="iso"),
    "white balance": dict(as_shot_wb=True),
    "tone curve": dict(tone_curve=True),
    "multiscale stage": dict(multiscale=True),
}
#: features whose kind the data chooses, not an option: either kind is accepted
FAMILY = {"lens shading": {"lens shading", "lens shading grid"}}
#: small and quick: a few levels, one contrast bin, two folds, one target space
BASE = dict(patch=5, levels=4, contrast_bins=1, level_range=(0.02, 0.6), seed=1, tune=True)
GRID = TuneGrid(spaces=("xyz",), patches=(5,), shading=(False,), multiscale=(False,), folds=2)
ISOS = (100, 400, 1600)
H, W = 192, 256


def _chart(h: int, w: int, seed: int) -> np.ndarray:
    """Linear RGB: flat patches of 32 x 32 pixels (lens shading and the tone curve are
    learned from flat blocks) with a few sharp-edged discs across them (texture)."""
    rng = np.random.default_rng(seed)
    cols = rng.uniform(0.03, 0.85, size=(h // 32 + 1, w // 32 + 1, 3))
    img = np.repeat(np.repeat(cols, 32, axis=0), 32, axis=1)[:h, :w].astype(np.float32)
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(6):
        cy, cx, r = rng.integers(0, h), rng.integers(0, w), rng.integers(4, 12)
        img[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = rng.uniform(0.03, 0.85, 3)
    return img


def _shading(h: int, w: int) -> np.ndarray:
    """A colour lens fall-off, off centre (R to 0.6, B to 0.75 in the far corner)."""
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((yy - 0.4 * h) / h) ** 2 + ((xx - 0.45 * w) / w) ** 2
    r2 = r2 / r2.max()
    return np.stack([1 - 0.4 * r2, 1 - 0.15 * r2, 1 - 0.25 * r2], axis=-1).astype(np.float32)


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """Three raw + render pairs: ISOs 100, 400, 1600, an as-shot white, lens shading on
    the raws; the renders unshaded, with a tone curve of their own."""
    folder = tmp_path_factory.mktemp("features") / "pairs"
    folder.mkdir()
    fall = _shading(H, W)
    for i, iso in enumerate(ISOS):
        lin = _chart(H, W, seed=60 + i)
        wb = np.array([0.5, 1.0, 0.7])  # camera RGB of a white
        dn = mosaic_dn(np.clip(lin * fall * wb, 0, 1), "RGGB", 4095)
        write_raw(folder / f"p{i}.dng", dn, "RGGB", white_level=4095,
                  as_shot_neutral=wb, shot={"iso": iso})
        tone = np.clip(lin, 0, 1) ** 0.8  # a camera's tone curve: not the sRGB one
        write_image(folder / f"p{i}.png", srgb_encode(tone), space="srgb")
    return folder


def test_every_feature_has_training_options():
    assert sorted(TRAIN) == sorted(f.name for f in FEATURES)


def _cases():
    for name in (n for n, opts in TRAIN.items() if opts is not None):
        marks = [pytest.mark.slow] if name == "patch 9" else []  # a kernel compile
        yield pytest.param(name, marks=marks, id=name)


def _arrays(table) -> dict:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path = table.save(Path(tmp) / "t.npz")
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(_cases()))
def test_feature_trains_tuned_and_on_a_cluster(pairs, cluster, name):
    opts = {**BASE, **TRAIN[name]}
    if name == "patch 9":
        opts["tune_grid"] = TuneGrid(spaces=("xyz",), patches=(9,), shading=(False,),
                                     multiscale=(False,), folds=2)
    else:
        opts["tune_grid"] = GRID
    local = l3cli.train(pairs, **opts)
    held = {f.name for f in table_features(local)}
    assert held & FAMILY.get(name, {name}), (name, held)
    assert local.tuning is not None and local.tuning["candidates"]
    remote = l3cli.train(pairs, scheduler=cluster, **opts)
    a, b = _arrays(local), _arrays(remote)
    assert sorted(a) == sorted(b)
    for k in a:
        if k != "provenance":
            assert a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes(), k
    pa, pb = json.loads(str(a["provenance"])), json.loads(str(b["provenance"]))
    pa["tune"].pop("seconds")
    pb["tune"].pop("seconds")
    assert pa == pb
