"""``l3 render``: render raw files with a transform table."""

from __future__ import annotations

import click

from l3cli.cli.options import (
    InputPath,
    format_opt,
    output_opt,
    quiet,
    scheduler_opt,
    silenced,
    white_balance_opt,
    workers_opt,
)


@click.command(short_help="Render raw files with a transform table.")
@click.argument("table_path", metavar="TABLE.npz", type=InputPath(dir_okay=False))
@click.argument("raws", nargs=-1, required=True, type=InputPath())
@output_opt
@format_opt(help="Output format (default: from OUT's suffix, else exr). EXR keeps the "
                 "table's colour space (linear); TIFF/PNG/JPEG get display sRGB.")
@click.option("--compression", metavar="NAME", default=None,
              help="TIFF: none (default), lzw or zip. EXR: none (default for float32), rle, "
                   "zips (default with --half), zip or piz. All lossless.")
@click.option("--half", is_flag=True, help="EXR: write half floats (16-bit) instead of 32-bit.")
@click.option("--quality", type=click.IntRange(1, 100), default=95, show_default=True,
              help="JPEG quality (4:4:4 chroma).")
@white_balance_opt(
              help="White-balance multipliers for every raw instead of each raw's as-shot "
                   "white balance (for tables trained with white-balanced input; needed for "
                   "raws that carry none).")
@workers_opt
@scheduler_opt
def render(table_path: str, raws: tuple[str, ...], output: str, fmt: str | None,
           compression: str | None, half: bool, quality: int, white_balance,
           workers: int | None, scheduler: str | None) -> None:
    """Render RAW files with TABLE.npz into OUT (-o).

    A RAW may be a folder: a simulate folder gives its captures' raws, any
    other folder its raw files. OUT is a file for one raw file, a folder for
    several or for a folder (created if missing; outputs are named after the
    inputs' stems). Each output has the raw's
    full size, pixel-aligned with it. With --workers or --scheduler the files
    are rendered by dask.distributed workers, each reading its raw and writing
    its output itself (docs/distributed.md).
    """
    import contextlib

    from l3cli import buffers
    from l3cli.pairs import raw_files
    from l3cli.pipeline import IN_FLIGHT, Prefetch

    paths, from_folder = raw_files(raws)
    raws = tuple(str(p) for p in paths)
    with contextlib.ExitStack() as stack:
        # the prefetched decodes' mosaics come from the pipeline's buffer pool
        stack.enter_context(buffers.recycling(2 * (IN_FLIGHT + 1)))
        # the first raws decode (on the core start-up leaves idle) while the
        # render code imports and its machine code loads
        prefetch = None
        if raws and workers is None and scheduler is None:
            import threading

            from l3cli import kernel_store

            threading.Thread(target=kernel_store.prepare, name="l3-kernel-store",
                             daemon=True).start()
            prefetch = stack.enter_context(Prefetch(raws, count=IN_FLIGHT))
        _render(table_path, raws, output, fmt, compression, half, quality, white_balance,
                workers, scheduler, prefetch, from_folder)


def _render(table_path: str, raws: tuple[str, ...], output: str, fmt: str | None,
            compression: str | None, half: bool, quality: int, white_balance: str | None,
            workers: int | None, scheduler: str | None, prefetch, from_folder: bool) -> None:
    from pathlib import Path

    from l3cli.cli.options import distinct_inputs
    from l3cli.cli.paths import plan_outputs
    from l3cli.render import render_files, table_for_task

    table_for_task(table_path)  # a bad table fails before anything is created (cached)
    distinct_inputs(raws, "a raw")
    gains = white_balance
    plan = plan_outputs(raws, output, fmt, protect=[table_path], folder=from_folder)
    options = _write_options(plan.targets[0][1], compression, half, quality)
    with plan.writing():  # render_files checks every raw's white balance before any work
        render_files(table_path, [(str(r), o) for r, o in plan.targets], workers=workers,
                     scheduler=scheduler, show_progress=not quiet(), options=options,
                     white_balance=gains, prefetch=prefetch)
    if not silenced():
        n = len(plan.targets)
        where = plan.targets[0][1] if n == 1 and not from_folder else Path(output)
        click.echo(f"{where}: rendered {n} raw{'s' if n > 1 else ''}", err=True)


def _write_options(out, compression: str | None, half: bool, quality: int) -> dict:
    """``write_image`` keywords for the outputs' format; usage errors for options it lacks."""
    from l3cli.io.image import COMPRESSIONS, format_of

    fmt = format_of(out)
    if compression is not None and compression not in COMPRESSIONS.get(fmt, ()):
        allowed = ", ".join(COMPRESSIONS.get(fmt, ())) or "no --compression"
        raise click.BadParameter(f"{compression!r} is not a compression for {fmt} "
                                 f"(it takes {allowed})", param_hint="--compression")
    if half and fmt != "exr":
        raise click.BadParameter(f"--half is for EXR output, not {fmt}", param_hint="--half")
    options: dict = {"compression": compression} if compression is not None else {}
    if half:
        options["half"] = True
    if fmt == "jpg":
        options["quality"] = quality
    return options
