"""The features a transform table may hold: one list, by name.

A table is the per-class kernels plus optional features, each learned by an
option of ``l3 train`` and carried by every path that touches a table (render
to every format, ``l3 export``, ``l3 inspect``, distributed training, the
self-tuning). :data:`FEATURES` names them once; :func:`table_features` says
which a table holds, and how ``l3 inspect`` and an exported model describe
them. ``tests/test_feature_matrix.py`` builds a table with each feature of
this list and drives it through every path: a feature added here without
being carried everywhere fails that test.

Examples
--------
>>> [f.name for f in FEATURES][:3]
['lens shading', 'lens shading grid', 'patch 9']
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["FEATURES", "TableFeature", "table_features"]


@dataclass(frozen=True)
class TableFeature:
    """One optional feature of a table.

    Attributes
    ----------
    name
        How users, errors and the feature matrix test name it.
    option
        The ``l3 train`` option that learns it.
    present
        ``present(table)``: whether the table holds it.
    describe
        ``describe(table)``: one line for ``l3 inspect`` and an exported model.
    """

    name: str
    option: str
    present: Callable[[Any], bool]
    describe: Callable[[Any], str]


def _shading(t: Any) -> str:
    kind = "radial gain field" if t.shading.radial else (
        f"spline-grid gain field {t.shading.intervals[0]}x{t.shading.intervals[1]}")
    return f"lens shading ({kind} learned on {t.shading.size[1]}x{t.shading.size[0]} raws)"


FEATURES: tuple[TableFeature, ...] = (
    TableFeature("lens shading", "--shading",
                 lambda t: t.shading is not None and t.shading.radial, _shading),
    TableFeature("lens shading grid", "--shading",
                 lambda t: t.shading is not None and not t.shading.radial,
                 _shading),
    TableFeature("patch 9", "--patch 9", lambda t: t.definition.patch >= 9,
                 lambda t: f"patch {t.definition.patch}"),
    TableFeature("orientation bins", "--orientation-bins",
                 lambda t: bool(t.definition.orientation_bins),
                 lambda t: f"orientation bins {t.definition.orientation_bins}"),
    TableFeature("context bins", "--context-block", lambda t: bool(t.definition.context_block),
                 lambda t: (f"context bins ({t.definition.context_rule}, block "
                            f"{t.definition.context_block}, {t.definition.n_context})")),
    TableFeature("highlight bins", "--highlight-bins",
                 lambda t: bool(t.definition.highlight_bins), lambda t: "highlight bins"),
    TableFeature("condition bins", "--by", lambda t: t.conditions is not None,
                 lambda t: (f"condition bins ({t.conditions.by}, "
                            f"{t.conditions.values.size})")),
    TableFeature("white balance", "--as-shot-wb", lambda t: t.white_balance is not None,
                 lambda t: "as-shot white balance + adaptation"),
    TableFeature("tone curve", "--tone-curve", lambda t: t.tone_lut is not None,
                 lambda t: "tone curve"),
    TableFeature("multiscale stage", "--multiscale", lambda t: t.multiscale is not None,
                 lambda t: f"multiscale stage ({t.multiscale.n_classes} classes)"),
)


def table_features(table: Any) -> list[TableFeature]:
    """The features of :data:`FEATURES` that ``table`` holds, in the list's order."""
    return [f for f in FEATURES if f.present(table)]
