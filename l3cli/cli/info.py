"""``l3 info``: read raw files and report their layout, levels and clipping."""

from __future__ import annotations

import json
from pathlib import Path

import click

from l3cli.cli.options import InputPath, distinct_inputs


@click.command(short_help="Describe raw files; write CFA planes and a quick preview.")
@click.argument("raws", nargs=-1, required=True, type=InputPath(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
@click.option("--preview", type=click.Path(dir_okay=False),
              help="Write a quick binned, grey-world-balanced preview (one input only).")
@click.option("--planes", type=click.Path(file_okay=False),
              help="Write each CFA position's plane as a 16-bit TIFF into this folder.")
def info(raws: tuple[str, ...], as_json: bool, preview: str | None, planes: str | None) -> None:
    """Read RAWS (DNG/NEF/CR2/..., NAME.raw + NAME.raw.toml) and describe them.

    Prints size, CFA, black/white levels and per-channel mean, 99th percentile
    and clipped fraction. Use it to check a sidecar before training.
    """
    from l3cli.cli.paths import check_outputs, plan_folder
    from l3cli.colourspace import srgb_encode
    from l3cli.io.image import write_image
    from l3cli.io.raw import read_raw
    from l3cli.lens.gainmaps import apply_dng_gains
    from l3cli.rawinfo import quick_preview, raw_summary

    if preview and len(raws) != 1:
        raise click.BadParameter("--preview takes exactly one input raw", param_hint="--preview")
    plane_plan = plan_folder(planes, "--planes")
    check_outputs([(preview, "--preview")], raws)
    distinct_inputs(raws, "a raw")
    summaries = []
    for path in raws:
        raw = apply_dng_gains(read_raw(path))  # the DNG's gain maps applied
        s = raw_summary(raw)
        summaries.append(s)
        if preview:
            write_image(preview, srgb_encode(quick_preview(raw)), space="srgb")
        if planes:
            folder = Path(planes)
            outs = {key: folder / f"{Path(path).stem}_plane{key}.tif" for key in raw.planes()}
            check_outputs([(o, "--planes") for o in outs.values()], raws)
            with plane_plan.writing():
                for key, plane in raw.planes().items():
                    write_image(outs[key], plane, space="data")
    if as_json:
        click.echo(json.dumps(summaries if len(summaries) > 1 else summaries[0], indent=2))
        return
    for s in summaries:
        click.echo(f"{s['path']}: {s['width']}x{s['height']} CFA {s['cfa']} "
                   f"black {'/'.join(f'{b:g}' for b in s['black_level'])} "
                   f"white {s['white_level']:g} ({s['format']})")
        for name, c in s["channels"].items():
            click.echo(f"  {name:>3}: mean {c['mean']:.4f}  p99 {c['p99']:.4f}  "
                       f"clipped {100 * c['clipped']:.2f}%")
