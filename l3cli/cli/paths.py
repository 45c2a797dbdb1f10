"""Output planning for every writing command (as rasterio's ``resolve_inout``).

:func:`plan_outputs` decides, before any work: one output file or a folder of
outputs named after the inputs, the format from ``--format`` or the suffix,
and refuses outputs that are (or alias) an input. :class:`OutputPlan`
creates the output folders only when the work writes into them, and removes
a folder it created if the work failed and left it empty.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import click

__all__ = ["OutputPlan", "plan_outputs", "plan_folder", "check_outputs"]

#: ``--format`` name -> suffix of the written files.
FORMATS = {"exr": ".exr", "tiff": ".tif", "png": ".png", "jpg": ".jpg"}
_ALIASES = {".tiff": ".tif", ".jpeg": ".jpg"}


@dataclass
class OutputPlan:
    """Where a command writes.

    Attributes
    ----------
    targets
        ``(input, output)`` pairs, one per input.
    folders
        Output folders to create when the work starts writing.
    """

    targets: list[tuple[Path, Path]] = field(default_factory=list)
    folders: list[Path] = field(default_factory=list)
    what: str = "output"

    @contextlib.contextmanager
    def writing(self) -> Iterator[OutputPlan]:
        """Create the output folders; on failure remove those created here if left empty.

        When the run is interrupted (``KeyboardInterrupt``: Ctrl-C, SIGTERM,
        SIGHUP) the outputs written into a folder created here are removed
        first, so the folder goes too.
        """
        from l3cli.errors import OutputError
        from l3cli.startup import signals_deferred, test_point

        created: list[Path] = []
        try:
            for folder in self.folders:
                missing = [p for p in (folder, *folder.parents) if not p.exists()]
                # a signal between the mkdir and its record would leave the folder behind
                with signals_deferred():
                    try:
                        folder.mkdir(parents=True, exist_ok=True)
                    except OSError as exc:
                        raise OutputError(f"{folder}: cannot create the {self.what} folder "
                                          f"({exc.strerror or exc})") from exc
                    created.extend(missing)  # deepest first
            if self.folders:
                test_point("output-folder")
            yield self
        except BaseException as exc:
            if isinstance(exc, KeyboardInterrupt) and created:
                # interrupted (l3cli.startup.handle_signals): a folder made by this
                # run goes with what the run wrote into it; after an error the
                # complete outputs stay
                for _, out in self.targets:
                    if any(f in out.parents for f in created):
                        with contextlib.suppress(OSError):
                            out.unlink()
            for p in created:
                with contextlib.suppress(OSError):
                    p.rmdir()  # only when empty
            raise


def check_outputs(outputs: Iterable[tuple[str | os.PathLike | None, str]],
                  inputs: Iterable[str | os.PathLike | None]) -> None:
    """Refuse outputs (``(path, option)``; None skipped) that are or alias an input."""
    from l3cli.io.paths import refuse_overwrite

    refuse_overwrite([(p, w) for p, w in outputs if p is not None],
                     [p for p in inputs if p is not None])


def plan_folder(folder: str | os.PathLike | None, what: str) -> OutputPlan:
    """A plan for an output folder option (``--plots``, ``--planes``)."""
    from l3cli.errors import OutputError

    if folder is None:
        return OutputPlan()
    p = Path(folder)
    if p.exists() and not p.is_dir():
        raise OutputError(f"{p}: {what} must be a folder, and this is a file")
    return OutputPlan(folders=[p], what=what.lstrip("-"))


def _stem(p: Path) -> str:
    return p.name[: -len(p.suffix)] if p.suffix else p.name


def plan_outputs(inputs: Sequence[str | os.PathLike], output: str | os.PathLike,
                 fmt: str | None, *, protect: Iterable[str | os.PathLike] = (),
                 option: str = "-o", folder: bool = False) -> OutputPlan:
    """Plan one output per input: a file for one input, else a folder named after the stems.

    Parameters
    ----------
    inputs
        The input files.
    output
        ``-o``: a file (one input that is not an existing folder) or a folder.
    fmt
        ``--format`` name (:data:`FORMATS`), or None: the file's suffix, else EXR.
    protect
        Further inputs (tables, training folders) no output may overwrite.
    option
        The option's name for messages.
    folder
        An output folder even for one input (the inputs came from a folder).

    Raises
    ------
    click.BadParameter
        ``--format`` disagrees with the suffix; two inputs share a stem.
    OutputError
        A file where a folder is needed; an output that is or aliases an input.
    """
    from l3cli.errors import OutputError
    from l3cli.io.paths import check_name_length

    ins = [Path(p) for p in inputs]
    out = Path(output)
    check_name_length(out, option)
    plan = OutputPlan()
    if len(ins) == 1 and not out.is_dir() and not folder:
        suffix = out.suffix.lower()
        if suffix == "":
            out = out.with_suffix(FORMATS[fmt or "exr"])
        elif fmt is not None and _ALIASES.get(suffix, suffix) != FORMATS[fmt]:
            raise click.BadParameter(
                f"{output} does not end in {FORMATS[fmt]} as --format {fmt} asks",
                param_hint=option)
        plan.targets.append((ins[0], out))
    else:
        if out.exists() and not out.is_dir():
            raise OutputError(f"{out}: is a file; several inputs need an output folder")
        if not out.exists():
            plan.folders.append(out)
        suffix = FORMATS[fmt or "exr"]
        stems: set[str] = set()
        for p in ins:
            stem = _stem(p)
            if stem in stems:
                raise click.BadParameter(f"two inputs share the stem {stem!r}", param_hint="RAW")
            stems.add(stem)
            plan.targets.append((p, out / f"{stem}{suffix}"))
    check_outputs([(o, option) for _, o in plan.targets], [*ins, *protect])
    return plan
