#!/usr/bin/env python3
"""White balance as an input, on simulated data (issue 15, part 1).

    scripts/wb_experiment.py OUT_DIR [--size WxH] [--l3 L3]

The same scenes are simulated (``l3 simulate``, Bayer sample camera) under
several illuminants and rendered by a reference raw converter that does what
converters do with a DNG (:func:`converter`): Menon (2007) demosaic of the
white-balanced mosaic (gains ``1 / AsShotNeutral``), the DNG's camera matrix
(inverse ColorMatrix1), a Bradford chromatic adaptation from the shot's white
(the camera neutral taken through that matrix) to D65, and XYZ → linear sRGB;
the render is a linear-sRGB EXR next to the DNG (a pairs folder).

Three experiments, each trained on the three scenes astronaut, coffee and
chelsea and scored (``l3 evaluate``, S-CIELAB ΔE*ab at the defaults) on the
two others, rocket and macbeth:

``mixed-wb``
    train under A, FL2, D50 and D75; test under D65, LED-B3 and FL11 — with the
    white-balance handling (``--as-shot-wb``, the default for such pairs);
``mixed-nowb``
    the same data with ``--no-as-shot-wb`` (the old behaviour);
``fixed``
    the control: train and test under D65 alone.

Prints one JSON object with the mean S-CIELAB of each.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

TRAIN_SCENES = ("astronaut", "coffee", "chelsea")
#: The converter's demosaic (colour-demosaicing): not linear, so not learned exactly.
DEMOSAIC = "menon2007"
TEST_SCENES = ("rocket", "macbeth")
D65_XYZ = np.array([0.95047, 1.0, 1.08883])
XYZ_TO_LINEAR_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                               [-0.9692660, 1.8760108, 0.0415560],
                               [0.0556434, -0.2040259, 1.0572252]])


def _dng_colour(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """ColorMatrix1 (XYZ → camera) and AsShotNeutral of a DNG (tifffile)."""
    import tifffile

    with tifffile.TiffFile(path) as tf:
        tags = tf.pages[0].tags
        cm = np.array(tags["ColorMatrix1"].value, dtype=float).reshape(-1, 2)
        cm = (cm[:, 0] / cm[:, 1]).reshape(3, 3)
        n = np.array(tags["AsShotNeutral"].value, dtype=float).reshape(-1, 2)
    return cm, n[:, 0] / n[:, 1]


def converter(dng: Path) -> np.ndarray:
    """The reference rendering of a DNG: linear sRGB, float32 (H, W, 3)."""
    from colour.adaptation import matrix_chromatic_adaptation_VonKries

    from l3cli.baseline import demosaic
    from l3cli.io.raw import RawImage, read_raw

    raw = read_raw(dng)
    cm, neutral = _dng_colour(dng)
    neutral = neutral / neutral[1]
    gains = 1.0 / neutral
    chan = np.array([[gains["RGB".index(raw.cfa.channel_at(y, x))] for x in range(2)]
                     for y in range(2)], dtype=np.float32)
    h, w = raw.mosaic.shape
    wb = raw.mosaic * np.tile(chan, (h // 2 + 1, w // 2 + 1))[:h, :w]
    cam_wb = demosaic(RawImage(mosaic=wb, cfa=raw.cfa, black_level=raw.black_level,
                               white_level=raw.white_level), method=DEMOSAIC)
    cam_to_xyz = np.linalg.inv(cm)
    white = cam_to_xyz @ neutral
    cat = matrix_chromatic_adaptation_VonKries(white / white[1], D65_XYZ, transform="Bradford")
    m = XYZ_TO_LINEAR_SRGB @ cat @ cam_to_xyz @ np.diag(neutral)
    return np.einsum("ij,hwj->hwi", m, cam_wb).astype(np.float32)


def make_pairs(sim: Path, pairs: Path) -> None:
    """Turn a simulate folder into a pairs folder of DNG + reference EXR."""
    import shutil

    from l3cli.io.image import write_image

    pairs.mkdir(parents=True, exist_ok=True)
    for dng in sorted(sim.glob("*.dng")):
        shutil.copy(dng, pairs / dng.name)
        write_image(pairs / f"{dng.stem}.exr", converter(dng), space="linear-srgb")


def simulate(l3: str, out: Path, illuminants: list[str], scenes: tuple[str, ...], size: str,
             seed: int) -> Path:
    """Simulate ``scenes`` under each illuminant into one pairs folder."""
    out.mkdir(parents=True, exist_ok=True)
    pairs = out / "pairs"
    if pairs.exists():
        return pairs
    for ill in illuminants:
        sim = out / f"sim_{ill}"
        if not sim.exists():
            cmd = [l3, "-q", "simulate", str(Path(__file__).parent.parent / "sample_configs" /
                                              "bayer.toml"), "-o", str(sim),
                   "--illuminant", ill, "--lux", "500", "--size", size, "--seed", str(seed)]
            for s in scenes:
                cmd += ["--scene", s if s == "macbeth" else f"natural:{s}"]
            subprocess.run(cmd, check=True)
        make_pairs(sim, pairs)
    return pairs


def score(l3: str, table: Path, test: Path, out: Path, train_opts: list[str]) -> float:
    """Render the test DNGs and return the mean S-CIELAB against their references."""
    renders = out / "renders"
    dngs = sorted(str(p) for p in test.glob("*.dng"))
    subprocess.run([l3, "-q", "render", str(table), *dngs, "-o", str(renders), "--format", "exr"],
                   check=True)
    rep = out / "eval.json"
    refs = [str(test / f"{Path(d).stem}.exr") for d in dngs]
    outs = [str(renders / f"{Path(d).stem}.exr") for d in dngs]
    subprocess.run([l3, "-q", "evaluate", *outs, "--reference", *refs, "--json", str(rep),
                    "--exclude-border", "4"], check=True)
    return float(json.loads(rep.read_text())["summary"]["scielab_mean"])


def run(out: Path, *, l3: str = "l3", size: str = "320x240", seed: int = 1,
        only: tuple[str, ...] | None = None,
        train_opts: tuple[str, ...] = ()) -> dict[str, float]:
    """Run the experiments (all, or those named in ``only``); returns their mean S-CIELAB.

    ``train_opts``: extra ``l3 train`` options for every run.
    """
    out.mkdir(parents=True, exist_ok=True)
    sets = {
        "mixed_train": (["A", "FL2", "D50", "D75"], TRAIN_SCENES),
        "mixed_test": (["D65", "LED-B3", "FL11"], TEST_SCENES),
        "fixed_train": (["D65"], TRAIN_SCENES),
        "fixed_test": (["D65"], TEST_SCENES),
    }
    base = ["--target", "linear-srgb", "--seed", "1", *train_opts]
    runs = {"mixed-wb": ("mixed_train", "mixed_test", []),  # the default for such pairs
            "mixed-nowb": ("mixed_train", "mixed_test", ["--no-as-shot-wb"]),
            "fixed": ("fixed_train", "fixed_test", ["--as-shot-wb"]),
            "fixed-nowb": ("fixed_train", "fixed_test", ["--no-as-shot-wb"])}
    runs = {k: v for k, v in runs.items() if only is None or k in only}
    needed = {f for tr, te, _ in runs.values() for f in (tr, te)}
    folders = {k: simulate(l3, out / k, ills, scenes, size, seed + i)
               for i, (k, (ills, scenes)) in enumerate(sets.items()) if k in needed}
    result: dict[str, float] = {}
    for name, (tr, te, opts) in runs.items():
        d = out / name
        d.mkdir(exist_ok=True)
        table = d / "table.npz"
        subprocess.run([l3, "-q", "train", str(folders[tr]), "-o", str(table), *base, *opts],
                       check=True)
        result[name] = score(l3, table, folders[te], d, opts)
    return result


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--l3", default=str(Path(sys.executable).parent / "l3"))
    a = ap.parse_args()
    print(json.dumps(run(a.out, l3=a.l3, size=a.size), indent=1))
