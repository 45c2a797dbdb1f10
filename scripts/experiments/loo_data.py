"""Leave-one-image-out of data/fit variants on a pairs folder (issue 14, data side).

    python scripts/experiments/loo_data.py FOLDER VARIANT ...

VARIANT: comma-separated ``key=value`` of :class:`l3cli.train.TrainOptions`
over l3 train's pairs defaults (``augment=none``, ``sample_weight=none``,
``levels=48`` ...), or ``default`` for the defaults; extra keys: ``lam=K``
(GCV's λ times K), ``insample=1`` (train on all, score the training images),
``clip_high=V``/``clip_low=V`` (which render values train, l3cli.pairs).
Prints the mean held-out S-CIELAB (ISETCam 10° opponent, 96 dpi, 1 m,
4-pixel border excluded) and the per-image scores, from the cross-validation
machinery of ``l3 train --tune`` (l3cli.train.cv). Used on the bundled
Infinite-ISP frames/ only (never holdout/).
"""

import functools
import sys
import time

import numpy as np

import l3cli.train.cv as cvmod
import l3cli.train.fit as fit
from l3cli import defaults
from l3cli.pairs import CLIP_HIGH, CLIP_LOW, load_pair
from l3cli.render import render_mosaic
from l3cli.train import TrainOptions, find_pairs
from l3cli.train.cv import display_xyz, fold_stats, histogram, layout_stats, make_folds, make_units
from l3cli.train.ridge import solve_class as base_solve
from l3cli.train.ridge import solve_ridge


def parse(spec: str) -> tuple[dict, dict]:
    opts, extra = dict(defaults.PAIRS_LAYOUT), {}
    for kv in spec.split(","):
        if kv == "default":
            continue
        k, v = kv.split("=")
        if k in ("lam", "insample", "clip_high", "clip_low"):
            extra[k] = float(v)
        elif k in ("patch", "levels", "contrast_bins", "orientation_bins", "context_block"):
            opts[k] = int(v)
        elif k == "contrast_threshold":
            opts[k] = float(v)
        else:
            opts[k] = v
    return opts, extra


def scaled_solver(mult: float):
    def solve(n, xtx, xty, yy, *, grid):
        sol = base_solve(n, xtx, xty, yy, grid=grid)
        sol.kernel = solve_ridge(n, xtx, xty, sol.lam * mult)
        return sol
    return solve


def main() -> None:
    folder, specs = sys.argv[1], [parse(s) for s in sys.argv[2:]]
    pairs = find_pairs([folder])
    images = clip = None
    cache: dict = {}
    for (spec, extra), name in zip(specs, sys.argv[2:], strict=True):
        t0 = time.perf_counter()
        want = (extra.get("clip_high", CLIP_HIGH), extra.get("clip_low", CLIP_LOW))
        opts = TrainOptions(**spec)
        if want != clip:
            cvmod.load_pair = functools.partial(load_pair, clip_high=want[0], clip_low=want[1])
            images, clip = cvmod.load_cv_images(pairs, opts), want
            units = make_units(images)
            folds = make_folds(units, len(units))
            cache.clear()
        key = (opts.patch, opts.levels, opts.contrast_bins, opts.contrast_threshold,
               opts.sample_weight, opts.orientation_bins, opts.context_block)
        if key not in cache:
            cache.clear()
            cache[key] = layout_stats(images, units, opts, histogram(images, opts))
        lay = cache[key]
        if "lam" in extra:
            fit.solve_class = scaled_solver(extra["lam"])
        insample = bool(extra.get("insample"))
        scores = np.full(len(units), np.nan)
        for held in ([list(range(len(units)))] if insample else folds):
            table = fit.table_from_stats(fold_stats(lay, [] if insample else held,
                                                    opts.target_space), opts)
            for u in held:
                img = images[units[u].image]
                out = render_mosaic(table, img.mosaic)
                scores[u] = img.scorer.mean(display_xyz(out, opts.target_space, img.display))
        fit.solve_class = base_solve
        print(f"{name}: {scores.mean():.4f}  [{' '.join(f'{v:.3f}' for v in scores)}]  "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
