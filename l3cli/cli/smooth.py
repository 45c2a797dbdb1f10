"""``l3 smooth``: apply priors (symmetry, smoothness over levels, uniformity) to a table."""

from __future__ import annotations

import click

from l3cli import defaults
from l3cli.cli.options import InputPath, output_opt, silenced


def _strength(ctx, param, value):
    if value is None or value == "auto":
        return "auto"
    try:
        v = float(value)
    except ValueError:
        raise click.BadParameter(f"{value!r} is not 'auto' or a number") from None
    if not v >= 0 or v == float("inf"):
        raise click.BadParameter(f"{value!r} must be 'auto' or a finite number >= 0")
    return v


@click.command(short_help="Improve a table with priors: symmetry, smoothness, uniformity.")
@click.argument("table_path", metavar="TABLE.npz", type=InputPath(dir_okay=False))
@output_opt
@click.option("--symmetry/--no-symmetry", default=True, show_default=True,
              help="Average kernels of CFA positions whose patch layouts are mirror images "
                   "or rotations of each other.")
@click.option("--spline/--no-spline", default=True, show_default=True,
              help="Smooth every coefficient over log level (weighted smoothing spline); "
                   "fills empty classes.")
@click.option("--uniformity/--no-uniformity", default=True, show_default=True,
              help="Make a uniform scene render uniform (minimum-norm change of the kernels).")
@click.option("--spline-strength", default=str(defaults.SPLINE_STRENGTH), show_default=True,
              callback=_strength, metavar="auto|LAMBDA",
              help="Spline penalty λ (data weight = samples per coefficient, abscissa ln "
                   "level; larger = smoother); 'auto' picks λ per series by generalised "
                   "cross-validation.")
@click.option("--uniformity-target", type=click.Choice(["period-mean", "least-squares"]),
              default="period-mean", show_default=True,
              help="Common per-channel sums: the mean over CFA positions (keeps flat-area "
                   "colours) or the sample-weighted least-squares values.")
def smooth(table_path: str, output: str, symmetry: bool, spline: bool, uniformity: bool,
           spline_strength: float | str, uniformity_target: str) -> None:
    """Apply priors to TABLE.npz and write the smoothed table to OUT.npz (-o).

    Each prior is on by default and can be switched off; the output table
    records which ran, with what settings, and which empty classes were
    filled (see `l3 inspect`).
    """
    from l3cli.cli.paths import check_outputs
    from l3cli.smooth import smooth_table
    from l3cli.table import load_table, save_table

    check_outputs([(output, "-o")], [table_path])
    table = load_table(table_path)
    out = smooth_table(table, symmetry=symmetry, spline=spline, uniformity=uniformity,
                       spline_strength=spline_strength, uniformity_target=uniformity_target)
    out.provenance["smoothing"]["input"] = str(table_path)
    save_table(output, out)
    rec = out.provenance["smoothing"]
    if not silenced():
        click.echo(f"{output}: priors {', '.join(rec['priors']) or 'none'}; "
                   f"filled {len(rec['filled_classes'])} classes, {rec['still_empty']} still "
                   "empty", err=True)
