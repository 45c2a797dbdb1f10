"""The L3 paper's RGBW experiment on small data (issue 13): the 2x2 RGBW camera
vs the same camera with W replaced by G (an RGGB Bayer), each with its own
auto exposure (time up to 0.5 s, then analog gain up to 16x; black clamp),
trained on the Macbeth chart and the bundled natural photos at several light
levels and tested on the chart at light levels not used in training,
including a dim one where both cameras need gain.

Published (Jiang et al. 2017): mean Macbeth ΔE*ab 1.70 (RGBW) vs 1.65 (W→G).
The bar checked here (the issue's): RGBW no more than 15 % worse than the
Bayer, and both at most 3.0, over all test levels (docs/results.md,
experiment 2). ΔE is computed here with colour-science on the rendered patch
means, independently of ``l3 evaluate``.
"""

from __future__ import annotations

import importlib.util
import json
import sys

import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.colourspace import convert
from l3cli.io.image import read_image
from tests.builders import REPO


def _bayer_camera(path):
    """scripts/paper/cameras.py's ``bayer``: sample_configs/rgbw.toml with W -> G."""
    paper = REPO / "scripts" / "paper"
    sys.path.insert(0, str(paper))
    try:
        spec = importlib.util.spec_from_file_location("paper_cameras", paper / "cameras.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        mod.main(["bayer", str(path)])
    finally:
        sys.path.remove(str(paper))


def _macbeth_de(img, cap) -> float:
    import colour

    means = []
    for x0, y0, x1, y1 in cap["chart"]["patches"]:  # central half of each patch
        w, h = x1 - x0, y1 - y0
        means.append(img[y0 + h // 4:y1 - h // 4, x0 + w // 4:x1 - w // 4].reshape(-1, 3).mean(0))
    measured = np.asarray(means, dtype=np.float64)
    ideal = np.asarray(cap["chart"]["reference_xyz"], dtype=np.float64)
    wi = cap["chart"]["white_index"]
    measured = measured * (ideal[wi, 1] / measured[wi, 1])  # white-normalised (macbethColorError)
    wp = colour.XYZ_to_xy(ideal[wi])
    de = colour.delta_E(colour.XYZ_to_Lab(measured / ideal[wi, 1], wp),
                        colour.XYZ_to_Lab(ideal / ideal[wi, 1], wp), method="CIE 1976")
    return float(de.mean())


def _run(runner, args):
    res = runner.invoke(cli, ["-q", *map(str, args)])
    assert res.exit_code == 0, res.output
    return res


@pytest.mark.slow
def test_rgbw_vs_bayer_macbeth_delta_e_at_unseen_light_levels(runner, tmp_path):
    cams = {"rgbw": REPO / "sample_configs" / "rgbw.toml", "bayer": tmp_path / "bayer.toml"}
    _bayer_camera(cams["bayer"])
    size = ("--size", "320x240")  # experiment 2's size: at 160x120 the Bayer lands at 3.0
    test_lux = (20, 250, 900)  # 20 lux: time capped, gain 2.5x (RGBW) and 10x (Bayer)
    mean = {}
    for name, cam in cams.items():
        train, test = tmp_path / name / "train", tmp_path / name / "test"
        train.parent.mkdir()
        _run(runner, ["simulate", cam, "-o", train, "--scene", "macbeth", "--scene", "natural",
                      "--lux", 10, "--lux", 35, "--lux", 120, "--lux", 450, "--lux", 1600, "--lux", 5000,
                      "--seed", 1, *size])
        _run(runner, ["simulate", cam, "-o", test, "--scene", "macbeth",
                      *[a for x in test_lux for a in ("--lux", x)], "--seed", 2, *size])
        table = tmp_path / name / "table.npz"
        _run(runner, ["train", train, "-o", table, "--seed", 1, "--patch", 7])  # experiment 2's recipe
        des = []
        caps = json.loads((test / "manifest.json").read_text())["captures"]
        assert caps[0]["lux"] == 20 and caps[0]["analog_gain"] > 2  # the dim level needs gain
        for cap in caps:
            out = tmp_path / name / f"{cap['stem']}.exr"
            _run(runner, ["render", table, test / cap["raw"], "-o", out])
            img, space = read_image(out)
            des.append(_macbeth_de(convert(img, space, "xyz"), cap))
        mean[name] = float(np.mean(des))
    print(f"mean Macbeth dE*ab at {test_lux} lux: RGBW {mean['rgbw']:.2f}, Bayer {mean['bayer']:.2f}")
    assert mean["rgbw"] <= 1.15 * mean["bayer"], mean
    assert max(mean.values()) <= 3.0, mean
