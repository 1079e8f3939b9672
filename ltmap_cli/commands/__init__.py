"""One module per subcommand; each is imported only when its command runs."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ..errors import InputError, OutputError
from ..outputs.folder import output_target

FD_MARGIN = 64  # open files a run needs besides its logs' (numba's cache, outputs, threads)


def clock(seconds: float) -> str:
    """A log time for a person: ``"1:02:03.5"`` (h:mm:ss), ``"2:03.5"`` (m:ss) under an hour."""
    neg, s = seconds < 0, abs(seconds)
    h, rem = divmod(s, 3600.0)
    m, sec = divmod(rem, 60.0)
    if round(sec, 1) >= 60.0:  # (59.96 s shows as 1:00.0, not 0:60.0)
        m, sec = m + 1, 0.0
        if m >= 60:
            h, m = h + 1, 0
    text = f"{int(h)}:{int(m):02d}:{sec:04.1f}" if h else f"{int(m)}:{sec:04.1f}"
    return "-" + text if neg else text


class LogTime(click.ParamType):
    """Seconds of log time, as a number (``4800``, ``12.5``) or a clock (``1:20:00``, ``80:00``,
    ``1:20:00.5``): hours of log are easier to give by their clock."""

    name = "SECONDS|H:MM:SS"

    def convert(self, value, param, ctx):
        if isinstance(value, (int, float)):
            return float(value)
        text = str(value).strip()
        parts = text.split(":")
        try:
            if len(parts) > 3 or (len(parts) > 1 and not all(p.strip() for p in parts)):
                raise ValueError
            nums = [float(p) for p in parts]
            if len(nums) > 1 and (any(x < 0 or x != int(x) for x in nums[:-1]) or nums[-1] < 0 or
                                  any(x >= 60 for x in nums[1:])):  # fmt: skip
                raise ValueError
        except ValueError:
            self.fail(f"{text!r} is not a log time: give seconds (4800) or a clock (1:20:00, 80:00)", param, ctx)
        total = 0.0
        for x in nums:
            total = total * 60.0 + x
        return total


def allow_open_files(logs) -> None:
    """A recording split into many files (``rosbag record --split``, rosbag2 ``--max-bag-duration``:
    a day at one a minute is 1440 files) keeps each file open: the process's soft limit of open
    files (often 1024) is raised toward its hard limit when the logs need more. Beyond the hard
    limit, ``InputError`` in one line (before, the run stopped at the limit with "Too many open
    files; check the path, its permissions and the free space")."""
    import resource

    from ..io.sources import storage_files

    n = sum(len(storage_files(p)) if p.is_dir() else 1 for p in map(Path, logs))
    need = n + FD_MARGIN
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or need <= soft:
        return
    if hard != resource.RLIM_INFINITY and need > hard:
        raise InputError(f"{n} log files need more open files than this process may have (ulimit -Hn: {hard}); "
                         f"merge them first (`mcap merge`, `ros2 bag convert`) or raise the hard limit")  # fmt: skip
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (need if hard == resource.RLIM_INFINITY else min(hard, 2 * need),
                                                    hard))  # fmt: skip
    except (ValueError, OSError) as err:
        raise InputError(f"{n} log files need {need} open files and the limit ({soft}) could not be raised ({err}); "
                         f"run `ulimit -n {need}` first, or merge the files") from None


def nonempty_output(ctx: click.Context, param: click.Parameter, value: Path | None) -> Path | None:
    """Click callback of ``-o``: a path no run may replace (the current folder, one above it, '')
    is refused as the command line is read, with OutputFolder's own check, not after the work."""
    if value is not None:
        try:
            output_target(value, "-o")
        except OutputError as e:
            raise click.BadParameter(str(e)) from None
    return value


class StatusLine:
    """A status line on stderr: on a terminal redrawn in place (``show``); elsewhere (CI logs)
    printed as a line of its own when ``show`` is told it is worth one. ``note`` prints a line
    off the status line; ``close`` ends it."""

    def __init__(self, stream=None):
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._open = False

    def show(self, line: str, new: bool) -> None:
        if self.tty:
            self.stream.write("\r\x1b[K" + line)
            self.stream.flush()
            self._open = True
        elif new:
            self.stream.write(line + "\n")

    def note(self, text: str) -> None:
        if self._open:
            self.stream.write("\r\x1b[K")
        self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self._open:
            self.stream.write("\n")
            self.stream.flush()
            self._open = False


def sensor_options(cfg, fixed_frame=None, tf_mounts=(), scan_topics=(), cloud_topics=(), depth_topics=(),
                   camera_infos=()) -> None:
    """Replay's options that choose sensors and frames, applied to ``cfg`` (after its --config
    file, before --set: replay's order), for replay and for info (which says what replay would use)."""
    rc = cfg.replay
    if fixed_frame is not None:
        rc.fixed_frame = fixed_frame
    if tf_mounts:
        rc.tf = [*rc.tf, *tf_mounts]
    if camera_infos:
        rc.camera_info = [*rc.camera_info, *map(str, camera_infos)]
    for key, value in (("scan_topics", scan_topics), ("cloud_topics", cloud_topics), ("depth_topics", depth_topics)):
        if value:
            setattr(rc, key, list(value))
