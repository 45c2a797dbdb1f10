"""Options shared by several subcommands (rasterio ``rio`` style)."""

from __future__ import annotations

import click

from l3cli import defaults


class Finite(click.FloatRange):
    """A finite float option (NaN and ±inf refused, naming the option), optionally in
    a range (``click.FloatRange``'s ``min``/``max``/``min_open``/``max_open``).

    click's own float types accept ``nan`` and ``inf``, and a NaN passes every
    range check; every float option of l3 uses this type instead.

    Examples
    --------
    >>> Finite(min=0).convert("0.5", None, None)
    0.5
    >>> Finite().convert("nan", None, None)
    Traceback (most recent call last):
    ...
    click.exceptions.BadParameter: 'nan' is not a finite number.
    """

    name = "float"

    def convert(self, value, param, ctx):  # noqa: D102 - click API
        import math

        v = click.FLOAT.convert(value, param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return super().convert(v, param, ctx)

    def _describe_range(self) -> str:  # click API: no "[x<=None]" in --help without a range
        if self.min is None and self.max is None:
            return ""
        return super()._describe_range()


class InputPath(click.Path):
    """An input path: if it exists it must be a regular file or a folder (a FIFO,
    device or socket would block or make no sense as an input), as ``click.Path``
    otherwise (``file_okay``/``dir_okay``; a missing path is left to the command,
    which names it in its one-line error).

    Raises :class:`l3cli.errors.InputError` (one line, exit 1) for a special file.
    """

    def convert(self, value, param, ctx):  # noqa: D102 - click API
        import os
        import stat

        value = super().convert(value, param, ctx)
        try:
            mode = os.stat(value).st_mode
        except (OSError, ValueError):  # missing or unreadable: the command says so
            return value
        if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
            from l3cli.errors import InputError

            kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else
                    "a socket" if stat.S_ISSOCK(mode) else "a device")
            raise InputError(f"{os.fsdecode(value)}: is {kind}, not a regular file or folder; "
                             "l3 reads files")
        return value


def distinct_inputs(paths, what: str = "input") -> None:
    """Refuse an input given twice under two spellings (``sim`` and ``sim/``, a
    relative and an absolute path, a symbolic link): paths are compared after
    resolving, as :func:`l3cli.io.paths.same_file` does.

    Raises
    ------
    l3cli.errors.InputError
        Naming both spellings.
    """
    from l3cli.errors import InputError
    from l3cli.io.paths import same_file

    seen: list = []
    for p in paths:
        for q in seen:
            if same_file(p, q):
                raise InputError(f"{p}: given twice as {what} (the same as {q}); give each "
                                 "input once")
        seen.append(p)


def finite_numbers(value: str, count: int, param: click.Parameter | None = None,
                   ctx: click.Context | None = None) -> list[float]:
    """``count`` comma-separated finite numbers (``"0.1,0.2,0.8,0.9"``), else a
    ``click.BadParameter`` naming what is wrong."""
    import math

    try:
        parts = [float(v) for v in value.replace(" ", "").split(",")]
    except ValueError:
        raise click.BadParameter(f"{value!r}: expected {count} comma-separated numbers",
                                 ctx, param) from None
    if len(parts) != count:
        raise click.BadParameter(f"{value!r}: expected {count} comma-separated numbers, got "
                                 f"{len(parts)}", ctx, param)
    if not all(math.isfinite(v) for v in parts):
        raise click.BadParameter(f"{value!r}: every number must be finite (no nan or inf)",
                                 ctx, param)
    return parts


#: ``-o/--output`` for a single output path.
output_opt = click.option(
    "-o", "--output", "output", required=True, type=click.Path(dir_okay=True),
    help="Output file (or folder where the command says so).",
)

#: ``--seed`` for bit-identical runs.
seed_opt = click.option(
    "--seed", type=click.IntRange(0, 2**63 - 1), default=defaults.SEED, show_default=True,
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
    from l3cli.whitebalance.model import parse_gains

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
