#!/usr/bin/env python3
"""Write a spectral cube of the Esser chart's measured reflectances (to 1068 nm).

``esser.py OUT.npz [WxH [SHADE]]`` tiles the 113 bundled Esser reflectances
(``l3cli/data/spectral/reflectance_esser.csv``, ISETCam, MIT) into a
``wavelength`` + ``reflectance`` cube for ``l3 simulate --scene OUT.npz``:
three bands of square patches (1/24, 1/12 and 1/6 of the height wide), each
band a seeded shuffle of the patches with no gaps, so the chart has edges
between varied neighbours as well as flat interiors. Unlike the bundled
photos, whose near-infrared reflectance is modelled from their RGB, these
reflectances are measured into the near infrared, where the RGBW camera's W and
R pixels respond.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

CSV = Path(__file__).resolve().parents[2] / "l3cli" / "data" / "spectral" / "reflectance_esser.csv"


def esser_cube(width: int = 320, height: int = 240, seed: int = 0,
               shade: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``(wavelength (N,), reflectance (height, width, N))`` of the tiled Esser chart.

    With ``shade > 1`` each patch is dimmed by its own factor, log-uniform over
    ``1/shade .. 1`` (a chart in uneven light), so every colour also appears
    at low response levels.
    """
    rows = [ln for ln in CSV.read_text().splitlines() if ln and not ln.startswith("#")]
    table = np.array([[float(v) for v in ln.split(",")] for ln in rows[1:]])  # rows[0]: header
    wl, refl = table[:, 0], table[:, 1:].T  # (113, N)
    rng = np.random.default_rng(seed)
    cube = np.empty((height, width, wl.size), dtype=np.float32)
    bands = ((0, height // 6, max(height // 24, 1)), (height // 6, height // 2, max(height // 12, 1)),
             (height // 2, height, max(height // 6, 1)))
    for y0, y1, size in bands:
        ny, nx = -(-(y1 - y0) // size), -(-width // size)
        order = np.concatenate([rng.permutation(len(refl)) for _ in range(-(-ny * nx // len(refl)))])
        idx = order[:ny * nx].reshape(ny, nx)
        tile = np.repeat(np.repeat(idx, size, axis=0), size, axis=1)[: y1 - y0, :width]
        dim = np.exp(rng.uniform(-np.log(shade), 0.0, size=idx.shape)) if shade > 1 else np.ones(idx.shape)
        fac = np.repeat(np.repeat(dim, size, axis=0), size, axis=1)[: y1 - y0, :width]
        cube[y0:y1] = refl[tile] * fac[..., None].astype(np.float32)
    return wl, cube


def main(out: Path, size: str = "320x240", shade: str = "1") -> None:
    w, h = (int(v) for v in size.lower().split("x"))
    wl, cube = esser_cube(w, h, shade=float(shade))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.stem + ".tmp.npz")
    np.savez_compressed(tmp, wavelength=wl, reflectance=cube)
    tmp.replace(out)


if __name__ == "__main__":
    main(Path(sys.argv[1]), *sys.argv[2:4])
