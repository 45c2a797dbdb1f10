"""Regenerate the bundled spectral CSV files from the ISETCam data (maintainers only).

Run from the repository root::

    .venv/bin/python l3cli/data/spectral/convert_isetcam.py /path/to/isetcam/data

It reads ISETCam ``.mat`` files with ``scipy.io.loadmat(path, squeeze_me=True)``
and writes one CSV per data set next to this script (see README.md). Nothing in
l3 imports this script; the CSV files are what the simulator reads.

References
----------
.. [1] ISETCam, Stanford Center for Image Systems Engineering,
   https://github.com/ISET/isetcam (MIT licence; horizon-research fork, commit ad56275).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.io as sio

HERE = Path(__file__).resolve().parent


def _load(root: Path, rel: str) -> tuple[np.ndarray, np.ndarray, str]:
    m = sio.loadmat(root / rel, squeeze_me=True)
    wl = np.atleast_1d(m["wavelength"]).astype(np.float64)
    data = np.asarray(m["data"], dtype=np.float64)
    if data.ndim == 1:
        data = data[:, None]
    comment = str(m.get("comment", "")).replace("\n", " ")
    return wl, data, comment


def _write(name: str, kind: str, units: str, source: str, note: str,
           wl: np.ndarray, cols: dict[str, np.ndarray]) -> None:
    lines = [
        f"# kind: {kind}",
        f"# units: {units}",
        f"# source: {source}",
        "# licence: MIT (ISETCam), see LICENSE_isetcam_MIT.txt",
    ]
    if note:
        lines.append(f"# note: {note}")
    lines.append("wavelength_nm," + ",".join(cols))
    arr = np.column_stack([cols[k] for k in cols])
    for w, row in zip(wl, arr, strict=True):
        vals = ",".join(f"{v:.6g}" for v in row)
        lines.append(f"{w:g},{vals}")
    (HERE / f"{name}.csv").write_text("\n".join(lines) + "\n")


def _on(wl_src: np.ndarray, values: np.ndarray, wl: np.ndarray, *, hold: bool = False) -> np.ndarray:
    if hold:
        return np.interp(wl, wl_src, values)
    return np.interp(wl, wl_src, values, left=np.nan, right=np.nan)


def main(root: Path) -> None:
    """Convert the ISETCam ``data/`` folder at ``root`` into the bundled CSV files."""
    # --- QE presets ------------------------------------------------------
    wl, d, _ = _load(root, "sensor/colorfilters/RGB.mat")
    _write("qe_bayer_rgb", "qe", "electrons per photon",
           "ISETCam data/sensor/colorfilters/RGB.mat ('Default RGB sensors')",
           "ISETCam default sensor colour filters with an ideal photodetector (QE 1)",
           wl, {"R": d[:, 0], "G": d[:, 1], "B": d[:, 2]})

    wl, d, _ = _load(root, "sensor/colorfilters/interleavedRGBW.mat")
    keep = slice(None, None, 2)  # 2 nm is plenty
    _write("qe_interleaved_rgbw", "qe", "electrons per photon",
           "ISETCam data/sensor/colorfilters/interleavedRGBW.mat ('Converted from RGBSi')",
           "every 2nd nm", wl[keep], {"R": d[keep, 0], "G": d[keep, 1], "B": d[keep, 2],
                                      "W": d[keep, 3]})
    si_wl, si = wl, d[:, 3]

    wl, d, _ = _load(root, "sensor/cfa/cfaRGBNearIR.mat")
    pw, pd, _ = _load(root, "sensor/irfilters/irPassFilter.mat")
    ir_pass = _on(pw, pd[:, 0], wl, hold=True)  # held flat outside 415-945 nm
    ir_pass[wl < pw[0]] = 0.0
    si_on = np.interp(wl, si_wl, si)
    keep = slice(None, None, 2)
    _write("qe_rgb_nir", "qe", "electrons per photon",
           "ISETCam data/sensor/cfa/cfaRGBNearIR.mat (R, G, B filters), "
           "irfilters/irPassFilter.mat (NIR pass), colorfilters/interleavedRGBW.mat (W = silicon QE)",
           "R,G,B = cfaRGBNearIR filter x silicon QE (IR-blocked); NIR = IR-pass filter "
           "(held at its 945 nm value to 1068 nm) x silicon QE; every 2nd nm",
           wl[keep], {"R": (d[:, 0] * si_on)[keep], "G": (d[:, 1] * si_on)[keep],
                      "B": (d[:, 2] * si_on)[keep], "NIR": (ir_pass * si_on)[keep]})

    wl, d, c = _load(root, "sensor/colorfilters/nikon/NikonD200IR.mat")
    _write("qe_nikon_d200_ir", "qe", "electrons per photon (relative, peak 0.8)",
           f"ISETCam data/sensor/colorfilters/nikon/NikonD200IR.mat ('{c}')",
           "Nikon D200 sensitivities without its IR-cut filter", wl,
           {"R": d[:, 0], "G": d[:, 1], "B": d[:, 2]})

    wl, d, c = _load(root, "sensor/colorfilters/auto/MT9V024_RGB.mat")
    _write("qe_mt9v024_rgb", "qe", "electrons per photon",
           f"ISETCam data/sensor/colorfilters/auto/MT9V024_RGB.mat ('{c}')", "", wl,
           {"R": d[:, 0], "G": d[:, 1], "B": d[:, 2]})
    wl, d, c = _load(root, "sensor/colorfilters/auto/MT9V024_RGBW.mat")
    _write("qe_mt9v024_rgbw", "qe", "electrons per photon",
           f"ISETCam data/sensor/colorfilters/auto/MT9V024_RGBW.mat ('{c}')", "", wl,
           {"R": d[:, 0], "G": d[:, 1], "B": d[:, 2], "W": d[:, 3]})

    # --- IR-cut filters --------------------------------------------------
    wl, d, c = _load(root, "sensor/ircf_public.mat")
    keep = slice(None, None, 2)
    _write("filter_ircf_public", "filter", "transmittance",
           f"ISETCam data/sensor/ircf_public.mat ('{c}')", "every 2nd nm", wl[keep],
           {"T": d[keep, 0]})
    wl, d, c = _load(root, "sensor/irfilters/irFilter_schott.mat")
    _write("filter_schott_ir_cut", "filter", "transmittance",
           f"ISETCam data/sensor/irfilters/irFilter_schott.mat ('{c}')", "", wl, {"T": d[:, 0]})

    # --- Illuminants (visible + IR) -------------------------------------
    for tag in ("A", "CWF", "DAY", "U30"):
        wl, d, _ = _load(root, f"lights/visible_ir/ill_{tag}.mat")
        _write(f"illuminant_visir_{tag}", "illuminant", "relative spectral radiance (energy)",
               f"ISETCam data/lights/visible_ir/ill_{tag}.mat (Gretag light booth, measured)",
               "", wl, {"S": d[:, 0]})

    # --- Reflectances ------------------------------------------------------
    wl, d, c = _load(root, "surfaces/reflectances/macbethChart.mat")
    # ISETCam stores the chart column by column (4 rows); reorder to reading order.
    order = [col * 4 + row for row in range(4) for col in range(6)]
    cols = {f"P{i:02d}": d[:, j] for i, j in enumerate(order)}
    _write("reflectance_macbeth", "reflectance", "reflectance (0-1)",
           "ISETCam data/surfaces/reflectances/macbethChart.mat",
           "24 patches in reading order (P00 = dark skin, P18 = white, P23 = black)", wl, cols)

    _esser(root)

    # NIR extension basis: least-squares fit of reflectance(lambda > 680 nm) to
    # [1, r, g, b], where (r, g, b) are the linear sRGB values whose Mallett 2019
    # reflectance best fits the measured visible reflectance (400-700 nm).
    import colour

    basis = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019
    refl = []
    for rel in ("surfaces/reflectances/macbethChart.mat", "surfaces/reflectances/esserChart.mat"):
        wl, d, _ = _load(root, rel)
        refl.append(d)
    refl = np.concatenate(refl, axis=1)  # (173, 137), 380-1068 nm every 4 nm
    vis = (wl >= 400) & (wl <= 700)
    b_vis = np.stack([np.interp(wl[vis], basis.wavelengths, basis.values[:, k])
                      for k in range(3)], axis=1)
    rgb, *_ = np.linalg.lstsq(b_vis, refl[vis], rcond=None)  # (3, 137)
    rgb = np.clip(rgb, 0, 1)
    design = np.concatenate([np.ones((1, rgb.shape[1])), rgb], axis=0).T  # (137, 4)
    nir = wl >= 680
    coef, *_ = np.linalg.lstsq(design, refl[nir].T, rcond=None)  # (4, n_nir)
    resid = refl[nir].T - design @ coef
    rms = float(np.sqrt(np.mean(resid**2)))
    _write("nir_extension", "reflectance basis", "reflectance per unit coefficient",
           "fitted to ISETCam macbethChart.mat + esserChart.mat (137 reflectances, 380-1068 nm)",
           f"reflectance(lambda) = c0 + cr*r + cg*g + cb*b for lambda >= 680 nm, with (r,g,b) "
           f"the linear sRGB Mallett 2019 coefficients of the visible part; rms residual {rms:.4f}",
           wl[nir], {"c0": coef[0], "cr": coef[1], "cg": coef[2], "cb": coef[3]})
    print(f"NIR extension fit rms residual {rms:.4f}")


def _esser(root: Path) -> None:
    """The Esser chart's 113 reflectances (380-1068 nm), every 2nd sample (8 nm)."""
    wl, d, c = _load(root, "surfaces/reflectances/esserChart.mat")
    keep = slice(None, None, 2)
    _write("reflectance_esser", "reflectance", "reflectance (0-1)",
           f"ISETCam data/surfaces/reflectances/esserChart.mat ('{c}')",
           "113 patches (E000-E112) in ISETCam's column order; every 2nd sample (8 nm)",
           wl[keep], {f"E{i:03d}": d[keep, i] for i in range(d.shape[1])})


if __name__ == "__main__":
    main(Path(sys.argv[1]))
