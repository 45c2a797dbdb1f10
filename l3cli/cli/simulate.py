"""``l3 simulate``: simulate (raw, ideal XYZ) training captures of a camera."""

from __future__ import annotations

from pathlib import Path

import click

from l3cli.cli.options import (
    Finite,
    InputPath,
    quiet,
    scheduler_opt,
    seed_opt,
    silenced,
    workers_opt,
)


def _size(ctx: click.Context, param: click.Parameter, value: str | None) -> tuple[int, int] | None:
    if value is None:
        return None
    try:
        w, h = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"{value!r} is not WIDTHxHEIGHT (e.g. 480x320)") from None
    if w < 48 or h < 32:
        raise click.BadParameter(f"{value!r} is too small; at least 48x32")
    return w, h


def _print_list(ctx: click.Context, param: click.Parameter, value: bool) -> None:
    if not value or ctx.resilient_parsing:
        return
    from l3cli import spectral
    from l3cli.simulate.scenes import SCENES

    click.echo("scenes:      " + ", ".join(SCENES) + ", or a path")
    click.echo("illuminants: " + ", ".join(spectral.ILLUMINANTS))
    click.echo("QE presets:  " + ", ".join(spectral.QE_PRESETS))
    click.echo("IR filters:  " + ", ".join(spectral.IR_FILTERS))
    ctx.exit(0)


@click.command(short_help="Simulate raw captures and ideal XYZ targets of a camera.")
@click.argument("camera", type=InputPath(dir_okay=False))
@click.option("-o", "--output", "output", required=True, type=click.Path(file_okay=False),
              help="Output folder SIM_DIR (created; its parent must exist).")
@click.option("--scene", "scenes", multiple=True, metavar="NAME|PATH",
              help="Scene: macbeth, slanted-edge, natural (all bundled photos), "
                   "natural:NAME, or a path to an RGB image or a spectral cube .npz. "
                   "Repeatable. Default: macbeth and natural.")
@click.option("--illuminant", default=None, metavar="NAME",
              help="Illuminant (default: the camera's exposure.illuminant); "
                   "`l3 simulate --list` shows the names.")
@click.option("--lux", "lux", multiple=True, type=Finite(), metavar="LUX",
              help="Scene illuminance in lux, repeatable (default: the camera's "
                   "exposure.light_levels_lux).")
@click.option("--size", callback=_size, default=None, metavar="WxH",
              help="Image size in pixels [default: 480x320].")
@click.option("--exposure", "exposure_s", type=Finite(min=0, min_open=True), default=None,
              metavar="SECONDS",
              help="Fixed exposure time in seconds (overrides the camera's exposure mode).")
@click.option("--oversample", type=click.IntRange(1, 8), default=1, show_default=True, metavar="N",
              help="Scene samples per pixel and axis for the optics (2-4: more accurate "
                   "MTF near Nyquist, slower).")
@click.option("--no-blur", is_flag=True, help="Perfect lens (no diffraction blur).")
@click.option("--no-noise", is_flag=True, help="No sensor noise (raw = quantised noise-free signal).")
@click.option("--list", is_flag=True, is_eager=True, expose_value=False, callback=_print_list,
              help="List scenes, illuminants, QE presets and IR filters, then exit.")
@seed_opt
@workers_opt
@scheduler_opt
def simulate(camera: str, output: str, scenes: tuple[str, ...], illuminant: str | None,
             lux: tuple[float, ...], size: tuple[int, int] | None, exposure_s: float | None,
             oversample: int, no_blur: bool, no_noise: bool, seed: int, workers: int | None,
             scheduler: str | None) -> None:
    """Simulate captures of CAMERA.toml into SIM_DIR (-o).

    For each scene and light level it writes STEM.dng (or STEM.tif +
    STEM.tif.toml where DNG cannot describe the CFA), STEM.target.exr (ideal
    CIE XYZ, pixel-aligned), STEM.noisefree.exr and one manifest.json.
    With --workers or --scheduler the captures are simulated by
    dask.distributed workers; the files are the same as in process.
    """
    import logging

    from l3cli.camera import load_camera
    from l3cli.simulate.run import run_simulation

    for x in lux:
        if not x > 0:
            raise click.BadParameter(f"{x:g} lux: light levels must be > 0", param_hint="--lux")
    cam = load_camera(camera)
    show = not quiet()
    manifest = run_simulation(cam, output, scenes=list(scenes) or None, illuminant=illuminant,
                              lux=list(lux) or None, seed=seed, size=size,
                              blur=not no_blur, noise=not no_noise, exposure_s=exposure_s,
                              oversample=oversample, workers=workers, scheduler=scheduler,
                              show_progress=show,
                              protect=[camera, *(s for s in scenes if Path(s).is_file())])
    logging.getLogger(__name__).info("wrote %d captures to %s", len(manifest["captures"]), output)
    if not silenced():
        click.echo(f"{output}: {len(manifest['captures'])} captures", err=True)
