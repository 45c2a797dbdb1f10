"""Prototype of issue 14 parts 3-4: would an extra class dimension win by cross-validation?

    python scripts/experiments/extra_classes.py FOLDER {context,orientation} [BINS]

An extra per-pixel label (computed from the raw only) splits every class of
the default layout into BINS sub-classes. No classifier change is needed for
the measurement: each image's statistics are accumulated once per label
(masks), a fold subtracts the held-out image, one table is solved per label,
and the held-out image is rendered with every label's table and each pixel
taken from its own label's render. Scored as ``l3 train --tune`` scores
(leave-one-image-out S-CIELAB, ISETCam 10° opponent, display 8-bit renders).

* ``context``: log ratio of the 7x7 local mean to the mean over a 64x64
  neighbourhood (from a half-resolution guide image, as HDRNet's bilateral
  grid conditions local colour transforms): darker than / like / brighter
  than the surroundings, which a local tone map treats differently.
* ``orientation``: RAISR-like structure tensor of the half-resolution guide
  (gradient angle quantised to BINS - 1 directions for coherent, strong
  gradients; label 0 for flat or incoherent patches).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from scipy.ndimage import gaussian_filter, sobel, uniform_filter

from l3cli.errors import TableError
from l3cli.render import render_mosaic
from l3cli.train import TrainOptions, find_pairs
from l3cli.train.cv import display_xyz, histogram, load_cv_images, make_units
from l3cli.train.fit import definition_from_histogram, table_from_stats
from l3cli.train.stats import ClassStats, accumulate


def guide(mosaic: np.ndarray) -> np.ndarray:
    h, w = mosaic.shape
    return mosaic[: h // 2 * 2, : w // 2 * 2].reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))


def upsample(lab: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    up = np.repeat(np.repeat(lab, 2, axis=0), 2, axis=1)
    out = np.zeros(shape, dtype=np.int8)
    out[: up.shape[0], : up.shape[1]] = up
    out[up.shape[0]:, :] = out[up.shape[0] - 1:up.shape[0], :]
    out[:, up.shape[1]:] = out[:, up.shape[1] - 1:up.shape[1]]
    return out


def context_labels(mosaic: np.ndarray, bins: int) -> np.ndarray:
    g = guide(mosaic)
    local = uniform_filter(g, 4)  # ~7x7 raw pixels
    ctx = uniform_filter(g, 32)  # 64x64 raw pixels
    r = np.log2((local + 1e-3) / (ctx + 1e-3))
    edges = np.linspace(-1.0, 1.0, bins + 1)[1:-1]  # within +-1 stop = "like the surround"
    return upsample(np.searchsorted(edges, r).astype(np.int8), mosaic.shape)


def orientation_labels(mosaic: np.ndarray, bins: int) -> np.ndarray:
    g = np.log2(guide(mosaic) + 1e-3)
    gx, gy = sobel(g, axis=1), sobel(g, axis=0)
    jxx = gaussian_filter(gx * gx, 1.5)
    jyy = gaussian_filter(gy * gy, 1.5)
    jxy = gaussian_filter(gx * gy, 1.5)
    tr = jxx + jyy
    disc = np.sqrt((jxx - jyy) ** 2 + 4 * jxy**2)
    coh = disc / (tr + 1e-12)
    strength = np.sqrt(0.5 * (tr + disc))
    angle = 0.5 * np.arctan2(2 * jxy, jxx - jyy)  # -pi/2..pi/2
    nd = bins - 1
    a = np.floor((angle + np.pi / 2) / np.pi * nd + 0.5).astype(np.int64) % nd
    lab = np.where((coh > 0.5) & (strength > np.median(strength)), 1 + a, 0).astype(np.int8)
    return upsample(lab, mosaic.shape)


def main() -> None:
    folder, kind = sys.argv[1], sys.argv[2]
    bins = int(sys.argv[3]) if len(sys.argv) > 3 else (3 if kind == "context" else 5)
    t0 = time.perf_counter()
    opts = TrainOptions(target_space="linear-srgb")  # the defaults
    images = load_cv_images(find_pairs([folder]), opts)
    units = make_units(images)
    d = definition_from_histogram(images[0].cfa, histogram(images, opts), opts)
    fn = context_labels if kind == "context" else orientation_labels
    labels = [fn(im.mosaic, bins) for im in images]
    stats = []
    for im, lab in zip(images, labels, strict=True):
        tgt = np.ascontiguousarray(im.targets[:, :, :3])
        per = []
        for b in range(bins):
            st = ClassStats.zeros(d, 3, target_space="linear-srgb")
            m = lab == b if im.mask is None else (lab == b) & im.mask
            accumulate(st, im.mosaic, tgt, mask=m)
            per.append(st)
        stats.append(per)
        print(f"{im.pair.stem}: label shares "
              f"{' '.join(f'{(lab == b).mean():.2f}' for b in range(bins))}", flush=True)
    base_scores, split_scores = [], []
    for u in units:
        i = u.image
        keep = [j for j in range(len(images)) if j != i]
        tables = []
        for b in range(bins):
            st = sum((stats[j][b] for j in keep), ClassStats.zeros(d, 3, target_space="linear-srgb"))
            try:
                tables.append(table_from_stats(st, opts))
            except TableError:
                tables.append(None)
        all_st = sum((stats[j][b] for j in keep for b in range(bins)),
                     ClassStats.zeros(d, 3, target_space="linear-srgb"))
        base = table_from_stats(all_st, opts)
        out_base = render_mosaic(base, images[i].mosaic)
        out = out_base.copy()
        for b, t in enumerate(tables):
            if t is not None:
                sel = labels[i] == b
                out[sel] = render_mosaic(t, images[i].mosaic)[sel]
        sc = images[i].scorer
        base_scores.append(sc.mean(display_xyz(out_base, "linear-srgb", True)))
        split_scores.append(sc.mean(display_xyz(out, "linear-srgb", True)))
        print(f"held out {u.name(images)}: defaults {base_scores[-1]:.4f}, "
              f"with {kind} x{bins} {split_scores[-1]:.4f}", flush=True)
    print(f"LOO mean: defaults {np.mean(base_scores):.4f}, with {kind} x{bins} "
          f"{np.mean(split_scores):.4f} ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
