"""Summaries and quick looks at a raw mosaic (``l3 info``).

Nothing here is learned: it is the plain view of the data that a user checks
before training (levels, clipping, the CFA) and a fast preview.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from l3cli.io.raw import RawImage

__all__ = ["raw_summary", "quick_preview"]


def raw_summary(raw: RawImage) -> dict[str, Any]:
    """Per-channel statistics of a normalised mosaic.

    Returns
    -------
    dict
        ``width``, ``height``, ``cfa``, ``period``, ``black_level``,
        ``white_level`` and per channel ``mean``, ``p99`` and ``clipped``
        (fraction of pixels at or above 0.999 of white).
    """
    ph, pw = raw.cfa.period
    chans: dict[str, dict[str, float]] = {}
    for ci, name in enumerate(raw.cfa.channels):
        vals = [
            raw.mosaic[y::ph, x::pw]
            for y in range(ph)
            for x in range(pw)
            if raw.cfa.index_pattern[y, x] == ci
        ]
        v = np.concatenate([a.ravel() for a in vals])
        chans[name] = {
            "mean": float(v.mean()),
            "p99": float(np.percentile(v, 99)),
            "clipped": float(np.mean(v >= 0.999)),
        }
    return {
        "path": str(raw.path) if raw.path else None,
        "width": raw.width,
        "height": raw.height,
        "cfa": raw.cfa.spec,
        "period": [ph, pw],
        "black_level": [float(b) for b in raw.black_level],
        "white_level": float(raw.white_level),
        "format": raw.metadata.get("format"),
        "channels": chans,
    }


def quick_preview(raw: RawImage, *, white_balance: bool = True) -> np.ndarray:
    """A fast, low-resolution linear RGB preview by binning each CFA repeat.

    Each repeat of ``ph`` x ``pw`` pixels becomes one output pixel whose R, G and
    B are the means of the repeat's R, G and B pixels (W/NIR/other channels are
    ignored; a CFA without R, G and B gives a grey image of the repeat mean).

    Parameters
    ----------
    raw
        The mosaic.
    white_balance
        Scale channels so their means agree (grey world), then so the 99th
        percentile of the brightest channel is 1.

    Returns
    -------
    numpy.ndarray
        float32 (H // ph, W // pw, 3), linear, approximately in [0, 1].
    """
    ph, pw = raw.cfa.period
    h, w = (raw.height // ph) * ph, (raw.width // pw) * pw
    m = raw.mosaic[:h, :w].reshape(h // ph, ph, w // pw, pw)
    pat = raw.cfa.pattern
    out = []
    for name in ("R", "G", "B"):
        sel = [(y, x) for y in range(ph) for x in range(pw) if pat[y][x] == name]
        if not sel:
            break
        out.append(np.mean([m[:, y, :, x] for y, x in sel], axis=0))
    if len(out) < 3:
        grey = m.mean(axis=(1, 3))
        rgb = np.repeat(grey[:, :, None], 3, axis=2)
    else:
        rgb = np.stack(out, axis=-1)
    rgb = np.clip(rgb, 0, None)
    if white_balance:
        means = rgb.reshape(-1, 3).mean(axis=0)
        rgb = rgb * (means.max() / np.maximum(means, 1e-6))
        top = np.percentile(rgb, 99)
        rgb = rgb / max(float(top), 1e-6)
    return np.clip(rgb, 0, 1).astype(np.float32)
