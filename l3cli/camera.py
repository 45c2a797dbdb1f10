"""Camera description: a TOML file → validated frozen dataclasses.

A camera file has the sections ``[optics]``, ``[pixel]``, ``[readout]``,
``[cfa]``, ``[spectrum]`` and ``[exposure]`` (every key, unit, default and
range: ``docs/camera-toml.md``; examples: ``sample_configs/``). Unknown keys,
wrong types and out-of-range values raise :class:`l3cli.errors.ConfigError`
naming the file, the dotted key and what is allowed; a TOML syntax error names
the file and line.

Pixel electronics follow ISETCam's model: a conversion gain (µV per
electron), a voltage swing (V) and a full well (electrons) with
``full_well = swing / conversion_gain`` — give any two of the three.

References
----------
.. [1] Farrell, J. E., Catrysse, P. B. and Wandell, B. A. (2012). Digital camera
   simulation. Applied Optics 51(4), A80-A90.
.. [2] ISETCam sensorCreate / pixelCreate defaults,
   https://github.com/ISET/isetcam.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import MISSING, asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from l3cli.cfa import CFA
from l3cli.errors import ConfigError, InputError

__all__ = [
    "Camera",
    "Optics",
    "Pixel",
    "Readout",
    "CFAConfig",
    "Spectrum",
    "Exposure",
    "load_camera",
    "camera_from_dict",
]


@dataclass(frozen=True)
class Optics:
    """Diffraction-limited lens (circular aperture, incoherent light).

    Attributes
    ----------
    f_number
        Working f-number N (image-space), 0.5-64.
    focal_length_mm
        Focal length in mm (field angle for cos⁴ fall-off).
    transmittance
        Lens transmittance (0, 1], spectrally flat.
    cos4
        Apply off-axis cos⁴ irradiance fall-off.
    shading_corrected
        The camera corrects its lens shading: cos⁴ acts on the raw only and the
        target is the unshaded image (False: on both, as an uncorrected camera).
    relative_illumination
        None, or a measured per-channel fall-off of the raw (``{"radius": [...],
        channel: [...]}``, relative to the centre, linear in the normalised
        radius of :func:`l3cli.lens.field.normalised_coords`): acts on the raw only.
    """

    f_number: float = 4.0
    focal_length_mm: float = 4.0
    transmittance: float = 1.0
    cos4: bool = False
    shading_corrected: bool = False
    relative_illumination: dict | None = None


@dataclass(frozen=True)
class Pixel:
    """Pixel geometry and photodetector electronics (electrons and volts)."""

    pitch_um: float
    fill_factor: float
    conversion_gain_uv_per_e: float
    voltage_swing_v: float
    full_well_e: float
    read_noise_e: float
    dark_current_e_per_s: float
    dsnu_e: float
    prnu_percent: float

    @property
    def area_m2(self) -> float:
        """Light-sensitive area of one pixel in m² (pitch² × fill factor)."""
        return (self.pitch_um * 1e-6) ** 2 * self.fill_factor


@dataclass(frozen=True)
class Readout:
    """Analog gain and ADC."""

    analog_gain: float = 1.0
    bit_depth: int = 10
    black_level_dn: int = 64
    black_clamp: bool = False

    @property
    def white_level_dn(self) -> int:
        """Largest digital number, ``2**bit_depth - 1``."""
        return (1 << self.bit_depth) - 1


@dataclass(frozen=True)
class CFAConfig:
    """Colour filter array and the spectral QE of each of its channels.

    Attributes
    ----------
    cfa
        The pattern (:class:`l3cli.cfa.CFA`).
    qe
        QE preset name (:data:`l3cli.spectral.QE_PRESETS`) or CSV path as written.
    qe_source
        Resolved source: the preset name or the absolute CSV path.
    channel_columns
        (CFA channel, QE column) pairs, in ``cfa.channels`` order.
    ir_cut
        IR-cut filter name or CSV path (``"none"`` for none).
    ir_cut_source
        Resolved filter source.
    """

    cfa: CFA
    qe: str
    qe_source: str
    channel_columns: tuple[tuple[str, str], ...]
    ir_cut: str
    ir_cut_source: str


@dataclass(frozen=True)
class Spectrum:
    """Wavelength sampling of the simulation (nm, inclusive)."""

    start_nm: float
    stop_nm: float
    step_nm: float

    @property
    def wavelengths(self) -> np.ndarray:
        """The grid (N,) in nm."""
        from l3cli.spectral import wavelength_grid

        return wavelength_grid(self.start_nm, self.stop_nm, self.step_nm)


@dataclass(frozen=True)
class Exposure:
    """Exposure control and default light levels."""

    mode: str = "auto"
    target_fraction: float = 0.95
    max_time_s: float = 1.0
    max_analog_gain: float = 1.0
    time_s: float = 0.01
    illuminant: str = "D65"
    light_levels_lux: tuple[float, ...] = (10.0, 100.0, 1000.0)


@dataclass(frozen=True)
class Camera:
    """A simulated camera (see ``docs/camera-toml.md``)."""

    name: str
    file: str
    optics: Optics
    pixel: Pixel
    readout: Readout
    cfa: CFAConfig
    spectrum: Spectrum
    exposure: Exposure

    @property
    def wavelengths(self) -> np.ndarray:
        """Simulation wavelength grid in nm (N,)."""
        return self.spectrum.wavelengths

    def qe_curves(self, wavelengths: np.ndarray | None = None) -> np.ndarray:
        """Effective QE (electrons per photon) per CFA channel, IR-cut included; (N, C).

        Columns follow ``self.cfa.cfa.channels``.

        Raises
        ------
        ConfigError
            If the QE or the filter data do not cover the wavelengths.
        """
        from l3cli import spectral

        wl = self.wavelengths if wavelengths is None else np.asarray(wavelengths, float)
        base = Path(self.file).parent if self.file else None
        qe = spectral.load_qe(self.cfa.qe_source, base=base)
        cols = [qe.column(col) for _, col in self.cfa.channel_columns]
        s = spectral.Spectra(qe.wavelengths, np.stack(cols, axis=1),
                             tuple(c for c, _ in self.cfa.channel_columns), qe.source)
        out = s.resample(wl, what="QE")
        filt = spectral.load_ir_filter(self.cfa.ir_cut_source, base=base)
        if filt is not None:
            out = out * filt.resample(wl, what="IR-cut filter")[:, :1]
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able description for the simulation manifest."""
        d: dict[str, Any] = {
            "name": self.name,
            "file": Path(self.file).name if self.file else "",
            "cfa": self.cfa.cfa.spec,
            "cfa_pattern": self.cfa.cfa.to_list(),
            "pixel_pitch_um": self.pixel.pitch_um,
            "f_number": self.optics.f_number,
            "optics": asdict(self.optics),
            "pixel": asdict(self.pixel),
            "readout": {**asdict(self.readout), "white_level_dn": self.readout.white_level_dn},
            "qe": self.cfa.qe_source,
            "channel_columns": [list(p) for p in self.cfa.channel_columns],
            "ir_cut": self.cfa.ir_cut_source,
            "wavelength_nm": [self.spectrum.start_nm, self.spectrum.stop_nm, self.spectrum.step_nm],
            "exposure": {**asdict(self.exposure),
                         "light_levels_lux": list(self.exposure.light_levels_lux)},
        }
        return d


# --------------------------------------------------------------------------
# Validation helpers


class _Section:
    """Reads keys from one TOML table, tracking which were used."""

    def __init__(self, data: Any, prefix: str, file: str):
        if not isinstance(data, dict):
            raise ConfigError(f"{file}: [{prefix}] must be a table, got {type(data).__name__}")
        self.data = data
        self.prefix = prefix
        self.file = file
        self.used: set[str] = set()

    def key(self, k: str) -> str:
        return f"{self.prefix}.{k}" if self.prefix else k

    def err(self, k: str, msg: str) -> ConfigError:
        return ConfigError(f"{self.file}: {self.key(k)} {msg}")

    def number(self, k: str, default: float | None, *, lo: float | None = None,
               hi: float | None = None, lo_open: bool = False, hi_open: bool = False,
               integer: bool = False) -> float | None:
        self.used.add(k)
        if k not in self.data:
            return default
        v = self.data[k]
        if isinstance(v, bool) or not isinstance(v, int | float) or (integer and not isinstance(v, int)):
            kind = "an integer" if integer else "a number"
            raise self.err(k, f"must be {kind}, got {v!r}")
        if not math.isfinite(v):
            raise self.err(k, f"must be finite, got {v!r}")
        low_bad = lo is not None and (v <= lo if lo_open else v < lo)
        high_bad = hi is not None and (v >= hi if hi_open else v > hi)
        if low_bad or high_bad:
            lb = "" if lo is None else ("(" if lo_open else "[") + f"{lo:g}"
            hb = "" if hi is None else f"{hi:g}" + (")" if hi_open else "]")
            rng = f"{lb}, {hb}" if lo is not None and hi is not None else (
                f"{'>' if lo_open else '>='} {lo:g}" if lo is not None else f"{'<' if hi_open else '<='} {hi:g}")
            raise self.err(k, f"= {v!r} is out of range; allowed: {rng}")
        return int(v) if integer else float(v)

    def string(self, k: str, default: str | None, *, choices: tuple[str, ...] | None = None) -> str | None:
        self.used.add(k)
        if k not in self.data:
            return default
        v = self.data[k]
        if not isinstance(v, str):
            raise self.err(k, f"must be a string, got {v!r}")
        if choices is not None and v not in choices:
            raise self.err(k, f"= {v!r} is not allowed; allowed: {', '.join(choices)}")
        return v

    def boolean(self, k: str, default: bool) -> bool:
        self.used.add(k)
        if k not in self.data:
            return default
        v = self.data[k]
        if not isinstance(v, bool):
            raise self.err(k, f"must be true or false, got {v!r}")
        return v

    def raw(self, k: str) -> Any:
        self.used.add(k)
        return self.data.get(k)

    def finish(self, allowed_doc: str = "") -> None:
        extra = sorted(set(self.data) - self.used)
        if extra:
            where = f"[{self.prefix}]" if self.prefix else "the top level"
            raise ConfigError(
                f"{self.file}: unknown key {self.key(extra[0])!r}; keys allowed in {where}: "
                f"{', '.join(sorted(self.used))}"
            )


_SECTIONS = ("optics", "pixel", "readout", "cfa", "spectrum", "exposure")


def _default(cls: type, name: str) -> Any:
    """The default of field ``name`` of dataclass ``cls``: the one place a default is written."""
    for f in fields(cls):
        if f.name == name and f.default is not MISSING:
            return f.default
    raise KeyError(f"{cls.__name__}.{name} has no default")


def _sub(top: _Section, name: str) -> _Section:
    top.used.add(name)
    return _Section(top.data.get(name, {}), name, top.file)


def _pixel(sec: _Section) -> Pixel:
    pitch = sec.number("pitch_um", None, lo=0.2, hi=50.0)
    if pitch is None:
        raise sec.err("pitch_um", "is required (pixel pitch in µm, 0.2-50)")
    ff = sec.number("fill_factor", 1.0, lo=0.0, hi=1.0, lo_open=True)
    cg = sec.number("conversion_gain_uv_per_e", None, lo=0.0, hi=10000.0, lo_open=True)
    swing = sec.number("voltage_swing_v", None, lo=0.0, hi=20.0, lo_open=True)
    fw = sec.number("full_well_e", None, lo=0.0, hi=1e7, lo_open=True)
    given = [x is not None for x in (cg, swing, fw)]
    if sum(given) < 2:
        raise sec.err("conversion_gain_uv_per_e",
                      "missing: give two of conversion_gain_uv_per_e, voltage_swing_v, full_well_e")
    if cg is None:
        cg = swing / fw * 1e6
    elif swing is None:
        swing = fw * cg * 1e-6
    elif fw is None:
        fw = swing / (cg * 1e-6)
    elif abs(fw * cg * 1e-6 - swing) > 1e-3 * swing:
        raise sec.err("full_well_e", f"= {fw:g} is inconsistent with voltage_swing_v / "
                      f"conversion_gain ({swing / (cg * 1e-6):g} e-); give only two of the three")
    if fw < 1.0:
        raise sec.err("full_well_e", f"= {fw:g} e- is below one electron")
    return Pixel(
        pitch_um=pitch, fill_factor=ff, conversion_gain_uv_per_e=cg, voltage_swing_v=swing,
        full_well_e=fw,
        read_noise_e=sec.number("read_noise_e", 2.0, lo=0.0, hi=1000.0),
        dark_current_e_per_s=sec.number("dark_current_e_per_s", 0.0, lo=0.0, hi=1e6),
        dsnu_e=sec.number("dsnu_e", 0.0, lo=0.0, hi=1e4),
        prnu_percent=sec.number("prnu_percent", 0.0, lo=0.0, hi=50.0),
    )


def _cfa(sec: _Section, base: Path | None) -> CFAConfig:
    from l3cli import spectral

    pat = sec.raw("pattern")
    if pat is None:
        raise sec.err("pattern", "is required (e.g. \"RGGB\" or [[\"R\", \"G\"], [\"NIR\", \"B\"]])")
    if not isinstance(pat, str | list):
        raise sec.err("pattern", f"must be a string or a 2-D list of channel names, got {pat!r}")
    try:
        cfa = CFA.from_spec(pat)
    except ConfigError as exc:
        raise sec.err("pattern", f"is not a valid CFA: {exc}") from None
    qe = sec.string("qe", None)
    if qe is None:
        raise sec.err("qe", f"is required: a preset ({', '.join(spectral.QE_PRESETS)}) or a CSV path")
    if qe in spectral.QE_PRESETS:
        qe_source = qe
    elif spectral._is_path(qe):
        p = Path(qe)
        qe_source = str((base / p) if (base is not None and not p.is_absolute()) else p)
    else:
        raise sec.err("qe", f"= {qe!r} is not a QE preset; valid: "
                      f"{', '.join(spectral.QE_PRESETS)} (or a path to a CSV file)")
    try:
        qe_data = spectral.load_qe(qe_source)
    except (InputError, ConfigError) as exc:
        raise ConfigError(f"{sec.file}: cfa.qe: {exc}") from None
    mapping = sec.raw("channels") or {}
    if not isinstance(mapping, dict) or not all(isinstance(v, str) for v in mapping.values()):
        raise sec.err("channels", "must be a table CFA channel = \"QE column\"")
    for k in mapping:
        if k not in cfa.channels:
            raise sec.err(f"channels.{k}", f"is not a channel of the CFA; channels: {', '.join(cfa.channels)}")
    pairs = []
    for ch in cfa.channels:
        col = mapping.get(ch, ch)
        if col not in qe_data.names:
            raise sec.err(f"channels.{ch}" if ch in mapping else "qe",
                          f"has no QE column {col!r} for CFA channel {ch}; columns of {qe}: "
                          f"{', '.join(qe_data.names)} (map channels with cfa.channels)")
        pairs.append((ch, col))
    ir = sec.string("ir_cut", "none")
    if ir in spectral.IR_FILTERS:
        ir_source = ir
    elif spectral._is_path(ir):
        p = Path(ir)
        ir_source = str((base / p) if (base is not None and not p.is_absolute()) else p)
    else:
        raise sec.err("ir_cut", f"= {ir!r} is not an IR-cut filter; valid: "
                      f"{', '.join(spectral.IR_FILTERS)} (or a path to a CSV file)")
    try:
        spectral.load_ir_filter(ir_source)
    except (InputError, ConfigError) as exc:
        raise ConfigError(f"{sec.file}: cfa.ir_cut: {exc}") from None
    return CFAConfig(cfa=cfa, qe=qe, qe_source=qe_source, channel_columns=tuple(pairs),
                     ir_cut=ir, ir_cut_source=ir_source)


def _default_grid(cfa: CFAConfig) -> tuple[float, float, float]:
    """380-780 nm in 5 nm steps (within the QE range), or to 1060 nm in 10 nm steps when
    a channel (after the IR-cut filter) responds beyond 700 nm."""
    from l3cli import spectral

    qe = spectral.load_qe(cfa.qe_source)
    wl = qe.wavelengths
    filt = spectral.load_ir_filter(cfa.ir_cut_source)
    t = np.ones_like(wl) if filt is None else np.interp(wl, filt.wavelengths, filt.values[:, 0])
    cols = np.stack([qe.column(c) for _, c in cfa.channel_columns], axis=1) * t[:, None]
    total = np.trapezoid(cols, wl, axis=0)
    beyond = np.trapezoid(np.where(wl[:, None] > 705, cols, 0.0), wl, axis=0)
    start = max(380.0, math.ceil(wl[0] / 10.0) * 10.0)
    if np.any(beyond > 0.01 * np.maximum(total, 1e-30)) and wl[-1] >= 1000:
        stop = min(1060.0, math.floor(wl[-1] / 10.0) * 10.0)
        return (start, stop, 10.0)
    return (start, min(780.0, math.floor(wl[-1] / 5.0) * 5.0), 5.0)


def _spectrum(sec: _Section, cfa: CFAConfig) -> Spectrum:
    v = sec.raw("wavelength_nm")
    if v is None:
        return Spectrum(*_default_grid(cfa))
    if (not isinstance(v, list) or len(v) != 3
            or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)):
        raise sec.err("wavelength_nm", f"must be [start, stop, step] in nm, got {v!r}")
    start, stop, step = (float(x) for x in v)
    if not (300 <= start < stop <= 1200):
        raise sec.err("wavelength_nm", f"= {v!r}: need 300 <= start < stop <= 1200")
    if not (0.5 <= step <= 50) or abs((stop - start) / step - round((stop - start) / step)) > 1e-6:
        raise sec.err("wavelength_nm", f"= {v!r}: step must be 0.5-50 nm and divide stop - start")
    if (stop - start) / step + 1 > 400:
        raise sec.err("wavelength_nm", f"= {v!r}: at most 400 wavelengths")
    return Spectrum(start, stop, step)


def _exposure(sec: _Section) -> Exposure:
    from l3cli import spectral

    mode = sec.string("mode", _default(Exposure, "mode"), choices=("auto", "fixed"))
    ill = sec.string("illuminant", _default(Exposure, "illuminant"))
    if ill not in spectral.ILLUMINANTS:
        raise sec.err("illuminant", f"= {ill!r} is not an illuminant; valid: {', '.join(spectral.ILLUMINANTS)}")
    levels = sec.raw("light_levels_lux")
    rng = sec.raw("light_level_range_lux")
    count = sec.number("light_level_count", None, lo=1, hi=100, integer=True)
    if (rng is None) != (count is None):
        raise sec.err("light_level_range_lux" if rng is None else "light_level_count",
                      "is missing: give light_level_range_lux = [low, high] together with "
                      "light_level_count (log-spaced levels)")
    if rng is not None and levels is not None:
        raise sec.err("light_levels_lux", "cannot be combined with light_level_range_lux; give one")
    if rng is not None:
        if (not isinstance(rng, list) or len(rng) != 2
                or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in rng)
                or not (0 < rng[0] <= rng[1] <= 1e6)):
            raise sec.err("light_level_range_lux", f"= {rng!r}: need [low, high] with 0 < low <= high <= 1e6")
        levels_t = tuple(float(x) for x in np.geomspace(rng[0], rng[1], count))
    elif levels is None:
        levels_t = Exposure.light_levels_lux
    else:
        if (not isinstance(levels, list) or not levels
                or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in levels)):
            raise sec.err("light_levels_lux", f"must be a non-empty list of numbers, got {levels!r}")
        if any(not (0 < x <= 1e6) for x in levels):
            raise sec.err("light_levels_lux", f"= {levels!r}: each level must be in (0, 1e6] lux")
        levels_t = tuple(float(x) for x in levels)
    return Exposure(
        mode=mode,
        target_fraction=sec.number("target_fraction", _default(Exposure, "target_fraction"), lo=0.0, hi=1.0, lo_open=True),
        max_time_s=sec.number("max_time_s", _default(Exposure, "max_time_s"), lo=0.0, hi=3600.0, lo_open=True),
        max_analog_gain=sec.number("max_analog_gain", _default(Exposure, "max_analog_gain"), lo=1.0, hi=1000.0),
        time_s=sec.number("time_s", _default(Exposure, "time_s"), lo=0.0, hi=3600.0, lo_open=True),
        illuminant=ill,
        light_levels_lux=levels_t,
    )


def camera_from_dict(data: dict[str, Any], *, file: str | os.PathLike = "<camera>") -> Camera:
    """Validate a parsed camera description (the TOML's tables as dicts).

    Parameters
    ----------
    data
        Parsed TOML.
    file
        The file name used in messages and to resolve relative CSV paths.
    """
    fname = str(file)
    path = Path(fname)
    base = path.parent if fname != "<camera>" else None
    top = _Section(data, "", fname)
    name = top.string("name", path.stem if fname != "<camera>" else "camera")
    top.string("description", "")

    s = _sub(top, "optics")
    optics = Optics(
        f_number=s.number("f_number", _default(Optics, "f_number"), lo=0.5, hi=64.0),
        focal_length_mm=s.number("focal_length_mm", _default(Optics, "focal_length_mm"), lo=0.0, hi=5000.0, lo_open=True),
        transmittance=s.number("transmittance", _default(Optics, "transmittance"), lo=0.0, hi=1.0, lo_open=True),
        cos4=s.boolean("cos4", _default(Optics, "cos4")),
        shading_corrected=s.boolean("shading_corrected", _default(Optics, "shading_corrected")),
    )
    ri = s.raw("relative_illumination")
    s.finish()
    s = _sub(top, "pixel")
    pixel = _pixel(s)
    s.finish()
    s = _sub(top, "readout")
    bits = s.number("bit_depth", _default(Readout, "bit_depth"), lo=8, hi=16, integer=True)
    readout = Readout(
        analog_gain=s.number("analog_gain", _default(Readout, "analog_gain"), lo=0.0, hi=1000.0, lo_open=True),
        bit_depth=bits,
        black_level_dn=s.number("black_level_dn",
                                _default(Readout, "black_level_dn") if bits >= 10 else 16, lo=0,
                                hi=(1 << bits) - 2, integer=True),
        black_clamp=s.boolean("black_clamp", _default(Readout, "black_clamp")),
    )
    s.finish()
    s = _sub(top, "cfa")
    cfa = _cfa(s, base)
    s.finish()
    if ri is not None:
        from l3cli.illumination import check_relative_illumination

        optics = replace(optics, relative_illumination=check_relative_illumination(
            ri, list(cfa.cfa.channels), f"{fname}: optics.relative_illumination"))
    s = _sub(top, "spectrum")
    spectrum = _spectrum(s, cfa)
    s.finish()
    s = _sub(top, "exposure")
    exposure = _exposure(s)
    s.finish()
    top.finish()
    cam = Camera(name=name, file=fname if fname != "<camera>" else "", optics=optics, pixel=pixel,
                 readout=readout, cfa=cfa, spectrum=spectrum, exposure=exposure)
    try:
        cam.qe_curves()
    except ConfigError as exc:
        raise ConfigError(f"{fname}: spectrum.wavelength_nm: {exc}") from None
    return cam


def load_camera(path: str | os.PathLike) -> Camera:
    """Read and validate a camera TOML file.

    Raises
    ------
    InputError
        The file is missing or unreadable.
    ConfigError
        TOML syntax error (file and line), unknown key, wrong type or
        out-of-range value (file, dotted key and what is allowed).
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such camera file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read camera file ({exc})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: TOML syntax error: {exc}") from None
    return camera_from_dict(data, file=path)

