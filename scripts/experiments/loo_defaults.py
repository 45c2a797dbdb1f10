"""Leave-one-image-out on a pairs folder for a list of training settings (issue 14).

    python scripts/experiments/loo_defaults.py FOLDER "space,patch,levels,bins[,key=value...]" ...

Prints one line per setting: the mean held-out S-CIELAB (ISETCam 10° opponent,
96 dpi, 1 m, 4-pixel border excluded) and the per-image scores. Uses the
cross-validation machinery of ``l3 train --tune`` (l3cli.train.cv): one
statistics pass per image and layout, folds by subtraction. Used to derive the
defaults of ``l3 train`` on the bundled Infinite-ISP frames/ (never holdout/).
"""

import sys
import time

from l3cli.train import TrainOptions, find_pairs
from l3cli.train.cv import (
    fold_scores,
    histogram,
    layout_stats,
    load_cv_images,
    make_folds,
    make_units,
)


def parse(spec: str) -> dict:
    parts = spec.split(",")
    d = {"target_space": parts[0], "patch": int(parts[1]), "levels": int(parts[2]),
         "contrast_bins": int(parts[3])}
    for kv in parts[4:]:
        k, v = kv.split("=")
        d[k] = float(v)
    return d


def main() -> None:
    folder, specs = sys.argv[1], [parse(s) for s in sys.argv[2:]]
    pairs = find_pairs([folder])
    images = load_cv_images(pairs, TrainOptions())
    units = make_units(images)
    folds = make_folds(units, len(units))
    hists, cache = {}, {}
    for spec in specs:
        t0 = time.perf_counter()
        opts = TrainOptions(**spec)
        key = (opts.patch, opts.levels, opts.contrast_bins, opts.contrast_threshold,
               opts.saturation)
        if opts.patch not in hists:
            hists[opts.patch] = histogram(images, opts)
        if key not in cache:
            cache.clear()
            cache[key] = layout_stats(images, units, opts, hists[opts.patch])
        s = fold_scores(images, units, folds, cache[key], opts)
        print(f"{spec}: {s.mean():.4f}  [{' '.join(f'{v:.3f}' for v in s)}]  "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
