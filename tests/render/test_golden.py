"""Golden fixture: train, render and evaluate give the committed outputs exactly.

``tests/data/golden/make_golden.py`` made the committed outputs from the
committed tiny simulation folders; this test runs the same commands into a
temporary folder and compares: the table array by array, the renders, and the JSON
and text reports. A refactoring must leave them unchanged; a change meant to
alter them regenerates them with the script and says so.

"Unchanged" is to the last few float32 units, not bit for bit: OpenBLAS picks
its kernels for the CPU (AVX2 or AVX-512: another summation order in XᵀX) and
numba compiles the render for it, so the same code gives kernels that differ
by an ulp on another machine (seen: 8 of 30,000 kernel entries by 9e-10, the
Macbeth render by 7e-9, the reports in their 9th digit). Integer arrays,
strings and the provenance are compared exactly; floats to
:data:`RTOL` of their scale, far below any change of method (which moves
kernels by 1e-4 and scores in their printed digits).
"""

from __future__ import annotations

import importlib.util
import json
import re

import numpy as np
import pytest

from tests.builders import DATA

GOLDEN = DATA / "golden"
#: Relative tolerance of float outputs (of each array's largest magnitude): a few float32 ulps.
RTOL = 1e-6


def _script():
    spec = importlib.util.spec_from_file_location("make_golden", GOLDEN / "make_golden.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _provenance(z) -> dict:
    # paths of the inputs, whichever checkout made them
    p = json.loads(re.sub(r'[^"]*/tests/data/golden', "<golden>", str(z["provenance"])))
    for k in ("python", "l3_version"):  # of the machine, not of the method
        p.pop(k, None)
    return p


@pytest.fixture(scope="module")
def remade(tmp_path_factory):
    out = tmp_path_factory.mktemp("golden")
    _script().make_outputs(out)
    return out


def test_table_is_golden(remade):
    with np.load(GOLDEN / "table.npz", allow_pickle=False) as want, \
            np.load(remade / "table.npz", allow_pickle=False) as got:
        assert sorted(got.files) == sorted(want.files)
        for k in want.files:
            if k == "provenance":
                # numbers as floats (np.logspace's λ grid moves by an ulp with the CPU)
                _same_json(_provenance(got), _provenance(want), "provenance")
            else:
                assert got[k].dtype == want[k].dtype, k
                _same(got[k], want[k], k)


def _same(got: np.ndarray, want: np.ndarray, what: str) -> None:
    """Integers and strings equal; floats within RTOL of the array's scale, NaN where NaN."""
    assert got.shape == want.shape, what
    if want.dtype.kind != "f":
        np.testing.assert_array_equal(got, want, err_msg=what, strict=True)
        return
    scale = float(np.nanmax(np.abs(want))) if np.isfinite(want).any() else 0.0
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=RTOL * scale, err_msg=what)


@pytest.mark.parametrize("name", ["render/macbeth_D65_0100lux.exr",
                                  "render/slanted-edge_D65_0100lux.exr"])
def test_render_is_golden(remade, name):
    from l3cli.io.image import read_image

    got, got_space = read_image(remade / name)
    want, want_space = read_image(GOLDEN / name)
    assert got_space == want_space
    assert got.dtype == want.dtype == np.float32
    _same(got, want, name)


def _same_json(got, want, where: str = "") -> None:
    assert type(got) is type(want) or {type(got), type(want)} <= {int, float}, where
    if isinstance(want, dict):
        assert sorted(got) == sorted(want), where
        for k in want:
            _same_json(got[k], want[k], f"{where}/{k}")
    elif isinstance(want, list):
        assert len(got) == len(want), where
        for i, (g, w) in enumerate(zip(got, want, strict=True)):
            _same_json(g, w, f"{where}[{i}]")
    elif isinstance(want, float):
        # values the report rounds (to 4 or 5 decimals: Macbeth ΔE, MTF) may cross a
        # rounding boundary on a float32 ulp of the render (FMA or not): one unit of the
        # last decimal
        decimals = len(repr(want).split(".")[1]) if "." in repr(want) and "e" not in repr(
            want) else 99
        last = 10.0 ** -decimals if decimals <= 5 else 0.0
        assert got == pytest.approx(want, rel=RTOL, abs=max(RTOL, 1.0001 * last),
                                    nan_ok=True), where
    else:
        assert got == want, where


def test_json_report_is_golden(remade):
    _same_json(json.loads((remade / "report.json").read_text()),
               json.loads((GOLDEN / "report.json").read_text()))


def test_text_report_is_golden(remade):
    """The same lines, word for word; a number may differ by one unit of its last printed
    digit (a value an ulp from a rounding boundary)."""
    got = (remade / "report.txt").read_text().splitlines()
    want = (GOLDEN / "report.txt").read_text().splitlines()
    assert len(got) == len(want)
    for g_line, w_line in zip(got, want, strict=True):
        g_words, w_words = g_line.split(), w_line.split()
        assert len(g_words) == len(w_words), w_line
        for g, w in zip(g_words, w_words, strict=True):
            if re.fullmatch(r"-?\d+\.\d+", w) and re.fullmatch(r"-?\d+\.\d+", g):
                unit = 10.0 ** -len(w.split(".")[1])
                assert abs(float(g) - float(w)) <= unit * 1.0001, (w_line, g_line)
            else:
                assert g == w, (w_line, g_line)
