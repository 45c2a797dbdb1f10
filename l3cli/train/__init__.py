"""Training of L3 transform tables (see ``docs/training.md``).

The package is callable: ``l3cli.train(inputs, **options)`` is
:func:`l3cli.train.api.train`, what ``l3 train`` does (the inputs' defaults,
white balance, self-tuning, the multi-scale stage). ``l3cli.train.train`` is
the two passes with given :class:`TrainOptions`.

* :mod:`l3cli.train.api` -- the training policy: options in, table out;

* :mod:`l3cli.pairs` -- the input layer: pairs from ``simulate`` and pairs folders;
* :mod:`l3cli.train.stats` -- per-class sufficient statistics (they add);
* :mod:`l3cli.train.ridge` -- ridge regression and GCV from the statistics;
* :mod:`l3cli.train.fit` -- the two passes and the table.
"""

import sys
import types

from l3cli.pairs import LoadedPair, Pair, find_pairs, load_pair
from l3cli.train.fit import (
    TrainOptions,
    collect_stats,
    define_classes,
    table_from_stats,
    train,
)
from l3cli.train.ridge import DEFAULT_LAMBDA_GRID, gcv_curve, solve_class, solve_ridge
from l3cli.train.stats import ClassStats, accumulate

__all__ = [
    "Pair", "LoadedPair", "find_pairs", "load_pair", "TrainOptions", "collect_stats", "define_classes",
    "table_from_stats", "train", "DEFAULT_LAMBDA_GRID", "gcv_curve", "solve_class",
    "solve_ridge", "ClassStats", "accumulate",
]


class _CallableTrain(types.ModuleType):
    """The package's type: calling it trains as ``l3 train`` (:func:`l3cli.train.api.train`)."""

    def __call__(self, inputs, **options):
        from l3cli.train.api import train as train_inputs

        return train_inputs(inputs, **options)


sys.modules[__name__].__class__ = _CallableTrain
