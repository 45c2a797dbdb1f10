"""Regenerate the golden fixture used by ``tests/render/test_golden.py``.

Run from the repository root::

    .venv/bin/python tests/data/golden/make_golden.py            # outputs only
    .venv/bin/python tests/data/golden/make_golden.py --inputs   # also re-simulate

The inputs (two tiny ``l3 simulate`` folders of a Bayer camera, seeds 1 and 2)
are committed so that the fixture does not depend on the simulator. The
outputs are what ``l3 train``, ``l3 render`` and ``l3 evaluate`` make of
them: ``table.npz`` (compared array by array: a zip holds a time stamp),
``render/*.exr`` and ``report.json`` (compared byte for byte). Regenerate
the outputs only when a change is *meant* to alter them, and say so in the
commit message.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
CAMERA = REPO / "sample_configs" / "bayer.toml"
SIZE = "96x64"


def l3(*args: str) -> str:
    """Run one ``l3`` command in this process; its standard output, or raise."""
    from click.testing import CliRunner

    from l3cli.cli.main import cli

    res = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    if res.exit_code != 0:
        raise RuntimeError(f"l3 {' '.join(args)} failed: {res.output}")
    return res.stdout


def make_inputs() -> None:
    for name in ("train", "test"):
        shutil.rmtree(HERE / name, ignore_errors=True)
    # the noise-free images are not read by train, render or evaluate: not kept
    l3("simulate", str(CAMERA), "-o", str(HERE / "train"), "--scene", "macbeth",
       "--scene", "natural:astronaut", "--lux", "30", "--lux", "300", "--size", SIZE,
       "--seed", "1")
    l3("simulate", str(CAMERA), "-o", str(HERE / "test"), "--scene", "macbeth",
       "--scene", "slanted-edge", "--lux", "100", "--size", SIZE, "--seed", "2")
    for p in HERE.glob("*/*.noisefree.exr"):
        p.unlink()


def make_outputs(out: Path) -> None:
    """Train, render and evaluate into ``out`` (the test calls this too)."""
    out.mkdir(parents=True, exist_ok=True)
    table = out / "table.npz"
    l3("train", str(HERE / "train"), "-o", str(table), "--seed", "1", "--levels", "6")
    raws = sorted(str(p) for p in (HERE / "test").glob("*.dng"))
    shutil.rmtree(out / "render", ignore_errors=True)
    (out / "render").mkdir()
    l3("render", str(table), *raws, "-o", str(out / "render"))
    text = l3("evaluate", str(out / "render"), "--reference", str(HERE / "test"),
              "--json", str(out / "report.json"))
    (out / "report.txt").write_text(text, encoding="utf-8")


if __name__ == "__main__":
    if "--inputs" in sys.argv[1:]:
        make_inputs()
    make_outputs(HERE)
