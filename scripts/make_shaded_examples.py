#!/usr/bin/env python3
"""The bundled Infinite-ISP frames with a known lens shading on the raws (issue 27).

    scripts/make_shaded_examples.py OUT_DIR

Writes ``OUT_DIR/frames`` and ``OUT_DIR/holdout``: every raw of
``examples/infinite_isp`` darkened by a known per-channel radial fall-off
(:func:`shading_map`, a cos^4-like law about an off-centre optical centre,
different per colour), written with 8 more bits (:data:`SCALE`; pixels
clipped in the source stay clipped); the renders (the targets) are copied
unchanged. A camera that corrects its lens shading before
rendering looks like this: its raws are shaded, its renders are not.

``docs/training.md`` ("Lens shading") measures ``l3 train --shading`` on it;
``tests/lens/test_field.py`` checks that the learned field undoes the shading.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "examples" / "infinite_isp"
#: Optical centre (cy, cx) in normalised coordinates (l3cli.lens.field.normalised_coords).
CENTRE = (0.06, -0.09)
#: Per colour: relative illumination (1 + k r^2)^-2 (cos^4 of a lens whose tan of the
#: field angle is sqrt(k) r): at the corners (r ~ 1) R 0.64, G 0.69, B 0.56.
STRENGTH = {"R": 0.25, "G": 0.20, "B": 0.34}


def shading_map(height: int, width: int, cfa) -> np.ndarray:
    """The relative illumination of each pixel (float64 (H, W), 1 at the centre)."""
    from l3cli.lens.field import normalised_coords

    v, u = normalised_coords(height, width)
    r2 = (v[:, None] - CENTRE[0]) ** 2 + (u[None, :] - CENTRE[1]) ** 2
    k = np.array([STRENGTH[c] for c in cfa.channels])[cfa.channel_map(height, width)]
    return (1.0 + k * r2) ** -2


#: The shaded raws keep 8 more bits than the 8-bit source (16-bit TIFFs, levels x 256):
#: the lens darkens the light before a real sensor quantises it, so its corners are
#: quantised as finely as its centre relative to their signal; requantising the
#: darkened 8-bit values to 8 bits would add noise that no camera has and that the
#: renders (made from the unshaded raws) do not show.
SCALE = 256


def shade(src: Path, dst: Path) -> None:
    """Write a shaded copy of the raw ``src`` (16-bit TIFF + sidecar) at ``dst``."""
    import tomllib

    import tifffile

    from l3cli.io.raw import read_raw

    raw = read_raw(src)
    dn = tifffile.imread(src).astype(np.float64)
    black = raw.black_level.reshape(raw.cfa.period)
    bl = np.tile(black, (dn.shape[0] // black.shape[0] + 1,
                         dn.shape[1] // black.shape[1] + 1))[:dn.shape[0], :dn.shape[1]]
    out = SCALE * (bl + (dn - bl) * shading_map(*dn.shape, raw.cfa))
    # a pixel clipped in the source stays clipped: its light was at least the white
    # level, so the shaded sensor's value is unknown, not a shaded copy of the clip
    out = np.where(dn >= raw.white_level, SCALE * dn, out)
    tifffile.imwrite(dst, np.clip(np.round(out), 0, 65535).astype(np.uint16),
                     compression="zlib")
    side = tomllib.loads(Path(str(src) + ".toml").read_text())
    lines = [f'cfa = "{side["cfa"]}"', f"black_level = {SCALE * side['black_level']}",
             f"white_level = {SCALE * side['white_level']}", "bit_depth = 16",
             f'description = "{side.get("description", "")}, lens shading of '
             f'scripts/make_shaded_examples.py"']
    Path(str(dst) + ".toml").write_text("\n".join(lines) + "\n")


def main(out_dir: str) -> None:
    out = Path(out_dir)
    for part in ("frames", "holdout"):
        (out / part).mkdir(parents=True, exist_ok=True)
        for tif in sorted((SOURCE / part).glob("*.tif")):
            shade(tif, out / part / tif.name)
            shutil.copyfile(tif.with_suffix(".png"), out / part / tif.with_suffix(".png").name)
    shutil.copyfile(SOURCE / "charts.json", out / "charts.json")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
