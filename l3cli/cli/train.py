"""``l3 train``: learn a transform table from (raw, target) pairs."""

from __future__ import annotations

import click

from l3cli import defaults
from l3cli.cli.options import output_opt, quiet, scheduler_opt, seed_opt, workers_opt


def _odd(ctx: click.Context, param: click.Parameter, value: int) -> int:
    """--patch: an odd size >= 1 (the rule of :func:`l3cli.classify.check_patch`)."""
    from l3cli.classify import check_patch
    from l3cli.errors import ConfigError

    try:
        return check_patch(value, "")
    except ConfigError as exc:
        raise click.BadParameter(str(exc).strip()) from None


@click.command(short_help="Learn a transform table from simulate or pairs folders.")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(file_okay=False))
@output_opt
@click.option("--patch", type=int, default=defaults.PATCH, show_default=True, callback=_odd,
              help="Patch size (odd): the kernel sees PATCH x PATCH raw pixels.")
@click.option("--levels", type=click.IntRange(min=2), default=defaults.LEVELS, show_default=True,
              help="Number of response-level bins.")
@click.option("--spacing", type=click.Choice(["log", "linear"]), default=defaults.LEVEL_SPACING,
              show_default=True, help="Spacing of the level cut points.")
@click.option("--level-range", nargs=2, type=float, default=None, metavar="LOW HIGH",
              help="First and last level cut (normalised raw units); default: from the data "
                   "(just above its noise floor to near saturation).")
@click.option("--contrast-bins", type=click.IntRange(min=1), default=defaults.CONTRAST_BINS,
              show_default=True,
              help="Contrast bins per level (2 = flat / textured).")
@click.option("--contrast-threshold", type=float, default=None,
              help="Fixed relative-contrast threshold; default: the median of the data per level.")
@click.option("--saturation", type=float, default=defaults.SATURATION, show_default=True,
              help="Normalised value at or above which a pixel counts as saturated.")
@click.option("--merge-positions/--no-merge-positions", default=defaults.MERGE_POSITIONS,
              show_default=True,
              help="Share classes between CFA positions whose patch layouts coincide.")
@click.option("--target", "target_space",
              type=click.Choice(["xyz", "linear-srgb", "srgb", "lab"]), default=None,
              help="Colour space the table renders into [default: srgb (the renders' own "
                   "encoding) when every input is a pairs folder, else xyz].")
@click.option("--sample-fraction", type=click.FloatRange(min=0, max=1, min_open=True),
              default=defaults.SAMPLE_FRACTION, show_default=True,
              help="Use this random fraction of the pixels of each image (fixed by --seed).")
@click.option("--min-samples", "min_samples_factor", type=float,
              default=defaults.MIN_SAMPLES_FACTOR,
              show_default=True,
              help="A class needs at least this many samples per coefficient to be trained.")
@click.option("--scaled-renders", is_flag=True, default=False,
              help="Accept pairs-folder renders that are resized copies of their raws (e.g. "
                   "reduced-size camera JPEGs) and train them at their reduced resolution, "
                   "resampled onto the raw's pixels; without it such pairs are refused.")
@click.option("--orientation-bins", type=click.IntRange(min=0, max=16),
              default=defaults.ORIENTATION_BINS, show_default=True,
              help="Edge-angle classes from the patch's structure tensor (even N; 0 = off); "
                   "patches with coherence <= --coherence form one isotropic class.")
@click.option("--coherence", type=click.FloatRange(min=0, max=1, max_open=True),
              default=defaults.COHERENCE, show_default=True,
              help="Structure-tensor coherence at or below which a patch is isotropic.")
@click.option("--context-block", type=click.IntRange(min=0), default=defaults.CONTEXT_BLOCK,
              show_default=True,
              help="Context classes from a low-resolution guide of BLOCK x BLOCK pixel means "
                   "(0 = off).")
@click.option("--context-bins", type=click.IntRange(min=2), default=defaults.CONTEXT_BINS,
              show_default=True, help="Context bins (quantiles of the training data).")
@click.option("--context-rule", type=click.Choice(["mean", "ratio"]),
              default=defaults.CONTEXT_RULE, show_default=True,
              help="Context feature: the guide's level, or the patch level relative to it.")
@click.option("--highlight-bins", type=click.Choice(["0", "2"]),
              default=str(defaults.HIGHLIGHT_BINS), show_default=True,
              help="2 = split the classes by how much of the patch clips (at least "
                   "--highlight-fraction of its pixels saturated, or less); 0 = off.")
@click.option("--highlight-fraction", type=click.FloatRange(min=0, max=1, min_open=True),
              default=defaults.HIGHLIGHT_FRACTION, show_default=True,
              help="Fraction of saturated patch pixels that makes a strong highlight.")
@seed_opt
@workers_opt
@scheduler_opt
def train(inputs: tuple[str, ...], output: str, patch: int, levels: int, spacing: str,
          level_range: tuple[float, float] | None, contrast_bins: int,
          contrast_threshold: float | None, saturation: float, merge_positions: bool,
          target_space: str, sample_fraction: float, min_samples_factor: float,
          seed: int, scaled_renders: bool = False, workers: int | None = None,
          scheduler: str | None = None, orientation_bins: int = defaults.ORIENTATION_BINS,
          coherence: float = defaults.COHERENCE, context_block: int = defaults.CONTEXT_BLOCK,
          context_bins: int = defaults.CONTEXT_BINS,
          context_rule: str = defaults.CONTEXT_RULE,
          highlight_bins: str = str(defaults.HIGHLIGHT_BINS),
          highlight_fraction: float = defaults.HIGHLIGHT_FRACTION) -> None:
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

    pairs = find_pairs(list(inputs), scaled_renders=scaled_renders)
    if target_space is None:  # pairs folders reproduce their renders' encoding
        target_space = "srgb" if all(p.align for p in pairs) else "xyz"
    opts = TrainOptions(patch=patch, levels=levels, spacing=spacing,
                        level_range=tuple(level_range) if level_range else None,
                        contrast_bins=contrast_bins, contrast_threshold=contrast_threshold,
                        saturation=saturation, merge_positions=merge_positions,
                        target_space=target_space, sample_fraction=sample_fraction, seed=seed,
                        min_samples_factor=min_samples_factor,
                        orientation_bins=orientation_bins, coherence=coherence,
                        context_block=context_block, context_bins=context_bins,
                        context_rule=context_rule, highlight_bins=int(highlight_bins),
                        highlight_fraction=highlight_fraction)
    show = not quiet()
    table = train_table(pairs, opts, workers=workers, scheduler=scheduler, show_progress=show)
    save_table(output, table)
    n_tr = int((~table.empty).sum())
    logging.getLogger(__name__).info("wrote %s", output)
    if show:
        click.echo(f"{output}: {n_tr} of {table.empty.size} classes trained from "
                   f"{len(pairs)} captures ({int(table.counts.sum())} samples)", err=True)
