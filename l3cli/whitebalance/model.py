"""White balance as an input: the shot's white balance normalises the mosaic, and conditions the colour.

Real cameras choose a white balance per shot, and raw converters honour it in
two steps: they scale the raw channels by the shot's white-balance gains, and
they adapt their colour matrix to the shot's white (a chromatic adaptation).
A table trained on raws whose white balance differs per shot has to learn
both from a handful of shots, and cannot; l3 takes both as inputs instead.

Gains
    :func:`raw_gains` reads a raw's as-shot white balance as per-channel
    multipliers, normalised so that green is 1: LibRaw's camera white balance
    (``camera_whitebalance``; for DNGs ``1 / AsShotNeutral``) for anything
    rawpy reads, the sidecar key ``white_balance = [r, g, b]`` (multipliers,
    as LibRaw's) for headerless dumps and l3's TIFF/PNG mosaics.
    ``--white-balance R,G,B`` supplies or overrides them.
Normalisation
    :func:`apply_gains` multiplies every pixel by its channel's gain before
    classification and regression, in training and rendering alike. A pixel
    that is saturated in the raw stays at or above the saturation threshold,
    so the saturation classes still see real clipping.
Adaptation
    After normalising, what the converter still does differently per shot is,
    to a good approximation, a 3x3 matrix on the output colour
    (:data:`ADAPT_SPACE` of the table's output space) that depends smoothly on
    the white. Training fits one 3x3 matrix per training shot that maps the
    table's render onto the shot's target, models the matrix as linear in the
    white's features (:func:`white_features`: the log blue/red gain ratio, and
    the log green/magenta tint once four or more distinct whites are seen),
    retrains the table on targets with the modelled adaptation taken out, and
    records the model in the table (``TransformTable.white_balance``). Rendering
    applies the model's matrix for the raw's own white after the kernels.

A table records that it expects white-balanced input; a table without the
record renders as before, whatever the raw's metadata.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from l3cli.errors import InputError
from l3cli.io.metadata import check_gains  # re-exported (its home: the file layer)

__all__ = ["WB_FEATURE", "ADAPT_SPACE", "check_gains", "parse_gains", "raw_gains", "file_gains",
           "gains_or_error", "gain_pattern", "multiply_gains", "apply_gains", "white_features", "fit_adaptation_model",
           "adaptation_matrix", "adapt_image", "fit_shot_matrix", "WhiteBalanceModel",
           "training_gains", "training_mosaic", "training_target", "quick_rgb"]

#: Name of the feature rule recorded in tables.
WB_FEATURE = "log-gain-ratios-v1"
#: Linear space in which the adaptation matrix acts, per output space.
ADAPT_SPACE = {"xyz": "xyz", "linear-srgb": "linear-srgb", "srgb": "linear-srgb", "lab": "xyz"}
_RGB = ("R", "G", "B")


def parse_gains(text: str) -> np.ndarray:
    """``"R,G,B"`` multipliers (``--white-balance``) as gains normalised to green = 1."""
    try:
        vals = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        vals = [text]  # reported below
    return check_gains(vals, "--white-balance")


def raw_gains(raw: Any) -> np.ndarray | None:
    """The as-shot white-balance gains of a :class:`l3cli.io.raw.RawImage` (green = 1), or None.

    Raises
    ------
    InputError
        The metadata hold an unusable or contradictory white balance.
    """
    meta = raw.metadata or {}
    where = str(raw.path) if raw.path is not None else "raw"
    if meta.get("white_balance") is not None:  # sidecar key
        return check_gains(meta["white_balance"], f"{where}: white_balance")
    shot = meta.get("shot") or {}
    found: list[tuple[str, np.ndarray]] = []
    cam = meta.get("camera_whitebalance")
    if cam:
        desc = str(meta.get("color_desc", "RGBG"))
        by: dict[str, list[float]] = {}
        for letter, v in zip(desc, cam, strict=False):
            if v and math.isfinite(v) and v > 0:
                by.setdefault(letter, []).append(float(v))
        if all(c in by for c in _RGB):  # else LibRaw knows no camera white balance
            gains = np.array([by[c][0] for c in _RGB])
            found.append(("LibRaw's camera white balance", gains / gains[1]))
    if shot.get("as_shot_neutral") is not None:
        found.append(("AsShotNeutral", check_gains(
            1.0 / np.asarray(shot["as_shot_neutral"], dtype=np.float64),
            f"{where}: AsShotNeutral")))
    if shot.get("as_shot_white_xy") is not None and shot.get("color_matrix1") is not None:
        x, y = shot["as_shot_white_xy"]
        if y > 0:
            xyz = np.array([x / y, 1.0, (1.0 - x - y) / y])
            neutral = np.asarray(shot["color_matrix1"], dtype=np.float64).reshape(3, 3) @ xyz
            if np.all(neutral > 0):
                found.append(("AsShotWhiteXY", check_gains(1.0 / neutral,
                                                           f"{where}: AsShotWhiteXY")))
    if not found:
        return None
    name0, g = found[0]
    for name, other in found[1:]:
        if np.max(np.abs(np.log(other / g))) > 0.02:
            raise InputError(
                f"{where}: contradictory white balance: {name0} gives gains {_fmt(g)} but "
                f"{name} gives {_fmt(other)}; give the right one with --white-balance R,G,B")
    return g


def _fmt(g: np.ndarray) -> str:
    return ",".join(f"{v:.4g}" for v in g)


def file_gains(path: Any) -> np.ndarray | None:
    """The as-shot gains of a raw file without reading its pixels (a cheap pre-check)."""
    from pathlib import Path

    from l3cli.io.raw import read_raw, sidecar_path

    p = Path(path)
    sc = sidecar_path(p)
    if sc.exists() or p.suffix.lower() == ".raw":
        return raw_gains(read_raw(p))  # headerless: the sidecar decides, reading is cheap
    import rawpy

    from l3cli.io.metadata import read_shot_metadata

    try:
        with rawpy.imread(str(p)) as rp:
            meta = {"camera_whitebalance": [float(v) for v in rp.camera_whitebalance],
                    "color_desc": rp.color_desc.decode("ascii"),
                    "shot": read_shot_metadata(p)}
    except Exception:  # noqa: BLE001 - the full read reports unreadable files
        return raw_gains(read_raw(p))
    return raw_gains(type("Meta", (), {"metadata": meta, "path": p})())


def gains_or_error(raw: Any, override: np.ndarray | None) -> np.ndarray:
    """Gains for a table that expects white-balanced input: the override, else the raw's own.

    Raises
    ------
    InputError
        The raw carries no white balance and none is given.
    """
    if override is not None:
        return np.asarray(override, dtype=np.float64)
    g = raw_gains(raw)
    if g is None:
        raise InputError(
            f"{raw.path}: no white balance in the raw's metadata, and the table expects "
            "white-balanced input; give one with --white-balance R,G,B")
    return g


def gain_pattern(cfa: Any, gains: np.ndarray) -> np.ndarray:
    """The (R, G, B) ``gains`` laid out over one CFA period: float32 (ph, pw).

    Raises
    ------
    InputError
        The CFA has channels other than R, G and B.
    """
    other = [c for c in cfa.channels if c not in _RGB]
    if other:
        raise InputError(f"white balance needs an R, G, B CFA; {cfa.spec} has {', '.join(other)}")
    ph, pw = cfa.period
    gmap = np.empty((ph, pw), dtype=np.float32)
    for y in range(ph):
        for x in range(pw):
            gmap[y, x] = gains[_RGB.index(cfa.channel_at(y, x))]
    return gmap


def multiply_gains(mosaic: np.ndarray, pattern: np.ndarray, saturation: float) -> np.ndarray:
    """Multiply a float32 mosaic by its CFA positions' gains, in place; returns it.

    A pixel at or above ``saturation`` is never lowered (a gain below one does
    not hide clipping from the saturation classes); the products are float32.
    """
    sat = np.float32(saturation)
    ph, pw = pattern.shape
    for y in range(ph):
        for x in range(pw):
            g = np.float32(pattern[y, x])
            if g == 1:
                continue
            v = mosaic[y::ph, x::pw]
            if g > 1:  # the product of a pixel >= 0 is not below it: no clipping to keep
                np.multiply(v, g, out=v)
            else:
                np.multiply(v, g, out=v, where=~(v >= sat))
    return mosaic


def apply_gains(mosaic: np.ndarray, cfa: Any, gains: np.ndarray, saturation: float
                ) -> np.ndarray:
    """Multiply each pixel by its channel's gain (float32 copy).

    A pixel at or above ``saturation`` in the raw stays at or above it, so a
    gain below one does not hide clipping from the saturation classes.

    Raises
    ------
    InputError
        The CFA has channels other than R, G and B.
    """
    return multiply_gains(np.array(mosaic, dtype=np.float32), gain_pattern(cfa, gains), saturation)


def white_features(gains: np.ndarray, n_features: int) -> np.ndarray:
    """Features of a white: ``[log(b/r), log(g*g/(r*b))][:n_features]`` of its gains."""
    r, g, b = np.log(np.asarray(gains, dtype=np.float64))
    return np.array([b - r, 2 * g - r - b])[:n_features]


#: Largest magnitude of an adaptation coefficient a table may hold (the 3x3
#: matrices between whites are near the identity; this keeps a table's outputs
#: finite in float32 with the kernels' bound, :data:`l3cli.table.MAX_KERNEL_GAIN`).
MAX_ADAPTATION = 1e6


class WhiteBalanceModel:
    """The record a white-balancing table keeps (JSON in the table's ``white_balance`` key).

    Attributes
    ----------
    space
        Linear space the adaptation acts in.
    center
        Feature means of the training whites.
    coef
        (1 + n_features, 9): ``vec(A) = coef[0] + sum_k f_k coef[1 + k]``.
    whites
        Training gains, one row per shot.
    """

    def __init__(self, space: str, center: Sequence[float], coef: Any, whites: Any) -> None:
        self.space = str(space)
        self.center = np.asarray(center, dtype=np.float64).reshape(-1)
        self.coef = np.asarray(coef, dtype=np.float64).reshape(-1, 9)
        self.whites = np.asarray(whites, dtype=np.float64).reshape(-1, 3)
        if self.coef.shape[0] != 1 + self.center.size or not np.all(np.isfinite(self.coef)):
            raise ValueError("white-balance model: coefficients do not fit the features")
        if np.abs(self.coef).max(initial=0.0) > MAX_ADAPTATION:
            raise ValueError(f"white-balance model: coefficients beyond ±{MAX_ADAPTATION:g}")
        if not np.all(np.isfinite(self.center)):
            raise ValueError("white-balance model: feature centre holds NaN or Inf")
        if not np.all(np.isfinite(self.whites)) or not np.all(self.whites > 0):
            raise ValueError("white-balance model: training whites must be finite and positive")
        from l3cli.colourspace import SPACES

        if self.space not in SPACES:
            raise ValueError(f"white-balance model: space {self.space!r} is not one of "
                             f"{', '.join(SPACES)}")

    def as_dict(self) -> dict[str, Any]:
        return {"input": "as-shot", "feature": WB_FEATURE, "space": self.space,
                "center": self.center.tolist(), "coef": self.coef.tolist(),
                "whites": self.whites.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> WhiteBalanceModel:
        if d.get("feature") != WB_FEATURE or d.get("input") != "as-shot":
            raise ValueError(f"white-balance model {d.get('feature')!r} is not known")
        return cls(d["space"], d["center"], d["coef"], d["whites"])

    def matrix(self, gains: np.ndarray) -> np.ndarray:
        """The 3x3 adaptation for a white."""
        f = white_features(gains, self.center.size) - self.center
        return (self.coef[0] + f @ self.coef[1:]).reshape(3, 3)


def fit_shot_matrix(render: np.ndarray, target: np.ndarray, mask: np.ndarray | None,
                    *, step: int = 3) -> np.ndarray:
    """Least-squares 3x3 ``A`` with ``target ≈ A @ render`` per pixel (linear values)."""
    r = render[::step, ::step].reshape(-1, 3).astype(np.float64)
    t = target[::step, ::step].reshape(-1, 3).astype(np.float64)
    ok = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(t), axis=1)
    if mask is not None:
        ok &= mask[::step, ::step].reshape(-1)
    sol, *_ = np.linalg.lstsq(r[ok], t[ok], rcond=None)
    return sol.T


def fit_adaptation_model(whites: np.ndarray, mats: np.ndarray, space: str) -> WhiteBalanceModel:
    """Model per-shot matrices as linear in the white's features.

    One feature (blue/red) with two to three distinct whites, both with four
    or more; a constant matrix (their mean) when all whites coincide.
    """
    whites = np.asarray(whites, dtype=np.float64).reshape(-1, 3)
    mats = np.asarray(mats, dtype=np.float64).reshape(-1, 9)
    distinct = len({tuple(np.round(np.log(w), 3)) for w in whites})
    n_feat = 0 if distinct < 2 else (1 if distinct < 4 else 2)
    feats = np.array([white_features(w, n_feat) for w in whites]).reshape(len(whites), n_feat)
    center = feats.mean(axis=0) if n_feat else np.zeros(0)
    x = np.hstack([np.ones((len(whites), 1)), feats - center])
    coef, *_ = np.linalg.lstsq(x, mats, rcond=None)
    return WhiteBalanceModel(space, center, coef, whites)


def adapt_image(img: np.ndarray, matrix: np.ndarray, out_space: str, space: str) -> np.ndarray:
    """Apply ``matrix`` in linear ``space`` to an image in ``out_space`` (float32)."""
    from l3cli.colourspace import convert

    lin = convert(img, out_space, space) if out_space != space else img
    lin = np.einsum("ij,hwj->hwi", matrix.astype(np.float32), lin.astype(np.float32))
    out = convert(lin, space, out_space) if out_space != space else lin
    return np.ascontiguousarray(out, dtype=np.float32)


def adaptation_matrix(model: WhiteBalanceModel, gains: np.ndarray) -> np.ndarray:
    """The model's 3x3 for ``gains`` (a thin alias, for callers that hold a model)."""
    return model.matrix(gains)


# ------------------------------------------------------------------ training
def training_gains(raw: Any, opts: Any) -> np.ndarray:
    """Gains of a training raw: ``opts.wb_override``, else the raw's own.

    Raises
    ------
    InputError
        The raw carries no white balance and none is given.
    """
    if opts.wb_override is not None:
        return check_gains(opts.wb_override, "--white-balance")
    g = raw_gains(raw)
    if g is None:
        raise InputError(
            f"{raw.path}: no white balance in the raw's metadata; give one with "
            "--white-balance R,G,B or train without white balance (--no-as-shot-wb)")
    return g


def training_mosaic(raw: Any, opts: Any, fitted: Any = None) -> np.ndarray:
    """The mosaic training sees: shading-corrected when ``fitted.shading_field`` is set
    (:mod:`l3cli.lens.field`), then normalised by the white balance when ``opts.white_balance``.

    ``fitted`` is what training fitted before (:class:`l3cli.train.options.Fitted`;
    None: nothing)."""
    field = getattr(fitted, "shading_field", None)
    if field is not None:
        from l3cli.lens.field import corrected_raw

        raw = corrected_raw(field, raw, opts.saturation)
    if not getattr(opts, "white_balance", False):
        return raw.mosaic
    return apply_gains(raw.mosaic, raw.cfa, training_gains(raw, opts), opts.saturation)


def _key(raw_path: Any) -> str:
    from pathlib import Path

    return str(Path(raw_path).absolute())


def training_target(target: np.ndarray, raw_path: Any, opts: Any,
                    fitted: Any = None) -> np.ndarray:
    """The target with the modelled adaptation of its capture (``fitted.target_adapt``)
    taken out (when set)."""
    adapt = getattr(fitted, "target_adapt", None)
    if not adapt or _key(raw_path) not in adapt:
        return target
    space = ADAPT_SPACE[opts.target_space]
    return adapt_image(target, np.asarray(adapt[_key(raw_path)]), opts.target_space, space)


def quick_rgb(mosaic: np.ndarray, cfa: Any) -> np.ndarray:
    """A plain demosaic for estimating colour transforms: per channel, the
    normalised triangle-filtered average of its samples (float32 (H, W, 3), R, G, B)."""
    from scipy.ndimage import convolve

    k1 = np.array([1.0, 2.0, 3.0, 2.0, 1.0], dtype=np.float32)
    k = np.outer(k1, k1)
    h, w = mosaic.shape
    chan = np.asarray(cfa.channel_map(h, w))
    out = np.empty((h, w, 3), dtype=np.float32)
    for i, name in enumerate(_RGB):
        ci = list(cfa.channels).index(name)
        mask = (chan == ci).astype(np.float32)
        num = convolve(mosaic.astype(np.float32) * mask, k, mode="mirror")
        den = convolve(mask, k, mode="mirror")
        out[:, :, i] = num / np.maximum(den, 1e-6)
    return out
