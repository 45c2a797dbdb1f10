"""``l3 render``: render raw files with a transform table."""

from __future__ import annotations

import click

from l3cli.cli.options import output_opt, quiet, scheduler_opt, workers_opt
from l3cli.cli.paths import FORMATS as _FORMATS


@click.command(short_help="Render raw files with a transform table.")
@click.argument("table_path", metavar="TABLE.npz", type=click.Path(dir_okay=False))
@click.argument("raws", nargs=-1, required=True, type=click.Path(dir_okay=False))
@output_opt
@click.option("--format", "fmt", type=click.Choice(sorted(_FORMATS)), default=None,
              help="Output format (default: from OUT's suffix, else exr). EXR keeps the "
                   "table's colour space (linear); TIFF/PNG/JPEG get display sRGB.")
@workers_opt
@scheduler_opt
def render(table_path: str, raws: tuple[str, ...], output: str, fmt: str | None,
           workers: int | None, scheduler: str | None) -> None:
    """Render RAW files with TABLE.npz into OUT (-o).

    OUT is a file for one input, a folder for several (created if missing;
    outputs are named after the inputs' stems). Each output has the raw's
    full size, pixel-aligned with it. With --workers or --scheduler the files
    are rendered by dask.distributed workers, each reading its raw and writing
    its output itself (docs/distributed.md).
    """
    from l3cli.cli.paths import plan_outputs
    from l3cli.render import render_files, table_for_task

    table_for_task(table_path)  # a bad table fails before anything is created
    plan = plan_outputs(raws, output, fmt, protect=[table_path])
    with plan.writing():
        render_files(table_path, [(str(r), o) for r, o in plan.targets], workers=workers,
                     scheduler=scheduler, show_progress=not quiet())
