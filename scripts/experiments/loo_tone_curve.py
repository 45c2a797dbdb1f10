"""Leave-one-image-out with a learned tone curve fitted per fold (issue 14).

    python scripts/experiments/loo_tone_curve.py FOLDER [key=value ...]

Keys: training options (``levels=24``, ``patch=5``, ``contrast_bins=2``,
``contrast_threshold=0.2``, ``augment=none|flips|d4``, ``sample_weight=none|luminance``) and the curve's settings in
:mod:`l3cli.tone.curve` (``KNOTS``, ``SMOOTHNESS``, ``BLOCK``, ``FLAT_STD``).

Unlike ``l3 train --tune`` (one curve from all the images: the held-out
image's blocks are a small share of it), every fold here fits its curve to
the training images only and accumulates their statistics in that fold's
curve space, so nothing of the held-out image is used. Prints each held-out
frame's S-CIELAB (ISETCam 10° opponent, 96 dpi, 1 m, 4-pixel border
excluded, 8-bit display sRGB as ``l3 render`` writes it) and the mean. Used
to choose the defaults on the bundled Infinite-ISP frames/ (never holdout/).
"""

import sys
import time

import numpy as np

import l3cli.tone.curve as tc
from l3cli import defaults
from l3cli.render import render_mosaic
from l3cli.tone.fit import attach_curve
from l3cli.train import TrainOptions, find_pairs
from l3cli.train.cv import CV_SPACES, display_xyz, histogram, load_cv_images
from l3cli.train.fit import definition_from_histogram, table_from_stats
from l3cli.train.stats import ClassStats, accumulate
from l3cli.train.weights import sample_weights


def main() -> None:
    folder = sys.argv[1]
    kw = dict(defaults.PAIRS_LAYOUT, tone_curve=False)
    for arg in sys.argv[2:]:
        k, v = arg.split("=")
        if hasattr(tc, k):
            setattr(tc, k, type(getattr(tc, k))(v))
        elif k in ("augment", "sample_weight"):
            kw[k] = v
        else:
            kw[k] = int(v) if k in ("patch", "levels", "contrast_bins") else float(v)
    t0 = time.perf_counter()
    opts = TrainOptions(**kw)
    images = load_cv_images(find_pairs([folder]), opts)  # curve-free targets
    enc = 3 * CV_SPACES.index("srgb")
    yy = 3 * CV_SPACES.index("xyz") + 1  # the weights' luminance, as l3 train's
    d = definition_from_histogram(images[0].cfa, histogram(images, opts), opts)
    samples = [tc.block_samples(im.mosaic, im.cfa, im.targets[:, :, enc:enc + 3],
                                saturation=opts.saturation, mask=im.mask, block=tc.BLOCK)
               for im in images]
    scores = []
    for u, img in enumerate(images):
        curve = tc.fit_tone_curve([s for i, s in enumerate(samples) if i != u],
                                  knots=tc.KNOTS, smoothness=tc.SMOOTHNESS)
        st = ClassStats.zeros(d, 3, target_space="linear-srgb")
        for i, im in enumerate(images):
            if i != u:
                weight = sample_weights(im.targets[:, :, yy], im.mask, opts.sample_weight)
                accumulate(st, im.mosaic, curve.linearise(im.targets[:, :, enc:enc + 3]),
                           mask=im.mask, weight=weight)
        table = attach_curve(table_from_stats(st, opts), curve)
        out = render_mosaic(table, img.mosaic)
        scores.append(img.scorer.mean(display_xyz(out, "linear-srgb", True)))
        print(f"{img.pair.name}: {scores[-1]:.4f}", flush=True)
    print(f"{' '.join(sys.argv[2:]) or 'defaults'}: LOO {np.mean(scores):.4f}  "
          f"[{' '.join(f'{s:.3f}' for s in scores)}]  ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
