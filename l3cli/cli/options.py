"""Options shared by several subcommands (rasterio ``rio`` style)."""

from __future__ import annotations

import click

from l3cli import defaults

#: ``-o/--output`` for a single output path.
output_opt = click.option(
    "-o", "--output", "output", required=True, type=click.Path(dir_okay=True),
    help="Output file (or folder where the command says so).",
)

#: ``--seed`` for bit-identical runs.
seed_opt = click.option(
    "--seed", type=int, default=defaults.SEED, show_default=True,
    help="Random seed; the same seed gives bit-identical results.",
)

#: ``--workers`` / ``--scheduler`` for dask.distributed.
workers_opt = click.option(
    "--workers", type=click.IntRange(min=1), default=None,
    help="Start a local dask.distributed cluster with N worker processes.",
)
scheduler_opt = click.option(
    "--scheduler", metavar="ADDRESS", default=None,
    help="Use a running dask.distributed scheduler (e.g. tcp://host:8786).",
)


#: ``--format`` spellings that name a format by another of its suffixes.
FORMAT_ALIASES = {"tif": "tiff", "jpeg": "jpg"}


def format_opt(help: str):
    """``--format exr|jpg|png|tiff`` (``tif`` and ``jpeg`` accepted too) with the
    command's own help text; the value is the canonical name, or None."""
    from l3cli.cli.paths import FORMATS

    return click.option(
        "--format", "fmt", default=None, help=help,
        type=click.Choice(sorted([*FORMATS, *FORMAT_ALIASES]), case_sensitive=False),
        callback=lambda ctx, param, value: (FORMAT_ALIASES.get(value.lower(), value.lower())
                                            if value is not None else None))


def _gains(ctx: click.Context, param: click.Parameter, value: str | None):
    """``--white-balance R,G,B``: the gains as an array (green-normalised), or None."""
    if value is None:
        return None
    from l3cli.errors import InputError
    from l3cli.whitebalance import parse_gains

    try:
        return parse_gains(value)
    except InputError as exc:
        raise click.BadParameter(str(exc).split(": ", 1)[-1]) from None


def white_balance_opt(help: str):
    """``--white-balance R,G,B`` (parsed into gains) with the command's own help text."""
    return click.option("--white-balance", "white_balance", metavar="R,G,B", default=None,
                        callback=_gains, help=help)


def silenced(ctx: click.Context | None = None) -> bool:
    """True only under ``-q``: a command's one-line summary is printed otherwise,
    on a terminal or not (logs and CI see it too); progress bars follow :func:`quiet`."""
    ctx = ctx or click.get_current_context(silent=True)
    return bool(ctx and ctx.find_root().obj and ctx.find_root().obj.get("quiet"))


def quiet(ctx: click.Context | None = None) -> bool:
    """True when progress output should be hidden (-q, or stderr not a TTY)."""
    import sys

    ctx = ctx or click.get_current_context(silent=True)
    q = bool(ctx and ctx.find_root().obj and ctx.find_root().obj.get("quiet"))
    return q or not sys.stderr.isatty()
