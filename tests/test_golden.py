"""Golden fixture: train, render and evaluate give the committed outputs exactly.

``tests/data/golden/make_golden.py`` made the committed outputs from the
committed tiny simulation folders; this test runs the same commands into a
temporary folder and compares: the table array by array (bit for bit, the float64
λ to 1e-12; the provenance with the checkout's path taken out), the renders and the JSON and
text reports byte for byte. A refactoring must leave them unchanged; a change
meant to alter them regenerates them with the script and says so.
"""

from __future__ import annotations

import importlib.util
import json
import re

import numpy as np
import pytest

from tests.conftest import DATA

GOLDEN = DATA / "golden"


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
                assert _provenance(got) == _provenance(want)
            elif k == "lambdas":
                # float64 GCV λ = relative grid value x trace(centred X'X) / p: the trace
                # may move by an ulp with the process's BLAS state (seen after other
                # tests ran in the same process); the float32 kernels do not move
                np.testing.assert_allclose(got[k], want[k], rtol=1e-12, err_msg=k)
            else:
                assert got[k].dtype == want[k].dtype, k
                np.testing.assert_array_equal(got[k], want[k], err_msg=k, strict=True)


@pytest.mark.parametrize("name", ["render/macbeth_D65_0100lux.exr",
                                  "render/slanted-edge_D65_0100lux.exr",
                                  "report.json", "report.txt"])
def test_output_is_golden(remade, name):
    assert (remade / name).read_bytes() == (GOLDEN / name).read_bytes(), name
