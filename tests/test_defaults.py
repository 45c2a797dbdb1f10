"""Every default of ``l3cli.defaults`` written out, and what the defaults buy (issue 30).

The library and the CLI read their defaults from ``l3cli.defaults``, so a test
that compares a default with ``defaults.X`` cannot see it change. Here each
value is written literally: changing a default means changing this file too,
with the measurement that justifies it (docs/training.md, "Defaults"). The
quality floor checks what the pairs-folder defaults are for: ``l3 train`` with
no options on the bundled Infinite-ISP frames, scored on the held-out frames
(used here for evaluation only, never to train or tune).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from l3cli import defaults

ROOT = Path(__file__).resolve().parent.parent
EX = ROOT / "examples" / "infinite_isp"

#: The defaults as documented (docs/training.md, docs/evaluation.md, ``--help``).
EXPECTED = {
    "AUGMENT": "none",
    "COHERENCE": 0.5,
    "CONTEXT_BINS": 3,
    "CONTEXT_BLOCK": 0,
    "CONTEXT_RULE": "ratio",
    "CONTRAST_BINS": 2,
    "DPI": 96.0,
    "HIGHLIGHT_BINS": 0,
    "HIGHLIGHT_FRACTION": 0.25,
    "LEVELS": 24,
    "LEVEL_SPACING": "log",
    "MERGE_POSITIONS": True,
    "MIN_SAMPLES_FACTOR": 3.0,
    "MULTISCALE": False,
    "MULTISCALE_ENERGY_BINS": 8,
    "MULTISCALE_LEVELS": 12,
    "MULTISCALE_RIDGE": 1e-3,
    "MULTISCALE_SIGMAS": (1.0, 3.0, 9.0),
    "ORIENTATION_BINS": 0,
    "PAIRS_LAYOUT": {"patch": 7, "levels": 24, "contrast_bins": 3, "contrast_threshold": 0.2,
                     "target_space": "linear-srgb", "tone_curve": True,
                     "augment": "none", "sample_weight": "none", "shading": True},
    "PATCH": 5,
    "SAMPLE_FRACTION": 1.0,
    "SAMPLE_WEIGHT": "none",
    "SATURATION": 0.95,
    "SCIELAB_FILTERS": "distribution",
    "SCIELAB_OPPONENT": "xyz10",
    "SEED": 0,
    "SHADING": False,
    "SIMULATION_LAYOUT": {"patch": 5, "levels": 24, "contrast_bins": 2, "contrast_threshold": None,
                          "target_space": "xyz", "tone_curve": False,
                          "augment": "none", "sample_weight": "none", "shading": False},
    "SPLINE_STRENGTH": 0.02,
    "TONE_CURVE": False,
    # self-tuning by default for pairs folders (issue 27; tests/test_tune.py checks the CLI)
    "TUNE_GRID": {"spaces": None, "patches": (7, 9), "levels": (), "contrast_bins": (),
                  "contrast_thresholds": (), "augments": (), "sample_weights": (),
                  "shading": (True, False), "multiscale": (False, True), "folds": 5},
    "TUNE_PAIRS": True,
    "TUNE_SIMULATE": False,
    "TUNE_TOLERANCE": 0.05,
    "VIEWING_DISTANCE_M": 1.0,
    "WEIGHT_EXPONENT": 1.5,
    "WEIGHT_FLOOR": 0.01,
}


def test_every_default_is_the_documented_value():
    names = {k for k in vars(defaults) if k.isupper()}
    assert names == set(EXPECTED), "a default was added or removed: write its value in EXPECTED"
    for name, value in EXPECTED.items():
        got = getattr(defaults, name)
        assert type(got) is type(value), name
        assert got == value, name


def test_layouts_are_chosen_by_input_kind(tmp_path):
    # a pairs folder gets PAIRS_LAYOUT's values, anything else SIMULATION_LAYOUT's
    from l3cli.pairs import find_pairs
    from l3cli.train.options import layout_defaults

    pairs = find_pairs([EX / "frames"])
    got = layout_defaults(pairs)
    assert (got["patch"], got["levels"], got["contrast_bins"], got["contrast_threshold"]) == (7, 24, 3, 0.2)
    assert got["target_space"] == "linear-srgb" and got["tone_curve"] is True
    assert layout_defaults([])["target_space"] == "xyz"


@pytest.mark.slow
def test_train_with_no_options_beats_the_quality_floor(runner, tmp_path):
    # measured (2026-11-26): held-out S-CIELAB mean 0.325 (Outdoor3 0.318,
    # Outdoor4 0.333); 1.274 with --no-tone-curve. The floor sits between them
    # with room for numerical drift: a default turned off crosses it.
    from l3cli.cli.main import cli
    from l3cli.table import load_table

    table = tmp_path / "t.npz"
    res = runner.invoke(cli, ["-q", "train", str(EX / "frames"), "-o", str(table)])
    assert res.exit_code == 0, res.output
    held = [EX / "holdout" / f"{n}_crop" for n in ("Outdoor3", "Outdoor4")]
    out = tmp_path / "renders"
    res = runner.invoke(cli, ["-q", "render", str(table), *(f"{h}.tif" for h in held), "-o", str(out)])
    assert res.exit_code == 0, res.output
    renders = sorted(out.iterdir())
    assert [r.stem for r in renders] == ["Outdoor3_crop", "Outdoor4_crop"]
    report = tmp_path / "r.json"
    res = runner.invoke(cli, ["-q", "evaluate", *map(str, renders), "--reference",
                              *(f"{h}.png" for h in held), "--json", str(report)])
    assert res.exit_code == 0, res.output
    mean = json.loads(report.read_text())["summary"]["scielab_mean"]
    assert 0.05 < mean < 0.6
    # and the table is the pairs layout (checked after the floor, which must catch a
    # default turned off by itself)
    t = load_table(table)
    assert t.patch == 7 and t.definition.n_levels == 24 and t.output_space == "linear-srgb"
    assert t.provenance["tone_curve"]["used"] is True
