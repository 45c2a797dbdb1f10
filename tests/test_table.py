"""The NPZ transform table: round trip and validation on load."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from l3cli.errors import TableError
from l3cli.table import TABLE_VERSION, load_table, save_table
from tests.builders import make_table, npz_arrays, rewrite_npz


def test_round_trip(tmp_path):
    t = make_table()
    p = save_table(tmp_path / "t.npz", t)
    u = load_table(p)
    np.testing.assert_array_equal(u.kernels, t.kernels)
    np.testing.assert_array_equal(u.counts, t.counts)
    np.testing.assert_array_equal(u.empty, t.empty)
    np.testing.assert_array_equal(u.source_class, t.source_class)
    np.testing.assert_array_equal(u.lambdas, t.lambdas)
    assert u.definition.same_as(t.definition)
    assert u.output_space == "xyz" and u.provenance == {"inputs": ["a.dng"], "seed": 3}
    a = npz_arrays(p)  # plain dtypes only, loadable without pickle
    assert all(v.dtype != object for v in a.values())
    assert str(a["format"]) == "l3-table" and int(a["version"]) == TABLE_VERSION
    assert a["kernels"].dtype == np.float32 and a["kernels"].shape == (4 * 8 * 3 * 2, 26, 3)
    assert not list(tmp_path.glob(".l3-tmp*"))




@pytest.mark.parametrize(
    "change,match",
    [
        ({"version": np.array(99)}, "table version 99 is not supported"),
        ({"format": np.array("something-else")}, "format is 'something-else'"),
        ({"kernels": None}, "missing keys kernels"),
        ({"kernels": np.zeros((3, 26, 3), np.float32)}, r"kernels have shape \(3, 26, 3\)"),
        ({"counts": np.zeros(5, np.int64)}, "counts has shape"),
        ({"lambdas": np.zeros((192, 3), np.int64)}, "'lambdas' has dtype int64"),
        ({"cfa": np.array("RGXB")}, "bad class definition"),
        ({"empty": np.ones(192, bool)}, "no class is trained|falls back to another empty"),
        ({"provenance": np.array("{not json")}, "provenance is not JSON"),
        ({"output_space": np.array("cmyk")}, "output space 'cmyk'"),
    ],
)
def test_validation(tmp_path, change, match):
    p = save_table(tmp_path / "t.npz", make_table())
    rewrite_npz(p, **change)
    with pytest.raises(TableError, match=match) as exc:
        load_table(p)
    assert str(p) in str(exc.value) and "\n" not in str(exc.value)


def test_not_npz_and_damaged(tmp_path):
    txt = tmp_path / "t.npz"
    txt.write_text("hello")
    with pytest.raises(TableError, match="not an NPZ table"):
        load_table(txt)
    with open(tmp_path / "b.npz", "wb") as fh:  # a plain .npy under an .npz name
        np.save(fh, np.zeros(3))
    with pytest.raises(TableError, match="not an NPZ table"):
        load_table(tmp_path / "b.npz")
    good = save_table(tmp_path / "g.npz", make_table())
    data = good.read_bytes()
    (tmp_path / "trunc.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(TableError, match="damaged"):
        load_table(tmp_path / "trunc.npz")
    other = tmp_path / "other.npz"
    np.savez(other, x=np.zeros(3))
    with pytest.raises(TableError, match="no 'format' key"):
        load_table(other)
    with pytest.raises(TableError, match="no such table"):
        load_table(tmp_path / "missing.npz")
    obj = tmp_path / "obj.npz"
    with zipfile.ZipFile(obj, "w"):
        pass
    with pytest.raises(TableError):
        load_table(obj)


def test_provenance_is_json_string(tmp_path):
    p = save_table(tmp_path / "t.npz", make_table())
    assert json.loads(str(npz_arrays(p)["provenance"]))["seed"] == 3
