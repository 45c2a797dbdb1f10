"""A conventional pipeline to compare L3 with: Bayer demosaicking + a 3x3 colour matrix.

The raw mosaic (normalised, 0 = black, 1 = white level) is demosaicked with one
of colour-demosaicing's methods (bilinear, Malvar et al. 2004, Menon et al.
2007) into camera RGB; a 3x3 matrix ``M`` maps camera RGB to the target space,
``out = rgb @ M``. ``M`` is fitted by linear least squares on the same training
data as an L3 table (a ``simulate`` folder or a pairs folder), in a linear space:
XYZ, or linear sRGB when the target is display sRGB. Pixels near clipping (any
demosaicked channel above ``clip_level``) and a border of ``border`` pixels are
left out of the fit.

References
----------
H. S. Malvar, L. He and R. Cutler, "High-quality linear interpolation for
demosaicing of Bayer-patterned color images", Proc. IEEE ICASSP 2004, iii-485.
D. Menon, S. Andriani and G. Calvagno, "Demosaicing with directional filtering
and a posteriori decision", IEEE Trans. Image Processing 16(1), 132-141 (2007).
colour-demosaicing, https://github.com/colour-science/colour-demosaicing.
G. D. Finlayson, M. Mackiewicz and A. Hurlbert, "Color correction using
root-polynomial regression", IEEE Trans. Image Processing 24(5), 1460-1470
(2015) (the linear 3x3 least-squares correction is its degree-1 case).
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from l3cli.errors import ConfigError, InputError

if TYPE_CHECKING:
    from l3cli.cfa import CFA
    from l3cli.io.raw import RawImage

__all__ = [
    "DEMOSAIC_METHODS",
    "BaselineModel",
    "bayer_pattern",
    "demosaic",
    "fit_baseline",
    "render_baseline",
    "render_baseline_file",
]

log = logging.getLogger(__name__)


def _method(name: str) -> Callable:
    import colour_demosaicing as cd

    return {
        "bilinear": cd.demosaicing_CFA_Bayer_bilinear,
        "malvar2004": cd.demosaicing_CFA_Bayer_Malvar2004,
        "menon2007": cd.demosaicing_CFA_Bayer_Menon2007,
    }[name]


#: Demosaicking methods by name (colour-demosaicing functions).
DEMOSAIC_METHODS: tuple[str, ...] = ("bilinear", "malvar2004", "menon2007")

_FIT_SPACE = {"xyz": "xyz", "linear-srgb": "linear-srgb", "srgb": "linear-srgb", "lab": "xyz"}


def _check_method(name: str) -> str:
    key = name.lower().replace("-", "").replace("_", "").replace(" ", "")
    if key not in DEMOSAIC_METHODS:
        raise ConfigError(f"unknown demosaicking method {name!r}; allowed: {', '.join(DEMOSAIC_METHODS)}")
    return key


def bayer_pattern(cfa: CFA, *, name: str = "raw") -> str:
    """The colour-demosaicing pattern name (``RGGB``, ``BGGR``, ``GRBG``, ``GBRG``) of a CFA.

    Raises
    ------
    InputError
        If the CFA is not a 2x2 Bayer pattern of R, G, G, B.
    """
    pat = cfa.pattern
    flat = "".join(c for row in pat for c in row) if len(pat) == 2 and all(len(r) == 2 for r in pat) else ""
    if flat not in ("RGGB", "BGGR", "GRBG", "GBRG"):
        raise InputError(
            f"{name}: CFA {cfa.spec} is not a Bayer pattern (RGGB, BGGR, GRBG, GBRG); "
            "the conventional baseline handles Bayer raws only"
        )
    return flat


def demosaic(raw: RawImage, *, method: str = "menon2007") -> np.ndarray:
    """Demosaic a :class:`l3cli.io.raw.RawImage` into camera RGB, float32 (H, W, 3).

    Parameters
    ----------
    raw
        A Bayer raw (normalised mosaic).
    method
        ``bilinear``, ``malvar2004`` or ``menon2007``.

    References
    ----------
    Malvar et al. (2004); Menon et al. (2007); colour-demosaicing.
    """
    method = _check_method(method)
    pattern = bayer_pattern(raw.cfa, name=str(getattr(raw, "path", None) or "raw"))
    mosaic = np.asarray(raw.mosaic, dtype=np.float64)
    rgb = _method(method)(mosaic, pattern)
    return np.asarray(rgb, dtype=np.float32)


@dataclass
class BaselineModel:
    """A fitted baseline: demosaicking method and colour matrix.

    Attributes
    ----------
    method
        Demosaicking method name.
    matrix
        (3, 3) float64, ``out_linear = camera_rgb @ matrix``.
    target_space
        Output space (``xyz``, ``linear-srgb``, ``srgb`` or ``lab``).
    fit_space
        The linear space the matrix maps into (``xyz`` or ``linear-srgb``).
    provenance
        Training inputs, pixel count, RMS residual.
    """

    method: str
    matrix: np.ndarray
    target_space: str
    fit_space: str
    provenance: dict = field(default_factory=dict)

    def to_json(self) -> str:
        """JSON text of the model."""
        return json.dumps({
            "format": "l3-baseline", "version": 1, "method": self.method,
            "matrix": np.asarray(self.matrix).tolist(), "target_space": self.target_space,
            "fit_space": self.fit_space, "provenance": self.provenance,
        }, indent=2)

    @classmethod
    def from_json(cls, text: str, *, name: str = "baseline model") -> BaselineModel:
        """Read a model written by :meth:`to_json`."""
        try:
            d = json.loads(text)
            if d.get("format") != "l3-baseline":
                raise ValueError("format is not 'l3-baseline'")
            m = np.asarray(d["matrix"], dtype=np.float64)
            if m.shape != (3, 3) or not np.all(np.isfinite(m)):
                raise ValueError(f"matrix must be 3x3 finite numbers, got shape {m.shape}")
            return cls(_check_method(d["method"]), m, d["target_space"], d["fit_space"],
                       d.get("provenance", {}))
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise InputError(f"{name}: not an l3 baseline model ({exc})") from exc


def fit_baseline(
    inputs: Sequence[str | os.PathLike],
    *,
    method: str = "menon2007",
    target_space: str = "xyz",
    border: int = 4,
    clip_level: float = 0.98,
    max_pixels: int = 400_000,
    seed: int = 0,
) -> BaselineModel:
    """Fit the colour matrix of the baseline on training data.

    Parameters
    ----------
    inputs
        Training folders: ``simulate`` outputs or pairs folders (as ``l3 train``).
    method
        Demosaicking method.
    target_space
        Output space of the baseline.
    border
        Pixels left out on each side of every image.
    clip_level
        Pixels with a demosaicked channel above this (normalised) level are left out.
    max_pixels
        At most this many pixels (drawn with ``seed``) per capture enter the fit.
    seed
        Random seed of the pixel subsampling.

    Returns
    -------
    BaselineModel

    Raises
    ------
    InputError
        No usable pixels, non-Bayer raws, or unreadable training data.
    """
    from l3cli.colourspace import check_space
    from l3cli.pairs import find_pairs, load_pair

    method = _check_method(method)
    target_space = check_space(target_space)
    fit_space = _FIT_SPACE[target_space]
    pairs = find_pairs(list(inputs))
    rng = np.random.default_rng(seed)
    ata = np.zeros((3, 3))
    atb = np.zeros((3, 3))
    btb = np.zeros(3)
    n_total = 0
    for pair in pairs:
        loaded = load_pair(pair, target_space=fit_space)
        raw, target = loaded.raw, loaded.target
        rgb = demosaic(raw, method=method)
        h, w = rgb.shape[:2]
        b = min(border, (h - 1) // 2, (w - 1) // 2)
        sl = (slice(b, h - b), slice(b, w - b))
        x = rgb[sl].reshape(-1, 3).astype(np.float64)
        y = target[sl].reshape(-1, 3).astype(np.float64)
        ok = np.all(x <= clip_level, axis=1) & np.all(np.isfinite(x), axis=1)
        x, y = x[ok], y[ok]
        if len(x) > max_pixels:
            idx = rng.choice(len(x), size=max_pixels, replace=False)
            x, y = x[idx], y[idx]
        ata += x.T @ x
        atb += x.T @ y
        btb += (y * y).sum(axis=0)
        n_total += len(x)
        log.info("%s: %d pixels for the colour matrix", pair.name, len(x))
    if n_total < 3 or np.linalg.matrix_rank(ata) < 3:
        raise InputError("no usable (unclipped, non-degenerate) training pixels for the colour matrix")
    m = np.linalg.solve(ata, atb)
    sse = btb - 2 * np.einsum("ij,ij->j", m, atb) + np.einsum("ij,ik,kj->j", m, ata, m)
    rms = np.sqrt(np.maximum(sse, 0) / n_total)
    return BaselineModel(method, m, target_space, fit_space, {
        "inputs": [str(p) for p in inputs], "captures": len(pairs), "pixels": int(n_total),
        "rms_residual": rms.tolist(), "border": border, "clip_level": clip_level, "seed": seed,
    })


def render_baseline(model: BaselineModel, raw: RawImage) -> np.ndarray:
    """Render a raw with the baseline: float32 (H, W, 3) in ``model.target_space``."""
    from l3cli.colourspace import convert

    rgb = demosaic(raw, method=model.method)
    lin = (rgb.reshape(-1, 3).astype(np.float64) @ model.matrix).reshape(rgb.shape)
    return np.asarray(convert(lin.astype(np.float32), model.fit_space, model.target_space),
                      dtype=np.float32)


def render_baseline_file(
    model: BaselineModel, raw_path: str | os.PathLike, out_path: str | os.PathLike
) -> Path:
    """Read a raw, render it with the baseline and write ``out_path`` (format by suffix).

    As ``l3 render``: EXR keeps the target space (``l3:space`` attribute); TIFF,
    PNG and JPEG receive display sRGB.
    """
    from l3cli.io.image import write_image
    from l3cli.io.raw import read_raw
    from l3cli.lens.gainmaps import apply_dng_gains

    raw = apply_dng_gains(read_raw(raw_path))  # the DNG's gain maps applied
    img = render_baseline(model, raw)
    return write_image(out_path, img, space=model.target_space,
                       attributes={"l3:baseline": f"{model.method}+3x3"})
