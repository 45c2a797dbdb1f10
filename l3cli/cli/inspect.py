"""``l3 inspect``: describe a transform table; draw its kernels and coefficient curves."""

from __future__ import annotations

import json
from pathlib import Path

import click

from l3cli.cli.options import InputPath


def _levels(ctx, param, value):
    if not value:
        return None
    out = []
    for part in value.split(","):
        part = part.strip()
        try:
            out.append(int(part))
        except ValueError:
            raise click.BadParameter(f"{part!r} is not a level bin number") from None
    return out


@click.command(short_help="Describe a table: class layout, samples, λ, filled classes; plots.")
@click.argument("table_path", metavar="TABLE.npz", type=InputPath(dir_okay=False))
@click.option("--plots", "plots", type=click.Path(file_okay=False), default=None,
              help="Write kernel weight images, coefficient-vs-level curves (and the tone "
                   "curve of a table that has one) into this folder (created if missing).")
@click.option("--compare", "compare", type=InputPath(dir_okay=False), default=None,
              metavar="OTHER.npz",
              help="The table before smoothing (same classes): curves show it as markers.")
@click.option("--levels", "levels", callback=_levels, default=None, metavar="L1,L2,...",
              help="Level bins for the kernel images, with --plots (default: low, mid, high "
                   "and a saturated class).")
@click.option("--classes", "classes", type=click.Choice(["none", "trained", "all"]),
              default="trained", show_default=True,
              help="Per-class list (samples, λ per output, status, fallback source): classes "
                   "with their own kernel (trained or filled), all classes, or none.")
@click.option("--json", "as_json", is_flag=True,
              help="Print the summary as JSON (for programs) instead of text.")
def inspect(table_path: str, plots: str | None, compare: str | None, levels: list[int] | None,
            classes: str, as_json: bool) -> None:
    """Print a readable summary of TABLE.npz (or of a PIPELINE.onnx from `l3 export`).

    Class layout, levels with their cut points, samples and λ, empty classes,
    classes filled by `l3 smooth`, output space and provenance. With --plots,
    draw the kernels as weight images per position group and output channel,
    and the coefficients against the level (before/after with --compare).
    """
    if Path(table_path).suffix.lower() == ".onnx":  # a model `l3 export` wrote
        from l3cli.export.metadata import format_model_summary, model_summary

        info = model_summary(table_path)
        click.echo(json.dumps(info, indent=2) if as_json else format_model_summary(info))
        return
    from l3cli.cli.paths import plan_folder
    from l3cli.errors import ConfigError
    from l3cli.inspect import class_rows, format_summary, table_summary
    from l3cli.table import load_table

    # every option is checked before anything is printed or written
    if levels is not None and not plots:
        raise click.BadParameter("it picks the levels of the kernel figures; give --plots FOLDER too",
                                 param_hint="--levels")
    plot_plan = plan_folder(plots, "--plots")
    table = load_table(table_path)
    other = load_table(compare) if compare else None
    if other is not None and not other.definition.same_as(table.definition):
        raise click.BadParameter(
            f"{compare} has a different class definition than {table_path}",
            param_hint="--compare")
    if plots:
        from l3cli.plots_table import kernel_levels

        try:
            kernel_levels(table, levels)
        except ConfigError as exc:
            raise ConfigError(f"{table_path}: --levels: {exc}") from None
    summary = table_summary(table, name=str(table_path))
    if as_json:
        if classes != "none":
            summary["class_list"] = [r for r in class_rows(table)
                                     if classes == "all" or r["status"] != "empty"]
        click.echo(json.dumps(summary, indent=2, default=str))
    else:
        click.echo(format_summary(summary, table=table, classes=classes))
    if plots:
        from l3cli.plots_table import plot_coefficient_curves, plot_kernels, plot_tone_curve

        folder = Path(plots)
        stem = Path(table_path).stem
        with plot_plan.writing():
            written = plot_kernels(table, folder, levels=levels, name=stem)
            written += plot_coefficient_curves(table, folder, before=other, name=stem,
                                               before_name=Path(compare).name if compare else "")
            written += plot_tone_curve(table, folder, name=stem)
        click.echo(f"wrote {len(written)} figures to {folder}", err=True)
