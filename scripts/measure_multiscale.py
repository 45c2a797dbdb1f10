"""Measure ``l3 train --multiscale`` on simulated ISO 3200 captures (issue 27).

Usage::

    .venv/bin/python scripts/measure_multiscale.py WORKDIR [--train-opts "..."]

1. a camera: ``sample_configs/bayer.toml`` with ``analog_gain = 32`` (ISO 3200 on a
   base-ISO-100 sensor: the full well seen by the ADC falls from 10000 to 312 e-, so
   auto exposure lands mid-grey at ~55 e- and the raws are very noisy);
2. ``l3 simulate``: training captures (seed 0; Macbeth + the bundled photos at 100 and
   1000 lux) and test captures (seed 1, new noise; 100 lux);
3. ``l3 train`` on the training folder without and with ``--multiscale``; the ideal
   targets are the reference (the limit of a wide denoiser: noise-free, edges intact);
4. ``l3 render`` of the test raws to EXR by each table, ``l3 evaluate`` against the test
   folder (S-CIELAB, Macbeth ΔE), and the *flat-region noise*: the standard deviation
   of the render in the central half (by side) of each of the 24 Macbeth patches, mean
   over channels and patches (the table's output space, XYZ).

With ``--pairs`` the captures become pairs folders first (each raw beside its ideal
target written as an 8-bit display-sRGB PNG, as a camera's JPEG would be), so the
tables are trained and scored as a real camera's are: the pairs layout (patch 7,
linear-sRGB target, tone curve), registration of the renders on the raws, references
in display sRGB; the flat-region noise is then measured in linear sRGB.

Prints one Markdown table; the numbers are in docs/training.md ("Noise reduction
beyond the patch").
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def l3(*args: str) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "l3cli.cli.main", "-q", *args], check=True)
    return time.perf_counter() - t0


def flat_noise(render_dir: Path, test_dir: Path) -> float:
    from l3cli.io.image import read_image

    man = json.loads((test_dir / "manifest.json").read_text())
    stds = []
    for cap in man["captures"]:
        if not cap.get("chart"):
            continue
        img = read_image(render_dir / f"{cap['stem']}.exr")[0]
        for x0, y0, x1, y1 in cap["chart"]["patches"]:
            mw, mh = (x1 - x0) // 4, (y1 - y0) // 4
            patch = img[y0 + mh:y1 - mh, x0 + mw:x1 - mw].reshape(-1, img.shape[2])
            stds.append(patch.std(axis=0).mean())
    return float(np.mean(stds))


def as_pairs(sim: Path, out: Path) -> Path:
    """A pairs folder of a simulate folder's captures: ``STEM.dng`` + ``STEM.png`` (ideal target)."""
    import shutil

    from l3cli.io.image import read_image, write_image

    if (out / "done").exists():
        return out
    out.mkdir(parents=True, exist_ok=True)
    man = json.loads((sim / "manifest.json").read_text())
    for cap in man["captures"]:
        shutil.copy(sim / cap["raw"], out / f"{cap['stem']}.dng")
        target, space = read_image(sim / cap["target"])
        write_image(out / f"{cap['stem']}.png", target, space=space)
    (out / "done").write_text("")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("workdir", type=Path)
    ap.add_argument("--train-opts", default="", help="extra l3 train options (both tables)")
    ap.add_argument("--gain", type=float, default=32.0)
    ap.add_argument("--pairs", action="store_true",
                    help="train and score as pairs folders (display-sRGB PNG targets)")
    args = ap.parse_args()
    w = args.workdir
    w.mkdir(parents=True, exist_ok=True)
    toml = w / "iso3200.toml"
    text = (ROOT / "sample_configs" / "bayer.toml").read_text()
    text, n = re.subn(r"(?m)^analog_gain = [0-9.]+", f"analog_gain = {args.gain}", text)
    assert n == 1, "sample_configs/bayer.toml has no analog_gain line"
    toml.write_text(text)
    train, test = w / "train", w / "test"
    if not (train / "manifest.json").exists():
        l3("simulate", str(toml), "-o", str(train), "--lux", "100", "--lux", "1000",
           "--seed", "0")
    if not (test / "manifest.json").exists():
        l3("simulate", str(toml), "-o", str(test), "--lux", "100", "--seed", "1")
    ref = test
    if args.pairs:
        train, ref = as_pairs(train, w / "train_pairs"), as_pairs(test, w / "test_pairs")
    extra = shlex.split(args.train_opts)
    rows = []
    for name, flag in (("today (no stage)", "--no-multiscale"), ("--multiscale", "--multiscale")):
        tag = "ms" if flag == "--multiscale" else "base"
        table = w / f"{tag}.npz"
        t_train = l3("train", str(train), flag, *extra, "-o", str(table))
        out = w / f"render_{tag}"
        raws = sorted(str(p) for p in test.glob("*.dng"))
        t_render = l3("render", str(table), *raws, "-o", str(out), "--format", "exr")
        report = w / f"{tag}.json"
        l3("evaluate", str(out), "--reference", str(ref), "--json", str(report))
        summary = json.loads(report.read_text())["summary"]
        rows.append((name, flat_noise(out, test), summary["scielab_mean"],
                     summary.get("macbeth_de_mean", float("nan")), t_train, t_render))
    base = rows[0][1]
    print("| table | flat-region noise (std) | ratio | S-CIELAB mean | Macbeth ΔE*ab "
          "| train s | render s |")
    print("|---|---|---|---|---|---|---|")
    for name, noise, sc, mb, tt, tr in rows:
        print(f"| {name} | {noise:.5f} | {noise / base:.2f} | {sc:.3f} | {mb:.3f} "
              f"| {tt:.1f} | {tr:.1f} |")


if __name__ == "__main__":
    main()
