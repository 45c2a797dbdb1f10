"""Builders shared by the tests: small tables, simulate folders, raws, scenes.

Tests import them from here (never from another test module), and fixtures
from ``conftest.py``.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

from l3cli.cfa import CFA
from l3cli.classify import ClassDefinition
from l3cli.colourspace import srgb_encode
from l3cli.io.image import write_image
from l3cli.io.raw import write_raw
from l3cli.simulate.scenes import Scene
from l3cli.table import TransformTable
from l3cli.train.fit import fallback_sources
from tests.l3ref import features_reference

TESTS = Path(__file__).parent
DATA = TESTS / "data"
REPO = TESTS.parent
SHARED = REPO.parent / "shared" / "data"


def write_raws(folder, n, *, seed=0, shape=(34, 46)):
    rng = np.random.default_rng(seed)
    return [write_raw(folder / f"r{i}.dng", rng.integers(100, 4000, shape).astype(np.uint16),
                      "RGGB", white_level=4095) for i in range(n)]


H, W = 128, 160


def mosaic_dn(lin: np.ndarray, spec: str, white: int) -> np.ndarray:
    """The CFA samples of a linear RGB image (its own size) as integers up to ``white``."""
    c = CFA.from_spec(spec)
    chan = np.array([["RGB".index(n) for n in row] for row in c.pattern])
    h, w = lin.shape[:2]
    ph, pw = chan.shape
    idx = np.tile(chan, (-(-h // ph), -(-w // pw)))[:h, :w]
    m = np.take_along_axis(lin, idx[:, :, None], axis=2)[:, :, 0]
    return np.round(m * white).astype(np.uint16)


def write_headerless(folder: Path, stem: str, lin: np.ndarray) -> Path:
    dn = mosaic_dn(lin, "GRBG", 255).astype(np.uint8)
    raw = folder / f"{stem}.raw"
    dn.tofile(raw)
    (folder / f"{stem}.raw.toml").write_text(
        f'width = {W}\nheight = {H}\ndtype = "uint8"\ncfa = "GRBG"\n'
        "black_level = 0\nwhite_level = 255\n"
    )
    return raw


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


def npz_arrays(path):
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def rewrite_npz(path, **changes):
    a = npz_arrays(path)
    for k, v in changes.items():
        if v is None:
            del a[k]
        else:
            a[k] = v
    with open(path, "wb") as fh:
        np.savez(fh, **a)


def design_matrix(mosaic, d):
    """Explicit design matrix (H*W, q) from the numpy reference patches."""
    _, _, _, win = features_reference(mosaic, d.cfa, d.patch, d.saturation_threshold,
                                      d.contrast_eps)
    h, w = mosaic.shape
    return np.concatenate([win.reshape(h * w, -1), np.ones((h * w, 1))], axis=1)


def write_pair(folder, stem, mosaic, target, cfa="RGGB", target_space="xyz"):
    from l3cli.io.image import write_image
    from l3cli.io.raw import write_raw

    raw = write_raw(folder / f"{stem}.dng", np.round(mosaic * 4095).astype(np.uint16), cfa,
                    white_level=4095)
    write_image(folder / f"{stem}.target.exr", target, space=target_space,
                allow_nonfinite=True)  # the bad-input tests write NaN on purpose
    return raw


def sim_dir(tmp_path, n=2, shape=(40, 48), seed=0, nan=False, bad_size=False):
    rng = np.random.default_rng(seed)
    folder = tmp_path / f"sim{seed}"
    folder.mkdir()
    caps = []
    for i in range(n):
        m = rng.random(shape) * 0.8
        t = rng.random((*shape, 3)).astype(np.float32)
        if nan and i == n - 1:
            t[3, 4, 1] = np.nan
        if bad_size and i == n - 1:
            t = t[:-2]
        raw = write_pair(folder, f"cap{i}", m, t)
        caps.append({"stem": f"cap{i}", "raw": raw.name, "target": f"cap{i}.target.exr"})
    (folder / "manifest.json").write_text(json.dumps(
        {"format": "l3-simulation", "version": 1, "target": {"space": "xyz"}, "captures": caps}))
    return folder


def plausible_table(spec="RGGB", *, patch=5, n_levels=10, seed=0, empty_fraction=0.3,
                    noise=0.05) -> TransformTable:
    """A table whose kernels look trained: per-channel averages mapped by a positive
    3xC matrix, plus noise; some classes empty (holding their fallback's kernel)."""

    d = ClassDefinition.build(spec, patch=patch,
                              level_cuts=np.geomspace(0.003, 0.8, n_levels - 1),
                              contrast_cuts=0.3)
    rng = np.random.default_rng(seed)
    nch = d.cfa.n_channels
    mix = 0.2 + rng.random((3, nch))
    nc, q = d.n_classes, d.n_coeffs
    k = np.zeros((nc, q, 3))
    g = np.asarray(d.class_tuple(np.arange(nc))[0])
    for grp in range(d.n_groups):
        p = int(np.flatnonzero(d.position_group == grp)[0])
        lay = d.cfa.neighbourhood(p, patch).ravel()
        n_c = np.bincount(lay, minlength=nch)
        base = (mix[:, lay] / n_c[lay]).T  # (P, 3)
        sel = g == grp
        k[sel, :-1] = base
    k[:, :-1] += noise * rng.normal(size=(nc, q - 1, 3)) / q
    k[:, -1] = 0.01 * rng.normal(size=(nc, 3))
    counts = rng.integers(200, 5000, nc)
    empty = rng.random(nc) < empty_fraction
    empty[0] = False
    # every position group needs a trained class
    for grp in range(d.n_groups):
        empty[np.flatnonzero(g == grp)[0]] = False
    counts[empty] = rng.integers(0, 20, int(empty.sum()))
    src = fallback_sources(d, ~empty)
    lam = np.where(empty[:, None], np.nan, 1e-3)
    return TransformTable(definition=d, kernels=k[src].astype(np.float32), counts=counts,
                          lambdas=np.broadcast_to(lam, (nc, 3)).copy(), empty=empty,
                          source_class=src, output_space="xyz",
                          provenance={"inputs": ["synthetic"], "seed": seed})


MINIMAL = """
name = "t"
[pixel]
pitch_um = 2.0
conversion_gain_uv_per_e = 100.0
voltage_swing_v = 1.0
[cfa]
pattern = "RGGB"
qe = "bayer-rgb"
"""


def assert_one_line_error(res, *words: str, code: int = 1) -> str:
    """The CLI failed with ``code`` and printed exactly one ``Error:`` line holding ``words``."""
    assert res.exit_code == code, res.output
    assert "Traceback" not in res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith("Error:"), lines[0]
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def uniform_scene(h: int, w: int, wl: np.ndarray, reflectance: float = 0.5) -> Scene:
    return Scene("flat", np.ones((1, h, w), np.float32), np.full((1, wl.size), reflectance))


TUNE_OPTS = dict(patch=5, levels=4, contrast_bins=1, level_range=(0.02, 0.6))


def tune_pairs(folder: Path, scenes: dict[str, tuple[int, float]]) -> Path:
    """A pairs folder: per stem (scene seed, gain of the 'pipeline')."""
    folder.mkdir()
    for stem, (seed, gain) in scenes.items():
        lin = scene(H, W, seed=seed)
        write_headerless(folder, stem, lin)
        write_image(folder / f"{stem}.png", srgb_encode(np.clip(gain * lin, 0, 1)), space="srgb")
    return folder


def scene(h: int, w: int, seed: int) -> np.ndarray:
    """Linear RGB scene with sharp edges at many orientations and fine texture."""
    rng = np.random.default_rng(seed)
    img = np.full((h, w, 3), 0.2, dtype=np.float32)
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(60):
        col = rng.uniform(0.02, 0.9, 3).astype(np.float32)
        if rng.random() < 0.5:
            y0, x0 = rng.integers(0, h), rng.integers(0, w)
            img[y0 : y0 + rng.integers(4, h // 3), x0 : x0 + rng.integers(4, w // 3)] = col
        else:
            cy, cx, r = rng.integers(0, h), rng.integers(0, w), rng.integers(3, 30)
            img[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = col
    img *= (1 + 0.1 * rng.standard_normal((h, w, 1))).astype(np.float32)
    return np.clip(gaussian_filter(img, (0.7, 0.7, 0)), 0, 1).astype(np.float32)


def shaded_examples_script():
    spec = importlib.util.spec_from_file_location(
        "make_shaded_examples", REPO / "scripts" / "make_shaded_examples.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def write_dng_with_opcodes(path, dn, opcode_list2: bytes | None):
    """A minimal RGGB DNG written by tifffile (the tags of l3cli.io.raw.write_raw), with
    an OpcodeList2 tag (UNDEFINED bytes) when given."""
    import tifffile

    tags = [(33421, "H", 2, (2, 2), True), (33422, "B", 4, (0, 1, 1, 2), True),
            (50706, "B", 4, (1, 4, 0, 0), True), (50707, "B", 4, (1, 3, 0, 0), True),
            (50708, "s", 0, "l3 test", True), (50710, "B", 3, (0, 1, 2), True),
            (50711, "H", 1, 1, True), (50713, "H", 2, (2, 2), True),
            (50714, "I", 4, (64, 64, 64, 64), True), (50717, "I", 1, 4095, True),
            (50721, "2i", 9, (10000, 10000, 0, 10000, 0, 10000, 0, 10000, 10000, 10000,
                              0, 10000, 0, 10000, 0, 10000, 10000, 10000), True),
            (50728, "2I", 3, (10000, 10000, 10000, 10000, 10000, 10000), True),
            (50778, "H", 1, 21, True)]
    if opcode_list2 is not None:
        tags.append((51009, "B", len(opcode_list2), opcode_list2, True))
    tifffile.imwrite(path, dn.astype(np.uint16), photometric=32803, planarconfig=1,
                     compression=None, subfiletype=0, extratags=tags, metadata=None)
    return path


def phone_gain_maps(h, w):
    """Four GainMaps, one per Bayer position (as phones write them), 5x7 points each:
    :func:`tests.dngmake.phone_gain_maps` at ``points=(5, 7)``."""
    from tests.dngmake import phone_gain_maps as maps

    return maps(h, w, points=(5, 7))


def mosaic_raw(mosaic, spec="RGGB", path=None):
    """A :class:`l3cli.io.raw.RawImage` of a normalised float mosaic (black 0, white 1)."""
    from l3cli.cfa import CFA
    from l3cli.io.raw import RawImage

    cfa = CFA.from_spec(spec)
    return RawImage(mosaic=mosaic.astype(np.float32), cfa=cfa,
                    black_level=np.zeros(cfa.n_positions), white_level=1.0, path=path)
