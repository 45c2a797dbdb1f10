"""The ``l3`` command group.

Global options: ``-v/--verbose`` (repeatable), ``-q/--quiet``, ``--debug`` (full
tracebacks) and ``--version``. Subcommands live one per module in this package
and are registered lazily in :data:`_COMMANDS`, so ``l3 --help`` stays fast.

Errors: an :class:`l3cli.errors.L3Error` raised by the library becomes a one-line
``Error: ...`` on stderr and exit status 1; usage errors exit 2 (click).
"""

from __future__ import annotations

import errno
import importlib
import logging
import sys
from collections.abc import Iterable
from contextlib import AbstractContextManager
from typing import Any

import click

from l3cli import __version__, progress, startup
from l3cli.errors import L3Error


def _click_bar(items: Iterable[Any], *, label: str, length: int | None = None
               ) -> AbstractContextManager[Iterable[Any]]:
    """The progress bar the library draws through :func:`l3cli.progress.progress`."""
    return click.progressbar(items, label=label, length=length, file=sys.stderr)


progress.set_bar_factory(_click_bar)

#: OS errors that are the machine's state (full disk, I/O error), not l3 bugs.
_IO_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EFBIG, errno.EROFS,
                        errno.EACCES, errno.EPERM, errno.ENAMETOOLONG, errno.ELOOP})

#: name -> "module:attribute" of each registered subcommand. Register a command
#: only when it works.
_COMMANDS: dict[str, str] = {
    "info": "l3cli.cli.info:info",
    "evaluate": "l3cli.cli.evaluate:evaluate",
    "baseline": "l3cli.cli.baseline:baseline",
    "train": "l3cli.cli.train:train",
    "render": "l3cli.cli.render:render",
    "simulate": "l3cli.cli.simulate:simulate",
    "smooth": "l3cli.cli.smooth:smooth",
    "inspect": "l3cli.cli.inspect:inspect",
    "export": "l3cli.cli.export:export",
}

#: Commands whose start-up is trimmed (:mod:`l3cli.startup`): one OpenBLAS
#: thread (they call no BLAS routine) and no garbage collection while they load.
_LEAN_START = frozenset({"render", "info"})


class _LazyGroup(click.Group):
    """A click group that imports each subcommand's module on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(_COMMANDS))

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in _LEAN_START:
            startup.single_threaded_blas()  # before numpy loads (l3cli.startup)
        if cmd_name in _COMMANDS:
            mod_name, attr = _COMMANDS[cmd_name].split(":")
            return getattr(importlib.import_module(mod_name), attr)
        return super().get_command(ctx, cmd_name)

    def resolve_command(self, ctx: click.Context, args: list[str]):  # noqa: D401 - click API
        name, cmd, rest = super().resolve_command(ctx, args)
        if name in _LEAN_START:  # while it imports and loads its kernels (invoke resumes)
            startup.pause_gc()
            startup.arm_exit_now()  # main() may skip the interpreter's teardown
        else:  # main() paused it for the start-up; the other commands run with it (and
            startup.resume_gc(freeze=False)  # with the teardown, whose finalisers need it)
        return name, cmd, rest

    def invoke(self, ctx: click.Context):  # noqa: D401 - click API
        try:
            return self._invoke(ctx)
        finally:
            startup.resume_gc()

    def _invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except L3Error as exc:
            obj = ctx.obj or {}
            if obj.get("debug"):
                raise
            # one line, even where a file name holds a line break
            msg = str(exc).replace("\r", "\\r").replace("\n", "\\n")
            raise click.ClickException(msg) from exc
        except MemoryError as exc:
            if (ctx.obj or {}).get("debug"):
                raise
            raise click.ClickException("out of memory") from exc
        except OSError as exc:
            # a full disk or an I/O error outside l3's own write path: still one line
            if (ctx.obj or {}).get("debug") or exc.errno not in _IO_ERRNOS:
                if (ctx.obj or {}).get("debug"):
                    raise
                raise click.ClickException(
                    f"internal error: {type(exc).__name__}: {exc} (rerun with --debug for the "
                    "traceback and please report it)") from exc
            name = str(exc.filename) if exc.filename else ""
            where = f"{name if len(name) < 100 else name[:60] + '...'}: " if name else ""
            raise click.ClickException(f"{where}{exc.strerror or exc}") from exc
        except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP (startup.handle_signals)
            atomic = sys.modules.get("l3cli.io.atomic")
            if atomic is not None:  # temporaries whose own cleanup the signal cut short
                atomic.remove_live_temporaries()
            click.echo("Aborted.", err=True)
            sys.exit(startup.interrupt_status(exc))
        except (click.ClickException, click.exceptions.Exit, click.Abort):
            raise
        except Exception as exc:
            # A bug, not a user error: still one line, with the way to the traceback.
            if (ctx.obj or {}).get("debug"):
                raise
            raise click.ClickException(
                f"internal error: {type(exc).__name__}: {exc} (rerun with --debug for the "
                "traceback and please report it)"
            ) from exc


@click.group(cls=_LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="l3")
@click.option("-v", "--verbose", count=True, help="More log output (repeat for debug logs).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors; no progress bars.")
@click.option("--debug", is_flag=True, help="Show full tracebacks on errors.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: bool, debug: bool) -> None:
    """l3: learn a camera's image-processing pipeline (Local, Linear, Learned).

    Simulate or collect (raw, target) pairs, train a table of per-class affine
    transforms, smooth it with priors, render raw files with it and evaluate the
    result. Run `l3 COMMAND --help` for each step.
    """
    level = logging.WARNING - 10 * verbose
    if quiet:
        level = logging.ERROR
    if debug:
        level = min(level, logging.DEBUG)
    from l3cli.io.fd2 import Handler

    handler = Handler(sys.stderr)  # waits for LibRaw's stderr captures in other threads
    logging.basicConfig(
        level=max(level, logging.DEBUG),
        format="%(levelname)s %(name)s: %(message)s",
        handlers=[handler],
        force=True,
    )
    # Python warnings (numpy's "invalid value encountered ...") are log records
    # (py.warnings), shown with -vv / --debug only: l3 reports bad values itself
    logging.captureWarnings(True)
    logging.getLogger("py.warnings").setLevel(
        logging.DEBUG if level <= logging.DEBUG else logging.CRITICAL + 1)
    ctx.obj = {"verbose": verbose, "quiet": quiet, "debug": debug}
    startup.test_point("start")  # test-only: tests/cli/test_signals.py's first moment


def main() -> None:  # pragma: no cover - console entry point
    """Console entry point of ``l3``: the group, then a quick exit for the lean
    commands (:func:`l3cli.startup.exit_now`). SIGINT, SIGTERM and SIGHUP end
    a run alike (:func:`l3cli.startup.handle_signals`): cleaned up, exit 128+n."""
    startup.pause_gc(freeze=True)  # no collection while the command is found
    startup.handle_signals()
    try:
        try:
            cli()
        except KeyboardInterrupt as exc:  # outside a command (click's own parsing)
            click.echo("Aborted.", err=True)
            raise SystemExit(startup.interrupt_status(exc)) from None
    except SystemExit as exc:
        # a signal caught anywhere (click turns one during its parsing into exit 1)
        code = startup.interrupt_status() if startup.signal_received() else exc.code
        startup.exit_now(code)


if __name__ == "__main__":  # pragma: no cover
    main()
