"""`ltmap batch FLEET.yaml -o OUT`: every site's days replayed in order on a Dask engine."""

from __future__ import annotations

from pathlib import Path

import click

from ..config import parse_set
from ..fleet.graph import StaticTask, build_plan
from ..fleet.manifest import load_manifest
from ..fleet.runner import FAILED, NOT_RUN, UP_TO_DATE, Engine, execute
from ..fleet.tasks import DAY_OUTPUTS, STATIC_OUTPUTS, is_complete
from . import StatusLine

HELP = """Replay a fleet's logs: many robots, sites and days (docs/fleet.md).

\b
FLEET.yaml (paths relative to it):
  sites:
    lab:
      static: plans/lab.svg        # optional: SVG plan, map YAML or build-static folder
      days:                        # in order; a day is one or more logs replayed together
        - [logs/lab/mon.mcap]
        - [logs/lab/tue_a.bag, logs/lab/tue_b.bag]

Each site's days run in order, day N resuming from day N-1 (as `ltmap replay
--resume`); sites and --sweep points run in parallel on Dask.distributed: on this
machine (--workers) or on a running cluster (--address). Writes OUT/<site>/day<N>/
(OUT/<site>/<point>/day<N>/ when sweeping), OUT/<site>/static/ for an SVG plan, and
OUT/summary.csv + summary.png. A day already complete for the same inputs and
parameters is not replayed again. A failing day is retried once, then reported; the
site's later days are not run, the other sites go on. Exit 0: all done; 1: some
failed (listed); 2: bad manifest or options.
"""


MAX_LISTED = 20  # failed (and not run) tasks listed on stderr; summary.csv has them all


class BatchProgress(StatusLine):
    """One line on stderr: tasks done / running / failed, elapsed and left; outside a terminal a
    line whenever a task ends."""

    def __init__(self, stream=None):
        super().__init__(stream)
        self._last = None

    def __call__(self, c) -> None:
        left = "?" if c.left_s is None else _clock(c.left_s)
        extra = f" ({c.up_to_date} up to date)" if c.up_to_date else ""
        tail = f", {c.not_run} not run" if c.not_run else ""
        line = (
            f"batch: {c.done + c.up_to_date}/{c.total} done{extra}, {c.running} running, {c.failed} failed"
            f"{tail} | {_clock(c.elapsed_s)} elapsed, {left} left"
        )
        new = (c.finished, c.failed) != self._last
        self._last = (c.finished, c.failed)
        self.show(line, new)

    def note(self, text: str) -> None:
        """A line of its own (a retry, a task's warning), off the progress line."""
        super().note(f"ltmap: {text}")


def _clock(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


@click.command("batch", help=HELP, short_help="Replay a fleet's logs (sites x days) on a Dask engine.")
@click.argument("manifest", metavar="FLEET.yaml", type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    default=Path("ltmap_batch"),
    show_default=True,
    help="Output folder.",
)
@click.option(
    "--sweep",
    "sweeps",
    multiple=True,
    metavar="KEY=V1,V2,...",
    help="Replay every site once per value of parameter KEY (repeatable: every combination), "
    "e.g. --sweep map.layers.st_rise_s=5,10,15.",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    help="Worker processes of the local engine [default: the machine's cores].",
)
@click.option(
    "--address",
    metavar="HOST:PORT",
    help="Run on a running Dask scheduler (e.g. tcp://head:8786) instead "
    "of a local engine; OUT and the logs must be on a file system every worker sees.",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(path_type=Path),
    help="Parameters from a YAML file (the names of config.yaml), under the manifest's own.",
)
@click.option(
    "--set",
    "overrides",
    multiple=True,
    metavar="KEY=VALUE",
    help="Set a parameter for every site, e.g. --set map.layers.st_rise_s=10.",
)
@click.option("--no-plots", is_flag=True, help="Skip each day's plots/*.png (replay.plots: false).")
@click.option("--rerun", is_flag=True, help="Replay every day, even those complete for the same inputs.")
@click.option("--dry-run", is_flag=True, help="List the tasks and which are up to date; run nothing.")
@click.option("-q", "--quiet", is_flag=True, help="No progress line.")
@click.pass_context
def batch(
    ctx, manifest, output, sweeps, workers, address, config_file, overrides, no_plots, rerun, dry_run, quiet
):

    if address and workers:
        raise click.UsageError(
            "--workers sizes the local engine; with --address the cluster's workers are used"
        )
    fleet = load_manifest(manifest)
    sets = parse_set(overrides) + ([("replay.plots", False)] if no_plots else [])
    plan = build_plan(fleet, output, config_file=config_file, sets=sets, sweeps=sweeps)
    tasks = plan.tasks()
    if dry_run:
        for t in tasks:
            required = STATIC_OUTPUTS if isinstance(t, StaticTask) else DAY_OUTPUTS
            done = not rerun and is_complete(t.out_dir, t.key, required)
            click.echo(f"{'up to date' if done else 'to run':10s}  {t.label:40s}  {t.out_dir}")
        return
    bar = None if quiet else BatchProgress()
    notes = bar.note if bar is not None else (lambda text: click.echo(f"ltmap: {text}", err=True))
    try:
        result, written = execute(
            plan, Engine(address=address, workers=workers), rerun=rerun, progress=bar, notify=notes
        )
    finally:
        if bar is not None:
            bar.close()
    failed = result.by_status(FAILED)
    not_run = result.by_status(NOT_RUN)
    days = [s for s in result.states if not isinstance(s.task, StaticTask)]
    fresh = sum(s.status == UP_TO_DATE for s in days)
    ok = len(days) - sum(s.status in (FAILED, NOT_RUN) for s in days)
    click.echo(
        f"batch: {ok} of {len(days)} days done ({fresh} up to date, {ok - fresh} replayed), "
        f"{len(failed)} tasks failed, {len(not_run)} days not run, in {_clock(result.wall_s)}; "
        f"wrote {', '.join(str(p) for p in written)}"
    )
    for s in failed[:MAX_LISTED]:
        logs = " ".join(str(p) for p in getattr(s.task, "logs", ()) or (s.task.plan,))
        click.echo(
            f"ltmap: failed: {s.task.label} ({logs}), {s.attempts} attempts: {s.result.get('error')}",
            err=True,
        )
        if (ctx.obj or {}).get("debug") and s.result.get("traceback"):
            click.echo(s.result["traceback"], err=True)
    for s in not_run[:MAX_LISTED]:
        click.echo(f"ltmap: not run: {s.task.label}: {s.reason}", err=True)
    more = max(len(failed) - MAX_LISTED, 0) + max(len(not_run) - MAX_LISTED, 0)
    if more:
        click.echo(f"ltmap: ... {more} more failed or not run: see {written[0]}", err=True)
    if failed or not_run:
        ctx.exit(1)
