"""``l3 render``: render raw files with a transform table."""

from __future__ import annotations

from pathlib import Path

import click

from l3cli.cli.options import output_opt, quiet, scheduler_opt, workers_opt

_FORMATS = {"exr": ".exr", "tiff": ".tif", "png": ".png", "jpg": ".jpg"}
_ALIASES = {".tiff": ".tif", ".jpeg": ".jpg"}


@click.command(short_help="Render raw files with a transform table.")
@click.argument("table_path", metavar="TABLE.npz", type=click.Path(dir_okay=False))
@click.argument("raws", nargs=-1, required=True, type=click.Path(dir_okay=False))
@output_opt
@click.option("--format", "fmt", type=click.Choice(sorted(_FORMATS)), default=None,
              help="Output format (default: from OUT's suffix, else exr). EXR keeps the "
                   "table's colour space (linear); TIFF/PNG/JPEG get display sRGB.")
@click.option("--white-balance", "white_balance", metavar="R,G,B", default=None,
              help="White-balance multipliers for every raw instead of each raw's as-shot "
                   "white balance (for tables trained with white-balanced input; needed for "
                   "raws that carry none).")
@workers_opt
@scheduler_opt
def render(table_path: str, raws: tuple[str, ...], output: str, fmt: str | None,
           workers: int | None, scheduler: str | None, white_balance: str | None = None) -> None:
    """Render RAW files with TABLE.npz into OUT (-o).

    OUT is a file for one input, a folder for several (created if missing;
    outputs are named after the inputs' stems). Each output has the raw's
    full size, pixel-aligned with it. With --workers or --scheduler the files
    are rendered by dask.distributed workers, each reading its raw and writing
    its output itself (docs/distributed.md).
    """
    from l3cli.errors import OutputError
    from l3cli.render import check_white_balance, render_files, table_for_task

    table = table_for_task(table_path)  # a bad table fails before anything is created
    gains = None
    if white_balance is not None:
        from l3cli.errors import InputError
        from l3cli.whitebalance import parse_gains

        try:
            gains = parse_gains(white_balance)
        except InputError as exc:
            raise click.BadParameter(str(exc).split(": ", 1)[-1],
                                     param_hint="--white-balance") from None
    check_white_balance(table, list(raws), gains, table_name=Path(table_path).name)
    out = Path(output)
    targets: list[tuple[str, Path]] = []
    if len(raws) == 1 and not out.is_dir():
        suffix = out.suffix.lower()
        if suffix == "":
            out = out.with_suffix(_FORMATS[fmt or "exr"])
        elif fmt is not None and _ALIASES.get(suffix, suffix) != _FORMATS[fmt]:
            raise click.BadParameter(
                f"{output} does not end in {_FORMATS[fmt]} as --format {fmt} asks",
                param_hint="-o")
        targets.append((raws[0], out))
    else:
        if out.exists() and not out.is_dir():
            raise OutputError(f"{out}: is a file; several inputs need an output folder")
        out.mkdir(parents=True, exist_ok=True)
        suffix = _FORMATS[fmt or "exr"]
        stems: set[str] = set()
        for r in raws:
            p = Path(r)
            stem = p.name[: -len(p.suffix)] if p.suffix else p.name
            if stem in stems:
                raise click.BadParameter(f"two inputs share the stem {stem!r}", param_hint="RAW")
            stems.add(stem)
            targets.append((r, out / f"{stem}{suffix}"))
    render_files(table_path, targets, workers=workers, scheduler=scheduler,
                 show_progress=not quiet(), white_balance=gains)
