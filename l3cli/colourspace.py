"""Colour spaces l3 renders into, and the conversions between them.

One place for every colour conversion in l3 (colour-science does the work).

Spaces
------
``xyz``
    CIE 1931 XYZ, linear; a display white (D65) has Y = 1.
``linear-srgb``
    Linear-light sRGB (IEC 61966-2-1 primaries, D65), white = (1, 1, 1).
``srgb``
    Display sRGB: linear sRGB encoded with the sRGB transfer function, [0, 1].
``lab``
    CIE 1976 L*a*b* relative to D65 with white Y = 1 (L* in 0..100).
"""

from __future__ import annotations

import numpy as np

from l3cli.errors import ConfigError

__all__ = [
    "SPACES",
    "D65_XYZ",
    "XYZ_TO_LINEAR_SRGB",
    "LINEAR_SRGB_TO_XYZ",
    "srgb_encode",
    "srgb_decode",
    "convert",
    "check_space",
]

#: Colour spaces a table can render into.
SPACES: tuple[str, ...] = ("xyz", "linear-srgb", "srgb", "lab")
_ALIASES = {"linear_srgb": "linear-srgb", "linsrgb": "linear-srgb", "rgb": "linear-srgb",
            "cielab": "lab", "XYZ": "xyz"}

#: D65 white, Y = 1 (CIE 1931 2°, as colour-science's sRGB whitepoint).
D65_XYZ = np.array([0.95047, 1.0, 1.08883])

#: XYZ -> linear sRGB and back: IEC 61966-2-1's matrices, as colour-science's
#: ``RGB_COLOURSPACES["sRGB"]`` holds them (a test checks they are equal). Kept
#: here so that rendering to display sRGB does not import colour-science.
XYZ_TO_LINEAR_SRGB = np.array([[3.2406, -1.5372, -0.4986],
                               [-0.9689, 1.8758, 0.0415],
                               [0.0557, -0.204, 1.057]])
LINEAR_SRGB_TO_XYZ = np.array([[0.4124, 0.3576, 0.1805],
                               [0.2126, 0.7152, 0.0722],
                               [0.0193, 0.1192, 0.9505]])


def check_space(name: str) -> str:
    """Return the canonical space name, or raise naming the allowed ones."""
    key = _ALIASES.get(name, name).lower() if isinstance(name, str) else name
    if key not in SPACES:
        raise ConfigError(f"colour space {name!r} is not known; use one of {', '.join(SPACES)}")
    return key


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Encode linear sRGB with the sRGB transfer function (IEC 61966-2-1).

    Values are clipped to [0, 1] first. float32 in, float32 out.
    """
    import colour

    lin = np.clip(np.asarray(linear, dtype=np.float32), 0.0, 1.0)
    return np.asarray(colour.cctf_encoding(lin, function="sRGB"), dtype=np.float32)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """Decode sRGB-encoded values to linear light (IEC 61966-2-1)."""
    import colour

    enc = np.asarray(encoded, dtype=np.float32)
    return np.asarray(colour.cctf_decoding(enc, function="sRGB"), dtype=np.float32)


def _xyz_to_linear_srgb(xyz: np.ndarray) -> np.ndarray:
    return np.asarray(xyz @ XYZ_TO_LINEAR_SRGB.T, dtype=np.float32)


def _linear_srgb_to_xyz(rgb: np.ndarray) -> np.ndarray:
    return np.asarray(rgb @ LINEAR_SRGB_TO_XYZ.T, dtype=np.float32)


def _as_f32(img: np.ndarray) -> np.ndarray:
    return np.asarray(img, dtype=np.float32)


def _lab_white() -> np.ndarray:
    """xy chromaticity of l3's L*a*b* white (D65, Y = 1)."""
    import colour

    return colour.XYZ_to_xy(D65_XYZ)


def _lab_to_xyz(lab: np.ndarray) -> np.ndarray:
    import colour

    return _as_f32(colour.Lab_to_XYZ(lab, illuminant=_lab_white()))


def _xyz_to_lab(xyz: np.ndarray) -> np.ndarray:
    import colour

    return _as_f32(colour.XYZ_to_Lab(xyz, illuminant=_lab_white()))


#: Per space: (to XYZ, from XYZ).
_VIA_XYZ = {
    "xyz": (_as_f32, _as_f32),
    "linear-srgb": (_linear_srgb_to_xyz, _xyz_to_linear_srgb),
    "srgb": (lambda x: _linear_srgb_to_xyz(srgb_decode(x)),
             lambda x: srgb_encode(_xyz_to_linear_srgb(x))),
    "lab": (_lab_to_xyz, _xyz_to_lab),
}


def convert(img: np.ndarray, src: str, dst: str) -> np.ndarray:
    """Convert a float (..., 3) image between l3's colour spaces.

    Parameters
    ----------
    img
        (..., 3) array in space ``src``.
    src, dst
        Names from :data:`SPACES`.

    Returns
    -------
    numpy.ndarray
        float32 (..., 3) in ``dst``. Conversion to ``srgb`` clips to [0, 1].

    Examples
    --------
    >>> xyz = convert(np.array([1.0, 1.0, 1.0]), "linear-srgb", "xyz")  # the sRGB white
    >>> [round(float(v), 4) for v in xyz]
    [0.9505, 1.0, 1.089]
    >>> [abs(round(float(v), 3)) for v in convert(D65_XYZ, "xyz", "lab")]  # L* = 100, neutral
    [100.0, 0.0, 0.0]
    """
    src, dst = check_space(src), check_space(dst)
    img = np.asarray(img)
    if img.shape[-1] != 3:
        raise ConfigError(f"colour conversion needs 3 channels, got shape {img.shape}")
    if src == dst:
        return np.asarray(img, dtype=np.float32)
    if {src, dst} == {"linear-srgb", "srgb"}:
        return srgb_encode(img) if dst == "srgb" else srgb_decode(img)
    return _VIA_XYZ[dst][1](_VIA_XYZ[src][0](img))
