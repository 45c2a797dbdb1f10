"""``l3 train``: learn a transform table from (raw, target) pairs."""

from __future__ import annotations

import click

from l3cli import defaults
from l3cli.cli.options import (
    Finite,
    InputPath,
    output_opt,
    quiet,
    scheduler_opt,
    seed_opt,
    silenced,
    white_balance_opt,
    workers_opt,
)

_P, _S = defaults.PAIRS_LAYOUT, defaults.SIMULATION_LAYOUT


def _default(key: str, simulate: object | None = None) -> str:
    """``[default: V]`` when both input kinds share it, else both named."""
    p, s = _P[key], _S[key] if simulate is None else simulate
    if p == s:
        return f"[default: {p}]"
    return f"[default: {p} for pairs folders, {s} for simulate folders]"


class _Threshold(click.ParamType):
    """A positive float, or ``quantile`` (None: per-level quantiles of the data)."""

    name = "T|quantile"

    def convert(self, value, param, ctx):
        if value is None or value == "quantile":
            return value
        try:
            v = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is neither a number nor 'quantile'", param, ctx)
        if not 0 < v < float("inf"):
            self.fail(f"{value!r} must be a finite number > 0", param, ctx)
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


def _odd(ctx: click.Context, param: click.Parameter, value: int) -> int:
    """--patch: an odd size >= 1 (the rule of :func:`l3cli.classify.check_patch`)."""
    from l3cli.classify import check_patch
    from l3cli.errors import ConfigError

    if value is None:  # the default of the inputs' kind (l3cli.defaults)
        return None
    try:
        return check_patch(value, "")
    except ConfigError as exc:
        raise click.BadParameter(str(exc).strip()) from None


@click.command(short_help="Learn a transform table from simulate or pairs folders.")
@click.argument("inputs", nargs=-1, required=True, type=InputPath())
@output_opt
@click.option("--patch", type=int, default=None, callback=_odd,
              help="Patch size (odd): the kernel sees PATCH x PATCH raw pixels "
                   f"{_default('patch')}.")
@click.option("--levels", type=click.IntRange(min=2), default=None,
              help="Number of response-level bins "
                   f"{_default('levels')}.")
@click.option("--spacing", type=click.Choice(["log", "linear"]), default=defaults.LEVEL_SPACING,
              show_default=True, help="Spacing of the level cut points.")
@click.option("--level-range", nargs=2, type=Finite(min=0, min_open=True), default=None, metavar="LOW HIGH",
              help="First and last level cut (normalised raw units); default: from the data "
                   "(just above its noise floor to near saturation).")
@click.option("--contrast-bins", type=click.IntRange(min=1), default=None,
              help="Contrast bins per level (2 = flat / textured) "
                   f"{_default('contrast_bins')}.")
@click.option("--contrast-threshold", type=_Threshold(), default=None,
              help="Relative-contrast threshold (bin k starts at k x T), or 'quantile': "
                   "thresholds at the per-level quantiles of the data "
                   f"{_default('contrast_threshold', 'quantile')}.")
@click.option("--saturation", type=Finite(min=0, max=1.5, min_open=True), default=defaults.SATURATION, show_default=True,
              help="Normalised value at or above which a pixel counts as saturated.")
@click.option("--merge-positions/--no-merge-positions", default=defaults.MERGE_POSITIONS,
              show_default=True,
              help="Share classes between CFA positions whose patch layouts coincide.")
@click.option("--target", "target_space",
              type=click.Choice(["xyz", "linear-srgb", "srgb", "lab"]), default=None,
              help=f"Colour space the table renders into [default: {_P['target_space']} (the "
                   f"renders' space, linear) when every input is a pairs folder, else "
                   f"{_S['target_space']}].")
@click.option("--tone-curve/--no-tone-curve", "tone_curve", default=None,
              help="Learn the renders' per-channel tone curve from the pairs and train the "
                   "kernels in its linear space; the table maps their output back through "
                   "the curve (docs/training.md) [default: on for pairs folders with the "
                   "linear-srgb target, else off].")
@click.option("--shading/--no-shading", "shading", default=None,
              help="Learn the camera's lens-shading correction (a smooth per-channel gain over "
                   "sensor position, applied to the raw before classification; kept only where "
                   "it predicts held-out pairs better than none; docs/training.md) [default: "
                   "on for pairs folders, else off].")
@click.option("--sample-fraction", type=Finite(min=0, max=1, min_open=True),
              default=defaults.SAMPLE_FRACTION, show_default=True,
              help="Use this random fraction of the pixels of each image (fixed by --seed).")
@click.option("--min-samples", "min_samples_factor", type=Finite(min=1, min_open=True),
              default=defaults.MIN_SAMPLES_FACTOR,
              show_default=True,
              help="A class needs at least this many samples per coefficient to be trained.")
@click.option("--scaled-renders", is_flag=True, default=False,
              help="Accept pairs-folder renders that are resized copies of their raws (e.g. "
                   "reduced-size camera JPEGs) and train them at their reduced resolution, "
                   "resampled onto the raw's pixels; without it such pairs are refused.")
@click.option("--by", "by", type=click.Choice(["iso", "exposure", "white-balance"]),
              default=None,
              help="Learn one set of kernels per ISO, exposure time or as-shot white "
                   "balance (its b/r) of the training raws, from their metadata, into the "
                   "table; `l3 render` interpolates each raw's kernels between the two "
                   "nearest bins (in log value). Off by default.")
@click.option("--embedded-preview", is_flag=True, default=False,
              help="Train each raw of the INPUT folders against the JPEG preview the raw "
                   "embeds (rawpy's thumbnail; full size, or a resized copy trained at its "
                   "resolution) instead of a rendered image of the same stem.")
@click.option("--as-shot-wb/--no-as-shot-wb", "as_shot_wb", default=None,
              help="Normalise every raw by its as-shot white balance and condition the "
                   "colour on the shot's white (docs/real-camera.md) [default: on when every "
                   "input is a pairs folder and every raw carries a white balance].")
@white_balance_opt(
              help="White-balance multipliers for every training raw instead of their own "
                   "(implies --as-shot-wb).")
@click.option("--tune/--no-tune", "tune", default=None,
              help="Choose the options by cross-validation over the training images "
                   "(S-CIELAB of held-out images): target space, patch 7/9, lens shading "
                   "and the multi-scale stage on or off; options given here are kept fixed. "
                   "The cheapest to render of the candidates within one standard error of "
                   "the best is chosen; prints the candidates and records them in the table "
                   "(docs/training.md, \"Self-tuning\"). --no-tune trains the fixed defaults "
                   "[default: on for pairs folders, off for simulate folders].")
@click.option("--config", type=InputPath(dir_okay=False), callback=_read_config,
              is_eager=True, expose_value=False,
              help="TOML file whose [train] table sets these options (keys as the long "
                   "option names; a [train.tune] table sets the searched values).")
@click.option("--orientation-bins", type=click.IntRange(min=0, max=16),
              default=defaults.ORIENTATION_BINS, show_default=True,
              help="Edge-angle classes from the patch's structure tensor (even N; 0 = off); "
                   "patches with coherence <= --coherence form one isotropic class.")
@click.option("--coherence", type=Finite(min=0, max=1, max_open=True),
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
@click.option("--highlight-fraction", type=Finite(min=0, max=1, min_open=True),
              default=defaults.HIGHLIGHT_FRACTION, show_default=True,
              help="Fraction of saturated patch pixels that makes a strong highlight.")
@click.option("--augment", type=click.Choice(["none", "flips", "d4"]), default=None,
              help="Also train every pair mirrored and rotated, raw and render together "
                   "(d4: all 8 of the square's symmetries; flips: the 4 mirrors), re-phased "
                   "to the CFA; costs no extra pass over the pixels. Assumes the pipeline "
                   f"has no preferred direction {_default('augment')}.")
@click.option("--sample-weight", type=click.Choice(["none", "luminance"]), default=None,
              help="Weight each training pixel by its target's luminance in the fit "
                   f"{_default('sample_weight')}.")
@click.option("--multiscale/--no-multiscale", default=None,
              help="After the table, learn a multi-scale stage that blends wide low-passes of "
                   "the render with its detail per coarse class: noise reduction beyond the "
                   "patch, as cameras do (docs/training.md) [default: chosen by the tuning "
                   "for pairs folders, else off].")
@seed_opt
@workers_opt
@scheduler_opt
def train(inputs: tuple[str, ...], output: str, patch: int, levels: int, spacing: str,
          level_range: tuple[float, float] | None, contrast_bins: int,
          contrast_threshold: float | None, saturation: float, merge_positions: bool,
          target_space: str, sample_fraction: float, min_samples_factor: float,
          seed: int, scaled_renders: bool = False, tune: bool | None = None,
          workers: int | None = None,
          scheduler: str | None = None, as_shot_wb: bool | None = None,
          white_balance=None, embedded_preview: bool = False,
          by: str | None = None, orientation_bins: int = defaults.ORIENTATION_BINS,
          coherence: float = defaults.COHERENCE, context_block: int = defaults.CONTEXT_BLOCK,
          context_bins: int = defaults.CONTEXT_BINS,
          context_rule: str = defaults.CONTEXT_RULE,
          highlight_bins: str = str(defaults.HIGHLIGHT_BINS),
          highlight_fraction: float = defaults.HIGHLIGHT_FRACTION,
          tone_curve: bool | None = None, shading: bool | None = None,
          augment: str | None = None, sample_weight: str | None = None,
          multiscale: bool | None = None) -> None:
    """Train a table from INPUT folders and write it to TABLE.npz (-o).

    Each INPUT is an `l3 simulate` output folder (manifest.json) or a pairs
    folder (each raw file with a same-stem rendered image). Per class, an
    affine kernel is fitted by ridge regression with λ chosen by generalised
    cross-validation from per-class sufficient statistics.

    Pairs folders are self-tuned by default: target space, patch 7/9, lens
    shading and the multi-scale stage are chosen by cross-validation over the
    training images, preferring the cheaper render within one standard error
    of the best (--no-tune: the fixed defaults).

    With --workers or --scheduler each input is read and reduced to
    statistics by a dask.distributed worker; the table is the same as in
    process (docs/distributed.md; pairs folders then train the fixed defaults).
    """
    import logging

    from l3cli.cli.options import distinct_inputs
    from l3cli.cli.paths import check_outputs
    from l3cli.table import save_table
    from l3cli.train import TrainOptions, find_pairs
    from l3cli.train import train as train_table
    from l3cli.train.fit import layout_defaults

    check_outputs([(output, "-o")], inputs)
    distinct_inputs(inputs, "a training input")
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
    # the layout's defaults depend on what is trained from (l3cli.defaults)
    layout = layout_defaults(pairs)
    patch = layout["patch"] if patch is None else patch
    levels = layout["levels"] if levels is None else levels
    contrast_bins = layout["contrast_bins"] if contrast_bins is None else contrast_bins
    if contrast_threshold is None:
        contrast_threshold = layout["contrast_threshold"]
    elif contrast_threshold == "quantile":
        contrast_threshold = None
    target_space = target_space or layout["target_space"]
    if tone_curve is None:  # the layout's, where its target space is used
        from l3cli.train.fit import TONE_CURVE_SPACE

        tone_curve = layout["tone_curve"] and target_space == TONE_CURVE_SPACE
    augment = augment or layout["augment"]
    sample_weight = sample_weight or layout["sample_weight"]
    shading = layout["shading"] if shading is None else shading
    gains = white_balance
    if gains is not None:
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
                        wb_override=None if gains is None else gains.tolist(), by=by,
                        orientation_bins=orientation_bins, coherence=coherence,
                        context_block=context_block, context_bins=context_bins,
                        context_rule=context_rule, highlight_bins=int(highlight_bins),
                        highlight_fraction=highlight_fraction, tone_curve=tone_curve,
                        augment=augment, sample_weight=sample_weight, shading=shading)
    show = not quiet()
    asked = tune is not None
    tune = _want_tune(tune, pairs, opts, workers, scheduler)
    table = None
    if tune:
        from l3cli.errors import InputError, TableError

        try:
            table = _tune(pairs, opts, multiscale, show)
        except (InputError, TableError) as exc:
            if asked:  # --tune: its error is the user's answer
                raise
            # the default search cannot score these inputs (e.g. too little data for its
            # folds): the fixed defaults, which need less, with a note
            tune = False
            if not silenced():
                click.echo(f"note: self-tuning skipped ({exc}); training the fixed defaults",
                           err=True)
    if table is None:
        table = train_table(pairs, opts, workers=workers, scheduler=scheduler,
                            show_progress=show)
    if multiscale and not tune:  # the learned stage after the kernels (l3cli.multiscale)
        from l3cli.train.multiscale import attach_multiscale

        attach_multiscale(table, pairs, seed=seed, show_progress=show)
    save_table(output, table)
    n_tr = int((~table.empty).sum())
    logging.getLogger(__name__).info("wrote %s", output)
    if not silenced():
        click.echo(f"{output}: {n_tr} of {table.empty.size} classes trained from "
                   f"{len(pairs)} captures ({int(table.counts.sum())} samples)", err=True)


def _given(name: str) -> bool:
    """Whether the user set option ``name`` (command line, environment or --config)."""
    from click.core import ParameterSource

    src = click.get_current_context().get_parameter_source(name)
    return src in (ParameterSource.COMMANDLINE, ParameterSource.ENVIRONMENT,
                   ParameterSource.DEFAULT_MAP)


def _want_tune(tune, pairs, opts, workers, scheduler) -> bool:
    """``--tune``/``--no-tune``, else the default of the inputs' kind
    (:data:`l3cli.defaults.TUNE_PAIRS`); a defaulted search gives way (with a note)
    to what it cannot do: a cluster (--workers/--scheduler), --by, or a target
    space it cannot score."""
    from l3cli.train.cv import CV_SPACES
    from l3cli.train.fit import pairs_kind

    if tune is not None:
        if tune and (workers is not None or scheduler is not None):
            raise click.UsageError("--tune runs in this process; drop --workers/--scheduler")
        return tune
    if not (defaults.TUNE_PAIRS if pairs_kind(pairs) == "pairs" else defaults.TUNE_SIMULATE):
        return False
    why = ("--workers/--scheduler" if workers is not None or scheduler is not None
           else "--by" if opts.by else f"--target {opts.target_space}"
           if opts.target_space not in CV_SPACES else None)
    if why is None:
        return True
    if not silenced():
        click.echo(f"note: {why}: training the fixed defaults (the self-tuning of pairs "
                   "folders runs in this process without it; docs/training.md)", err=True)
    return False


def _tune(pairs, opts, multiscale, show):
    """The cross-validated search; prints progress and the candidate table."""
    from l3cli.train.tune import TuneGrid, format_candidates
    from l3cli.train.tune import tune as run_tune

    grid = click.get_current_context().meta.get("l3.tune_grid") or TuneGrid()
    values = {**vars(opts), "multiscale": multiscale}
    grid = grid.fixed(**{k: values[k] for k in TuneGrid.OPTIONS if _given(k)})
    loud = not (click.get_current_context().find_root().obj or {}).get("quiet")

    def report(k, c, score, seconds):
        if loud:
            on = {True: "on", False: "off"}
            click.echo(f"tune {k:>2}: {c.target_space:<11} patch {c.patch} shading "
                       f"{on[c.shading]:<3} multiscale {on[c.multiscale]:<3}  CV {score:.4f}  "
                       f"({seconds:.0f} s)", err=True)

    res = run_tune(pairs, opts, grid, show_progress=show, report=report)
    if loud:
        rec = res.record
        click.echo(f"tune: {len(rec['candidates'])} candidates, {len(rec['folds'])} folds, "
                   f"{rec['seconds']:.0f} s; {rec['metric']}", err=True)
        click.echo(format_candidates(rec), err=True)
    return res.table
