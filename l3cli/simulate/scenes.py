"""Spectral scenes as low-rank factorisations ``R(x, λ) = Σ_k a_k(x) S_k(λ)``.

A scene is a stack of K spatial maps ``a_k`` (float32, (K, H, W)) and K
spectra ``S_k`` on the simulation wavelength grid (float64, (K, N)). For a
reflectance scene the spectra are reflectances (the illuminant is applied
later); for a radiance scene they are relative spectral radiances (energy).
This keeps memory and work proportional to K instead of the number of
wavelengths, and it is exact: the optics are linear, so each map is blurred
with the spectrally weighted OTF of its spectrum (``l3cli.simulate.core``).

Every scene is sampled with one sample per pixel, each sample being the mean
over the pixel's square (a box pixel aperture): the slanted edge is rendered
with the exact area covered on each side of the edge.

Scenes:

* ``macbeth`` — the 24 ISETCam Macbeth reflectances (380-1068 nm) as a 4x6
  chart of square patches on a dark grey surround (reflectance 0.2 flat),
  with patch boxes in reading order.
* ``slanted-edge`` — an ISO 12233-style edge tilted 5° from vertical, grey
  reflectances 0.8 (left) and 0.2 (right) (4:1 contrast).
* ``natural`` (and any RGB image path) — an sRGB photo, decoded to linear
  sRGB, up-sampled to reflectance with the Mallett & Yuksel (2019) basis in the
  visible (exact up to 720 nm, so colorimetry is unaffected) and a linear NIR
  model fitted to 137 measured ISETCam reflectances beyond (blended over 720-780 nm).
* a spectral cube ``.npz`` with ``wavelength`` (N,) nm and ``reflectance`` or
  ``radiance`` (H, W, N).

References
----------
.. [1] ISO 12233:2017 Photography — Electronic still picture imaging —
   Resolution and spatial frequency responses.
.. [2] Mallett, I. and Yuksel, C. (2019). Spectral Primary Decomposition for
   Rendering with sRGB Reflectance. EGSR.
.. [3] McCamy, C. S., Marcus, H. and Davidson, J. G. (1976). A color-rendition
   chart. J. Applied Photographic Engineering 2(3), 95-99.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from l3cli import spectral
from l3cli.errors import ConfigError, InputError

__all__ = [
    "Scene",
    "SCENES",
    "NATURAL_IMAGES",
    "SCENE_DIR",
    "make_scene",
    "macbeth_scene",
    "slanted_edge_scene",
    "rgb_image_scene",
    "spectral_cube_scene",
    "edge_area_coverage",
]

#: Folder of the bundled natural photos.
SCENE_DIR = Path(__file__).resolve().parent.parent / "data" / "scenes"

#: Bundled natural photos (stem -> file).
NATURAL_IMAGES: dict[str, str] = {
    "astronaut": "astronaut.jpg",
    "coffee": "coffee.jpg",
    "chelsea": "chelsea.jpg",
    "rocket": "rocket.jpg",
}

#: Scene names accepted by :func:`make_scene` (besides paths).
SCENES: dict[str, str] = {
    "macbeth": "24-patch Macbeth ColorChecker (ISETCam reflectances, 380-1068 nm)",
    "slanted-edge": "ISO 12233 slanted edge, 5 degrees, reflectances 0.8/0.2",
    "natural": "all bundled natural photos: " + ", ".join(NATURAL_IMAGES),
    **{f"natural:{k}": f"bundled photo {v}" for k, v in NATURAL_IMAGES.items()},
}

SURROUND_REFLECTANCE = 0.2
EDGE_LIGHT, EDGE_DARK, EDGE_ANGLE_DEG = 0.8, 0.2, 5.0


@dataclass
class Scene:
    """A spectral scene on the simulation grid.

    Attributes
    ----------
    name
        Scene name used in capture stems.
    maps
        (K, H, W) float32 spatial weights.
    spectra
        (K, N) float64 spectra on the simulation wavelengths.
    kind
        ``"reflectance"`` (lit by the capture's illuminant) or ``"radiance"``
        (relative spectral radiance, energy units; scaled so that the mean
        luminance equals that of an 18 % grey under the capture's lux).
    chart
        Macbeth geometry (``rows``, ``cols``, ``patches``, ``white_index``) or None.
    edge
        Slanted-edge geometry (``roi``, ``angle_deg``) or None.
    source
        What the scene came from (file or description).
    """

    name: str
    maps: np.ndarray
    spectra: np.ndarray
    kind: str = "reflectance"
    chart: dict[str, Any] | None = None
    edge: dict[str, Any] | None = None
    source: str = ""
    oversample: int = 1
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) in sensor pixels (the maps hold ``oversample`` samples per pixel and axis)."""
        return int(self.maps.shape[1]) // self.oversample, int(self.maps.shape[2]) // self.oversample


# ---------------------------------------------------------------- Macbeth

def macbeth_geometry(height: int, width: int) -> dict[str, Any]:
    """Patch boxes of a 4x6 chart centred in an image (reading order, x1/y1 exclusive).

    The chart fills about 90 % of the limiting dimension; patches are squares
    with gaps of 1/5 of the patch size (surround visible between them).
    """
    rows, cols = 4, 6
    # pitch p: 6 patches + 7 gaps of p/5... chart width = cols*p + (cols+1)*g, g = p/5.
    p = min(0.92 * width / (cols + (cols + 1) / 5), 0.92 * height / (rows + (rows + 1) / 5))
    g = p / 5
    if p < 4:
        raise ConfigError(f"image {width}x{height} is too small for a Macbeth chart "
                          "(need patches of at least 4 pixels; use at least 48x32)")
    cw, ch = cols * p + (cols + 1) * g, rows * p + (rows + 1) * g
    x0, y0 = (width - cw) / 2, (height - ch) / 2
    boxes = []
    for r in range(rows):
        for c in range(cols):
            bx0 = x0 + g + c * (p + g)
            by0 = y0 + g + r * (p + g)
            boxes.append([int(round(bx0)), int(round(by0)), int(round(bx0 + p)), int(round(by0 + p))])
    return {"rows": rows, "cols": cols, "patches": boxes, "white_index": 18, "black_index": 23}


def macbeth_scene(height: int, width: int, wavelengths: np.ndarray, *, oversample: int = 1) -> Scene:
    """The Macbeth chart: 24 patch maps + a surround map (patch edges on pixel boundaries)."""
    geo = macbeth_geometry(height, width)
    refl = spectral.macbeth_reflectances(wavelengths)  # (N, 24)
    s = oversample
    maps = np.zeros((25, height * s, width * s), dtype=np.float32)
    maps[24] = 1.0
    for i, (x0, y0, x1, y1) in enumerate(geo["patches"]):
        maps[i, y0 * s:y1 * s, x0 * s:x1 * s] = 1.0
        maps[24, y0 * s:y1 * s, x0 * s:x1 * s] = 0.0
    spectra = np.concatenate([refl.T, np.full((1, len(wavelengths)), SURROUND_REFLECTANCE)], axis=0)
    return Scene("macbeth", maps, spectra, chart=geo, source="ISETCam macbethChart reflectances",
                 oversample=s)


# ------------------------------------------------------------ slanted edge

def _clip_integral(u: np.ndarray) -> np.ndarray:
    """Antiderivative of clip(u, 0, 1)."""
    return np.where(u <= 0, 0.0, np.where(u >= 1, u - 0.5, 0.5 * u * u))


def edge_area_coverage(height: int, width: int, *, angle_deg: float = EDGE_ANGLE_DEG,
                       x_centre: float | None = None, y_centre: float | None = None) -> np.ndarray:
    """Exact fraction of each pixel square left of a line tilted ``angle_deg`` from vertical.

    The edge passes through (``x_centre``, ``y_centre``) (pixel-corner
    coordinates; default the image centre) at ``x_e(y) = xc + tan(angle) (y - yc)``.
    Pixel (i, j) covers [j, j+1] x [i, i+1]; the result is
    ``∫_i^{i+1} clip(x_e(y) - j, 0, 1) dy``, computed in closed form.
    """
    xc = width / 2 if x_centre is None else x_centre
    yc = height / 2 if y_centre is None else y_centre
    s = math.tan(math.radians(angle_deg))
    i = np.arange(height, dtype=np.float64)[:, None]
    j = np.arange(width, dtype=np.float64)[None, :]
    a = xc + s * (i - yc) - j  # x_e(i) - j
    if abs(s) < 1e-12:
        return np.clip(a, 0.0, 1.0)
    return np.clip((_clip_integral(a + s) - _clip_integral(a)) / s, 0.0, 1.0)


def slanted_edge_scene(height: int, width: int, wavelengths: np.ndarray,
                       *, angle_deg: float = EDGE_ANGLE_DEG, oversample: int = 1) -> Scene:
    """A light (left) / dark (right) edge through the centre, tilted 5°."""
    s = oversample
    cover = edge_area_coverage(height * s, width * s, angle_deg=angle_deg).astype(np.float32)
    maps = np.stack([cover, 1.0 - cover]).astype(np.float32)
    n = len(wavelengths)
    spectra = np.stack([np.full(n, EDGE_LIGHT), np.full(n, EDGE_DARK)])
    rh, rw = int(height * 0.6), int(min(width * 0.4, height * 0.6))
    roi = [width // 2 - rw // 2, height // 2 - rh // 2, width // 2 - rw // 2 + rw,
           height // 2 - rh // 2 + rh]
    edge = {"roi": roi, "angle_deg": float(angle_deg), "orientation": "vertical",
            "light_reflectance": EDGE_LIGHT, "dark_reflectance": EDGE_DARK}
    return Scene("slanted-edge", maps, spectra, edge=edge, source="analytic slanted edge",
                 oversample=s)


# ------------------------------------------------------------- RGB photos

def _linear_axis(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices and weights of linear interpolation with pixel-centre alignment."""
    x = (np.arange(n_out, dtype=np.float64) + 0.5) * (n_in / n_out) - 0.5
    x = np.clip(x, 0.0, n_in - 1)
    i0 = np.floor(x).astype(np.intp)
    i1 = np.minimum(i0 + 1, n_in - 1)
    return i0, i1, (x - i0).astype(np.float32)


def _resize(img: np.ndarray, height: int, width: int) -> np.ndarray:
    """Centre-crop (H, W, C) to the target aspect, resample; returns (C, height, width) float32.

    Shrinking first low-passes with a Gaussian (σ = 0.5/zoom − 0.5 input pixels) to
    avoid aliasing; resampling is separable linear interpolation with pixel centres aligned.
    """
    from scipy import ndimage

    h, w = img.shape[:2]
    target = width / height
    if w / h > target:
        nw = max(1, int(round(h * target)))
        x0 = (w - nw) // 2
        img = img[:, x0:x0 + nw]
    else:
        nh = max(1, int(round(w / target)))
        y0 = (h - nh) // 2
        img = img[y0:y0 + nh]
    h, w = img.shape[:2]
    zy, zx = height / h, width / w
    chans = np.ascontiguousarray(np.moveaxis(img.astype(np.float32), 2, 0))  # (C, h, w)
    if zy < 1 or zx < 1:
        sig = (0.0, max(0.0, 0.5 / zy - 0.5) if zy < 1 else 0.0, max(0.0, 0.5 / zx - 0.5) if zx < 1 else 0.0)
        chans = ndimage.gaussian_filter(chans, sigma=sig, mode="nearest")
    y0i, y1i, wy = _linear_axis(h, height)
    x0i, x1i, wx = _linear_axis(w, width)
    rows = chans[:, y0i] * (1 - wy)[None, :, None] + chans[:, y1i] * wy[None, :, None]  # (C, H, w)
    out = np.empty((chans.shape[0], height, width), dtype=np.float32)
    for c in range(chans.shape[0]):
        r = rows[c]
        np.multiply(r[:, x0i], 1 - wx, out=out[c])
        out[c] += r[:, x1i] * wx
    return out


def rgb_to_reflectance_basis(wavelengths: np.ndarray) -> np.ndarray:
    """Spectra (4, N) for maps (r, g, b, 1) of linear sRGB.

    Visible: Mallett & Yuksel (2019) basis for r, g, b up to 720 nm; beyond 780 nm the
    fitted NIR model ``c0 + cr r + cg g + cb b``; linear blend over 720-780 nm (where the
    CIE colour-matching functions are below 0.1 % of their peak).
    """
    wl = np.asarray(wavelengths, dtype=np.float64)
    vis = spectral.mallett2019_basis(wl)  # (N, 3); defined 380-780
    if wl.min() < 380:
        raise ConfigError(f"natural scenes need wavelengths >= 380 nm, the camera starts at {wl.min():g} nm")
    nir = spectral.nir_extension()
    if wl.max() > nir.wavelengths[-1] + 1e-6:
        raise ConfigError(f"natural scenes are defined up to {nir.wavelengths[-1]:g} nm, the camera "
                          f"reaches {wl.max():g} nm")
    beta = np.clip((wl - 720.0) / 60.0, 0.0, 1.0)
    ext = np.zeros((len(wl), 4))
    m = wl >= nir.wavelengths[0]
    ext[m] = nir.resample(wl[m])
    spectra = np.zeros((4, len(wl)))
    for k in range(3):
        spectra[k] = (1 - beta) * vis[:, k] + beta * ext[:, k + 1]
    spectra[3] = beta * ext[:, 0]
    return spectra


def _read_rgb(path: Path) -> np.ndarray:
    from l3cli.colourspace import convert
    from l3cli.io.image import read_image

    try:
        img, space = read_image(path)
    except InputError:
        raise
    except Exception as exc:  # OIIO can raise on odd files
        raise InputError(f"{path}: cannot read scene image ({exc})") from None
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    elif img.shape[2] >= 4:
        img = img[:, :, :3]
    elif img.shape[2] != 3:
        raise InputError(f"{path}: scene image must have 1, 3 or 4 channels, got {img.shape[2]}")
    if space == "srgb":
        lin = convert(img, "srgb", "linear-srgb")
    elif space in ("linear-srgb", "xyz"):
        lin = img if space == "linear-srgb" else convert(img, "xyz", "linear-srgb")
        peak = float(np.percentile(lin, 99.5)) if lin.size else 1.0
        lin = lin / max(peak, 1e-12)
    else:
        lin = convert(img, space, "linear-srgb")
    return np.clip(lin, 0.0, 1.0).astype(np.float32)


def rgb_image_scene(path: str | os.PathLike, height: int, width: int, wavelengths: np.ndarray,
                    *, name: str | None = None, oversample: int = 1) -> Scene:
    """An RGB image up-sampled to spectral reflectance (see module notes)."""
    path = Path(path)
    s = oversample
    rgb = _resize(_read_rgb(path), height * s, width * s)  # (3, H, W)
    maps = np.empty((4, height * s, width * s), dtype=np.float32)
    maps[:3] = rgb
    maps[3] = 1.0
    return Scene(name or _stem_name(path), maps, rgb_to_reflectance_basis(wavelengths),
                 source=str(path), oversample=s)


def spectral_cube_scene(path: str | os.PathLike, height: int, width: int,
                        wavelengths: np.ndarray, *, oversample: int = 1) -> Scene:
    """A spectral cube ``.npz``: ``wavelength`` (N,) nm + ``reflectance`` or ``radiance`` (H, W, N)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = set(z.files)
            if "wavelength" not in keys or not ({"reflectance", "radiance"} & keys):
                raise InputError(f"{path}: a spectral cube needs arrays 'wavelength' and "
                                 f"'reflectance' or 'radiance'; found {', '.join(sorted(keys)) or 'none'}")
            kind = "reflectance" if "reflectance" in keys else "radiance"
            wl = np.asarray(z["wavelength"], dtype=np.float64).ravel()
            cube = np.asarray(z[kind], dtype=np.float32)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"{path}: cannot read spectral cube ({exc.__class__.__name__}: {exc})") from None
    if cube.ndim != 3 or cube.shape[2] != wl.size:
        raise InputError(f"{path}: {kind} must be (H, W, N) with N = len(wavelength) = {wl.size}, "
                         f"got {cube.shape}")
    if not np.all(np.isfinite(cube)) or np.any(cube < 0):
        raise InputError(f"{path}: {kind} must be finite and non-negative")
    s = spectral.Spectra(wl, np.eye(wl.size), tuple(str(w) for w in wl), str(path))
    # Interpolation matrix from the cube's wavelengths onto the grid.
    interp = s.resample(wavelengths, what=f"spectral cube {kind}")  # (Ngrid, Ncube)
    small = _resize(cube, height * oversample, width * oversample)  # (Ncube, H, W)
    if wl.size > interp.shape[0]:
        # More bands than simulation wavelengths: resample the maps instead.
        maps = np.tensordot(interp.astype(np.float32), small, axes=(1, 0))
        spectra = np.eye(interp.shape[0])
    else:
        maps = small
        spectra = interp.T.copy()
    return Scene(_stem_name(path), maps, spectra, kind=kind, source=str(path), oversample=oversample)


def _stem_name(path: Path) -> str:
    stem = path.name.split(".")[0]
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "-" for ch in stem)
    return safe or "scene"


def expand_scene_names(names: list[str]) -> list[str]:
    """Expand ``natural`` into the bundled photos; keep other names and paths."""
    out: list[str] = []
    for n in names:
        if n == "natural":
            out.extend(f"natural:{k}" for k in NATURAL_IMAGES)
        else:
            out.append(n)
    return out


def check_scene_name(name: str) -> None:
    """Raise ConfigError/InputError early for an unknown name or a missing path."""
    if name in SCENES:
        return
    if "/" in name or os.sep in name or Path(name).suffix:
        if not Path(name).exists():
            raise InputError(f"{name}: scene file does not exist")
        return
    raise ConfigError(f"unknown scene {name!r}; valid: {', '.join(SCENES)} "
                      "(or a path to an RGB image or a spectral cube .npz)")


def make_scene(name: str, height: int, width: int, wavelengths: np.ndarray, *,
               oversample: int = 1) -> Scene:
    """Build a scene by name (:data:`SCENES`) or from a file path.

    Parameters
    ----------
    name
        Scene name or path.
    height, width
        Sensor size in pixels.
    wavelengths
        Simulation grid (nm).
    oversample
        Scene samples per pixel and axis (1-8); the optics are applied at that
        resolution and the result is averaged over each pixel's area.

    Raises
    ------
    ConfigError
        Unknown scene name (lists the valid ones).
    InputError
        Unreadable image or cube.
    """
    check_scene_name(name)
    s = int(oversample)
    if not 1 <= s <= 8:
        raise ConfigError(f"oversample must be 1-8, got {oversample!r}")
    if name == "macbeth":
        return macbeth_scene(height, width, wavelengths, oversample=s)
    if name == "slanted-edge":
        return slanted_edge_scene(height, width, wavelengths, oversample=s)
    if name.startswith("natural:"):
        key = name.split(":", 1)[1]
        return rgb_image_scene(SCENE_DIR / NATURAL_IMAGES[key], height, width, wavelengths,
                               name=key, oversample=s)
    if name == "natural":
        raise ConfigError("'natural' names several scenes; expand it with expand_scene_names")
    p = Path(name)
    if p.suffix.lower() == ".npz":
        return spectral_cube_scene(p, height, width, wavelengths, oversample=s)
    return rgb_image_scene(p, height, width, wavelengths, oversample=s)
