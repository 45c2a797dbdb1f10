"""A pair read twice in one process (``l3 train``'s tone-curve pass, then its kernels')
is aligned, and its alignment logged, once; a changed file is aligned anew."""

from __future__ import annotations

import logging
import os

import numpy as np

from l3cli.pairs import find_pairs, load_pair
from l3cli.pairs import load as pairs_mod  # where load_pair calls align


def test_second_load_reuses_the_alignment_and_logs_it_once(pairs_dir, caplog,  # noqa: F811
                                                             monkeypatch):
    calls = []
    real = pairs_mod.align

    def counting(*a, **k):
        calls.append(k["render_name"])
        return real(*a, **k)

    monkeypatch.setattr(pairs_mod, "align", counting)
    (pair,) = [p for p in find_pairs([pairs_dir]) if p.name == "b"]
    with caplog.at_level(logging.DEBUG, logger="l3cli.pairs"):
        first = load_pair(pair)
        second = load_pair(pair)
    assert len(calls) == 1
    msgs = [(r.levelno, r.getMessage()) for r in caplog.records if r.getMessage().startswith("b:")]
    assert [lv for lv, _ in msgs] == [logging.INFO, logging.DEBUG]
    assert msgs[1][1].endswith("(alignment reused)")
    assert first.alignment == second.alignment and (first.alignment.dy, first.alignment.dx) == (4, 4)
    np.testing.assert_array_equal(first.target, second.target)
    np.testing.assert_array_equal(first.raw.mosaic, second.raw.mosaic)
    np.testing.assert_array_equal(first.weight_mask, second.weight_mask)
    # the render rewritten (new mtime): aligned again
    st = os.stat(pair.target)
    os.utime(pair.target, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    load_pair(pair)
    assert len(calls) == 2
