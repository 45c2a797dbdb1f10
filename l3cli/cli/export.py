"""``l3 export``: write a table as a standard ONNX graph (docs/export.md)."""

from __future__ import annotations

import click

from l3cli.cli.options import InputPath, output_opt, silenced


@click.command(short_help="Write a table as an ONNX graph that renders as `l3 render` does.")
@click.argument("table_path", metavar="TABLE.npz", type=InputPath(dir_okay=False))
@output_opt
@click.option("--display", "display", is_flag=True,
              help="The graph ends in the display encoding (sRGB integers for 3-channel "
                   "tables, as TIFF/PNG hold) instead of float values in the table's space.")
@click.option("--bits", type=click.Choice(["8", "16"]), default=None,
              help="Display integers: uint8 or uint16 (with --display)  [default: 8].")
def export(table_path: str, output: str, display: bool, bits: str | None) -> None:
    """Write TABLE.npz as an ONNX model (-o PIPELINE.onnx) of standard operators.

    The model takes a normalised float32 mosaic (N, 1, H, W) in the table's
    CFA phase, plus the raw's white-balance gains or condition value where the
    table needs them, and outputs (N, C, H, W) as `l3 render` renders it
    (docs/export.md). A table feature the graph cannot express is refused by
    name. `l3 inspect PIPELINE.onnx` shows the model's metadata.
    """
    from l3cli.cli.paths import check_outputs
    from l3cli.export import export_table

    if bits is not None and not display:
        raise click.UsageError("--bits applies to display output only; add --display")
    # before any work, as every writing command: the output may not be (or alias) the table
    check_outputs([(output, "-o")], [table_path])
    path = export_table(table_path, output, output="display" if display else "linear",
                        bits=int(bits or 8))
    if not silenced():
        click.echo(f"wrote {path}", err=True)
