"""The NPZ transform table: round trip and validation on load."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from l3cli.classify import ClassDefinition
from l3cli.errors import TableError
from l3cli.table import TABLE_VERSION, TransformTable, load_table, save_table


def make_table(spec="RGGB", patch=5, n_out=3, seed=0, space="xyz") -> TransformTable:
    d = ClassDefinition.build(spec, patch=patch, level_cuts=[0.05, 0.2], contrast_cuts=0.3)
    rng = np.random.default_rng(seed)
    nc, q = d.n_classes, d.n_coeffs
    empty = np.zeros(nc, bool)
    empty[1::2] = True
    src = np.where(empty, np.arange(nc) - 1, np.arange(nc))
    k = rng.normal(size=(nc, q, n_out)).astype(np.float32)
    k[empty] = k[src[empty]]
    lam = np.where(empty[:, None], np.nan, 1e-3 * np.ones((nc, n_out)))
    return TransformTable(definition=d, kernels=k, counts=np.where(empty, 0, 500),
                          lambdas=lam, empty=empty, source_class=src, output_space=space,
                          provenance={"inputs": ["a.dng"], "seed": 3})


def _arrays(path):
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


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
    a = _arrays(p)  # plain dtypes only, loadable without pickle
    assert all(v.dtype != object for v in a.values())
    assert str(a["format"]) == "l3-table" and int(a["version"]) == TABLE_VERSION
    assert a["kernels"].dtype == np.float32 and a["kernels"].shape == (4 * 8 * 3 * 2, 26, 3)
    assert not list(tmp_path.glob(".l3-tmp*"))


def _rewrite(path, **changes):
    a = _arrays(path)
    for k, v in changes.items():
        if v is None:
            del a[k]
        else:
            a[k] = v
    with open(path, "wb") as fh:
        np.savez(fh, **a)


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
    _rewrite(p, **change)
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
    assert json.loads(str(_arrays(p)["provenance"]))["seed"] == 3
