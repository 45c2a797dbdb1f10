"""The learned per-channel tone curve (l3cli.tone.curve) and its use in training and render."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from l3cli.cfa import CFA
from l3cli.colourspace import srgb_decode, srgb_encode
from l3cli.errors import TableError
from l3cli.io.image import write_image
from l3cli.render import render_mosaic
from l3cli.table import TransformTable, load_table, save_table
from l3cli.tone.curve import (
    ToneCurve,
    apply_curve,
    block_samples,
    fit_tone_curve,
    select_curve,
)
from l3cli.train import TrainOptions, find_pairs, train

#: A camera matrix from the raw's RGB to the pipeline's linear RGB (rows sum to 1).
M = np.array([[1.5, -0.4, -0.1], [-0.2, 1.4, -0.2], [0.0, -0.5, 1.5]], dtype=np.float32)


def s_curve(v: np.ndarray) -> np.ndarray:
    """A pipeline's S-shaped tone curve (increasing on [0, 1], not sRGB)."""
    return (0.5 - 0.5 * np.cos(np.pi * np.clip(v, 0, 1) ** 0.45)).astype(np.float32)


def s_curve_inverse(e: np.ndarray) -> np.ndarray:
    return (np.arccos(1 - 2 * np.asarray(e, dtype=np.float64)) / np.pi) ** (1 / 0.45)


def patchwork(h: int, w: int, seed: int, square: int = 16) -> np.ndarray:
    """Camera-linear RGB of flat squares of random colours (a chart of many patches)."""
    rng = np.random.default_rng(seed)
    cols = rng.uniform(0.03, 0.6, (h // square, w // square, 3)).astype(np.float32)
    img = np.repeat(np.repeat(cols, square, axis=0), square, axis=1)
    return img + 0.002 * rng.standard_normal(img.shape).astype(np.float32)


def bayer(lin: np.ndarray, spec: str = "GRBG") -> np.ndarray:
    cfa = CFA.from_spec(spec)
    order = [("RGB".index(c)) for c in cfa.channels]
    idx = np.asarray(order)[cfa.channel_map(*lin.shape[:2])]
    return np.take_along_axis(lin, idx[:, :, None], axis=2)[:, :, 0].astype(np.float32)


def pipeline(lin: np.ndarray) -> np.ndarray:
    """The renders' encoded values: matrix, then the S-curve per channel."""
    return s_curve(np.clip(lin @ M.T, 0, 1))


def test_a_known_tone_curve_is_recovered():
    cfa = CFA.from_spec("GRBG")
    samples = []
    for seed in (1, 2):
        lin = patchwork(256, 320, seed)
        samples.append(block_samples(bayer(lin), cfa, pipeline(lin)))
    assert all(s[2].sum() > 500 for s in samples)
    curve = fit_tone_curve(samples)
    assert curve is not None
    x = np.linspace(0, 1, curve.knots.shape[0])
    inner = (x >= 0.1) & (x <= 0.9)
    want = s_curve_inverse(x[inner])
    for c in range(3):  # up to scale (the matrix takes it): f(1) = 1 is extrapolated
        got = curve.knots[inner, c]
        got = got * (got @ want) / (got @ got)
        np.testing.assert_allclose(got, want, atol=0.005)
        assert np.all(np.diff(curve.knots[:, c]) > 0)


def test_an_srgb_pipeline_gives_the_srgb_decoding():
    cfa = CFA.from_spec("RGGB")
    lin = patchwork(256, 256, 3)
    enc = srgb_encode(np.clip(lin @ M.T, 0, 1))
    curve = fit_tone_curve([block_samples(bayer(lin, "RGGB"), cfa, enc)])
    x = np.linspace(0, 1, curve.knots.shape[0]).astype(np.float32)
    inner = (x >= 0.1) & (x <= 0.8)
    want = srgb_decode(x[inner])
    for c in range(3):
        got = curve.knots[inner, c]
        np.testing.assert_allclose(got * (got @ want) / (got @ got), want, atol=0.005)


def test_too_few_flat_blocks_give_no_curve():
    cfa = CFA.from_spec("GRBG")
    rng = np.random.default_rng(0)
    lin = rng.uniform(0.05, 0.6, (64, 64, 3)).astype(np.float32)  # texture: nothing flat
    assert fit_tone_curve([block_samples(bayer(lin), cfa, pipeline(lin))]) is None


@pytest.mark.parametrize("space", ["srgb", "linear-srgb"])
def test_the_look_up_table_inverts_the_curve(space):
    knots = np.stack([s_curve_inverse(np.linspace(0, 1, 17))] * 3, axis=1)
    curve = ToneCurve(knots / knots[-1])
    e = np.random.default_rng(4).uniform(0, 1, (40, 50, 3)).astype(np.float32)
    v = curve.linearise(e)
    back = apply_curve(v.copy(), *curve.lut(space))
    want = e if space == "srgb" else srgb_decode(e)
    # between knots the curve is linear, its inverse by the table: nearly exact
    np.testing.assert_allclose(back, want, atol=2e-3)
    # outside the range the ends of the table hold
    lo, hi = v.min() - 1.0, v.max() + 1.0
    ends = apply_curve(np.array([[[lo, lo, lo], [hi, hi, hi]]], np.float32), *curve.lut(space))
    np.testing.assert_allclose(ends[0, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(ends[0, 1], 1.0, atol=1e-6)


def _table(tmp_path: Path) -> TransformTable:
    folder = _write_pairs(tmp_path / "p", (5,))
    return train(find_pairs([folder]), TrainOptions(patch=3, levels=4, contrast_bins=1,
                                                    target_space="linear-srgb"))


def test_table_round_trip_and_render_apply_the_table(tmp_path: Path):
    t = _table(tmp_path)
    assert t.tone_lut is None
    knots = np.stack([s_curve_inverse(np.linspace(0, 1, 17))] * 3, axis=1)
    lut = ToneCurve(knots).lut("linear-srgb")
    mosaic = bayer(patchwork(64, 96, 7))
    plain = render_mosaic(t, mosaic)
    t.tone_lut = lut
    save_table(tmp_path / "t.npz", t)
    back = load_table(tmp_path / "t.npz")
    np.testing.assert_array_equal(back.tone_lut[0], lut[0])
    curved = render_mosaic(back, mosaic)
    np.testing.assert_allclose(curved, apply_curve(plain.copy(), *lut), atol=1e-6)
    assert not np.allclose(curved, plain, atol=1e-3)


def test_a_damaged_tone_curve_is_refused(tmp_path: Path):
    t = _table(tmp_path)
    arrs = t.to_arrays()
    arrs["tone_lut"] = np.zeros((8, 3), np.float32)  # without its range
    np.savez(tmp_path / "bad.npz", **arrs)
    with pytest.raises(TableError, match="bad.npz.*tone_lut"):
        load_table(tmp_path / "bad.npz")
    arrs["tone_range"] = np.array([[1, 1, 1], [1, 1, 1]], np.float32)  # empty range
    np.savez(tmp_path / "bad2.npz", **arrs)
    with pytest.raises(TableError, match="bad2.npz.*empty range"):
        load_table(tmp_path / "bad2.npz")


def _write_pairs(folder: Path, seeds, h: int = 256, w: int = 320) -> Path:
    folder.mkdir()
    for seed in seeds:
        lin = np.clip(patchwork(h, w, seed), 0, 1)
        stem = f"s{seed}"
        np.round(bayer(lin) * 255).astype(np.uint8).tofile(folder / f"{stem}.raw")
        (folder / f"{stem}.raw.toml").write_text(
            f'width = {w}\nheight = {h}\ndtype = "uint8"\ncfa = "GRBG"\n'
            "black_level = 0\nwhite_level = 255\n")
        write_image(folder / f"{stem}.png", pipeline(lin), space="srgb")
    return folder


@pytest.mark.slow
def test_training_in_the_curve_space_fits_an_s_curve_pipeline(tmp_path: Path):
    """A matrix then an S-curve: the per-class kernels in linear-srgb bend the curve
    level by level and miss; in the learned curve space the pipeline is linear."""
    train_dir = _write_pairs(tmp_path / "train", (11, 12, 14))
    test_lin = np.clip(patchwork(256, 320, 13), 0, 1)
    raw = np.round(bayer(test_lin) * 255).astype(np.float32) / 255.0
    want = srgb_decode(pipeline(test_lin))
    errs = {}
    for on in (False, True):
        t = train(find_pairs([train_dir]), TrainOptions(patch=3, levels=8, contrast_bins=1,
                                                        target_space="linear-srgb",
                                                        tone_curve=on))
        assert (t.tone_lut is not None) == on
        assert ("tone_curve" in t.provenance) == on
        out = render_mosaic(t, raw)
        errs[on] = float(np.abs(out - want)[8:-8, 8:-8].mean())
    assert errs[True] < 0.5 * errs[False]


def test_the_curve_is_used_only_where_it_beats_the_srgb_decoding():
    cfa = CFA.from_spec("GRBG")
    lins = [patchwork(256, 320, seed) for seed in (21, 22, 23)]
    s_pipe = [block_samples(bayer(lin), cfa, pipeline(lin)) for lin in lins]
    curve, rec = select_curve(s_pipe)
    assert curve is not None and rec["used"]
    assert rec["heldout_rms"] < 0.5 * rec["srgb_heldout_rms"]
    srgb_pipe = [block_samples(bayer(lin), cfa, srgb_encode(np.clip(lin @ M.T, 0, 1)))
                 for lin in lins]
    curve, rec = select_curve(srgb_pipe)
    assert curve is None and not rec["used"]
    # one image: its two halves are the held-out units
    big = patchwork(384, 480, 24)
    curve, rec = select_curve([block_samples(bayer(big), cfa, pipeline(big))])
    assert curve is not None and rec["used"]
