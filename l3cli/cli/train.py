"""``l3 train``: learn a transform table from (raw, target) pairs.

A thin mapping of flags onto :func:`l3cli.train.api.train` (which holds the
policy: the inputs' defaults, white balance, self-tuning, the multi-scale
stage); the library's errors and notes name parameters, said here as flags.
"""

from __future__ import annotations

import logging

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
    statistics by a dask.distributed worker, and self-tuning scores its
    candidates' folds there; the table is the same as in process
    (docs/distributed.md).

    The same from Python: l3cli.train(INPUTS, **options) (README, "From Python").
    """
    from pathlib import Path

    from l3cli.cli.options import distinct_inputs
    from l3cli.cli.paths import check_outputs
    from l3cli.errors import ConfigError, OptionError
    from l3cli.train.api import train as train_inputs

    check_outputs([(output, "-o")], inputs)
    distinct_inputs(inputs, "a training input")
    ctx = click.get_current_context()
    flags = _flags(ctx.command)
    loud = not silenced()
    options = dict(
        patch=patch, levels=levels, spacing=spacing,
        level_range=tuple(level_range) if level_range else None,
        contrast_bins=contrast_bins, contrast_threshold=contrast_threshold,
        saturation=saturation, merge_positions=merge_positions, target_space=target_space,
        tone_curve=tone_curve, shading=shading, sample_fraction=sample_fraction,
        min_samples_factor=min_samples_factor, scaled_renders=scaled_renders, by=by,
        embedded_preview=embedded_preview, as_shot_wb=as_shot_wb,
        white_balance=None if white_balance is None else tuple(white_balance.tolist()),
        tune=tune, tune_grid=ctx.meta.get("l3.tune_grid"),
        orientation_bins=orientation_bins, coherence=coherence, context_block=context_block,
        context_bins=context_bins, context_rule=context_rule,
        highlight_bins=int(highlight_bins), highlight_fraction=highlight_fraction,
        augment=augment, sample_weight=sample_weight, multiscale=multiscale, seed=seed)

    def note(n) -> None:
        if loud:
            click.echo(f"note: {n.named(flags.get(n.parameter))}", err=True)

    def report(k, c, score, seconds) -> None:
        if loud:
            on = {True: "on", False: "off"}
            click.echo(f"tune {k:>2}: {c.target_space:<11} patch {c.patch} shading "
                       f"{on[c.shading]:<3} multiscale {on[c.multiscale]:<3}  CV {score:.4f}  "
                       f"({seconds:.0f} s)", err=True)

    try:
        table = train_inputs(inputs, workers=workers, scheduler=scheduler,
                             show_progress=not quiet(), report=report, note=note,
                             scratch=Path(output).absolute().parent, **options)
    except OptionError as exc:  # the library names parameters; here, their flags
        raise ConfigError(exc.named(flags.get(exc.parameter, exc.parameter))) from None
    rec = table.tuning
    if rec is not None and loud:
        from l3cli.train.tune import format_candidates

        click.echo(f"tune: {len(rec['candidates'])} candidates, {len(rec['folds'])} folds, "
                   f"{rec['seconds']:.0f} s; {rec['metric']}", err=True)
        click.echo(format_candidates(rec), err=True)
    table.save(output)
    n_tr = int((~table.empty).sum())
    logging.getLogger(__name__).info("wrote %s", output)
    if loud:
        n_pairs = len(table.provenance.get("inputs", ()))
        click.echo(f"{output}: {n_tr} of {table.empty.size} classes trained from "
                   f"{n_pairs} captures ({int(table.counts.sum())} samples)", err=True)


def _flags(command: click.Command) -> dict[str, str]:
    """Each parameter's flag (its long name: ``target_space`` -> ``--target``), for the
    library's errors and notes, which name parameters."""
    out = {"wb_override": "--white-balance", "white_balance": "--white-balance"}
    for p in command.params:
        longs = [o for o in p.opts if o.startswith("--")]
        if longs:
            out[p.name] = longs[0]
    return out
