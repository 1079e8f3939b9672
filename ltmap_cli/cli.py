"""The `ltmap` command: parse, build objects, show progress, report errors in one line.

Subcommands live in ``ltmap_cli.commands.<name>`` and are imported only when invoked, so that
``ltmap --help`` does not pay for numba, open3d or the log readers. This is the only place that
turns an ``LtmapError`` into a message and an exit status; nothing below it prints or exits.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
import traceback
import warnings

import click

from . import __version__
from .errors import INTERRUPTED, LtmapError, LtmapWarning

# name -> (module, attribute, one-line help shown by `ltmap --help` without importing it)
COMMANDS: dict[str, tuple[str, str, str]] = {
    "replay": ("ltmap_cli.commands.replay", "replay", "Replay logs through the layered map."),
    "info": ("ltmap_cli.commands.info", "info", "Show what a log holds and what replay would use."),
    "build-static": ("ltmap_cli.commands.build_static", "build_static", "Build the static map from a plan."),
    "diff": ("ltmap_cli.commands.diff", "diff", "Compare two maps cell by cell."),
    "plan": ("ltmap_cli.commands.plan", "plan", "Plan an A* path on a map."),
    "simulate": ("ltmap_cli.commands.simulate", "simulate", "Write a simulated log from a scenario."),
    "batch": ("ltmap_cli.commands.batch", "batch", "Replay a fleet's logs (sites x days) on a Dask engine."),
}


def _available() -> dict[str, tuple[str, str, str]]:
    return {n: v for n, v in COMMANDS.items() if importlib.util.find_spec(v[0]) is not None}


class LazyGroup(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(_available())

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        spec = _available().get(name)
        if spec is None:
            return None
        module = importlib.import_module(spec[0])
        return getattr(module, spec[1])

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, spec[2]) for name, spec in sorted(_available().items())]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        """Click's main, with every error in one line: a usage error (bad option value, missing
        argument, unknown option or command) is ``ltmap: error: <what>; see ltmap CMD --help``,
        exit status 2, instead of click's four lines. ``LtmapWarning``s from below the CLI are
        printed as ``ltmap: warning: ...`` lines on stderr."""
        prog_name = prog_name or "ltmap"  # also when called as a function (tests): messages say ltmap
        self._invoked = prog_name  # the command line so far, for errors click raises without a context
        with warnings.catch_warnings():
            warnings.simplefilter("always", LtmapWarning)
            warnings.showwarning = _show_warning(warnings.showwarning)
            try:
                rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
                code = rv if isinstance(rv, int) else 0  # an int is the status of ctx.exit(...)
            except click.exceptions.NoArgsIsHelpError as exc:  # bare `ltmap`: the help, as click does
                exc.show()
                code = exc.exit_code
            except click.UsageError as exc:
                where = exc.ctx.command_path if exc.ctx is not None else self._invoked
                what = " ".join(exc.format_message().split()).rstrip(".")
                click.echo(f"ltmap: error: {what}; see {where} --help", err=True)
                code = 2
            except click.ClickException as exc:
                click.echo(f"ltmap: error: {' '.join(exc.format_message().split())}", err=True)
                code = exc.exit_code
            except click.Abort as exc:
                if _unwinding_ctrl_c(exc):  # Ctrl-C (replay: the second one)
                    click.echo(INTERRUPTED_LINE, err=True)
                    code = INTERRUPTED
                else:
                    click.echo("Aborted!", err=True)
                    code = 1
        if standalone_mode:
            sys.exit(code)
        return code

    def resolve_command(self, ctx: click.Context, args: list[str]):
        name, cmd, rest = super().resolve_command(ctx, args)
        if cmd is not None:
            self._invoked = f"{ctx.command_path} {cmd.name or name}"
        return name, cmd, rest

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except BrokenPipeError:  # the reader of stdout went away (`ltmap info LOG | head`): no error line;
            # what is left for stdout goes nowhere (Python's advice for SIGPIPE), status 1
            try:
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, sys.stdout.fileno())
            except (OSError, ValueError):  # (a stdout without a file descriptor: a test runner's)
                pass
            ctx.exit(1)
        except Exception as exc:
            # raised by a clean-up the interrupt broke: still the interrupt (status 1 once, with
            # numpy's "Cannot compare structured arrays" after a second Ctrl-C)
            interrupted = _unwinding_ctrl_c(exc)
            if not interrupted and not isinstance(exc, (LtmapError, OSError)):
                cache_error = _kernel_cache_error(exc)
                if cache_error is None:
                    raise
                exc = cache_error
            if (ctx.obj or {}).get("debug") or os.environ.get("LTMAP_DEBUG"):
                # the traceback, then the same line and the same exit status as without --debug
                click.echo(traceback.format_exc().rstrip("\n"), err=True)
            if interrupted:
                click.echo(INTERRUPTED_LINE, err=True)
                ctx.exit(INTERRUPTED)
            if isinstance(exc, OSError):  # a file system failure no check foresaw (permission, disk full)
                where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
                click.echo(f"ltmap: error: {where}{exc.strerror or exc}; check the path, its permissions and "
                           "the free space", err=True)
                ctx.exit(2)
            click.echo(f"ltmap: error: {exc}", err=True)
            ctx.exit(exc.exit_code)


INTERRUPTED_LINE = "ltmap: interrupted; nothing was written (an output folder keeps what it held)"


def _unwinding_ctrl_c(exc: BaseException) -> bool:
    """Whether ``exc`` was raised while a KeyboardInterrupt was being handled (in its chain of
    contexts): a ``finally`` or ``except`` that the interrupt left a half-done state to."""
    seen = set()
    e = exc.__context__
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__context__
    return False


def _kernel_cache_error(exc: Exception) -> LtmapError | None:
    """numba failing on a damaged file of its kernel cache, as one error
    (``warmup.kernel_cache_error``); None for anything else, click's own exits included (whose
    path does not import numba for it)."""
    if "numba" not in sys.modules or isinstance(exc, (click.exceptions.Exit, click.Abort, click.ClickException)):
        return None
    from .pipeline.warmup import kernel_cache_error

    return kernel_cache_error(exc)


def _show_warning(fallback):
    def show(message, category, filename, lineno, file=None, line=None):
        if not issubclass(category, LtmapWarning):
            return fallback(message, category, filename, lineno, file, line)
        if sys.stderr.isatty():
            sys.stderr.write("\n")  # off the progress bar's line
        click.echo(f"ltmap: warning: {message}", err=True)

    return show


@click.group("ltmap", cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="ltmap")
@click.option("--debug", is_flag=True, help="Show the full traceback of an error (same exit status).")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """ltmap: replay robot logs (ROS 1 bags, ROS 2 bags, MCAP) through a layered long-term
    3D map, and write map_server maps, long-term snapshots and latency measurements."""
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug


FAST_EXIT = ("replay",)  # commands whose process ends without the interpreter's teardown once they succeed


def main() -> None:
    """The ``ltmap`` program. After a successful replay the process ends at once (``os._exit``):
    the outputs are written and synced by then (``OutputFolder.commit``), and the interpreter's
    teardown of numba's compiled kernels and the map's arrays took 0.15 to 0.2 s, 3 % of a 30 s
    log's whole run. After Ctrl-C too, once every ``finally`` has run (the staging folder removed,
    the reader closed): the interpreter's exit joins every worker thread, and a second Ctrl-C
    raised while the map thread was inside a thread pool's own locks could leave one held, its
    workers blocked on it for ever (a replay hung so at its exit). Any other outcome exits as
    usual."""
    try:
        cli(prog_name="ltmap")
    except SystemExit as done:
        command = str(getattr(cli, "_invoked", "")).split()[-1:]
        if (done.code in (0, None) and command and command[0] in FAST_EXIT) or done.code == INTERRUPTED:
            try:
                sys.stdout.flush()
                sys.stderr.flush()
            except OSError:  # a closed pipe: exit as usual
                raise done from None
            os._exit(done.code or 0)
        raise


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
