"""CFA model: parsing, positions, neighbourhoods, crops and flips."""

import numpy as np
import pytest

from l3cli.cfa import CFA
from l3cli.errors import ConfigError


@pytest.mark.parametrize(
    "spec, period, channels",
    [
        ("RGGB", (2, 2), ("R", "G", "B")),
        ("grbg", (2, 2), ("G", "R", "B")),
        ("RGBWWRGBBWRGGBWR", (4, 4), ("R", "G", "B", "W")),
        ("RGB/GBR", (2, 3), ("R", "G", "B")),
        ("R G / NIR B", (2, 2), ("R", "G", "B", "NIR")),
        ([["R", "G"], ["NIR", "B"]], (2, 2), ("R", "G", "NIR", "B")),
        (["RG", "GB"], (2, 2), ("R", "G", "B")),
    ],
)
def test_parse(spec, period, channels):
    cfa = CFA.from_spec(spec)
    assert cfa.period == period
    assert set(cfa.channels) == set(channels)
    # the canonical spec round-trips
    assert CFA.from_spec(cfa.spec) == cfa


@pytest.mark.parametrize("bad", ["RGQB", "RGG", "", "RG/GBB", [["R", "X"], ["G", "B"]]])
def test_bad_specs_name_the_problem(bad):
    with pytest.raises(ConfigError) as exc:
        CFA.from_spec(bad)
    assert "CFA" in str(exc.value)


def test_unknown_letter_lists_allowed():
    with pytest.raises(ConfigError, match="allowed: R, G, B"):
        CFA.from_spec("RGQB")


def test_position_and_channel_maps_agree_with_pattern():
    cfa = CFA.from_spec("GRBG")
    pos = cfa.position_map(5, 7)
    ch = cfa.channel_map(5, 7)
    for y in range(5):
        for x in range(7):
            assert pos[y, x] == cfa.position_at(y, x) == (y % 2) * 2 + x % 2
            assert cfa.channels[ch[y, x]] == cfa.channel_at(y, x)
    masks = cfa.masks(5, 7)
    assert masks.sum() == 35 and np.all(masks.sum(axis=0) == 1)


def test_equivalent_positions():
    # Bayer: the two greens see different neighbourhoods (R left/right vs B) -> 4 groups
    assert len(CFA.from_spec("RGGB").equivalent_positions(5)) == 4
    # a pattern written with a redundant period (2x4 that repeats every 2 columns):
    # positions two columns apart see identical layouts
    groups = CFA.from_spec("WRWR/BWBW").equivalent_positions(3)
    assert sorted(map(sorted, groups)) == [[0, 2], [1, 3], [4, 6], [5, 7]]
    # a monochrome "CFA" has a single neighbourhood for all positions
    assert CFA.from_spec("WWWW").equivalent_positions(5) == [[0, 1, 2, 3]]


def test_shift_matches_cropping():
    cfa = CFA.from_spec("RGBWWRGBBWRGGBWR")
    h, w = 12, 12
    ch = np.array([[cfa.channel_at(y, x) for x in range(w)] for y in range(h)])
    for dy, dx in [(1, 0), (0, 3), (2, 1), (5, 7)]:
        sub = cfa.shifted(dy, dx)
        crop = ch[dy:, dx:]
        for y in range(crop.shape[0]):
            for x in range(crop.shape[1]):
                assert sub.channel_at(y, x) == crop[y, x]


@pytest.mark.parametrize("w, h", [(10, 8), (11, 9)])
def test_flip_matches_mirroring(w, h):
    cfa = CFA.from_spec("GRBG")
    ch = np.array([[cfa.channel_at(y, x) for x in range(w)] for y in range(h)])
    for hor, ver in [(True, False), (False, True), (True, True)]:
        f = cfa.flipped(horizontal=hor, vertical=ver, width=w, height=h)
        m = ch[::-1 if ver else 1, ::-1 if hor else 1]
        assert all(f.channel_at(y, x) == m[y, x] for y in range(h) for x in range(w))


def test_dng_codes():
    assert CFA.from_spec("RGGB").dng_codes() == [0, 1, 1, 2]
    assert CFA.from_spec("RGBW" * 4).dng_codes() is None
