"""``l3 evaluate``: S-CIELAB, PSNR, Macbeth ΔE and MTF50 of rendered images."""

from __future__ import annotations

import click

from l3cli import defaults
from l3cli.cli.options import Finite, InputPath


def _numbers(count: int, *, integers: bool = False):
    def convert(ctx, param, value):
        if value is None:
            return None
        from l3cli.cli.options import finite_numbers

        parts = finite_numbers(value, count, param, ctx)
        return [int(round(v)) for v in parts] if integers else parts

    return convert


class _GreedyOption(click.Option):
    """A repeatable option that also takes the values following it (``--reference A B``).

    The values after the option, up to the next word that starts with ``-``, all
    belong to it, as the contract's ``--reference REF...`` reads.
    """

    def add_to_parser(self, parser, ctx):  # noqa: D102 - click API
        result = super().add_to_parser(parser, ctx)
        for opt in self.opts:
            popt = parser._long_opt.get(opt) or parser._short_opt.get(opt)
            if popt is None:
                continue
            original = popt.process

            def process(value, state, _original=original):
                _original(value, state)
                while state.rargs and not state.rargs[0].startswith("-"):
                    _original(state.rargs.pop(0), state)

            popt.process = process
        return result


@click.command(short_help="Score rendered images: S-CIELAB, PSNR, Macbeth ΔE, MTF50.")
@click.argument("rendered", nargs=-1, required=True, type=InputPath(exists=True))
@click.option("--reference", "references", cls=_GreedyOption, multiple=True, required=True,
              type=InputPath(exists=True), metavar="REF...",
              help="Reference images (one per rendered image, in order; all the paths after "
                   "--reference up to the next option), a folder of references matched by stem, "
                   "or a `l3 simulate` folder.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False),
              help="Write the report as JSON (atomically).")
@click.option("--dpi", type=Finite(min=0, min_open=True), default=defaults.DPI, show_default=True,
              help="Display resolution for S-CIELAB (dots per inch).")
@click.option("--distance", type=Finite(min=0, min_open=True), default=defaults.VIEWING_DISTANCE_M, show_default=True,
              help="Viewing distance for S-CIELAB (metres).")
@click.option("--filters", type=click.Choice(["distribution", "original"]),
              default=defaults.SCIELAB_FILTERS,
              show_default=True, help="S-CIELAB filter set (ISETCam's default, or the 1997 paper's).")
@click.option("--opponent", type=click.Choice(["xyz10", "xyz2", "hpe", "isetcam-10deg", "isetcam-2deg"]),
              default=defaults.SCIELAB_OPPONENT, show_default=True,
              help="S-CIELAB XYZ -> opponent matrix: ISETCam's xyz2opp for the 10° (as the paper) or "
                   "2° observer, or HPE LMS then Poirson-Wandell (l3's former default). "
                   "isetcam-10deg/-2deg: old names of xyz10/xyz2.")
@click.option("--plots", "plots_dir", type=click.Path(file_okay=False),
              help="Write figures (ΔE map + histogram, MTF, Macbeth, crops) into this folder.")
@click.option("--chart", "chart", callback=_numbers(8), metavar="x0,y0,x1,y1,x2,y2,x3,y3",
              help="Outer corners of a Macbeth chart's patch grid in the images: top-left "
                   "(dark skin), top-right, bottom-right (black), bottom-left (white).")
@click.option("--edge", "edge", callback=_numbers(4, integers=True), metavar="x0,y0,x1,y1",
              help="Region holding a slanted edge in the images (x1, y1 exclusive).")
@click.option("--pixel-pitch", "pixel_pitch", type=Finite(min=0, min_open=True),
              metavar="UM", help="Pixel pitch in micrometres for MTF50 in cycles/mm "
                                 "(default: the simulation manifest's).")
@click.option("--exclude-border", type=click.IntRange(min=0), default=0, show_default=True,
              metavar="N", help="Ignore N pixels on every side for S-CIELAB and PSNR.")
@click.option("--align", "align", is_flag=True, default=False,
              help="Find each reference in its render first (a camera JPEG or converter output "
                   "that is a crop of the raw, possibly mirrored or rotated) and score the "
                   "render's matching window; --chart/--edge are then in the reference's pixels.")
@click.pass_context
def evaluate(ctx: click.Context, rendered: tuple[str, ...], references: tuple[str, ...],
             json_path: str | None, dpi: float, distance: float, filters: str, opponent: str,
             plots_dir: str | None, chart: list[float] | None, edge: list[int] | None,
             pixel_pitch: float | None, exclude_border: int, align: bool) -> None:
    """Compare RENDERED images (files, or one folder) with references.

    \b
    l3 evaluate out.png --reference ref.png --json report.json
    l3 evaluate RENDER_DIR --reference SIM_DIR --json report.json --plots figs

    S-CIELAB (ΔE*ab, Zhang & Wandell 1997) is computed for the display given by
    --dpi and --distance; with a simulation folder the manifest gives the Macbeth
    chart (ΔE*ab after white normalisation, as ISETCam) and the slanted edge
    (ISO 12233 MTF50). CIEDE2000 values are extra keys. See docs/evaluation.md.
    """
    from l3cli.evaluate import EvalOptions, format_table, report_dict, write_report
    from l3cli.evaluate import evaluate as run_evaluate

    if dpi <= 0:
        raise click.BadParameter(f"{dpi}: must be positive", param_hint="--dpi")
    if distance <= 0:
        raise click.BadParameter(f"{distance}: must be positive", param_hint="--distance")
    from l3cli.cli.options import distinct_inputs
    from l3cli.cli.paths import check_outputs, plan_folder

    # a rendered image given twice would be scored (and averaged into the summary) twice; one
    # reference may serve several renders (two tables' renders of one raw)
    distinct_inputs(rendered, "a rendered image")
    check_outputs([(json_path, "--json")], [*rendered, *references])
    plots = plan_folder(plots_dir, "--plots")
    options = EvalOptions(dpi=dpi, distance=distance, filters=filters, opponent=opponent,
                          chart_corners=chart, edge_roi=edge, pixel_pitch_um=pixel_pitch,
                          exclude_border=exclude_border, keep_images=bool(plots_dir), align=align)
    reports, summary = run_evaluate(list(rendered), list(references), options)
    report = report_dict(reports, summary, settings=options.settings())
    if plots_dir:
        from l3cli.evaluate.plots import plot_report

        with plots.writing():
            for r in reports:
                plot_report(r, plots_dir, dpi=dpi, distance_m=distance)
    if json_path:  # last: a failed run leaves no complete-looking report
        write_report(json_path, report)
    click.echo(format_table(reports, summary))
