"""Training of L3 transform tables (see ``docs/training.md``).

* :mod:`l3cli.pairs` -- the input layer: pairs from ``simulate`` and pairs folders;
* :mod:`l3cli.train.stats` -- per-class sufficient statistics (they add);
* :mod:`l3cli.train.ridge` -- ridge regression and GCV from the statistics;
* :mod:`l3cli.train.fit` -- the two passes and the table.
"""

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
