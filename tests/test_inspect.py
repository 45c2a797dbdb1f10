"""``l3 inspect``: the table summary, the class list, the figures."""

from __future__ import annotations

import json

import numpy as np
import pytest

from l3cli.cli.main import cli
from l3cli.errors import ConfigError
from l3cli.inspect import (
    class_rows,
    compress_ranges,
    format_summary,
    saturation_name,
    table_summary,
)
from l3cli.smooth import smooth_table
from l3cli.table import load_table, save_table
from tests.builders import plausible_table


def test_compress_ranges_and_saturation_names():
    assert compress_ranges([7, 1, 2, 3, 9, 10]) == "1-3, 7, 9-10"
    assert compress_ranges([]) == "none"
    assert saturation_name(0, ("R", "G", "B")) == "-"
    assert saturation_name(0b101, ("R", "G", "B")) == "R+B"


def test_summary_facts():
    t = plausible_table("RGGB", n_levels=6, seed=1)
    s = table_summary(t, name="t.npz")
    d = t.definition
    assert s["cfa"] == {"spec": "RG/GB", "period": [2, 2], "channels": ["R", "G", "B"]}
    assert s["layout"]["classes"] == d.n_classes == 4 * 8 * 6 * 2
    assert s["layout"]["groups"] == [[0], [1], [2], [3]]
    assert [lv["from"] for lv in s["levels"]][1:] == pytest.approx(d.level_cuts.tolist())
    assert s["levels"][-1]["to"] is None
    assert sum(lv["samples"] for lv in s["levels"]) == s["samples"] == int(t.counts.sum())
    assert s["classes"]["empty"] == int(t.empty.sum())
    assert sorted(i for v in s["empty"].values() for i in v) == np.flatnonzero(t.empty).tolist()
    assert s["filled"] == {} and s["smoothing"] is None
    assert s["output_space"] == "xyz"
    json.dumps(s)  # JSON-serialisable
    text = format_summary(s)
    assert "CFA RG/GB" in text and "smoothing: not smoothed" in text
    assert "inputs" in text  # provenance


def test_summary_lists_classes_filled_by_smoothing():
    t = plausible_table("RGGB", seed=2)
    sm = smooth_table(t)
    s = table_summary(sm, name="s.npz")
    filled = sorted(i for v in s["filled"].values() for i in v)
    assert filled == np.flatnonzero(t.empty & ~sm.empty).tolist() and filled
    assert s["classes"]["filled"] == len(filled)
    text = format_summary(s, table=sm, classes=True)
    assert "filled classes (by prior):" in text and "spline:" in text
    rows = class_rows(sm)
    assert [r["class"] for r in rows if r["status"].startswith("filled")] == filled
    assert all(r["lambda"] == [None] * 3 for r in rows if r["status"] != "trained")


def test_cli_inspect_text_json_and_plots(tmp_path, runner):
    raw = plausible_table("RGGB", n_levels=6, seed=3)
    a = save_table(tmp_path / "raw.npz", raw)
    b = save_table(tmp_path / "smooth.npz", smooth_table(raw))
    r = runner.invoke(cli, ["inspect", str(b)])
    assert r.exit_code == 0, r.output
    assert "position groups" in r.output and "filled classes (by prior):" in r.output
    listed = [ln for ln in r.output.splitlines() if ln.strip().split(" ")[0].isdigit()
              and ("trained" in ln or "filled:" in ln)]
    assert len(listed) == int((~raw.empty).sum()) + int((raw.empty & ~load_table(b).empty).sum())
    r = runner.invoke(cli, ["inspect", str(b), "--json", "--classes", "all"])
    assert r.exit_code == 0, r.output
    js = json.loads(r.output)
    assert len(js["class_list"]) == raw.definition.n_classes
    assert js["smoothing"]["priors"] == ["symmetry", "spline", "uniformity"]
    out = tmp_path / "plots"
    r = runner.invoke(cli, ["inspect", str(b), "--plots", str(out), "--compare", str(a),
                            "--levels", "0,3"])
    assert r.exit_code == 0, r.output
    names = sorted(p.name for p in out.glob("*.png"))
    assert names == ["smooth_curves.png", "smooth_kernels_level00.png",
                     "smooth_kernels_level03.png"]
    assert all(p.stat().st_size > 5000 for p in out.glob("*.png"))



def test_default_kernel_levels_are_low_mid_high_and_saturated(tmp_path):
    from l3cli.plots_table import default_levels, plot_kernels

    t = plausible_table("RGGB", n_levels=6, seed=4, empty_fraction=0.0)
    chosen = default_levels(t)
    assert chosen["low"] == (0, 0) and chosen["mid"] == (0, 3) and chosen["high"] == (0, 5)
    assert chosen["saturated"][0] > 0
    t.empty[:] = True  # only two levels of the unsaturated pattern trained
    d = t.definition
    for g in range(d.n_groups):
        for lv in (1, 4):
            for c in range(d.n_contrast):
                t.empty[d.class_index(g, 0, lv, c)] = False
    assert default_levels(t) == {"low": (0, 1), "mid": (0, 4), "high": (0, 4)}
    paths = plot_kernels(t, tmp_path, levels=[2], name="t")
    assert [p.name for p in paths] == ["t_kernels_level02.png"]


def test_cli_inspect_errors(tmp_path, runner):
    a = save_table(tmp_path / "a.npz", plausible_table("RGGB", n_levels=6))
    b = save_table(tmp_path / "b.npz", plausible_table("GRBG", n_levels=6))
    r = runner.invoke(cli, ["inspect", str(a), "--compare", str(b)])
    assert r.exit_code == 2 and "different class definition" in r.output
    r = runner.invoke(cli, ["inspect", str(a), "--plots", str(tmp_path / "p"), "--levels", "9"])
    assert r.exit_code == 1 and "level 9 is not in 0..5" in r.output
    r = runner.invoke(cli, ["inspect", str(a), "--levels", "x"])
    assert r.exit_code == 2
    r = runner.invoke(cli, ["inspect", str(a), "--classes", "some"])
    assert r.exit_code == 2
    (tmp_path / "file").write_text("x")
    r = runner.invoke(cli, ["inspect", str(a), "--plots", str(tmp_path / "file" / "sub")])
    assert r.exit_code == 1 and "cannot create the plots folder" in r.output
    r = runner.invoke(cli, ["inspect", str(tmp_path / "none.npz")])
    assert r.exit_code == 1 and "none.npz" in r.output


def test_plot_kernels_rejects_bad_contrast(tmp_path):
    from l3cli.plots_table import plot_kernels

    with pytest.raises(ConfigError, match="contrast bin 5"):
        plot_kernels(plausible_table(n_levels=4), tmp_path, contrast=5)


def test_cli_inspect_checks_options_before_any_output(tmp_path, runner):
    a = save_table(tmp_path / "a.npz", plausible_table("RGGB", n_levels=6))
    r = runner.invoke(cli, ["inspect", str(a), "--plots", str(tmp_path / "p"), "--levels", "2,30"])
    assert r.exit_code == 1
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert lines[0].startswith("Error:") and "--levels" in lines[0] and "a.npz" in lines[0]
    assert "level 30 is not in 0..5" in lines[0]
    assert not (tmp_path / "p").exists()  # nothing written either
    r = runner.invoke(cli, ["inspect", str(a), "--levels", "2"])
    assert r.exit_code == 2 and "--plots" in r.output and "CFA" not in r.output


def test_inspect_text_is_plain_not_json(tmp_path, runner):
    from l3cli.inspect import plain_value

    raw = plausible_table("GRBG", n_levels=6, seed=3)
    raw.provenance["options"] = {"lambda_grid": np.logspace(-9, 1, 41).tolist(), "patch": 5,
                                 "white_balance": False, "level_range": None}
    raw.provenance["tone_curve"] = {"knots": np.linspace(0, 1, 66).reshape(33, 2).tolist(),
                                    "used": True, "heldout_rms": 0.0026981}
    b = save_table(tmp_path / "s.npz", smooth_table(raw))
    r = runner.invoke(cli, ["inspect", str(b), "--classes", "none"])
    assert r.exit_code == 0, r.output
    out = r.output
    assert "lambda_grid: 41 values from 1e-09 to 10, log-spaced (x1.78 each)" in out
    assert "knots: 33 x 2 numbers from 0 to 1" in out
    assert "heldout_rms: 0.002698" in out and "used: yes" in out
    assert "white_balance: no" in out and "level_range: none" in out
    assert "0: G at (0,0); 1: R at (0,1); 2: B at (1,0); 3: G at (1,1)" in out
    assert not [ln for ln in out.splitlines() if ln.strip().endswith(("]}", "}")) or '": ' in ln]
    js = json.loads(runner.invoke(cli, ["inspect", str(b), "--json"]).output)
    assert len(js["provenance"]["options"]["lambda_grid"]) == 41  # --json keeps every number
    assert plain_value([0.5, 1]) == "0.5, 1" and plain_value([]) == "none"
    assert plain_value(["a"] * 8) == "a, a, a, a, a, a, ... (8 in all)"
