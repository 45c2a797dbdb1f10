"""Helpers shared by l3's figures (matplotlib, Agg backend, imported lazily).

* :func:`pyplot` -- ``matplotlib.pyplot`` on the non-interactive Agg backend;
* :func:`plain_log_axis` -- a log axis labelled with plain numbers (0.02, 0.05,
  0.1) whatever its span: matplotlib's default labels every minor tick of an
  axis spanning about one decade with ``2×10⁻²``-style text, which overprints;
* :func:`group_name` -- the CFA colour and position(s) of a position group
  (``"G at (0,1)"``), the words figures and summaries use instead of its index.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["pyplot", "plain_log_axis", "group_name", "log_subs", "channel_colour"]

#: Line colours of channels named by colour (others take the colour cycle's).
CHANNEL_COLOURS = {"R": "#d62728", "G": "#2ca02c", "B": "#1f77b4", "W": "0.45", "Y": "#bcbd22",
                   "C": "#17becf", "M": "#e377c2", "X": "#d62728", "Z": "#1f77b4"}


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def log_subs(lo: float, hi: float) -> tuple[float, ...]:
    """Mantissas of the labelled ticks of a log axis from ``lo`` to ``hi``.

    1, 2, 3, 5 within a decade and a half, 1, 2, 5 up to three decades, then
    the powers of ten alone: some five to ten labels on any span.

    Examples
    --------
    >>> log_subs(0.015, 0.4)
    (1.0, 2.0, 3.0, 5.0)
    >>> log_subs(1e-3, 1.0)
    (1.0, 2.0, 5.0)
    >>> log_subs(1e-6, 1.0)
    (1.0,)
    """
    if not (lo > 0 and hi > lo):
        return (1.0,)
    decades = math.log10(hi / lo)
    if decades <= 1.5:
        return (1.0, 2.0, 3.0, 5.0)
    if decades <= 3.2:
        return (1.0, 2.0, 5.0)
    return (1.0,)


def plain_log_axis(ax, which: str = "x", *, lo: float | None = None,
                   hi: float | None = None) -> None:
    """Make ``ax``'s x (or y) axis logarithmic with plain-number labels.

    Major ticks at the mantissas :func:`log_subs` picks for the axis's span
    (``lo``/``hi``, default the current data limits), labelled ``0.02``,
    ``0.05``, ``0.1`` ...; unlabelled minor ticks at every integer mantissa.
    """
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    axis = ax.xaxis if which == "x" else ax.yaxis
    (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    if lo is None or hi is None:
        lims = ax.dataLim.intervalx if which == "x" else ax.dataLim.intervaly
        lo = lims[0] if lo is None else lo
        hi = lims[1] if hi is None else hi
    axis.set_major_locator(LogLocator(base=10.0, subs=log_subs(float(lo), float(hi))))
    axis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    axis.set_minor_locator(LogLocator(base=10.0, subs=np.arange(2, 10) * 1.0))
    axis.set_minor_formatter(NullFormatter())


def channel_colour(name: str, index: int) -> str:
    """A line colour for a channel: red for R, green for G, blue for B, grey for W ...

    Channels of other names (``IR``, ``NIR``, ``E``) take the colour cycle's
    ``C{index + 4}`` (purple, brown, pink ... -- not red, green or blue).
    """
    return CHANNEL_COLOURS.get(str(name).upper(), f"C{(index + 4) % 10}")


def group_name(definition, group: int) -> str:
    """The CFA colour and (row, column) in the CFA repeat of a position group's positions.

    Examples
    --------
    >>> from l3cli.classify import ClassDefinition
    >>> d = ClassDefinition.build("GRBG", patch=5, level_cuts=[0.5])
    >>> [group_name(d, g) for g in range(d.n_groups)]
    ['G at (0,0)', 'R at (0,1)', 'B at (1,0)', 'G at (1,1)']
    """
    cfa = definition.cfa
    pw = cfa.period[1]
    where: dict[str, list[str]] = {}
    for p in np.flatnonzero(np.asarray(definition.position_group) == group):
        r, c = divmod(int(p), pw)
        where.setdefault(cfa.pattern[r][c], []).append(f"({r},{c})")
    return "; ".join(f"{ch} at {', '.join(pos)}" for ch, pos in where.items())
