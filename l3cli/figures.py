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


#: Labelled-tick mantissas of a log axis, densest first (:func:`log_subs`).
LOG_SUBS = ((1.0, 2.0, 3.0, 5.0), (1.0, 2.0, 5.0), (1.0, 3.0), (1.0,))


def _log_ticks(lo: float, hi: float, subs: tuple[float, ...]) -> list[float]:
    k0, k1 = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    return [s * 10.0 ** k for k in range(k0, k1 + 1) for s in subs
            if lo * (1 - 1e-9) <= s * 10.0 ** k <= hi * (1 + 1e-9)]


def log_subs(lo: float, hi: float, *, length_in: float | None = None, fontsize: float = 7.0,
             vertical: bool = False) -> tuple[float, ...]:
    """Mantissas of the labelled ticks of a log axis from ``lo`` to ``hi``.

    The densest of 1-2-3-5, 1-2-5, 1-3 and 1 whose labels fit: with the axis's
    length ``length_in`` (inches) given, neighbouring labels (``f"{v:g}"``
    text, ``fontsize`` points, side by side or, ``vertical``, stacked) must
    not touch; without it, 1-2-3-5 up to a decade and a half, 1-2-5 up to
    three decades, then the powers of ten alone.

    Examples
    --------
    >>> log_subs(0.015, 0.4)
    (1.0, 2.0, 3.0, 5.0)
    >>> log_subs(1e-3, 1.0)
    (1.0, 2.0, 5.0)
    >>> log_subs(1e-3, 1.0, length_in=2.5)
    (1.0, 3.0)
    >>> log_subs(1e-6, 1.0)
    (1.0,)
    """
    if not (lo > 0 and hi > lo):
        return (1.0,)
    span = math.log10(hi / lo)
    if length_in is None:
        return LOG_SUBS[0] if span <= 1.5 else LOG_SUBS[1] if span <= 3.2 else LOG_SUBS[-1]
    em = fontsize / 72.0  # inches; digits are 0.64 em wide in DejaVu Sans, "." and "-" 0.35

    def width(v: float) -> float:
        text = f"{v:g}"
        return em * (0.64 * len(text) - 0.29 * sum(c in ".-" for c in text))

    for subs in LOG_SUBS:
        ticks = _log_ticks(lo, hi, subs)
        pos = [length_in * math.log10(v / lo) / span for v in ticks]
        if vertical:
            need = [1.6 * fontsize / 72.0] * max(len(ticks) - 1, 0)
        else:
            size = [width(v) for v in ticks]
            need = [(a + b) / 2 + 0.8 * em for a, b in zip(size, size[1:], strict=False)]
        if all(b - a >= n for a, b, n in zip(pos, pos[1:], need, strict=False)):
            return subs
    return LOG_SUBS[-1]


def plain_log_axis(ax, which: str = "x", *, lo: float | None = None,
                   hi: float | None = None) -> None:
    """Make ``ax``'s x (or y) axis logarithmic with plain-number labels.

    Major ticks at the mantissas :func:`log_subs` picks for the axis's span
    (``lo``/``hi``, default the current data limits) and drawn length (the
    axes' size in the figure, less a small margin), labelled
    ``0.02``, ``0.05``, ``0.1`` ...; unlabelled minor ticks at every integer
    mantissa. Set the tick label size before calling it.
    """
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    axis = ax.xaxis if which == "x" else ax.yaxis
    (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    if lo is None or hi is None:
        lims = ax.dataLim.intervalx if which == "x" else ax.dataLim.intervaly
        lo = lims[0] if lo is None else lo
        hi = lims[1] if hi is None else hi
    w_in, h_in = ax.figure.get_size_inches()
    box = ax.get_position()
    length = 0.92 * (box.width * w_in if which == "x" else box.height * h_in)
    ticks = axis.get_major_ticks()
    size = ticks[0].label1.get_fontsize() if ticks else 7.0
    subs = log_subs(float(lo), float(hi), length_in=length, fontsize=size,
                    vertical=which != "x")
    axis.set_major_locator(LogLocator(base=10.0, subs=subs))
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
