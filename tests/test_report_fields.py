"""report.json timing fields and the progress line of `ltmap replay` (issue 3), on a shipped sample.

The log's duration is taken from the MCAP summary (mcap's own reader), independently of ltmap's
readers; the progress line's format is ProgressBar's (commands/replay.py): on a stream that is not
a terminal it prints one line per 10 % of log time.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from ltmap_cli.cli import cli

LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "01_static_object" / "log.mcap"
PROGRESS = re.compile(  # (a log of an hour or more gives its times as clocks: 15:00.0/1:00:00.0 log)
    r"^\[[#.]+\] +((?P<done>\d+\.\d)/(?P<total>\d+\.\d) s|(?P<cdone>[\d:]+\.\d)/(?P<ctotal>[\d:]+\.\d)) log"
    r" \| +\d+\.\d frames/s \| +\d+\.\dx real time"
    r"( \| (?P<left>\d+ s|\d+ min \d\d s|\d+ h \d\d min) left)?$"
)

pytestmark = pytest.mark.skipif(not LOG.exists(), reason=f"{LOG} not shipped")


def _runner() -> CliRunner:
    try:  # click < 8.2 mixes stderr into output unless told not to
        return CliRunner(mix_stderr=False)
    except TypeError:  # click >= 8.2 keeps result.stderr apart
        return CliRunner()


def _summary():
    from mcap.reader import make_reader

    with LOG.open("rb") as f:
        summary = make_reader(f).get_summary()
    stats = summary.statistics
    duration = (stats.message_end_time - stats.message_start_time) / 1e9
    scans = [cid for cid, ch in summary.channels.items() if ch.topic == "/scan"]
    n_scans = sum(stats.channel_message_counts[cid] for cid in scans)
    return duration, duration / max(n_scans - 1, 1)  # the log's duration and its scan period


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = {}
    for name, extra in (("loud", []), ("quiet", ["-q"])):
        folder = tmp_path_factory.mktemp(name) / "out"
        result = _runner().invoke(cli, ["replay", str(LOG), "-o", str(folder), "--no-plots", *extra])
        assert result.exit_code == 0, (result.output, result.stderr)
        report = json.loads((folder / "report.json").read_text())
        out[name] = (result, report)
    return out


def test_log_duration_is_the_mcap_duration(runs):
    duration, period = _summary()
    assert duration > 10.0 and 0.0 < period < 1.0  # the sample: 30 s of 10 Hz scans
    for _, report in runs.values():
        assert abs(report["log_duration_s"] - duration) <= period


def test_wall_time_and_speed(runs):
    for _, report in runs.values():
        log_s, wall_s, speed = report["log_duration_s"], report["wall_time_s"], report["speed_vs_real_time"]
        assert wall_s > 0.0
        # the report divides unrounded values and rounds to 0.01; log_s and wall_s are rounded to
        # 0.001, which moves the quotient by at most speed * (0.0005 / log_s + 0.0005 / wall_s)
        slack = 0.005 + 0.005 + speed * (0.0005 / log_s + 0.0005 / wall_s) + 1e-9
        assert abs(speed - round(log_s / wall_s, 2)) <= slack
        assert speed > 0.0


def test_peak_memory_plausible(runs):
    for _, report in runs.values():
        assert 50.0 <= report["peak_memory_mb"] <= 4000.0


def test_progress_line_on_stderr_unless_quiet(runs):
    result, report = runs["loud"]
    lines = [line for line in result.stderr.splitlines() if PROGRESS.match(line)]
    assert lines, result.stderr
    for line in lines:
        m = PROGRESS.match(line)
        assert float(m["total"]) == pytest.approx(report["log_duration_s"], abs=0.05)
        assert 0.0 <= float(m["done"]) <= float(m["total"])
    # log time done never goes back
    done = [float(PROGRESS.match(line)["done"]) for line in lines]
    assert done == sorted(done)

    quiet, _ = runs["quiet"]
    assert "real time" not in quiet.stderr and "s log |" not in quiet.stderr
    assert not any(PROGRESS.match(line) for line in quiet.stderr.splitlines())
    # the summary line (stdout) is printed either way
    assert "x real time" in quiet.stdout and "x real time" in result.stdout


def test_progress_line_gives_the_time_left_at_the_speed_so_far():
    import io

    from ltmap_cli.commands.replay import ProgressBar, time_left
    from ltmap_cli.pipeline.replay import Progress

    # an hour of log, a quarter done in 112.5 s of wall time: 8x, so 2700 s of log take 337.5 s
    out = io.StringIO()
    bar = ProgressBar(out)
    bar(Progress(log_done_s=900.0, log_total_s=3600.0, frames=40500, wall_s=112.5))
    line = out.getvalue().strip()
    m = PROGRESS.match(line)
    assert m and m["left"] == "5 min 38 s", line
    assert (m["cdone"], m["ctotal"]) == ("15:00.0", "1:00:00.0")  # an hour of log: clocks, as --start takes them
    assert time_left(36000.0, 8.0) == "1 h 15 min" and time_left(45.0, 1.0) == "45 s" and time_left(-1, 2) == "0 s"
    # no guess in the first seconds (under 5 % of the log), nor once the log is done
    for p in (Progress(60.0, 3600.0, 10, 1.0), Progress(3600.0, 3600.0, 10, 400.0)):
        out = io.StringIO()
        ProgressBar(out)(p)
        assert "left" not in out.getvalue() and PROGRESS.match(out.getvalue().strip())


def test_progress_speed_leaves_out_the_first_runs_compiling(tmp_path):
    """The bar's speed and time left are the mapping's: the kernels' warm-up (a first run's
    compiling, stage ``warmup``) is not counted as time spent on the log."""
    import io
    import time

    from ltmap_cli.commands.replay import ProgressBar
    from ltmap_cli.config import Config
    from ltmap_cli.pipeline.replay import NS, Replay, ReplayRequest

    seen = []
    run = Replay(Config(), ReplayRequest([LOG], tmp_path / "out"), progress=seen.append)
    run.log_total_s = 100.0
    run._t_wall0 = time.perf_counter() - 50.0  # 50 s since the run began, 40 of them compiling
    run.timer.add("warmup", 40.0)
    run._report_progress(20 * NS, force=True)  # 20 s of log mapped in the other 10 s: 2x
    p = seen[-1]
    assert 10.0 <= p.wall_s < 10.5 and 1.9 < p.speed <= 2.0
    out = io.StringIO()
    ProgressBar(out)(p)
    m = PROGRESS.match(out.getvalue().strip())
    assert m and m["left"] in ("40 s", "39 s"), out.getvalue()  # 80 s of log at 2x


def test_config_yaml_names_the_inputs_and_repeats_the_run(tmp_path):
    """config.yaml holds the parameters; its header comment names the inputs (logs, --static,
    --resume), which are not parameters. Running the header's command gives the same map."""
    import shlex

    first = tmp_path / "first"
    r = _runner().invoke(cli, ["replay", str(LOG), "-o", str(first), "-q", "--no-plots",
                               "--set", "map.layers.st_rise_s=10"])  # fmt: skip
    assert r.exit_code == 0, r.output
    text = (first / "config.yaml").read_text()
    header = text.splitlines()[1]
    assert header.startswith("# ltmap replay ")
    args = shlex.split(header[2:])
    assert args[2] == str(LOG) and args[args.index("-o") + 1] == str(first)
    args[args.index("-o") + 1] = str(tmp_path / "again")
    r = _runner().invoke(cli, [*args[1:], "-q", "--no-plots"])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "again" / "map.pgm").read_bytes() == (first / "map.pgm").read_bytes()
    assert "st_rise_s: 10.0" in (tmp_path / "again" / "config.yaml").read_text()
