"""``l3 train``: learn a transform table from (raw, target) pairs."""

from __future__ import annotations

import click

from l3cli.cli.options import output_opt, quiet, scheduler_opt, seed_opt, workers_opt
from l3cli.train.fit import (
    DEFAULT_CONTRAST_BINS,
    DEFAULT_CONTRAST_THRESHOLD,
    DEFAULT_LEVELS,
    DEFAULT_PAIRS_TARGET,
    DEFAULT_PATCH,
    DEFAULT_SIMULATION_TARGET,
)


class _Threshold(click.ParamType):
    """A positive float, or ``quantile`` (None: per-level quantiles of the data)."""

    name = "T|quantile"

    def convert(self, value, param, ctx):
        if value is None or value == "quantile":
            return None
        try:
            v = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is neither a number nor 'quantile'", param, ctx)
        if not v > 0:
            self.fail(f"{value!r} must be > 0", param, ctx)
        return v


def _read_config(ctx: click.Context, param: click.Parameter, value: str | None) -> None:
    """``--config FILE``: its ``[train]`` table becomes the options' defaults."""
    if value is None:
        return
    from l3cli.train.tune import read_train_config

    allowed = {p.name for p in ctx.command.params if p.name not in ("config", "inputs")}
    options, grid = read_train_config(value, allowed)
    ctx.default_map = {**(ctx.default_map or {}), **options}
    ctx.meta["l3.tune_grid"] = grid


@click.command(short_help="Learn a transform table from simulate or pairs folders.")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(file_okay=False))
@output_opt
@click.option("--patch", type=int, default=DEFAULT_PATCH, show_default=True,
              help="Patch size (odd): the kernel sees PATCH x PATCH raw pixels.")
@click.option("--levels", type=click.IntRange(min=2), default=DEFAULT_LEVELS, show_default=True,
              help="Number of response-level bins.")
@click.option("--spacing", type=click.Choice(["log", "linear"]), default="log",
              show_default=True, help="Spacing of the level cut points.")
@click.option("--level-range", nargs=2, type=float, default=None, metavar="LOW HIGH",
              help="First and last level cut (normalised raw units); default: from the data "
                   "(just above its noise floor to near saturation).")
@click.option("--contrast-bins", type=click.IntRange(min=1), default=DEFAULT_CONTRAST_BINS,
              show_default=True, help="Contrast bins per level (2 = flat / textured).")
@click.option("--contrast-threshold", type=_Threshold(), default=DEFAULT_CONTRAST_THRESHOLD,
              show_default=True,
              help="Relative-contrast threshold (bin k starts at k x T), or 'quantile': "
                   "thresholds at the per-level quantiles of the data.")
@click.option("--saturation", type=float, default=0.95, show_default=True,
              help="Normalised value at or above which a pixel counts as saturated.")
@click.option("--merge-positions/--no-merge-positions", default=True, show_default=True,
              help="Share classes between CFA positions whose patch layouts coincide.")
@click.option("--target", "target_space",
              type=click.Choice(["xyz", "linear-srgb", "srgb", "lab"]), default=None,
              help=f"Colour space the table renders into [default: {DEFAULT_PAIRS_TARGET} (the "
                   f"renders' space, linear) when every input is a pairs folder, else "
                   f"{DEFAULT_SIMULATION_TARGET}].")
@click.option("--sample-fraction", type=click.FloatRange(min=0, max=1, min_open=True),
              default=1.0, show_default=True,
              help="Use this random fraction of the pixels of each image (fixed by --seed).")
@click.option("--min-samples", "min_samples_factor", type=float, default=3.0,
              show_default=True,
              help="A class needs at least this many samples per coefficient to be trained.")
@click.option("--scaled-renders", is_flag=True, default=False,
              help="Accept pairs-folder renders that are resized copies of their raws (e.g. "
                   "reduced-size camera JPEGs) and train them at their reduced resolution, "
                   "resampled onto the raw's pixels; without it such pairs are refused.")
@click.option("--tune", is_flag=True, default=False,
              help="Choose target space, patch, levels, contrast bins and contrast threshold by "
                   "cross-validation "
                   "over the training images (S-CIELAB of held-out images); prints the "
                   "candidates and records them in the table (docs/training.md).")
@click.option("--config", type=click.Path(dir_okay=False), callback=_read_config,
              is_eager=True, expose_value=False,
              help="TOML file whose [train] table sets these options (keys as the long "
                   "option names; a [train.tune] table sets the searched values).")
@seed_opt
@workers_opt
@scheduler_opt
def train(inputs: tuple[str, ...], output: str, patch: int, levels: int, spacing: str,
          level_range: tuple[float, float] | None, contrast_bins: int,
          contrast_threshold: float | None, saturation: float, merge_positions: bool,
          target_space: str, sample_fraction: float, min_samples_factor: float,
          seed: int, scaled_renders: bool = False, tune: bool = False,
          workers: int | None = None,
          scheduler: str | None = None) -> None:
    """Train a table from INPUT folders and write it to TABLE.npz (-o).

    Each INPUT is an `l3 simulate` output folder (manifest.json) or a pairs
    folder (each raw file with a same-stem rendered image). Per class, an
    affine kernel is fitted by ridge regression with λ chosen by generalised
    cross-validation from per-class sufficient statistics.

    With --workers or --scheduler each input is read and reduced to
    statistics by a dask.distributed worker; the table is the same as in
    process (docs/distributed.md).
    """
    import logging

    from l3cli.table import save_table
    from l3cli.train import TrainOptions, find_pairs
    from l3cli.train import train as train_table
    from l3cli.train.fit import default_target_space

    if patch < 1 or patch % 2 == 0:
        raise click.BadParameter(f"{patch} is not an odd size >= 1", param_hint="--patch")
    pairs = find_pairs(list(inputs), scaled_renders=scaled_renders)
    if target_space is None:
        target_space = default_target_space(pairs)
    opts = TrainOptions(patch=patch, levels=levels, spacing=spacing,
                        level_range=tuple(level_range) if level_range else None,
                        contrast_bins=contrast_bins, contrast_threshold=contrast_threshold,
                        saturation=saturation, merge_positions=merge_positions,
                        target_space=target_space, sample_fraction=sample_fraction, seed=seed,
                        min_samples_factor=min_samples_factor)
    show = not quiet()
    if tune:
        table = _tune(pairs, opts, workers, scheduler, show)
    else:
        table = train_table(pairs, opts, workers=workers, scheduler=scheduler,
                            show_progress=show)
    save_table(output, table)
    n_tr = int((~table.empty).sum())
    logging.getLogger(__name__).info("wrote %s", output)
    if show:
        click.echo(f"{output}: {n_tr} of {table.empty.size} classes trained from "
                   f"{len(pairs)} captures ({int(table.counts.sum())} samples)", err=True)


def _tune(pairs, opts, workers, scheduler, show):
    """``--tune``: the cross-validated search; prints the candidate table."""
    from l3cli.train.tune import format_candidates
    from l3cli.train.tune import tune as run_tune

    if workers is not None or scheduler is not None:
        raise click.UsageError("--tune runs in this process; drop --workers/--scheduler")
    grid = click.get_current_context().meta.get("l3.tune_grid")
    res = run_tune(pairs, opts, grid, show_progress=show)
    if not (click.get_current_context().find_root().obj or {}).get("quiet"):
        rec = res.record
        click.echo(f"tune: {len(rec['candidates'])} candidates, {len(rec['folds'])} folds, "
                   f"{rec['seconds']:.0f} s; {rec['metric']}", err=True)
        click.echo(format_candidates(rec), err=True)
    return res.table
