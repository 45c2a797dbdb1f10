"""Spectral data: QE presets, filters, illuminants, reflectances and CMFs.

Everything is a :class:`Spectra`: a wavelength grid in nm (strictly
increasing) and one column of values per named channel. Bundled data live in
``l3cli/data/spectral/`` as small CSV files (``#`` comment lines, then a header
``wavelength_nm,NAME,...``) converted from ISETCam (MIT licence); CIE data
(colour-matching functions, standard illuminants) come from colour-science.

User CSV files use the same layout (comment lines optional). Wavelengths must
be strictly increasing, values finite and non-negative.

Resampling is linear interpolation; asking for a wavelength outside the
tabulated range is an error (:func:`Spectra.resample`), never a silent
extrapolation.

References
----------
.. [1] ISETCam, Stanford Center for Image Systems Engineering,
   https://github.com/ISET/isetcam (data/sensor, data/lights, data/surfaces).
.. [2] CIE 015:2018 Colorimetry, 4th edition (CIE 1931 2° observer, illuminants
   A, D-series).
.. [3] Mallett, I. and Yuksel, C. (2019). Spectral Primary Decomposition for
   Rendering with sRGB Reflectance. Eurographics Symposium on Rendering.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from l3cli.errors import ConfigError, InputError

__all__ = [
    "Spectra",
    "DATA_DIR",
    "QE_PRESETS",
    "IR_FILTERS",
    "ILLUMINANTS",
    "read_spectra_csv",
    "load_qe",
    "load_ir_filter",
    "load_illuminant",
    "macbeth_reflectances",
    "nir_extension",
    "mallett2019_basis",
    "cie_cmfs",
    "luminous_efficiency",
    "wavelength_grid",
    "H_PLANCK",
    "C_LIGHT",
    "KM",
]

#: Folder of bundled spectral CSV files.
DATA_DIR = Path(__file__).resolve().parent / "data" / "spectral"

H_PLANCK = 6.62607015e-34  #: Planck constant, J s
C_LIGHT = 2.99792458e8  #: speed of light, m/s
KM = 683.002  #: maximum luminous efficacy, lm/W (CIE)

#: QE preset name -> (CSV file, description). Columns are CFA channel names.
QE_PRESETS: dict[str, tuple[str, str]] = {
    "bayer-rgb": ("qe_bayer_rgb.csv", "ISETCam default RGB filters, 370-730 nm"),
    "interleaved-rgbw": ("qe_interleaved_rgbw.csv", "ISETCam interleaved RGBW (R,G,B,W), 380-1068 nm"),
    "rgb-nir": ("qe_rgb_nir.csv", "IR-blocked R,G,B plus an NIR pixel (ISETCam cfaRGBNearIR), 380-1068 nm"),
    "nikon-d200-ir": ("qe_nikon_d200_ir.csv", "Nikon D200 without IR-cut filter, 380-1068 nm"),
    "mt9v024-rgb": ("qe_mt9v024_rgb.csv", "Aptina MT9V024 RGB, 380-1080 nm"),
    "mt9v024-rgbw": ("qe_mt9v024_rgbw.csv", "Aptina MT9V024 RGBW, 380-1080 nm"),
}

#: IR-cut filter name -> (CSV file, description); "none" means no filter.
IR_FILTERS: dict[str, tuple[str | None, str]] = {
    "none": (None, "no IR-cut filter (transmittance 1)"),
    "ircf-public": ("filter_ircf_public.csv", "Largan K098-BIR690UV IR-cut filter, 350-1200 nm"),
    "schott": ("filter_schott_ir_cut.csv", "Schott IR-cut filter, 380-1068 nm"),
}

_CIE_ILLUMINANTS = ("D50", "D55", "D65", "D75", "FL2", "FL7", "FL11", "LED-B3")

#: Illuminant name -> description.
ILLUMINANTS: dict[str, str] = {
    "A": "CIE illuminant A (Planckian 2856 K, any wavelength range)",
    "E": "equal-energy illuminant (any wavelength range)",
    **{n: f"CIE {n} (colour-science, 300-780 nm)" for n in _CIE_ILLUMINANTS},
    "visir-A": "ISETCam measured tungsten (Gretag booth A), 380-1068 nm",
    "visir-CWF": "ISETCam measured cool white fluorescent, 380-1068 nm",
    "visir-DAY": "ISETCam measured daylight simulator, 380-1068 nm",
    "visir-U30": "ISETCam measured U30 fluorescent, 380-1068 nm",
}


@dataclass(frozen=True)
class Spectra:
    """Spectral functions on a common wavelength grid.

    Parameters
    ----------
    wavelengths
        (N,) nm, strictly increasing.
    values
        (N, K) one column per name.
    names
        K column names.
    source
        Where the data came from (a file or a description), for messages.
    """

    wavelengths: np.ndarray
    values: np.ndarray
    names: tuple[str, ...]
    source: str

    def __post_init__(self) -> None:
        wl = np.asarray(self.wavelengths, dtype=np.float64)
        v = np.asarray(self.values, dtype=np.float64)
        if v.ndim == 1:
            v = v[:, None]
        object.__setattr__(self, "wavelengths", wl)
        object.__setattr__(self, "values", v)
        if wl.ndim != 1 or v.shape[0] != wl.size or v.shape[1] != len(self.names):
            raise InputError(f"{self.source}: wavelengths {wl.shape} and values {v.shape} "
                             f"do not match {len(self.names)} names")
        if wl.size < 2 or np.any(np.diff(wl) <= 0):
            raise InputError(f"{self.source}: wavelengths must be strictly increasing "
                             "(at least two samples)")
        if not np.all(np.isfinite(v)):
            raise InputError(f"{self.source}: values must be finite numbers")

    def column(self, name: str) -> np.ndarray:
        """Values of one named column (N,)."""
        if name not in self.names:
            raise ConfigError(f"{self.source}: no column {name!r}; columns are "
                              f"{', '.join(self.names)}")
        return self.values[:, self.names.index(name)]

    def covers(self, wavelengths: np.ndarray) -> bool:
        """Whether the tabulated range includes every wavelength given."""
        wl = np.asarray(wavelengths, dtype=np.float64)
        return bool(wl.min() >= self.wavelengths[0] - 1e-6 and wl.max() <= self.wavelengths[-1] + 1e-6)

    def resample(self, wavelengths: np.ndarray, *, what: str = "data") -> np.ndarray:
        """Linearly interpolate onto ``wavelengths``; (M, K).

        Raises
        ------
        ConfigError
            If ``wavelengths`` reaches outside the tabulated range.
        """
        wl = np.asarray(wavelengths, dtype=np.float64)
        if not self.covers(wl):
            raise ConfigError(
                f"{self.source}: {what} covers {self.wavelengths[0]:g}-{self.wavelengths[-1]:g} nm "
                f"but the simulation needs {wl.min():g}-{wl.max():g} nm; choose a wavelength "
                "range inside it ([spectrum] wavelength_nm) or data that cover the range"
            )
        return np.stack([np.interp(wl, self.wavelengths, self.values[:, k])
                         for k in range(self.values.shape[1])], axis=1)


def read_spectra_csv(path: str | os.PathLike, *, kind: str = "spectral data",
                     nonnegative: bool = True) -> Spectra:
    """Read a spectral CSV: optional ``#`` comments, header, numeric rows.

    Parameters
    ----------
    path
        CSV file; the first column is wavelength in nm (header ``wavelength_nm``
        or ``wavelength``), then one column per channel.
    kind
        What the data are (for error messages).
    nonnegative
        Reject negative values.

    Raises
    ------
    InputError
        Missing/unreadable file, non-numeric cells, wavelengths not strictly
        increasing, negative or non-finite values.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read {kind} CSV ({exc.__class__.__name__}: {exc})") from None
    rows = [r for r in csv.reader(line for line in text.splitlines()
                                  if line.strip() and not line.lstrip().startswith("#"))]
    if len(rows) < 3:
        raise InputError(f"{path}: {kind} CSV needs a header and at least two rows")
    header = [h.strip() for h in rows[0]]
    if len(header) < 2 or header[0].lower() not in ("wavelength_nm", "wavelength", "nm"):
        raise InputError(f"{path}: {kind} CSV header must start with 'wavelength_nm' then "
                         f"one column per channel, got {','.join(header)!r}")
    data = []
    for i, r in enumerate(rows[1:], start=2):
        if len(r) != len(header):
            raise InputError(f"{path}: data row {i - 1} has {len(r)} cells, header has {len(header)}")
        try:
            data.append([float(c) for c in r])
        except ValueError:
            raise InputError(f"{path}: data row {i - 1} has a non-numeric cell: {','.join(r)!r}") from None
    arr = np.asarray(data, dtype=np.float64)
    wl = arr[:, 0]
    if np.any(np.diff(wl) <= 0):
        bad = int(np.argmax(np.diff(wl) <= 0))
        raise InputError(f"{path}: wavelengths must be strictly increasing "
                         f"({wl[bad]:g} nm is followed by {wl[bad + 1]:g} nm)")
    vals = arr[:, 1:]
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{path}: {kind} values must be finite numbers")
    if nonnegative and np.any(vals < 0):
        k = np.argwhere(vals < 0)[0]
        raise InputError(f"{path}: {kind} must be non-negative; {header[k[1] + 1]} is "
                         f"{vals[k[0], k[1]]:g} at {wl[k[0]]:g} nm")
    return Spectra(wl, vals, tuple(header[1:]), str(path))


@lru_cache(maxsize=32)
def _bundled(filename: str, nonnegative: bool = True) -> Spectra:
    return read_spectra_csv(DATA_DIR / filename, nonnegative=nonnegative)


def _unknown(what: str, name: str, valid: dict) -> ConfigError:
    return ConfigError(f"unknown {what} {name!r}; valid: {', '.join(valid)} (or a path to a CSV file)")


def _is_path(name: str) -> bool:
    return "/" in name or os.sep in name or name.lower().endswith(".csv")


def load_qe(name_or_path: str, *, base: Path | None = None) -> Spectra:
    """Quantum efficiency (electrons per photon) per CFA channel.

    Parameters
    ----------
    name_or_path
        A preset from :data:`QE_PRESETS` or a CSV path (relative paths are
        taken relative to ``base``, usually the camera file's folder).
    """
    if name_or_path in QE_PRESETS:
        return _bundled(QE_PRESETS[name_or_path][0])
    if _is_path(name_or_path):
        p = Path(name_or_path)
        if not p.is_absolute() and base is not None:
            p = base / p
        return read_spectra_csv(p, kind="QE")
    raise _unknown("QE preset", name_or_path, QE_PRESETS)


def load_ir_filter(name_or_path: str, *, base: Path | None = None) -> Spectra | None:
    """IR-cut filter transmittance (one column), or None for ``"none"``."""
    if name_or_path in IR_FILTERS:
        fname = IR_FILTERS[name_or_path][0]
        return None if fname is None else _bundled(fname)
    if _is_path(name_or_path):
        p = Path(name_or_path)
        if not p.is_absolute() and base is not None:
            p = base / p
        s = read_spectra_csv(p, kind="IR-cut filter transmittance")
        if s.values.shape[1] != 1:
            raise InputError(f"{p}: an IR-cut filter CSV has one value column, got "
                             f"{s.values.shape[1]}")
        return s
    raise _unknown("IR-cut filter", name_or_path, IR_FILTERS)


def _cie_a(wl: np.ndarray) -> np.ndarray:
    # CIE 015:2018 eq. 2.1 (relative, 100 at 560 nm).
    c2 = 1.435e7
    return 100.0 * (560.0 / wl) ** 5 * (np.expm1(c2 / (2848.0 * 560.0)) / np.expm1(c2 / (2848.0 * wl)))


def load_illuminant(name: str, wavelengths: np.ndarray) -> np.ndarray:
    """Relative spectral power (energy units) of an illuminant on ``wavelengths``.

    Raises
    ------
    ConfigError
        Unknown name (lists the valid ones) or a range that does not cover
        ``wavelengths``.
    """
    wl = np.asarray(wavelengths, dtype=np.float64)
    if name == "A":
        return _cie_a(wl)
    if name == "E":
        return np.ones_like(wl)
    if name in _CIE_ILLUMINANTS:
        import colour

        sd = colour.SDS_ILLUMINANTS[name]
        s = Spectra(sd.wavelengths, sd.values, (name,), f"illuminant {name}")
        return s.resample(wl, what="illuminant")[:, 0]
    if name.startswith("visir-") and name in ILLUMINANTS:
        s = _bundled(f"illuminant_visir_{name[6:]}.csv")
        return s.resample(wl, what=f"illuminant {name}")[:, 0]
    raise ConfigError(f"unknown illuminant {name!r}; valid: {', '.join(ILLUMINANTS)}")


def macbeth_reflectances(wavelengths: np.ndarray) -> np.ndarray:
    """The 24 Macbeth ColorChecker reflectances (ISETCam, 380-1068 nm); (N, 24).

    Patches are in reading order: 0 = dark skin, 18 = white, 23 = black.
    """
    return _bundled("reflectance_macbeth.csv").resample(wavelengths, what="Macbeth reflectances")


def mallett2019_basis(wavelengths: np.ndarray) -> np.ndarray:
    """Mallett & Yuksel (2019) sRGB reflectance basis on ``wavelengths``; (N, 3).

    Within 380-780 nm the colour-science table; outside it the basis is not
    defined and the caller must extend it (see :func:`nir_extension`).
    """
    import colour

    b = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019
    wl = np.asarray(wavelengths, dtype=np.float64)
    return np.stack([np.interp(wl, b.wavelengths, b.values[:, k]) for k in range(3)], axis=1)


def nir_extension() -> Spectra:
    """NIR reflectance model ``c0 + cr r + cg g + cb b`` for λ ≥ 680 nm (columns c0, cr, cg, cb).

    Fitted by least squares to the 137 ISETCam Macbeth + Esser reflectances
    (380-1068 nm); see ``l3cli/data/spectral/README.md``.
    """
    return _bundled("nir_extension.csv", nonnegative=False)


@lru_cache(maxsize=8)
def _cmfs_table() -> tuple[np.ndarray, np.ndarray]:
    import colour

    c = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    return np.asarray(c.wavelengths, float), np.asarray(c.values, float)


def cie_cmfs(wavelengths: np.ndarray) -> np.ndarray:
    """CIE 1931 2° colour-matching functions on ``wavelengths``; (N, 3).

    Zero outside the tabulated 360-830 nm (the functions are < 1e-6 there).
    """
    wl_t, v = _cmfs_table()
    wl = np.asarray(wavelengths, dtype=np.float64)
    return np.stack([np.interp(wl, wl_t, v[:, k], left=0.0, right=0.0) for k in range(3)], axis=1)


def luminous_efficiency(wavelengths: np.ndarray) -> np.ndarray:
    """Photopic luminous efficiency V(λ) (= CIE 1931 ȳ) on ``wavelengths``; (N,)."""
    return cie_cmfs(wavelengths)[:, 1]


def wavelength_grid(start: float, stop: float, step: float) -> np.ndarray:
    """Inclusive wavelength grid ``start, start+step, ..., stop`` in nm."""
    n = int(round((stop - start) / step)) + 1
    return start + step * np.arange(n, dtype=np.float64)
