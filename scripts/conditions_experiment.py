#!/usr/bin/env python3
"""Condition-indexed tables (``l3 train --by``) against one table, on simulated data (issue 15, part 2).

    scripts/conditions_experiment.py

Reuses the captures and reference pipelines of ``tests/test_conditions.py``
(run from the repository root): an ISO sweep whose noise grows with ISO and
whose reference denoises harder at higher ISO, trained on ISO 100, 400,
1600, 6400 and scored (RMSE) on ISO 200, 800, 3200 with two held-out scenes
-- with one or two scenes per training ISO, and with a reference whose
processing does not change with ISO; then the white-balance case (one shot
per white), one table against ``--by white-balance`` and ``--as-shot-wb``.
Prints one line per case. Takes well under a minute on one core.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from click.testing import CliRunner  # noqa: E402

import tests.test_conditions as tc  # noqa: E402
from l3cli.cli.main import cli  # noqa: E402
from l3cli.table import load_table  # noqa: E402


def _train(folder: Path, out: Path, *extra: str, levels: int = 6) -> Path:
    res = CliRunner().invoke(cli, ["-q", "train", str(folder), "-o", str(out), "--target",
                                   "linear-srgb", "--levels", str(levels), "--seed", "1", *extra])
    if res.exit_code:
        raise SystemExit(res.output)
    return out


def main() -> None:
    per_iso = tc.reference
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for case in ("per-ISO denoise", "fixed pipeline"):
            tc.reference = per_iso if case == "per-ISO denoise" else (lambda m, iso: per_iso(m, 400))
            for scenes in ((0,), (0, 1)):
                run = d / f"{case[:5]}{len(scenes)}"
                run.mkdir()
                train = tc._folder(run / "train", tc.TRAIN_ISO, scenes, seed=1)
                test = tc._folder(run / "test", tc.TEST_ISO, (2, 3), seed=2)
                _train(train, run / "single.npz")
                binned = _train(train, run / "binned.npz", "--by", "iso")
                res = CliRunner().invoke(cli, ["-q", "smooth", str(binned), "-o",
                                               str(run / "smoothed.npz")])
                if res.exit_code:
                    raise SystemExit(res.output)
                r = {n: tc._rmse(load_table(run / f"{n}.npz"), test)
                     for n in ("single", "binned", "smoothed")}
                print(f"ISO sweep, {case}, {len(scenes)} scene(s) per ISO: one table "
                      f"{r['single']:.5f}, --by iso {r['binned']:.5f}, + l3 smooth "
                      f"{r['smoothed']:.5f}", flush=True)
        tc.reference = per_iso
        train = tc._wb_folder(d / "wb-train", tc.WB_TRAIN, seed=10)
        test = tc._wb_folder(d / "wb-test", tc.WB_TEST, seed=20)
        for name, extra in (("one table", ()), ("--by white-balance", ("--by", "white-balance")),
                            ("--as-shot-wb", ("--as-shot-wb",)),
                            ("--as-shot-wb --by white-balance",
                             ("--as-shot-wb", "--by", "white-balance"))):
            t = _train(train, d / "wb.npz", *extra, levels=4)
            print(f"white balance, one shot per white: {name} {tc._rmse(load_table(t), test):.5f}",
                  flush=True)


if __name__ == "__main__":
    main()
