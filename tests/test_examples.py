"""The compact Infinite-ISP tutorial set bundled in ``examples/infinite_isp`` (issue 15, part 6)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from l3cli.io.image import read_image
from l3cli.io.raw import read_raw
from l3cli.metrics.macbeth import chart_patches_from_corners, patch_means
from l3cli.pairs import find_pairs

ROOT = Path(__file__).resolve().parent.parent
EX = ROOT / "examples" / "infinite_isp"
SHARED = ROOT.parent / "shared" / "data" / "raw" / "infinite_isp"
CHARTS = json.loads((EX / "charts.json").read_text())["frames"]


def test_example_set_is_small_and_licensed():
    total = sum(f.stat().st_size for f in EX.rglob("*") if f.is_file())
    assert total < 9_000_000
    assert "Apache License" in (EX / "LICENSE-Apache-2.0.txt").read_text()
    assert (EX / "NOTICE.txt").exists()
    # frames/ pairs up three training crops; holdout/ two evaluation crops
    assert len(find_pairs([EX / "frames"])) == 3
    assert len(find_pairs([EX / "holdout"])) == 2


@pytest.mark.parametrize("name", sorted(CHARTS))
def test_crop_reads_and_chart_in_view(name):
    info = CHARTS[name]
    raw = read_raw(EX / info["folder"] / f"{name}.tif")
    render, _ = read_image(EX / info["folder"] / f"{name}.png")
    assert raw.shape == render.shape[:2] == (768, 1024)
    assert raw.cfa.spec.replace("/", "") == "GRBG"
    boxes = chart_patches_from_corners(info["corners"], image_shape=render.shape)
    lum = patch_means(render, boxes, fraction=0.5).mean(axis=1)
    # shifted corners still land on the chart: white (18) brightest, black (23) darkest
    assert int(np.argmax(lum)) == 18 and int(np.argmin(lum)) == 23


@pytest.mark.skipif(not SHARED.exists(), reason="full frames not available")
@pytest.mark.parametrize("name", sorted(CHARTS))
def test_crop_matches_full_frame(name):
    info = CHARTS[name]
    x0, y0, w, h = info["crop_xywh"]
    stem = info["source"]
    crop = read_raw(EX / info["folder"] / f"{name}.tif")
    ref = read_raw(SHARED / info["folder"] / f"{stem}.raw")
    np.testing.assert_array_equal(crop.mosaic, ref.mosaic[y0:y0 + h, x0:x0 + w])
    render, _ = read_image(EX / info["folder"] / f"{name}.png")
    full, _ = read_image(SHARED / info["folder"] / f"{stem}.png")
    np.testing.assert_array_equal(render, full[y0:y0 + h, x0:x0 + w])
