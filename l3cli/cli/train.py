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
@click.option("--by", "by", type=click.Choice(["iso"]), default=None,
              help="Learn one set of kernels per ISO of the training raws (from their "
                   "metadata) into the table; `l3 render` interpolates between the two "
                   "nearest ISOs of each raw.")
@click.option("--embedded-preview", is_flag=True, default=False,
              help="Train each raw of the INPUT folders against the JPEG preview the raw "
                   "embeds (rawpy's thumbnail; full size, or a resized copy trained at its "
                   "resolution) instead of a rendered image of the same stem.")
@click.option("--as-shot-wb/--no-as-shot-wb", "as_shot_wb", default=None,
              help="Normalise every raw by its as-shot white balance and condition the "
                   "colour on the shot's white (docs/real-camera.md) [default: on when every "
                   "input is a pairs folder and every raw carries a white balance].")
@click.option("--white-balance", "white_balance", metavar="R,G,B", default=None,
              help="White-balance multipliers for every training raw instead of their own "
                   "(implies --as-shot-wb).")
@seed_opt
@workers_opt
@scheduler_opt
def train(inputs: tuple[str, ...], output: str, patch: int, levels: int, spacing: str,
          level_range: tuple[float, float] | None, contrast_bins: int,
          contrast_threshold: float | None, saturation: float, merge_positions: bool,
          target_space: str, sample_fraction: float, min_samples_factor: float,
          seed: int, scaled_renders: bool = False, workers: int | None = None,
          scheduler: str | None = None, as_shot_wb: bool | None = None,
          white_balance: str | None = None, embedded_preview: bool = False,
          by: str | None = None) -> None:
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

    from l3cli.cli.paths import check_outputs
    from l3cli.table import save_table
    from l3cli.train import TrainOptions, find_pairs
    from l3cli.train import train as train_table

    check_outputs([(output, "-o")], inputs)
    if embedded_preview:
        import shutil
        import tempfile
        from pathlib import Path

        from l3cli.preview import preview_pairs

        parent = Path(output).absolute().parent
        work = tempfile.mkdtemp(prefix=".l3-tmp-previews-",
                                dir=parent if parent.is_dir() else None)
        click.get_current_context().call_on_close(lambda: shutil.rmtree(work, ignore_errors=True))
        pairs = preview_pairs(list(inputs), work)
    else:
        pairs = find_pairs(list(inputs), scaled_renders=scaled_renders)
    if target_space is None:  # pairs folders reproduce their renders' encoding
        target_space = "srgb" if all(p.align for p in pairs) else "xyz"
    gains = None
    if white_balance is not None:
        from l3cli.errors import InputError
        from l3cli.whitebalance import parse_gains

        try:
            gains = parse_gains(white_balance)
        except InputError as exc:
            raise click.BadParameter(str(exc).split(": ", 1)[-1],
                                     param_hint="--white-balance") from None
        if as_shot_wb is False:
            raise click.BadParameter("--white-balance needs white-balanced training; drop "
                                     "--no-as-shot-wb", param_hint="--white-balance")
        as_shot_wb = True
    if as_shot_wb is None:  # real cameras: on when every raw says its white balance
        from l3cli.whitebalance import file_gains

        as_shot_wb = all(p.align for p in pairs) and all(
            file_gains(p.raw) is not None for p in pairs)
    opts = TrainOptions(patch=patch, levels=levels, spacing=spacing,
                        level_range=tuple(level_range) if level_range else None,
                        contrast_bins=contrast_bins, contrast_threshold=contrast_threshold,
                        saturation=saturation, merge_positions=merge_positions,
                        target_space=target_space, sample_fraction=sample_fraction, seed=seed,
                        min_samples_factor=min_samples_factor, white_balance=as_shot_wb,
                        wb_override=None if gains is None else gains.tolist(), by=by)
    show = not quiet()
    table = train_table(pairs, opts, workers=workers, scheduler=scheduler, show_progress=show)
    save_table(output, table)
    n_tr = int((~table.empty).sum())
    logging.getLogger(__name__).info("wrote %s", output)
    if show:
        click.echo(f"{output}: {n_tr} of {table.empty.size} classes trained from "
                   f"{len(pairs)} captures ({int(table.counts.sum())} samples)", err=True)
