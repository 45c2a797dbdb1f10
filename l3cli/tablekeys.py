"""Optional key groups of a table file: all present, or none.

A table feature that a table may or may not hold (lens shading, the
multi-scale stage) is stored as a group of NPZ keys whose first key names
the rule that produced it. :func:`optional_group` is the one check every
such group starts with: none present (the table lacks the feature), all
present with the rule this l3 applies, or a :class:`~l3cli.errors.TableError`.

Examples
--------
>>> import numpy as np
>>> optional_group({}, ("x_rule", "x_values"), "x-v1") is None
True
>>> arrs = {"x_rule": np.array("x-v1"), "x_values": np.zeros(3)}
>>> optional_group(arrs, ("x_rule", "x_values"), "x-v1")
True
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from l3cli.errors import TableError

__all__ = ["optional_group"]


def optional_group(arrs: Mapping[str, np.ndarray], keys: Sequence[str], rule: str) -> bool | None:
    """Check a group of optional keys whose first key holds the rule's name.

    Parameters
    ----------
    arrs
        The table's arrays.
    keys
        The group's keys, the rule's key first.
    rule
        The rule this l3 applies.

    Returns
    -------
    None when no key of the group is present, True when all are and the rule matches.

    Raises
    ------
    TableError
        Some keys missing (naming them), or another rule.
    """
    present = [k for k in keys if k in arrs]
    if not present:
        return None
    if len(present) != len(keys):
        missing = ", ".join(k for k in keys if k not in arrs)
        raise TableError(f"damaged table, missing keys {missing}")
    stored = arrs[keys[0]]
    if stored.dtype.kind != "U" or stored.ndim != 0 or str(stored) != rule:
        raise TableError(f"{keys[0]} {str(stored)!r} is not supported; this l3 applies {rule!r}")
    return True
