"""Figures of a transform table (matplotlib, Agg backend, imported lazily).

* :func:`plot_kernels` -- the L3 paper's kernel figures: per chosen response
  level, the weight image of every position group and output channel (weights
  spread over the patch at low levels, where noise dominates, and concentrate
  at the centre at high levels);
* :func:`plot_coefficient_curves` -- coefficients against the response level
  (per-channel weight sums, centre tap, offset) of one table, or of a table
  before (markers) and after (lines) ``l3 smooth``.

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
from l3cli.io.atomic import atomic_path, check_writable_dir
from l3cli.table import TransformTable

__all__ = ["default_levels", "plot_kernels", "plot_coefficient_curves", "level_values"]

_OUT_NAMES = {"xyz": ("X", "Y", "Z"), "linear-srgb": ("R", "G", "B"), "srgb": ("R", "G", "B"),
              "lab": ("L*", "a*", "b*")}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    _pyplot().close(fig)
    return path


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


def plot_kernels(table: TransformTable, out_dir: str | os.PathLike, *,
                 levels: Sequence[int] | None = None, contrast: int = 0,
                 name: str = "table") -> list[Path]:
    """One PNG per chosen level: weight images per position group x output channel.

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
    if levels is None:
        chosen = default_levels(table)
    else:
        chosen = {}
        for lv in levels:
            if not 0 <= int(lv) < nl:
                raise ConfigError(f"level {lv} is not in 0..{nl - 1} (the table has {nl} levels)")
            chosen[f"level{int(lv):02d}"] = (0, int(lv))
    plt = _pyplot()
    s_ = d.patch
    onames = _OUT_NAMES.get(table.output_space, tuple(f"out{i}" for i in range(table.n_out)))
    chans = d.cfa.channels
    lvals = level_values(table)
    paths = []
    from l3cli.inspect import saturation_name

    for label, (sat, lev) in chosen.items():
        fig, axes = plt.subplots(ng, table.n_out, figsize=(2.0 * table.n_out + 1.0, 2.0 * ng + 0.6),
                                 squeeze=False)
        fig.subplots_adjust(left=0.03, right=0.90, top=1 - 0.5 / (2.0 * ng + 0.6) - 0.03,
                            bottom=0.02, wspace=0.35, hspace=0.45)
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
                ax.set_xticks([])
                ax.set_yticks([])
                status = "empty" if table.empty[cls[g]] else f"n={table.counts[cls[g]]}"
                ax.set_title(f"grp {g} -> {onames[o] if o < len(onames) else o}\n"
                             f"{status}, b={k[-1, o]:.3g}", fontsize=7)
            fig.colorbar(im, ax=list(axes[:, o]), fraction=0.05, pad=0.02, shrink=0.9)
        fig.suptitle(f"{name}: level {lev} (~{lvals[lev]:.3g}), saturated "
                     f"{saturation_name(sat, chans)}, contrast {contrast}", fontsize=9)
        paths.append(_save(fig, out_dir / f"{name}_kernels_{label}.png"))
    return paths


def _curves(table: TransformTable, g: int, sat: int, contrast: int):
    """(labels, values (n_curves, nl, n_out)): channel sums, centre tap, offset."""
    from l3cli.smooth.uniformity import channel_sums

    d = table.definition
    ng, ns, nl, nc = d.shape
    idx = np.array([np.ravel_multi_index((g, sat, lv, contrast), d.shape) for lv in range(nl)])
    k = table.kernels[idx].astype(np.float64)
    sums = channel_sums(table.kernels, d)[idx]  # (nl, nch, n_out)
    centre = (d.patch * d.patch) // 2
    labels = [f"sum {c}" for c in d.cfa.channels] + ["centre tap", "offset"]
    vals = np.concatenate([sums.transpose(1, 0, 2), k[None, :, centre], k[None, :, -1]], axis=0)
    return labels, vals, ~table.empty[idx]


def plot_coefficient_curves(table: TransformTable, out_dir: str | os.PathLike, *,
                            before: TransformTable | None = None, saturation: int = 0,
                            contrast: int = 0, name: str = "table") -> list[Path]:
    """Coefficients against response level: one PNG, a row per position group.

    Per output channel: the summed weight of each CFA channel, the centre tap
    and the offset against the level (log axis). With ``before`` (the table
    before smoothing, same class definition) its values are drawn as markers
    (hollow where the class was empty) and ``table``'s as lines.

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
    plt = _pyplot()
    x = level_values(table)
    onames = _OUT_NAMES.get(table.output_space, tuple(f"out{i}" for i in range(table.n_out)))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fig, axes = plt.subplots(ng, table.n_out, figsize=(4.0 * table.n_out, 2.8 * ng + 0.6),
                             squeeze=False)
    fig.subplots_adjust(left=0.07, right=0.98, top=1 - 0.6 / (2.8 * ng + 0.6), bottom=0.06,
                        wspace=0.25, hspace=0.55)
    for g in range(ng):
        labels, vals, trained = _curves(table, g, saturation, contrast)
        if before is not None:
            _, bvals, btrained = _curves(before, g, saturation, contrast)
        members = np.flatnonzero(d.position_group == g).tolist()
        for o in range(table.n_out):
            ax = axes[g, o]
            for i, lab in enumerate(labels):
                col = colours[i % len(colours)]
                ax.plot(x, vals[i, :, o], "-", color=col, label=lab, lw=1.2)
                if before is not None:
                    ax.plot(x[btrained], bvals[i, btrained, o], "o", color=col, ms=3)
                    ax.plot(x[~btrained], bvals[i, ~btrained, o], "o", mfc="none", color=col,
                            ms=3)
            ax.set_xscale("log")
            ax.set_title(f"group {g} {members} -> {onames[o] if o < len(onames) else o}",
                         fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
            if g == ng - 1:
                ax.set_xlabel("response level (normalised raw)", fontsize=8)
            if g == 0 and o == 0:
                ax.legend(fontsize=6)
    what = "after (lines) vs before (markers, hollow = empty)" if before is not None \
        else "coefficients"
    fig.suptitle(f"{name}: {what}; saturation pattern {saturation}, contrast {contrast}",
                 fontsize=9)
    return [_save(fig, out_dir / f"{name}_curves.png")]
