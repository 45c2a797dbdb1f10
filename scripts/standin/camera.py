#!/usr/bin/env python3
"""A stand-in for a camera with a known truth (issue 41): development data for lens shading.

    scripts/standin/camera.py OUT_DIR [RAW_OR_FOLDER ...] [--holdout RAW_OR_FOLDER ...]
                              [--crop HxW]
    scripts/standin/camera.py OUT_DIR --seed N   # another lens (centres, strengths, shapes)
    scripts/standin/camera.py check TABLE.npz [--truth OUT_DIR/truth.json]

Without raws it takes the bundled frames (``examples/infinite_isp/frames`` for
training, ``holdout`` for evaluation only); any raw ``l3cli.io.raw.read_raw``
reads works too (``l3 simulate`` captures: their ``.dng``). Each raw is taken
as the light that reached an *unshaded* sensor. The stand-in camera

1. shades it by a known relative illumination :func:`illumination` (per colour,
   each about its own off-centre optical centre and elliptical: red falls to
   about 0.5 in the far corner, green 0.62, blue 0.56), which is what its sensor
   records (``OUT/shaded/<part>/<stem>.tif``, 16-bit + sidecar: the lens
   darkens the light before the sensor quantises it, so 8 more bits than an
   8-bit source are kept);
2. renders the sensor's values as an in-camera pipeline would, each step a
   well-kept library's operation: the exact lens-shading correction (the
   inverse of step 1, so the render is that of the unshaded raw); fixed
   white-balance gains; Malvar (2004) demosaicing (colour-demosaicing); a
   3x3 colour matrix; a wide edge-aware noise reduction (the guided filter of
   He, Sun and Tang (2010), radius 8, on the display-encoded image, every
   channel guided by the luminance; box means by ``scipy.ndimage``); unsharp
   masking of the luminance (Gaussian sigma 1.2 px, amount 0.6); an S-shaped
   tone curve after the sRGB encoding; 8-bit PNG
   (``OUT/shaded/<part>/<stem>.png``).

``OUT/control/<part>`` holds the same renders with the *unshaded* raws at the
same 16-bit scale: the truly corrected control (the true gain applied before
training). ``OUT/truth.json`` records the field's parameters. The truth for a
learned field (``l3cli.lens.field.gain_map``): ``1 / illumination(...)`` up to a
scale per channel (:func:`field_error`).

Never train or tune on ``holdout``: it is scored only.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SOURCE = ROOT / "examples" / "infinite_isp"

#: Per colour: optical centre (cy, cx) in normalised coordinates
#: (l3cli.lens.field.normalised_coords: 0 at the image centre, 1 at the half-diagonal),
#: strength k of the fall-off (1 + k r'^2)^-2 and ellipticity e (r'^2 = (1 + e) dv^2 +
#: (1 - e) du^2): red falls most and toward the lower right.
LENS = {"R": {"centre": (-0.10, -0.14), "k": 0.36, "e": 0.15},
        "G": {"centre": (-0.05, -0.08), "k": 0.22, "e": 0.10},
        "B": {"centre": (0.02, -0.03), "k": 0.28, "e": -0.08}}
#: The camera's white-balance gains (R, G, B) and colour matrix (camera RGB -> linear sRGB,
#: rows sum to one).
WB_GAINS = (1.9, 1.0, 1.6)
MATRIX = np.array([[1.55, -0.40, -0.15], [-0.22, 1.42, -0.20], [0.02, -0.45, 1.43]])
#: Guided filter: radius (px) and regularisation (display values, squared).
NR_RADIUS, NR_EPS = 8, 0.03 ** 2
#: Unsharp masking of the luminance: Gaussian sigma (px) and amount.
USM_SIGMA, USM_AMOUNT = 1.2, 0.6
#: Tone curve after the sRGB encoding: y = 0.5 + 0.5 tanh(s (x - 0.5)) / tanh(s / 2).
TONE_S = 2.2
#: Extra bits of the shaded raws (16-bit from the source's levels).
SCALE_BITS = 16


def random_lens(seed: int) -> dict:
    """Another lens of the same family for ``seed`` (0: :data:`LENS`): per colour, the
    centre within 0.2 of the image centre on each axis, strength k from 0.12 to 0.45
    (a corner at 0.72 .. 0.40 of the centre's illumination), ellipticity within 0.25, so
    that a fit is never tuned to one field."""
    if not seed:
        return LENS
    rng = np.random.default_rng(seed)
    return {c: {"centre": tuple(float(x) for x in rng.uniform(-0.2, 0.2, 2).round(3)),
                "k": round(float(rng.uniform(0.12, 0.45)), 3),
                "e": round(float(rng.uniform(-0.25, 0.25)), 3)} for c in "RGB"}


def illumination(height: int, width: int, cfa, lens: dict | None = None) -> np.ndarray:
    """The lens's relative illumination of each pixel (float64 (H, W), at most 1);
    ``lens`` as :data:`LENS` (the default)."""
    from l3cli.lens.field import normalised_coords

    lens = LENS if lens is None else lens
    v, u = normalised_coords(height, width)
    out = np.empty((height, width))
    chan = cfa.channel_map(height, width)
    for c, name in enumerate(cfa.channels):
        p = lens[name]
        dv = v[:, None] - p["centre"][0]
        du = u[None, :] - p["centre"][1]
        r2 = (1 + p["e"]) * dv ** 2 + (1 - p["e"]) * du ** 2
        s = (1.0 + p["k"] * r2) ** -2
        out[chan == c] = s[chan == c]
    return out


def field_error(gains: np.ndarray, cfa, lens: dict | None = None) -> dict[str, float]:
    """Rms relative error per colour of a per-pixel correction ``gains`` (H, W) against
    the truth ``1 / illumination``, each colour's scale removed (the kernels absorb it)."""
    h, w = gains.shape
    q = np.asarray(gains, dtype=np.float64) * illumination(h, w, cfa, lens)
    chan = cfa.channel_map(h, w)
    out = {}
    for c, name in enumerate(cfa.channels):
        qc = q[chan == c]
        out[name] = float(np.sqrt(np.mean((qc / qc.mean() - 1.0) ** 2)))
    return out


def _box(x: np.ndarray, r: int) -> np.ndarray:
    from scipy.ndimage import uniform_filter

    return uniform_filter(x, size=2 * r + 1, mode="reflect")


def guided_filter(guide: np.ndarray, src: np.ndarray, r: int, eps: float) -> np.ndarray:
    """The guided filter (He, Sun and Tang 2010) of ``src`` by the grey ``guide``."""
    mi, ms = _box(guide, r), _box(src, r)
    cov = _box(guide * src, r) - mi * ms
    var = _box(guide * guide, r) - mi * mi
    a = cov / (var + eps)
    b = ms - a * mi
    return _box(a, r) * guide + _box(b, r)


def render(mosaic: np.ndarray, cfa) -> np.ndarray:
    """The stand-in camera's 8-bit sRGB render (uint8 (H, W, 3)) of an *unshaded*
    normalised mosaic (its lens correction has been applied)."""
    from colour_demosaicing import demosaicing_CFA_Bayer_Malvar2004
    from scipy.ndimage import gaussian_filter

    from l3cli.colourspace import srgb_encode

    gain = np.array([WB_GAINS["RGB".index(c)] for c in cfa.channels])[cfa.channel_map(
        *mosaic.shape)]
    rgb = demosaicing_CFA_Bayer_Malvar2004(np.clip(mosaic, 0, 1) * gain,
                                         "".join("".join(r) for r in cfa.pattern))
    lin = np.clip(rgb @ MATRIX.T, 0.0, 1.0)
    enc = srgb_encode(lin)
    luma = enc @ np.array([0.2126, 0.7152, 0.0722])
    den = np.stack([guided_filter(luma, enc[..., k], NR_RADIUS, NR_EPS) for k in range(3)],
                   axis=-1)
    y = den @ np.array([0.2126, 0.7152, 0.0722])
    sharp = den + (USM_AMOUNT * (y - gaussian_filter(y, USM_SIGMA, mode="reflect")))[..., None]
    x = np.clip(sharp, 0.0, 1.0)
    toned = 0.5 + 0.5 * np.tanh(TONE_S * (x - 0.5)) / np.tanh(TONE_S / 2)
    return np.round(np.clip(toned, 0, 1) * 255).astype(np.uint8)


def make_one(raw_path: Path, out: Path, part: str, crop: tuple[int, int] | None,
             lens: dict | None = None) -> str:
    """Write the shaded raw, the control raw and the render of one source raw."""
    from l3cli.io.image import write_image
    from l3cli.io.raw import read_raw
    from l3cli.io.raw_write import write_raw

    raw = read_raw(raw_path)
    m = np.asarray(raw.mosaic, dtype=np.float64)
    if crop is not None:  # central crop, even offsets (keeps the CFA phase)
        h, w = crop
        y0 = (m.shape[0] - h) // 4 * 2
        x0 = (m.shape[1] - w) // 4 * 2
        m = m[y0:y0 + h, x0:x0 + w]
    clipped = m >= 1.0
    white = 2 ** SCALE_BITS - 1
    stem = raw_path.name.split(".")[0]
    shaded = np.where(clipped, 1.0, m * illumination(*m.shape, raw.cfa, lens))
    for kind, values in (("shaded", shaded), ("control", m)):
        folder = out / kind / part
        folder.mkdir(parents=True, exist_ok=True)
        dn = np.round(np.clip(values, 0, 1) * white).astype(np.uint16)
        write_raw(folder / f"{stem}.tif", dn, raw.cfa, black_level=0, white_level=white,
                  description=f"stand-in camera ({kind}) of {raw_path.name}")
        write_image(folder / f"{stem}.png", render(m, raw.cfa), space="srgb")
    return stem


def _raws(args: list[str]) -> list[Path]:
    from l3cli.pairs import raw_files

    return [Path(p) for p in raw_files([Path(a) for a in args])[0]]


def check(table_path: str, lens: dict | None = None) -> dict[str, float] | None:
    """Print the rms error per colour of a table's learned field against the truth
    (``lens``: a ``truth.json``'s, default :data:`LENS`)."""
    from l3cli.lens.field import gain_map
    from l3cli.table import load_table

    table = load_table(table_path)
    field = table.shading
    if field is None:
        print(f"{table_path}: no gain field")
        return None
    cfa = table.definition.cfa
    err = field_error(gain_map(field, field.size, cfa.period), cfa, lens)
    print(f"{table_path}: {type(field).__name__} "
          + ", ".join(f"{c} {100 * e:.3f} %" for c, e in err.items()) + " rms")
    return err


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["check"]:
        ap = argparse.ArgumentParser(description="the tables' fields against the truth")
        ap.add_argument("tables", nargs="+")
        ap.add_argument("--truth", default=None, help="OUT_DIR/truth.json (default: LENS)")
        a = ap.parse_args(argv[1:])
        lens = json.loads(Path(a.truth).read_text())["lens"] if a.truth else None
        for t in a.tables:
            check(t, lens)
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("raws", nargs="*")
    ap.add_argument("--holdout", nargs="*", default=None)
    ap.add_argument("--crop", default=None, help="central crop HxW (even)")
    ap.add_argument("--seed", type=int, default=0,
                    help="another lens of the family (random_lens); 0: LENS")
    a = ap.parse_args(argv)
    out = Path(a.out)
    train = _raws(a.raws) if a.raws else sorted((SOURCE / "frames").glob("*.tif"))
    hold = (_raws(a.holdout) if a.holdout is not None
            else [] if a.raws else sorted((SOURCE / "holdout").glob("*.tif")))
    crop = tuple(int(x) for x in a.crop.lower().split("x")) if a.crop else None
    lens = random_lens(a.seed)
    for part, paths in (("frames", train), ("holdout", hold)):
        for p in paths:
            make_one(p, out, part, crop, lens)
    out.mkdir(parents=True, exist_ok=True)
    (out / "truth.json").write_text(json.dumps({"lens": lens, "seed": a.seed, "wb_gains": WB_GAINS,
                                                "matrix": MATRIX.tolist()}, indent=1) + "\n")


if __name__ == "__main__":
    sys.exit(main())
