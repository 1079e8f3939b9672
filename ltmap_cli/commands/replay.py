"""`ltmap replay LOG [LOG ...]`: parse, build the run, show progress, print a summary."""

from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager, suppress
from pathlib import Path

import click

from ..analysis.hints import replay_hints
from ..config import dump_config as dump
from ..config import load_config, parse_set, set_dotted
from ..errors import INTERRUPTED, ConfigError
from ..outputs.folder import OutputFolder, check_completed_input, listing
from ..pipeline.replay import Replay, ReplayRequest
from . import LogTime, StatusLine, allow_open_files, clock, nonempty_output, sensor_options

ETA_AFTER_S = 2.0  # the time left is shown after this much wall time (or 5 % of the log): no wild first guess
LONG_LOG_S = 3600.0  # a log this long shows its times as clocks (1:02:03.5), as --start / --end take them
HARD_STOP_S = 5.0  # after a second Ctrl-C the clean-up may take this long; then the process ends without it


def time_left(log_left_s: float, speed: float) -> str:
    """The wall time the rest of the log takes at ``speed`` (x real time), rounded for a person:
    ``"45 s"``, ``"5 min 38 s"``, ``"2 h 05 min"``."""
    s = int(round(max(log_left_s, 0.0) / speed))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {(s % 3600) // 60:02d} min"


def summary_line(report: dict) -> str:
    """The line a replay ends with (stdout); an hour of log or more gives its times as clocks; a
    first run says how much of its time was the kernels' compiling (which the next runs skip)."""
    used = sum(report["frames_used"].values())
    skipped = sum(report["frames_skipped"].values())
    log_s, wall_s = report["log_duration_s"], report["wall_time_s"]
    took = (f"{clock(log_s)} of log in {clock(wall_s)}" if log_s >= LONG_LOG_S else
            f"{log_s:.1f} s of log in {wall_s:.1f} s")  # fmt: skip
    compiled = report.get("kernels_compiled_s", 0.0)
    first = f"; {compiled:.0f} s of it compiling kernels, first run only" if compiled >= 1.0 else ""
    return (f"replayed {took} ({report['speed_vs_real_time']}x real time end to end; mapping alone "
            f"{report['mapping_speed_vs_real_time']}x{first}): {used} frames used, {skipped} skipped, "
            f"{report['voxels']['long_term_occupied']} long-term voxels")


class ProgressBar(StatusLine):
    """A one-line bar on stderr: log time done / total, frames/s, speed against real time and the
    time left at that speed (hours of log take a while); outside a terminal a line every 10 %.
    Steps other than mapping (compiling kernels, writing plots) are named once, on lines of their
    own."""

    def __init__(self, stream=None, width: int = 28):
        super().__init__(stream)
        self.width = width
        self._last_decile = -1
        self._phase = None

    def __call__(self, p) -> None:
        if p.phase is not None:
            if p.phase != self._phase:
                self._phase = p.phase
                self.note(f"ltmap: {p.phase} ...")
            return
        frac = min(p.log_done_s / p.log_total_s, 1.0) if p.log_total_s > 0 else 1.0
        fill = int(frac * self.width)
        fps = p.frames / p.wall_s if p.wall_s > 0 else 0.0
        done = (f"{clock(p.log_done_s):>9}/{clock(p.log_total_s)} log" if p.log_total_s >= LONG_LOG_S else
                f"{p.log_done_s:7.1f}/{p.log_total_s:.1f} s log")  # fmt: skip
        line = (
            f"[{'#' * fill}{'.' * (self.width - fill)}] {done}"
            f" | {fps:6.1f} frames/s | {p.speed:5.1f}x real time"
        )
        if frac < 1.0 and p.speed > 0 and (p.wall_s >= ETA_AFTER_S or frac >= 0.05):
            line += f" | {time_left(p.log_total_s - p.log_done_s, p.speed)} left"
        decile = 10 if frac >= 1.0 else int(frac * 10)
        new = decile > self._last_decile
        if new:
            self._last_decile = decile
        self.show(line, new)


class HardStop:
    """After a second Ctrl-C (``arm``, from ``first_ctrl_c_stops``), the clean-up (the run's
    threads stopped, its staging folder removed, the output folder's lock let go) may take
    ``HARD_STOP_S``; if it waits longer (a thread stuck on a disk that hangs, a lock the
    interrupt left held inside a thread pool, the staging folder's removal), a watcher thread
    ends the process then anyway, saying so, with status 130: a thread of its own, since the
    main thread may be the one stuck (a signal's handler would not run in a system call). The
    next run removes the staging folder left. Leaving the context (the clean-up done) stops the
    watcher. Its line is written from another thread that it waits for a second at most, as a
    stderr that no one reads (a pipe paused in ``less``) would block the write."""

    def __init__(self, output: Path):
        self.output = output
        self._armed = threading.Event()
        self._done = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> HardStop:
        self._thread = threading.Thread(target=self._watch, name="ltmap-hard-stop", daemon=True)
        self._thread.start()
        return self

    def arm(self) -> None:
        """(A signal handler's call: the main thread never holds this event's lock otherwise.)"""
        self._armed.set()

    @property
    def armed(self) -> bool:
        return self._armed.is_set() and not self._done.is_set()

    def __exit__(self, *exc) -> None:
        self._done.set()
        self._armed.set()  # (wakes the watcher, which then ends)
        if self._thread is not None:
            self._thread.join()

    def _watch(self) -> None:
        self._armed.wait()
        if self._done.wait(HARD_STOP_S):
            return
        text = (f"ltmap: interrupted; the clean-up did not end within {HARD_STOP_S:g} s, so ltmap stopped without "
                f"it: nothing was written ({self.output}/ keeps what it held; the next run removes its staging folder)")
        say = threading.Thread(target=_write_stderr, args=("\n" + text + "\n",), daemon=True)
        say.start()
        say.join(1.0)
        os._exit(INTERRUPTED)


def _write_stderr(text: str) -> None:
    with suppress(OSError, ValueError):  # (no stderr to say it on)
        os.write(sys.stderr.fileno(), text.encode())


@contextmanager
def first_ctrl_c_stops(run: Replay, say, output: Path, hard_stop: HardStop | None = None):
    """While in it, a first Ctrl-C (SIGINT) stops reading the log: the frames read so far are
    mapped and the outputs written as for a log that ended there (``Replay.interrupt``); a second
    one stops at once (KeyboardInterrupt: nothing written, the output folder keeps what it held),
    and arms ``hard_stop`` (the clean-up's time bound). A first one after the whole log was read
    (``Replay.whole_log_read``) says so: the run ends as a complete one. Not in a thread other
    than the main one, nor when SIGINT is ignored (a background job)."""
    old = signal.getsignal(signal.SIGINT) if threading.current_thread() is threading.main_thread() else None
    if old is None or old is signal.SIG_IGN:
        yield
        return

    def stop(signum, frame):
        signal.signal(signal.SIGINT, second)
        again = f"Ctrl-C again to stop at once; {output}/ then keeps what it held"
        if run.whole_log_read:  # (nothing left to stop: the outputs are those of the whole log)
            say(f"ltmap: interrupted after the whole log was read: finishing {output}/ ({again})")
            return
        run.interrupt()
        say(f"ltmap: interrupted: mapping the frames read so far and writing {output}/ ({again})")

    def second(signum, frame):
        signal.signal(signal.SIGINT, signal.default_int_handler)  # (a third raises again)
        if hard_stop is not None:
            hard_stop.arm()
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _xy(text: str, flag: str) -> list[float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        shown = text if text.strip() else repr(text)  # an empty value is shown as ''
        raise ConfigError(f"{flag} {shown}: expected X,Y in metres, e.g. {flag} 3.5,-1.0") from None
    return [x, y]


@click.command("replay")
@click.argument("logs", nargs=-1, type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("ltmap_out"), show_default=True,
              callback=nonempty_output,
              help="Output folder, replaced as a whole when the run completes (a failed run leaves it as it was).")
@click.option("--force", is_flag=True, help="Replace the output folder even if ltmap did not write it.")
@click.option("--static", "static", type=click.Path(path_type=Path),
              help="Static map S: a build-static output (folder or static.yaml) or any map_server YAML.")
@click.option("--resume", type=click.Path(path_type=Path),
              help="Start LT from an earlier completed output folder or a snapshot (state .npz or .ot).")
@click.option("--config", "config_file", type=click.Path(path_type=Path), help="Parameters from a YAML file "
              "(the names of config.yaml / --dump-config).")
@click.option("--dump-config", is_flag=True, help="Print the effective parameters as YAML and exit.")
@click.option("--fixed-frame", help="Fixed frame (default: map when tf has it, else odom).")
@click.option("--tf", "tf_mounts", multiple=True, metavar="PARENT:CHILD=x,y,z,roll,pitch,yaw",
              help="Add a transform the log lacks (metres, radians). Repeatable.")
@click.option("--camera-info", "camera_infos", multiple=True, metavar="[TOPIC=]FILE",
              help="A depth camera's calibration YAML (camera_calibration's file, or a CameraInfo saved from "
              "`ros2 topic echo --once`) for depth images recorded without their CameraInfo; with TOPIC, for that "
              "depth topic instead of its logged one. Repeatable.")
@click.option("--scan-topic", multiple=True, help="LaserScan topic to use (repeatable; default: all).")
@click.option("--cloud-topic", multiple=True, help="PointCloud2 topic to use (repeatable; default: all).")
@click.option("--depth-topic", multiple=True, help="Depth image topic to use: an Image, or image_transport's "
              ".../compressedDepth or .../compressed (repeatable; default: all, each image once).")
@click.option("--start", "start_s", type=LogTime(),
              help="Map the sensor frames from this much log time after the log's first message (seconds, or "
              "a clock: 1:20:00) (tf from a little before); the log is read up to there without mapping it.")
@click.option("--end", "end_s", type=LogTime(),
              help="Map up to this much log time after the log's first message (seconds or 1:20:00; default: "
              "its end).")
@click.option("--resolution", type=float, help="Voxel size in metres (default 0.05).")
@click.option("--tick", type=float, help="Update tick of ST/LT in seconds of log time (default 0.2).")
@click.option("--snapshot-every", type=float, help="Seconds of log time between snapshots (default 60).")
@click.option("--mode", type=click.Choice(["trinary", "scale", "raw"]), help="map.pgm mode, as map_server's "
              "(default trinary).")
@click.option("--allow-truncated", is_flag=True, help="Replay what a cut-off or damaged log holds (an MCAP chunk that fails its CRC is skipped, the chunks after it are read), exit 0.")
@click.option("--plan-goal", metavar="X,Y", help="Plan A* to this goal (fixed frame) every tick and time how "
              "fast the path reacts to each event (planner latency).")
@click.option("--robot-radius", type=float, help="Robot radius for the planner's inflation, m (default 0.2).")
@click.option("--mcap", "--mcap-out", "mcap_out", is_flag=True, help="Also write OUT/replay.mcap (maps, voxels, fused scan, tf) for "
              "Foxglove or RViz.")
@click.option("--map-period", type=float, help="Seconds of log time between map messages in replay.mcap (1.0).")
@click.option("--no-plots", is_flag=True, help="Skip OUT/plots/*.png.")
@click.option("--depth-outlier-filter", is_flag=True, help="Drop flying pixels at depth edges before integrating "
              "(open3d radius outlier removal; radius and neighbours: replay.depth_outlier_*).")
@click.option("--localize", is_flag=True, help="Estimate map -> odom from the scans: aligned to --static and "
              "tracked along the log, or scan-matching odometry without --static (a log with only /scan). "
              "Writes OUT/localization.csv. Parameters: replay.localization.*.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Set any parameter by its config name, e.g. --set map.layers.st_rise_s=10.")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
def replay(logs, output, force, static, resume, config_file, dump_config, fixed_frame, tf_mounts, camera_infos,
           scan_topic, cloud_topic,
           depth_topic, start_s, end_s, resolution, tick, snapshot_every, mode, allow_truncated, plan_goal, robot_radius, mcap_out,
           map_period, no_plots, depth_outlier_filter, localize, overrides, quiet):
    """Replay LOGS (ROS 1 .bag, ROS 2 bag folders, .mcap) at their recorded time through the
    layered long-term map, and write map.pgm/.yaml (P), long_term.*, static.*, snapshots/
    (OctoMap .ot, .ply, exact state), report.json and config.yaml into the output folder."""

    cfg = load_config(config_file)
    flags = {
        "replay.start_s": start_s,
        "replay.end_s": end_s,
        "map.resolution": resolution,
        "map.layers.tick": tick,
        "replay.snapshot_every": snapshot_every,
        "replay.mode": mode,
        "replay.robot_radius": robot_radius,
        "replay.map_period": map_period,
        "replay.mcap_out": True if mcap_out else None,
        "replay.plots": False if no_plots else None,
        "replay.depth_outlier_filter": True if depth_outlier_filter else None,
        "replay.localize": True if localize else None,
        "replay.plan_goal": _xy(plan_goal, "--plan-goal") if plan_goal is not None else None,
    }
    for key, value in flags.items():
        if value is not None:
            set_dotted(cfg, key, value)
    sensor_options(cfg, fixed_frame, tf_mounts, scan_topic, cloud_topic, depth_topic, camera_infos)
    if allow_truncated:
        cfg.replay.allow_truncated = True
    for key, value in parse_set(overrides):
        set_dotted(cfg, key, value)
    cfg.validate()
    if dump_config:
        click.echo(dump(cfg), nl=False)
        return
    if not logs:
        raise click.UsageError("give at least one LOG (a .bag, a ROS 2 bag folder or an .mcap)")


    allow_open_files(logs)
    bar = None if quiet else ProgressBar()
    # first the output folder (lock, checks, staging): a bad -o must not cost a whole replay
    check_completed_input(static, "--static", "give its static.yaml, or build it again with ltmap build-static")
    with HardStop(output) as hard_stop, OutputFolder(output, command="replay", force=force) as out:
        out.refuse_inputs_inside(logs, "LOG")
        out.refuse_inputs_inside([static], "--static")
        request = ReplayRequest(list(logs), out.staging, static=static, resume=resume, final_dir=out.final)
        run = Replay(cfg, request, progress=bar)
        try:
            with first_ctrl_c_stops(run, bar.note if bar is not None else lambda t: click.echo(t, err=True), output,
                                    hard_stop):  # fmt: skip
                report = run.run()
        finally:
            if bar is not None:
                bar.close()
        manifest = out.commit({"logs": [str(p) for p in logs]})
    click.echo(summary_line(report))
    loc = report.get("localization")
    if loc is not None and loc.get("child_frame"):
        click.echo(f"  localization: {loc['message']}")
    for reason, n in sorted(report["frames_skipped"].items(), key=lambda kv: -kv[1]):
        click.echo(f"  skipped {n} x: {reason}")
    for topic, why in sorted((report.get("topics_not_used") or {}).items()):
        if "not chosen" not in why:  # topics the user left out on purpose need no word
            click.echo(f"ltmap: warning: {topic} not used: {why}", err=True)
    for hint in replay_hints(report, st_rise_s=cfg.map.layers.st_rise_s, resolution=cfg.map.resolution):
        click.echo(f"ltmap: warning: {hint}", err=True)
    plan = (report.get("events") or {}).get("plan") or {}
    if plan.get("warning"):
        click.echo(f"ltmap: warning: {plan['warning']}", err=True)
    if report.get("stopped_at"):
        click.echo(f"  log damaged or cut off: {report['stopped_at']}")
    click.echo(f"wrote {output}/: {listing(manifest)}")
    stopped = report.get("interrupted_at_s")
    if stopped is not None:
        click.echo(f"ltmap: interrupted at {stopped:.1f} s of log time (from its first message): {output}/ holds the "
                   f"map up to there; to map the rest, add --start {stopped:g} --resume {output} -o <another folder>",
                   err=True)  # fmt: skip
        click.get_current_context().exit(INTERRUPTED)

