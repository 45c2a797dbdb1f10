"""The simulation manifest reader/writer: version and values checked, one line naming the key."""

from __future__ import annotations

import json

import pytest

from l3cli.errors import InputError, OutputError
from l3cli.io.manifest import (
    MANIFEST_VERSION,
    capture_files,
    read_manifest,
    write_manifest,
)


def _manifest(**cap):
    return {"format": "l3-simulation", "version": MANIFEST_VERSION, "camera": {},
            "target": {"space": "xyz"},
            "captures": [{"stem": "a", "raw": "a.dng", "target": "a.target.exr", **cap}]}


def test_round_trip_and_listed_files(tmp_path):
    m = _manifest(lux=100.0, edge={"roi": [0, 0, 8, 8]})
    write_manifest(tmp_path, m)
    got = read_manifest(tmp_path)
    assert got == m
    assert read_manifest(tmp_path / "manifest.json") == m
    assert capture_files(tmp_path, got) == [tmp_path / "manifest.json", tmp_path / "a.dng",
                                            tmp_path / "a.target.exr"]


@pytest.mark.parametrize("change, key", [
    ({"version": 2}, "version 2 is not supported"),
    ({"version": "1"}, "version must be an integer"),
    ({"format": "other"}, "format must be"),
    ({"captures": {}}, "'captures' must be a list"),
    ({"target": {"space": "cmyk"}}, "target.space"),
])
def test_top_level_problems_name_the_key(tmp_path, change, key):
    (tmp_path / "manifest.json").write_text(json.dumps({**_manifest(), **change}))
    with pytest.raises(InputError, match=key):
        read_manifest(tmp_path)


@pytest.mark.parametrize("cap, key", [
    ({"raw": "../../etc/passwd"}, r"captures\[0\].raw"),
    ({"target": "sub/x.exr"}, r"captures\[0\].target"),
    ({"lux": -1}, r"captures\[0\].lux"),
    ({"exposure_s": "fast"}, r"captures\[0\].exposure_s"),
    ({"width": 1.5}, r"captures\[0\].width"),
    ({"white_xyz": [1, 2]}, r"captures\[0\].white_xyz"),
    ({"edge": {"roi": [0, 0, "x", 1]}}, r"edge.roi\[2\]"),
    ({"chart": {"patches": [[0, 0, 1, 1]], "white_index": 5}}, "white_index"),
])
def test_capture_problems_name_the_key(tmp_path, cap, key):
    (tmp_path / "manifest.json").write_text(json.dumps(_manifest(**cap)))
    with pytest.raises(InputError, match=key):
        read_manifest(tmp_path)


def test_not_json_not_utf8_and_missing(tmp_path):
    with pytest.raises(InputError, match="no manifest.json"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_bytes(b"\xff\xfe{")
    with pytest.raises(InputError, match="cannot read the simulation manifest"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text('{"format": ')
    with pytest.raises(InputError, match="cannot read the simulation manifest"):
        read_manifest(tmp_path)


def test_writer_refuses_a_bad_manifest(tmp_path):
    with pytest.raises(OutputError, match="lux"):
        write_manifest(tmp_path, _manifest(lux=float("nan")))
    assert list(tmp_path.iterdir()) == []


def test_writer_refuses_non_finite_numbers_anywhere(tmp_path):
    m = _manifest()
    m["camera"] = {"gain": float("inf")}
    with pytest.raises(OutputError, match="bad manifest"):
        write_manifest(tmp_path, m)
