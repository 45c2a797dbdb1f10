"""``l3 baseline``: render Bayer raws with demosaicking + a fitted 3x3 colour matrix."""

from __future__ import annotations

from pathlib import Path

import click

from l3cli.cli.options import InputPath, format_opt, output_opt, quiet, seed_opt

_METHODS = ("bilinear", "malvar2004", "menon2007")


def _expand_raws(raws: tuple[str, ...]) -> list[Path]:
    """Raw files; a ``simulate`` folder stands for all its captures' raws."""
    from l3cli.errors import InputError

    out: list[Path] = []
    for r in raws:
        p = Path(r)
        if p.is_dir():
            from l3cli.io.manifest import is_simulation_dir, read_manifest

            if not is_simulation_dir(p):
                raise InputError(f"{p}: a folder RAW must be a `l3 simulate` output (no manifest.json)")
            out.extend(p / c["raw"] for c in read_manifest(p)["captures"])
        else:
            out.append(p)
    return out


@click.command(short_help="Conventional pipeline: demosaic + fitted 3x3 colour matrix.")
@click.argument("raws", nargs=-1, required=True, type=InputPath(exists=True))
@click.option("--train", "train_inputs", multiple=True, required=True,
              type=InputPath(exists=True, file_okay=False),
              help="Training folder (a `l3 simulate` output or a pairs folder) for the colour "
                   "matrix; repeatable. Use the data the L3 table was trained on.")
@output_opt
@click.option("--demosaic", "method", type=click.Choice(_METHODS), default="menon2007",
              show_default=True, help="Demosaicking method (colour-demosaicing).")
@click.option("--target", "target_space", type=click.Choice(["xyz", "linear-srgb", "srgb", "lab"]),
              default="xyz", show_default=True, help="Output colour space (as a table's).")
@format_opt(help="Output format (default: from OUT's suffix, else exr). EXR keeps the target "
                 "space (linear); TIFF/PNG/JPEG get display sRGB.")
@click.option("--save-model", type=click.Path(dir_okay=False),
              help="Also write the fitted method and matrix as JSON.")
@seed_opt
def baseline(raws: tuple[str, ...], train_inputs: tuple[str, ...], output: str, method: str,
             target_space: str, fmt: str | None, save_model: str | None, seed: int) -> None:
    """Render Bayer RAWS with a classic pipeline into OUT (-o).

    Each raw is demosaicked (bilinear, Malvar 2004 or Menon 2007) and mapped to
    the target space by a 3x3 matrix fitted by least squares on the --train
    data. A RAW may be a `l3 simulate` folder (all its captures). OUT is a file
    for one input, a folder for several (outputs named after the inputs' stems),
    as for `l3 render`:

    \b
    l3 baseline SIM_DIR --train SIM_DIR -o BASE_DIR --demosaic menon2007
    l3 evaluate BASE_DIR --reference SIM_DIR --json base.json
    """
    from l3cli.baseline import fit_baseline, render_baseline_file
    from l3cli.cli.options import distinct_inputs
    from l3cli.cli.paths import check_outputs, plan_outputs
    from l3cli.io.atomic import atomic_path
    from l3cli.progress import progress

    raw_paths = _expand_raws(raws)
    distinct_inputs(raw_paths, "a raw")
    distinct_inputs(train_inputs, "a --train input")
    plan = plan_outputs(raw_paths, output, fmt, protect=train_inputs)
    check_outputs([(save_model, "--save-model"), *((o, "-o") for _, o in plan.targets)],
                  [*raw_paths, *train_inputs])
    model = fit_baseline(list(train_inputs), method=method, target_space=target_space, seed=seed)
    with plan.writing():
        for raw_path, dst in progress(plan.targets, label="baseline", enabled=not quiet()):
            render_baseline_file(model, raw_path, dst)
        if save_model:
            with atomic_path(save_model) as tmp:
                tmp.write_text(model.to_json() + "\n")
