"""Atomic output: rename on success, nothing left on failure, ordinary permissions."""

from __future__ import annotations

import os
import stat

import pytest

from l3cli.errors import OutputError
from l3cli.io.atomic import atomic_path


def test_success_renames_and_uses_umask_permissions(tmp_path):
    old = os.umask(0o027)
    try:
        with atomic_path(tmp_path / "out.txt") as tmp:
            assert tmp.parent == tmp_path and tmp.name.startswith(".l3-tmp-")
            tmp.write_text("done")
    finally:
        os.umask(old)
    out = tmp_path / "out.txt"
    assert out.read_text() == "done"
    assert stat.S_IMODE(out.stat().st_mode) == 0o640  # 0666 & ~027, not mkstemp's 0600
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_failure_leaves_nothing_and_keeps_old_file(tmp_path):
    out = tmp_path / "out.txt"
    out.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(out) as tmp:
        tmp.write_text("half")
        raise RuntimeError("writer failed")
    assert out.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_empty_output_is_an_error(tmp_path):
    with pytest.raises(OutputError, match="nothing was written"), atomic_path(tmp_path / "e.txt"):
        pass
    assert list(tmp_path.iterdir()) == []
