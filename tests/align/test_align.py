"""Registration of renders against their raw (l3cli.align).

Synthetic pairs: a random scene of coloured rectangles and discs is mosaicked
(RGGB) into a RawImage and, independently, rendered as display sRGB; the
render is then cropped, mirrored or resized by known amounts, and the
registration must recover exactly those amounts (or refuse the pair).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter, zoom

from l3cli.align import (
    FLIPS,
    Alignment,
    align,
    align_scaled,
    aligned_pair,
    apply_flip,
    raw_luminance,
    register,
    scaled_pair,
)
from l3cli.cfa import CFA
from l3cli.colourspace import srgb_decode, srgb_encode
from l3cli.errors import InputError
from l3cli.io.raw import RawImage
from tests.builders import scene


def mosaic(lin: np.ndarray, cfa: str = "RGGB") -> RawImage:
    c = CFA.from_spec(cfa)
    idx = c.channel_map(*lin.shape[:2])
    order = {n: i for i, n in enumerate("RGB")}
    chan = np.vectorize(lambda i: order[c.channels[i]])(idx)
    m = np.take_along_axis(lin, chan[:, :, None], axis=2)[:, :, 0]
    return RawImage(mosaic=m.astype(np.float32), cfa=c, black_level=np.zeros(4),
                    white_level=1.0)


@pytest.fixture(scope="module")
def pair() -> tuple[RawImage, np.ndarray]:
    lin = scene(192, 256, seed=1)
    return mosaic(lin), srgb_encode(lin)


def test_full_frame_aligns_at_zero(pair):
    raw, render = pair
    a = align(raw, render)
    assert (a.dy, a.dx, a.flip) == (0, 0, "none")
    assert a.score > 0.8 and a.sharpness > 20


def test_rawtherapee_crop_4_each_side(pair):
    raw, render = pair
    a = align(raw, render[4:-4, 4:-4])
    assert (a.dy, a.dx, a.flip, a.height, a.width) == (4, 4, "none", 184, 248)


def test_dng_default_crop():
    # Blackmagic Pocket 4K: DefaultCrop origin (x=16, y=8); scaled-down geometry.
    lin = scene(200, 280, seed=2)
    raw = mosaic(lin)
    render = srgb_encode(lin)[8 : 8 + 180, 16 : 16 + 256]
    a = align(raw, render)
    assert (a.dy, a.dx, a.flip) == (8, 16, "none")
    crop, target = aligned_pair(raw, render, a)
    # the crop keeps the CFA phase: (8, 16) is even, RGGB stays RGGB
    assert crop.cfa.spec == "RG/GB" and crop.shape == (180, 256)
    np.testing.assert_array_equal(crop.mosaic, raw.mosaic[8:188, 16:272])
    np.testing.assert_array_equal(target, render)


@pytest.mark.parametrize("flip", ["none", "horizontal", "vertical", "both"])
def test_mirrored_render(pair, flip):
    raw, render = pair
    cropped = render[3:-5, 5:-3]  # odd offsets: the CFA phase changes
    mirrored = apply_flip(cropped, flip)
    a = align(raw, mirrored)
    assert (a.dy, a.dx, a.flip) == (3, 5, flip)  # mirrorings are their own inverse
    crop, target = aligned_pair(raw, mirrored, a)
    np.testing.assert_array_equal(target, cropped)
    assert crop.cfa.spec == "BG/GR"  # RGGB from (3, 5): odd row (G B), odd column -> B
    np.testing.assert_array_equal(crop.mosaic, raw.mosaic[3:-5, 5:-3])


@pytest.mark.parametrize("k", [1, 3])
def test_rotated_render(pair, k):
    raw, render = pair
    cropped = render[10:160, 20:200]
    rotated = np.rot90(cropped, k)  # 90 degrees counter-clockwise (k=1) or clockwise (k=3)
    a = align(raw, rotated)
    assert (a.dy, a.dx) == (10, 20)
    assert a.flip == {1: "transpose-horizontal", 3: "transpose-vertical"}[k]
    assert (a.height, a.width) == (180, 150)
    crop, target = aligned_pair(raw, rotated, a)
    np.testing.assert_array_equal(target, cropped)
    np.testing.assert_array_equal(crop.mosaic, raw.mosaic[10:160, 20:200])


def test_transposed_orientations_are_the_dihedral_group():
    x = np.arange(12).reshape(3, 4)
    seen = {apply_flip(x, f).tobytes() + bytes(apply_flip(x, f).shape) for f in FLIPS}
    assert len(FLIPS) == 8 and len(seen) == 8
    for f in FLIPS:  # every orientation is undone by one of them
        y = apply_flip(x, f)
        assert any(np.array_equal(apply_flip(y, g), x) for g in FLIPS)


def test_resized_render_refused(pair):
    raw, render = pair
    small = np.clip(zoom(render, (0.9, 0.9, 1), order=1), 0, 1)
    with pytest.raises(InputError, match=r"small\.png does not align with big\.raw.*scaled"):
        align(raw, small, raw_name="big.raw", render_name="small.png")


@pytest.mark.parametrize(("z", "crop", "flip"), [(0.9, 0, "none"), (0.75, 10, "none"),
                                                 (0.5, 0, "horizontal")])
def test_resized_render_registered_when_asked(pair, z, crop, flip):
    """align_scaled recovers the resize geometry to a fraction of a raw pixel.

    scipy's zoom maps the first and last pixel centres of its input onto those
    of its output, so render pixel r lies on raw row crop + r (H' - 1) / (h - 1).
    """
    raw, render = pair
    src = render[crop:192 - crop, crop:256 - crop]
    small = apply_flip(np.clip(zoom(src, (z, z, 1), order=1), 0, 1), flip)
    h, w = small.shape[:2]
    with pytest.raises(InputError, match="does not align"):
        align(raw, small)
    a = align_scaled(raw, small, raw_name="big.raw", render_name="small.png")
    assert a.flip == flip and a.score > 0.8
    for origin, step, n, true_step in ((a.y0, a.step_y, h, (src.shape[0] - 1) / (h - 1)),
                                       (a.x0, a.step_x, w, (src.shape[1] - 1) / (w - 1))):
        assert origin == pytest.approx(crop, abs=0.25)
        assert origin + (n - 1) * step == pytest.approx(crop + (n - 1) * true_step, abs=0.3)


def test_scaled_pair_resamples_onto_the_raw_grid():
    from dataclasses import replace

    from scipy.ndimage import gaussian_filter

    lin = scene(192, 256, seed=4)
    raw, render = mosaic(lin), srgb_encode(lin)
    small = np.clip(zoom(render, (0.8, 0.8, 1), order=1), 0, 1)
    a = align_scaled(raw, small)
    errors = []
    for shift in (0.0, 0.5):
        crop, target, good = scaled_pair(raw, small, replace(a, y0=a.y0 + shift))
        y, x, hh, ww = crop.metadata["crop"]
        assert y % 2 == 0 and x % 2 == 0 and crop.cfa.spec == "RG/GB"  # the raw's CFA phase
        assert target.shape == (hh, ww, 3) and good.all()
        # the truth on the raw grid, blurred about as much as the down- and up-sampling
        truth = gaussian_filter(srgb_decode(render[y:y + hh, x:x + ww]), (0.6, 0.6, 0))
        errors.append(float(np.abs(srgb_decode(target) - truth)[8:-8, 8:-8].mean()))
    assert errors[0] < 0.006  # measured 0.0038 (0.0103 half a pixel off)
    assert errors[1] > 2 * errors[0]


def test_scaled_pair_excludes_invalid_render_pixels(pair):
    raw, render = pair
    small = np.clip(zoom(render, (0.9, 0.9, 1), order=1), 0, 1)
    a = align_scaled(raw, small)
    valid = np.ones(small.shape[:2], bool)
    valid[50, 60] = False
    crop, _, good = scaled_pair(raw, small, a, valid=valid)
    y, x = crop.metadata["crop"][:2]
    # raw pixels within one render pixel of (50, 60) are out, the rest in
    ry = (np.arange(good.shape[0]) + y - a.y0) / a.step_y
    rx = (np.arange(good.shape[1]) + x - a.x0) / a.step_x
    near = (np.abs(ry - 50)[:, None] < 1) & (np.abs(rx - 60)[None, :] < 1)
    assert not good[near].any() and good[~near].all()


def test_scaled_registration_refuses_a_different_shot(pair):
    raw, _ = pair
    other = np.clip(zoom(srgb_encode(scene(192, 256, seed=7)), (0.9, 0.9, 1), order=1), 0, 1)
    with pytest.raises(InputError, match="b.png does not align with a.raw even as a resized copy"):
        align_scaled(raw, other, raw_name="a.raw", render_name="b.png")


def test_different_shot_refused(pair):
    raw, _ = pair
    other = srgb_encode(scene(192, 256, seed=7))
    with pytest.raises(InputError, match="does not align.*different shot"):
        align(raw, other, raw_name="a.raw", render_name="b.png")


def test_render_larger_than_raw_refused(pair):
    raw, render = pair
    big = np.pad(render, ((2, 2), (2, 2), (0, 0)))
    with pytest.raises(InputError, match="larger than its raw"):
        align(raw, big)


def test_raw_luminance_is_phase_free():
    # A flat grey scene seen through any CFA phase gives a flat luminance.
    lin = np.full((16, 20, 3), 0.25, dtype=np.float32)
    lin[..., 0] = 0.5  # reddish: grey world balances the channels
    for spec in ("RGGB", "GRBG", "BGGR"):
        lum = raw_luminance(mosaic(lin, spec))
        assert lum.shape == (16, 20)
        np.testing.assert_allclose(lum, lum[0, 0], rtol=1e-6)


def test_register_recovers_shift_on_luminance():
    rng = np.random.default_rng(3)
    lum = gaussian_filter(rng.random((128, 160)).astype(np.float32), 1.5)
    a = register(lum, lum[10:100, 7:140])
    assert isinstance(a, Alignment)
    assert (a.dy, a.dx, a.flip) == (10, 7, "none")


def test_featureless_render(pair):
    raw, render = pair
    flat = np.full_like(render, 0.5)
    a = align(raw, flat)
    assert (a.dy, a.dx, a.flip) == (0, 0, "none") and np.isnan(a.score)
    with pytest.raises(InputError, match="featureless and smaller"):
        align(raw, flat[4:-4, 4:-4])


@pytest.mark.slow
def test_real_dng_default_crop_and_mirror(shared_data):
    """Blackmagic DNG rendered by LibRaw, cut to its DNG DefaultCrop and mirrored."""
    import rawpy

    from l3cli.io.raw import read_raw

    path = shared_data / "raw" / "misc" / "blackmagic_pocket4k_rggb.dng"
    raw = read_raw(path)
    s = raw.metadata["sizes"]
    y0, x0 = s["crop_top_margin"], s["crop_left_margin"]
    hh, ww = s["crop_height"], s["crop_width"]
    assert (y0, x0, hh, ww) == (8, 16, 2160, 4096)
    with rawpy.imread(str(path)) as rp:
        rgb = rp.postprocess(half_size=False, use_camera_wb=True, output_bps=8,
                             demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR)
    render = rgb[y0 : y0 + hh, x0 : x0 + ww].astype(np.float32) / 255
    a = align(raw, render[::-1], raw_name=path.name, render_name="darktable-like.jpg")
    assert (a.dy, a.dx, a.flip) == (8, 16, "vertical")
    assert a.score > 0.9
