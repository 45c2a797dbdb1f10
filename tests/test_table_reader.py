"""The table reader refuses what its checks are for (issue 30: mutants that survived).

A targeted mutation run (``scripts/mutants.py``, ``tests/README.md``) showed five
checks of :func:`l3cli.table.load_table` that no test exercised: scalar keys
stored as arrays, a tone curve's lookup table without its range, an empty range, a
fallback class one past the last, a pickled array.
"""

from __future__ import annotations

import numpy as np
import pytest

from l3cli.errors import TableError
from l3cli.table import load_table, save_table
from tests.builders import make_table, rewrite_npz


@pytest.mark.parametrize(("key", "value"), [("patch", np.array([5])), ("cfa", np.array(["RGGB"])),
                                            ("saturation_threshold", np.array([0.95]))])
def test_a_scalar_key_stored_as_an_array_is_refused(tmp_path, key, value):
    path = save_table(tmp_path / "t.npz", make_table())
    rewrite_npz(path, **{key: value})
    with pytest.raises(TableError, match=rf"t\.npz: key '{key}' must be a scalar, has shape \(1,\)"):
        load_table(path)


@pytest.mark.parametrize("present", ["tone_lut", "tone_range"])
def test_half_a_tone_curve_is_refused(tmp_path, present):
    path = save_table(tmp_path / "t.npz", make_table())
    arrays = {"tone_lut": np.linspace(0, 1, 16, dtype=np.float32)[:, None].repeat(3, 1),
              "tone_range": np.array([[0.0] * 3, [1.0] * 3], np.float32)}
    rewrite_npz(path, **{present: arrays[present]})
    with pytest.raises(TableError, match="tone_lut and tone_range come together"):
        load_table(path)
    rewrite_npz(path, **arrays)  # both: a table with a tone curve
    t = load_table(path)
    assert t.tone_lut is not None and t.tone_lut[0].shape == (16, 3)


def test_an_empty_tone_range_is_refused(tmp_path):
    path = save_table(tmp_path / "t.npz", make_table())
    lut = np.linspace(0, 1, 16, dtype=np.float32)[:, None].repeat(3, 1)
    rewrite_npz(path, tone_lut=lut, tone_range=np.array([[0.0, 0.0, 0.5], [1.0, 1.0, 0.5]], np.float32))
    with pytest.raises(TableError, match="empty range"):
        load_table(path)


def test_a_fallback_class_past_the_last_is_refused(tmp_path):
    t = make_table()
    path = save_table(tmp_path / "t.npz", t)
    nc = t.definition.n_classes
    last = int(np.flatnonzero(~t.empty)[-1])  # the last trained class: a valid fallback
    for value, ok in ((last, True), (nc, False)):  # nc: one past the last class
        src = t.source_class.copy()
        src[0] = value
        rewrite_npz(path, source_class=src)
        if ok:
            assert load_table(path).source_class[0] == last
        else:
            with pytest.raises(TableError, match="source_class holds indices outside the classes"):
                load_table(path)


def test_a_pickled_array_is_never_loaded(tmp_path):
    # NPZ loads with allow_pickle=False: an object array (a pickle, which could run
    # code when loaded) makes the table unreadable instead of being unpickled
    path = save_table(tmp_path / "t.npz", make_table())
    rewrite_npz(path, extra=np.array([{"pickled": True}], dtype=object))
    with pytest.raises(TableError, match=r"t\.npz: not an NPZ table or damaged \(.*allow_pickle"):
        load_table(path)
