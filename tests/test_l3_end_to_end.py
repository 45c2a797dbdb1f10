"""End to end: simulate → train → render a Macbeth capture at an unseen light level.

Mean ΔE*ab (CIE 1976, colour-science) of the 24 patch means against the ideal
chart XYZ from the manifest must be <= 3.0, for a Bayer and an RGBW camera.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.colourspace import convert
from l3cli.io.image import read_image
from tests.builders import REPO


def _patch_means(img, boxes):
    out = []
    for x0, y0, x1, y1 in boxes:  # central half of each patch, away from edges
        w, h = x1 - x0, y1 - y0
        out.append(img[y0 + h // 4 : y1 - h // 4, x0 + w // 4 : x1 - w // 4].reshape(-1, 3).mean(0))
    return np.array(out)


@pytest.mark.slow
@pytest.mark.parametrize("camera", ["bayer.toml", "rgbw.toml"])
def test_macbeth_delta_e_at_unseen_light_level(runner, tmp_path, camera):
    import colour

    cfg = str(REPO / "sample_configs" / camera)
    train_dir, test_dir = tmp_path / "train", tmp_path / "test"
    size = ["--size", "240x160"]
    res = runner.invoke(cli, ["-q", "simulate", cfg, "-o", str(train_dir), "--scene", "macbeth",
                              "--scene", "natural", "--lux", "20", "--lux", "200", "--lux",
                              "2000", "--seed", "1", *size])
    assert res.exit_code == 0, res.output
    res = runner.invoke(cli, ["-q", "simulate", cfg, "-o", str(test_dir), "--scene", "macbeth",
                              "--lux", "500", "--seed", "2", *size])
    assert res.exit_code == 0, res.output
    table = tmp_path / "table.npz"
    res = runner.invoke(cli, ["-q", "train", str(train_dir), "-o", str(table), "--seed", "1"])
    assert res.exit_code == 0, res.output
    cap = json.loads((test_dir / "manifest.json").read_text())["captures"][0]
    out = tmp_path / "render.exr"
    res = runner.invoke(cli, ["-q", "render", str(table), str(test_dir / cap["raw"]), "-o", str(out)])
    assert res.exit_code == 0, res.output
    img, space = read_image(out)
    assert space == "xyz" and img.shape == (cap["height"], cap["width"], 3)
    chart = cap["chart"]
    measured = _patch_means(convert(img, space, "xyz"), chart["patches"])
    ideal = np.asarray(chart["reference_xyz"])
    white = ideal[chart["white_index"]]
    wp = colour.XYZ_to_xy(white)
    de = colour.delta_E(colour.XYZ_to_Lab(measured / white[1], wp),
                        colour.XYZ_to_Lab(ideal / white[1], wp), method="CIE 1976")
    print(f"{camera}: mean dE*ab {de.mean():.2f}, max {de.max():.2f}")
    assert de.mean() <= 3.0, np.round(de, 2)
