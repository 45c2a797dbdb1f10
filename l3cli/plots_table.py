"""Figures of a transform table (matplotlib, Agg backend, imported lazily).

* :func:`plot_kernels` -- the L3 paper's kernel figures: per chosen response
  level, the weight image of every position group and output channel (weights
  spread over the patch at low levels, where noise dominates, and concentrate
  at the centre at high levels);
* :func:`plot_coefficient_curves` -- coefficients against the response level
  (per-channel weight sums, centre weight, offset) of one table, or of a table
  before (markers) and after (lines) ``l3 smooth``;
* :func:`plot_tone_curve` -- a table's learned tone curve (``l3 train`` on
  pairs whose pipeline's curve is not the sRGB one).

Every panel names its CFA position by colour and place (``G at (0,1)``,
:func:`l3cli.figures.group_name`), every axis and colour bar carries a label.

References
----------
.. [1] Q. Tian, S. Lansel, J. E. Farrell, B. A. Wandell, "Automating the design
   of image processing pipelines for novel color filter arrays: Local, Linear,
   Learned (L3) method", Proc. SPIE 9023, Digital Photography X (2014), Fig. 4.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from l3cli.classify import describe_difference
from l3cli.errors import ConfigError, TableError
from l3cli.figures import channel_colour, group_name, plain_log_axis, pyplot
from l3cli.io.atomic import atomic_path, check_writable_dir
from l3cli.table import TransformTable

__all__ = ["default_levels", "kernel_levels", "plot_kernels", "plot_coefficient_curves",
           "plot_tone_curve", "level_values", "saturation_words", "LEVEL_LABEL"]

_OUT_NAMES = {"xyz": ("X", "Y", "Z"), "linear-srgb": ("R", "G", "B"), "srgb": ("R", "G", "B"),
              "lab": ("L*", "a*", "b*")}

#: Axis label of the response level (the classes' level feature).
LEVEL_LABEL = "response level (patch mean of the raw, 0-1)"


def _save(fig, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    pyplot().close(fig)
    return path


def _out_names(table: TransformTable) -> tuple[str, ...]:
    names = _OUT_NAMES.get(table.output_space, ())
    return tuple(names[o] if o < len(names) else f"output {o}" for o in range(table.n_out))


def _space_words(table: TransformTable) -> str:
    if table.tone_lut is not None:
        return f"the learned tone-curve space (then a look-up table to {table.output_space})"
    return table.output_space


def saturation_words(bits: int, channels: tuple[str, ...]) -> str:
    """``"no channel saturated"``, ``"G saturated"``, ``"R+G saturated"``."""
    from l3cli.inspect import saturation_name

    name = saturation_name(bits, channels)
    return "no channel saturated" if name == "-" else f"{name} saturated"


def level_values(table: TransformTable) -> np.ndarray:
    """Representative response level of every level bin (``exp`` of the spline abscissa)."""
    from l3cli.smooth.spline import level_abscissa

    return np.exp(level_abscissa(table.definition))


def default_levels(table: TransformTable) -> dict[str, tuple[int, int]]:
    """``{label: (saturation pattern, level)}`` for low / mid / high / saturated.

    Low, mid and high are the lowest, middle and highest trained unsaturated
    levels (any position group, contrast bin 0 preferred); ``saturated`` is the
    best-sampled trained class with a saturated channel (absent when none).
    """
    d = table.definition
    ng, ns, nl, nc = d.shape
    trained = (~table.empty).reshape(ng, ns, nl, nc)
    counts = table.counts.reshape(ng, ns, nl, nc)
    lv = np.flatnonzero(trained[:, 0].any(axis=(0, 2)))
    out: dict[str, tuple[int, int]] = {}
    if lv.size:
        out["low"] = (0, int(lv[0]))
        out["mid"] = (0, int(lv[lv.size // 2]))
        out["high"] = (0, int(lv[-1]))
    sat_counts = np.where(trained[:, 1:], counts[:, 1:], 0).sum(axis=(0, 3))  # (ns-1, nl)
    if sat_counts.size and sat_counts.max() > 0:
        s, lev = np.unravel_index(int(np.argmax(sat_counts)), sat_counts.shape)
        out["saturated"] = (int(s) + 1, int(lev))
    return out


def kernel_levels(table: TransformTable, levels: Sequence[int] | None = None
                  ) -> dict[str, tuple[int, int]]:
    """``{label: (saturation pattern, level)}`` of the kernel figures.

    ``levels`` (level bins of the unsaturated pattern) or, when None,
    :func:`default_levels`. Raises :class:`~l3cli.errors.ConfigError` for a
    level outside the table's bins, so a command can check ``--levels``
    before it prints or writes anything.
    """
    if levels is None:
        return default_levels(table)
    nl = table.definition.shape[2]
    bad = [int(lv) for lv in levels if not 0 <= int(lv) < nl]
    if bad:
        raise ConfigError(f"level {bad[0]} is not in 0..{nl - 1} (the table has {nl} level bins)")
    return {f"level{int(lv):02d}": (0, int(lv)) for lv in levels}


def _status(table: TransformTable, cls: int, filled: dict[int, str]) -> str:
    if table.empty[cls]:
        return f"empty: uses class {int(table.source_class[cls])}'s kernel"
    if cls in filled:
        return f"filled by smoothing ({filled[cls]})"
    return f"{int(table.counts[cls])} samples"


def plot_kernels(table: TransformTable, out_dir: str | os.PathLike, *,
                 levels: Sequence[int] | None = None, contrast: int = 0,
                 name: str = "table") -> list[Path]:
    """One PNG per chosen level: weight images per position group x output channel.

    Each panel is the kernel of one class -- the weight of every raw pixel of
    the patch (letters: its CFA colour, for patches up to 7x7) in one output
    of the centre pixel -- titled with the centre's CFA colour and position,
    the samples it was trained on and its offset; one colour bar per output.

    Parameters
    ----------
    table
        The table.
    out_dir
        Existing, writable folder.
    levels
        Level bins to draw (unsaturated pattern); default :func:`default_levels`
        (low, mid, high and a saturated class).
    contrast
        Contrast bin to draw.
    name
        Prefix of the file names.

    Returns
    -------
    list of Path
        ``{name}_kernels_{label}.png`` files written.
    """
    out_dir = check_writable_dir(out_dir)
    d = table.definition
    ng, ns, nl, nc = d.shape
    if not 0 <= contrast < nc:
        raise ConfigError(f"contrast bin {contrast} is not in 0..{nc - 1}")
    chosen = kernel_levels(table, levels)
    from l3cli.inspect import filled_classes

    plt = pyplot()
    s_ = d.patch
    r = s_ // 2
    onames = _out_names(table)
    chans = d.cfa.channels
    lvals = level_values(table)
    filled = filled_classes(table)
    ticks = sorted({0, r, s_ - 1})
    paths = []
    for label, (sat, lev) in chosen.items():
        fig, axes = plt.subplots(ng, table.n_out, figsize=(2.3 * table.n_out + 1.4, 2.3 * ng + 1.1),
                                 squeeze=False, layout="constrained")
        cls = [int(np.ravel_multi_index((g, sat, lev, contrast), d.shape)) for g in range(ng)]
        for o in range(table.n_out):
            vmax = float(np.abs(table.kernels[cls, :-1, o]).max()) or 1.0
            for g in range(ng):
                p = int(np.flatnonzero(d.position_group == g)[0])
                lay = d.cfa.neighbourhood(p, s_)
                k = table.kernels[cls[g]]
                ax = axes[g, o]
                im = ax.imshow(k[:-1, o].reshape(s_, s_), cmap="RdBu_r", vmin=-vmax, vmax=vmax)
                if s_ <= 7:
                    for yy in range(s_):
                        for xx in range(s_):
                            ax.text(xx, yy, chans[lay[yy, xx]], ha="center", va="center",
                                    fontsize=6, color="0.2")
                ax.set_xticks(ticks, [f"{t - r:+d}" if t != r else "0" for t in ticks]
                              if g == ng - 1 else [])
                ax.set_yticks(ticks, [f"{t - r:+d}" if t != r else "0" for t in ticks]
                              if o == 0 else [])
                ax.tick_params(labelsize=7, length=2)
                if g == ng - 1:
                    ax.set_xlabel("column offset (pixels)", fontsize=7)
                if o == 0:
                    ax.set_ylabel("row offset (pixels)", fontsize=7)
                ax.set_title(f"{group_name(d, g)} → {onames[o]}\n"
                             f"{_status(table, cls[g], filled)}, offset {k[-1, o]:.3g}",
                             fontsize=7)
            cb = fig.colorbar(im, ax=list(axes[:, o]), fraction=0.05, pad=0.02, shrink=0.6)
            cb.set_label(f"weight in output {onames[o]}", fontsize=7)
            cb.ax.tick_params(labelsize=7)
        fig.suptitle(f"{name}: kernels of response level bin {lev} of 0-{nl - 1} (level "
                     f"≈ {lvals[lev]:.3g}), {saturation_words(sat, chans)}, contrast bin "
                     f"{contrast} of 0-{nc - 1}\neach panel: weight of every raw pixel of the "
                     f"{s_}x{s_} patch (letter: its CFA colour) in one output of the centre "
                     f"pixel; offset: the constant term", fontsize=8)
        paths.append(_save(fig, out_dir / f"{name}_kernels_{label}.png"))
    return paths


def _curves(table: TransformTable, g: int, sat: int, contrast: int):
    """(labels, values (n_curves, nl, n_out), trained): channel sums, centre weight, offset."""
    from l3cli.smooth.uniformity import channel_sums

    d = table.definition
    ng, ns, nl, nc = d.shape
    idx = np.array([np.ravel_multi_index((g, sat, lv, contrast), d.shape) for lv in range(nl)])
    k = table.kernels[idx].astype(np.float64)
    sums = channel_sums(table.kernels, d)[idx]  # (nl, nch, n_out)
    centre = (d.patch * d.patch) // 2
    labels = [f"sum of the {c} weights" for c in d.cfa.channels] + ["centre pixel's weight",
                                                                      "offset"]
    vals = np.concatenate([sums.transpose(1, 0, 2), k[None, :, centre], k[None, :, -1]], axis=0)
    return labels, vals, ~table.empty[idx]


def plot_coefficient_curves(table: TransformTable, out_dir: str | os.PathLike, *,
                            before: TransformTable | None = None, saturation: int = 0,
                            contrast: int = 0, name: str = "table",
                            before_name: str = "before") -> list[Path]:
    """Coefficients against response level: one PNG, a row per position group.

    Per output channel: the summed weight of each CFA channel, the centre
    pixel's weight and the offset against the level (log axis, plain-number
    labels). With ``before`` (the table before smoothing, same class
    definition, named ``before_name`` in the title) its values are drawn as
    markers (hollow where the class was empty) and ``table``'s as lines.

    Returns
    -------
    list of Path
        ``[{name}_curves.png]``.
    """
    out_dir = check_writable_dir(out_dir)
    d = table.definition
    if before is not None and not before.definition.same_as(d):
        raise TableError("the two tables have different class definitions "
                         f"({describe_difference(before.definition, d)}); cannot compare")
    if before is not None and before.n_out != table.n_out:
        raise TableError("the two tables have different numbers of output channels")
    ng, ns, nl, nc = d.shape
    if not 0 <= saturation < ns:
        raise ConfigError(f"saturation pattern {saturation} is not in 0..{ns - 1}")
    if not 0 <= contrast < nc:
        raise ConfigError(f"contrast bin {contrast} is not in 0..{nc - 1}")
    plt = pyplot()
    x = level_values(table)
    onames = _out_names(table)
    nch = d.cfa.n_channels
    colours = [channel_colour(c, i) for i, c in enumerate(d.cfa.channels)] + ["k", "0.5"]
    styles = ["-"] * nch + ["-", "--"]  # channel sums, centre weight, offset
    fig, axes = plt.subplots(ng, table.n_out, figsize=(4.0 * table.n_out, 2.6 * ng + 1.3),
                             squeeze=False, layout="constrained")
    handles = []
    for g in range(ng):
        labels, vals, trained = _curves(table, g, saturation, contrast)
        if before is not None:
            _, bvals, btrained = _curves(before, g, saturation, contrast)
        for o in range(table.n_out):
            ax = axes[g, o]
            for i, lab in enumerate(labels):
                col = colours[i]
                (line,) = ax.plot(x, vals[i, :, o], styles[i], color=col, label=lab, lw=1.2)
                if g == 0 and o == 0:
                    handles.append(line)
                if before is not None:
                    ax.plot(x[btrained], bvals[i, btrained, o], "o", color=col, ms=3)
                    ax.plot(x[~btrained], bvals[i, ~btrained, o], "o", mfc="none", color=col,
                            ms=3)
            ax.tick_params(labelsize=7)
            plain_log_axis(ax, "x", lo=float(x.min()), hi=float(x.max()))
            ax.set_title(f"{group_name(d, g)} → output {onames[o]}", fontsize=8)
            ax.grid(alpha=0.3)
            ax.grid(alpha=0.12, which="minor")
            if g == ng - 1:
                ax.set_xlabel(LEVEL_LABEL, fontsize=7)
            if o == 0:
                ax.set_ylabel("weight or offset", fontsize=7)
    fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=7,
               frameon=False)
    what = (f"lines: this table, markers: {before_name} (hollow: class empty there)"
            if before is not None else "one point per level bin")
    fig.suptitle(f"{name}: kernel coefficients against response level, "
                 f"{saturation_words(saturation, d.cfa.channels)}, contrast bin {contrast} of "
                 f"0-{nc - 1}\n{what}; outputs in {_space_words(table)}", fontsize=9)
    return [_save(fig, out_dir / f"{name}_curves.png")]


def plot_tone_curve(table: TransformTable, out_dir: str | os.PathLike, *,
                    name: str = "table") -> list[Path]:
    """The learned tone curve of a table (nothing for a table without one).

    The table's look-up table per output channel: the kernels' output (the
    curve space) against the table's output, on linear axes and on log axes
    (plain-number labels) for the dark end, with the identity for reference.

    Returns
    -------
    list of Path
        ``[{name}_tone_curve.png]``, or ``[]`` when the table has no tone curve.
    """
    if table.tone_lut is None:
        return []
    out_dir = check_writable_dir(out_dir)
    plt = pyplot()
    lut, lo_hi = table.tone_lut
    onames = _out_names(table)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), layout="constrained")
    for o in range(table.n_out):
        v = np.linspace(float(lo_hi[0, o]), float(lo_hi[1, o]), lut.shape[0])
        col = channel_colour(onames[o], o)
        for ax in axes:
            ax.plot(v, lut[:, o], color=col, lw=1.3, label=f"output {onames[o]}")
    hi = float(max(lo_hi[1].max(), lut.max()))
    for ax in axes:
        ax.plot([0, hi], [0, hi], color="0.6", ls="--", lw=0.8, label="identity")
        ax.set_xlabel("kernel output (learned tone-curve space)", fontsize=8)
        ax.set_ylabel(f"table output ({table.output_space})", fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    axes[0].set_title("linear axes", fontsize=9)
    axes[0].legend(fontsize=7)
    x_lo = float(lo_hi[0].min()) * 0.8 if lo_hi[0].min() > 0 else 1e-3 * hi
    y_lo = 1e-3 * hi
    plain_log_axis(axes[1], "x", lo=x_lo, hi=hi)
    plain_log_axis(axes[1], "y", lo=y_lo, hi=hi)
    axes[1].set_xlim(x_lo, hi)
    axes[1].set_ylim(y_lo, hi)
    axes[1].set_title("log axes (the dark end)", fontsize=9)
    fig.suptitle(f"{name}: learned tone curve -- the look-up table applied after the kernels, "
                 "per output channel", fontsize=9)
    return [_save(fig, out_dir / f"{name}_tone_curve.png")]
