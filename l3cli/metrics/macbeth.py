"""Colour error on a Macbeth ColorChecker, as ISETCam's ``macbethColorError``.

The mean XYZ over the central region of each of the 24 patches is measured;
all measured values are scaled so that the measured white patch has the Y of
the ideal white patch; both the measured and the ideal patches go to CIELAB with
the ideal white patch as the white point; ΔE*ab (CIE 1976) and CIEDE2000 are
reported per patch and as means.

Patch geometry comes either as 24 boxes (the ``simulate`` manifest) or from the
four outer corners of the chart's patch grid in the image, mapped to the patch
centres by a projective transform (:func:`chart_patches_from_corners`).

References
----------
C. S. McCamy, H. Marcus and J. G. Davidson, "A color-rendition chart", Journal
of Applied Photographic Engineering 2(3), 95-99 (1976).
ISETCam ``macbethColorError``, ``chartRectangles``, https://github.com/ISET/isetcam.
CIE 015:2018 (CIELAB); CIE 142-2001 (CIEDE2000).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from l3cli.errors import InputError
from l3cli.metrics._common import as_image, delta_e, xyz_to_lab

__all__ = [
    "MACBETH_ROWS",
    "MACBETH_COLS",
    "MACBETH_WHITE_INDEX",
    "MacbethResult",
    "homography",
    "chart_patches_from_corners",
    "patch_means",
    "macbeth_delta_e",
]

MACBETH_ROWS = 4
MACBETH_COLS = 6
#: Index of the white patch (row 4, column 1) in reading order.
MACBETH_WHITE_INDEX = 18


@dataclass(frozen=True)
class MacbethResult:
    """Per-patch colour errors on a chart.

    Attributes
    ----------
    measured_xyz
        (P, 3) patch means after white normalisation.
    ideal_xyz
        (P, 3) ideal patch XYZ.
    measured_lab, ideal_lab
        (P, 3) CIELAB of both, with the ideal white patch as white.
    delta_e_ab
        (P,) ΔE*ab (CIE 1976) per patch.
    delta_e_2000
        (P,) CIEDE2000 per patch.
    white_scale
        The factor applied to the measured XYZ.
    """

    measured_xyz: NDArray
    ideal_xyz: NDArray
    measured_lab: NDArray
    ideal_lab: NDArray
    delta_e_ab: NDArray
    delta_e_2000: NDArray
    white_scale: float

    @property
    def mean_ab(self) -> float:
        """Mean ΔE*ab over the patches."""
        return float(np.mean(self.delta_e_ab))

    @property
    def mean_2000(self) -> float:
        """Mean CIEDE2000 over the patches."""
        return float(np.mean(self.delta_e_2000))


def homography(src: ArrayLike, dst: ArrayLike) -> NDArray:
    """3x3 projective map H with ``dst ~ H @ [src, 1]`` from four point pairs.

    Parameters
    ----------
    src, dst
        (4, 2) points (x, y); no three collinear.

    References
    ----------
    R. Hartley and A. Zisserman, Multiple View Geometry in Computer Vision, 2nd ed.
    (2004), section 4.1 (direct linear transform).
    """
    s = np.asarray(src, dtype=np.float64).reshape(4, 2)
    d = np.asarray(dst, dtype=np.float64).reshape(4, 2)
    a = []
    for (x, y), (u, v) in zip(s, d, strict=True):
        a.append([x, y, 1, 0, 0, 0, -u * x, -u * y, -u])
        a.append([0, 0, 0, x, y, 1, -v * x, -v * y, -v])
    _, sv, vt = np.linalg.svd(np.asarray(a))
    if sv[-2] < 1e-10 * sv[0]:
        raise InputError("chart corners are degenerate (three of them on a line?)")
    h = vt[-1].reshape(3, 3)
    return h / h[2, 2]


def _apply(h: NDArray, pts: NDArray) -> NDArray:
    p = np.c_[pts, np.ones(len(pts))] @ h.T
    return p[:, :2] / p[:, 2:3]


def chart_patches_from_corners(
    corners: ArrayLike,
    *,
    image_shape: tuple[int, ...],
    rows: int = MACBETH_ROWS,
    cols: int = MACBETH_COLS,
    fraction: float = 0.5,
) -> list[tuple[int, int, int, int]]:
    """Sampling boxes of a chart's patches from its four outer corners.

    Parameters
    ----------
    corners
        (4, 2) or 8 numbers: the outer corners of the patch grid, in the order
        top-left (dark-skin corner), top-right (bluish-green corner), bottom-right
        (black corner), bottom-left (white corner), as (x, y) pixel coordinates.
    image_shape
        Shape of the image, (H, W[, C]); every corner must lie inside it.
    rows, cols
        Chart layout (4 x 6 for the Macbeth chart).
    fraction
        Side of each sampling box relative to the local patch cell (0 < f <= 1).

    Returns
    -------
    list of (x0, y0, x1, y1)
        One box per patch in reading order, x1/y1 exclusive, at least one pixel.

    Raises
    ------
    InputError
        If a corner is outside the image or the corners are degenerate.
    """
    c = np.asarray(corners, dtype=np.float64).reshape(-1)
    if c.size != 8 or not np.all(np.isfinite(c)):
        raise InputError(f"chart corners need 8 numbers x0,y0,...,x3,y3, got {c.size}")
    c = c.reshape(4, 2)
    h, w = int(image_shape[0]), int(image_shape[1])
    names = ("top-left", "top-right", "bottom-right", "bottom-left")
    for name, (x, y) in zip(names, c, strict=True):
        if not (0 <= x <= w and 0 <= y <= h):
            raise InputError(
                f"chart corner {name} ({x:g}, {y:g}) is outside the {w}x{h} image"
            )
    if not 0 < fraction <= 1:
        raise InputError(f"patch fraction must be in (0, 1], got {fraction}")
    edges = np.roll(c, -1, axis=0) - c
    turns = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    if not (np.all(turns > 1.0) or np.all(turns < -1.0)):
        raise InputError(
            "chart corners are degenerate: they must form a convex quadrilateral in the order "
            "top-left, top-right, bottom-right, bottom-left"
        )
    hm = homography([[0, 0], [cols, 0], [cols, rows], [0, rows]], c)
    boxes = []
    for r in range(rows):
        for q in range(cols):
            u0, u1 = q + 0.5 - fraction / 2, q + 0.5 + fraction / 2
            v0, v1 = r + 0.5 - fraction / 2, r + 0.5 + fraction / 2
            # Largest axis-aligned box inside the mapped central quadrilateral.
            quad = _apply(hm, np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]]))
            xs = np.sort(quad[:, 0])
            ys = np.sort(quad[:, 1])
            x0, x1 = int(np.ceil(xs[1])), int(np.floor(xs[2]))
            y0, y1 = int(np.ceil(ys[1])), int(np.floor(ys[2]))
            centre = _apply(hm, np.array([[q + 0.5, r + 0.5]]))[0]
            if x1 <= x0:
                x0 = int(np.floor(centre[0]))
                x1 = x0 + 1
            if y1 <= y0:
                y0 = int(np.floor(centre[1]))
                y1 = y0 + 1
            x0, x1 = max(0, x0), min(w, x1)
            y0, y1 = max(0, y0), min(h, y1)
            boxes.append((x0, y0, max(x1, x0 + 1), max(y1, y0 + 1)))
    return boxes


def _central(box: Sequence[int], fraction: float) -> tuple[int, int, int, int]:
    x0, y0, x1, y1 = (int(v) for v in box)
    bw, bh = x1 - x0, y1 - y0
    mw = int(round(bw * (1 - fraction) / 2))
    mh = int(round(bh * (1 - fraction) / 2))
    return x0 + mw, y0 + mh, max(x1 - mw, x0 + mw + 1), max(y1 - mh, y0 + mh + 1)


def patch_means(
    image: ArrayLike, boxes: Sequence[Sequence[int]], *, fraction: float = 1.0
) -> NDArray:
    """Mean of each box's central region.

    Parameters
    ----------
    image
        (H, W, C) image.
    boxes
        ``(x0, y0, x1, y1)`` per patch (x1/y1 exclusive).
    fraction
        Side of the central region relative to the box (1 = the whole box).

    Returns
    -------
    ndarray
        (P, C) means.

    Raises
    ------
    InputError
        If a box is empty or outside the image.
    """
    img = as_image(image)
    h, w = img.shape[:2]
    out = []
    for i, box in enumerate(boxes):
        if len(box) != 4:
            raise InputError(f"patch {i}: a box needs 4 numbers x0, y0, x1, y1, got {list(box)}")
        x0, y0, x1, y1 = _central(box, fraction)
        if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
            raise InputError(f"patch {i} box {list(box)} is outside the {w}x{h} image")
        out.append(img[y0:y1, x0:x1].reshape(-1, img.shape[2]).mean(axis=0))
    return np.asarray(out)


def macbeth_delta_e(
    measured_xyz: ArrayLike,
    ideal_xyz: ArrayLike,
    *,
    white_index: int = MACBETH_WHITE_INDEX,
    normalise_white: bool = True,
) -> MacbethResult:
    """ΔE per patch between measured and ideal chart XYZ (ISETCam ``macbethColorError``).

    Parameters
    ----------
    measured_xyz
        (P, 3) measured mean XYZ per patch (any scale).
    ideal_xyz
        (P, 3) ideal XYZ per patch.
    white_index
        Index of the white patch (18 on the Macbeth chart).
    normalise_white
        Scale ``measured_xyz`` so its white patch has the ideal white's Y.

    Returns
    -------
    MacbethResult
        Per-patch ΔE*ab and CIEDE2000, with the ideal white patch as CIELAB white.

    Raises
    ------
    InputError
        On mismatched shapes, a bad white index or a non-positive white.

    References
    ----------
    ISETCam ``macbethColorError``; CIE 015:2018; CIE 142-2001.
    """
    m = np.asarray(measured_xyz, dtype=np.float64)
    ideal = np.asarray(ideal_xyz, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != 3 or m.shape != ideal.shape:
        raise InputError(
            f"measured patches {m.shape} and ideal patches {ideal.shape} must both be (P, 3)"
        )
    if not 0 <= white_index < len(m):
        raise InputError(f"white patch index {white_index} is not in 0..{len(m) - 1}")
    white = ideal[white_index]
    if white[1] <= 0:
        raise InputError(f"ideal white patch has Y = {white[1]:g}; it must be positive")
    scale = 1.0
    if normalise_white:
        my = m[white_index, 1]
        if not my > 0:
            raise InputError(f"measured white patch has Y = {my:g}; cannot normalise the white")
        scale = float(white[1] / my)
    m = m * scale
    lab_m = xyz_to_lab(m, white)
    lab_i = xyz_to_lab(ideal, white)
    return MacbethResult(
        measured_xyz=m,
        ideal_xyz=ideal,
        measured_lab=lab_m,
        ideal_lab=lab_i,
        delta_e_ab=delta_e(lab_m, lab_i, method="CIE 1976"),
        delta_e_2000=delta_e(lab_m, lab_i, method="CIE 2000"),
        white_scale=scale,
    )
