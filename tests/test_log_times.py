"""Log times as people give them for hours of log: --start / --end take seconds or a clock
(1:20:00), the progress bar of a long log and `ltmap info` show clocks, and info gives a log's
span as UTC dates when its record times are wall-clock times."""

from __future__ import annotations

import click
import pytest
from click.testing import CliRunner

from ltmap_cli.cli import cli
from ltmap_cli.commands import LogTime, clock
from ltmap_cli.commands.info import _utc


@pytest.mark.parametrize("text, seconds", [
    ("4800", 4800.0), ("12.5", 12.5), ("0", 0.0), ("1:20:00", 4800.0), ("80:00", 4800.0), ("1:20:00.5", 4800.5),
    ("0:05", 5.0), (" 2:03:04 ", 7384.0), ("100:00", 6000.0),
])  # fmt: skip
def test_a_log_time_is_seconds_or_a_clock(text, seconds):
    assert LogTime().convert(text, None, None) == seconds


@pytest.mark.parametrize("text", ["1:75", "1:2:3:4", "a:b", "1::2", ":30", "-1:00", "1:-5", "1.5:00", "", "1:60:00"])
def test_what_is_not_a_log_time_is_refused(text):
    with pytest.raises(click.BadParameter, match="is not a log time: give seconds"):
        LogTime().convert(text, None, None)


def test_clock():
    assert clock(0) == "0:00.0" and clock(59.96) == "1:00.0" and clock(3723.5) == "1:02:03.5"
    assert clock(3599.96) == "1:00:00.0" and clock(7384.04) == "2:03:04.0" and clock(-65) == "-1:05.0"
    assert LogTime().convert(clock(3723.5), None, None) == 3723.5  # what is shown can be given back


def test_start_and_end_as_clocks_map_the_same_window(tmp_path):
    from test_replay_outputs import LOG

    runner = CliRunner()
    outs = []
    for k, (a, b) in enumerate((("5", "10.5"), ("0:05", "0:10.5"))):
        out = tmp_path / f"o{k}"
        r = runner.invoke(cli, ["replay", str(LOG), "--start", a, "--end", b, "-o", str(out), "-q", "--no-plots"])
        assert r.exit_code == 0, r.output
        outs.append(out)
    assert (outs[0] / "map.pgm").read_bytes() == (outs[1] / "map.pgm").read_bytes()
    r = runner.invoke(cli, ["replay", str(LOG), "--start", "1:75", "-o", str(tmp_path / "bad"), "-q"])
    assert r.exit_code == 2 and "'1:75' is not a log time" in r.output and not (tmp_path / "bad").exists()


def test_info_gives_utc_dates_of_wall_clock_logs_only():
    s = 10**9
    assert _utc(1_700_000_000 * s, 1_700_000_030 * s) == "; 2023-11-14 22:13:20 .. 22:13:50 UTC"
    assert _utc(1_700_000_000 * s, 1_700_100_000 * s) == "; 2023-11-14 22:13:20 .. 2023-11-16 02:00:00 UTC"
    assert _utc(0, 30 * s) == "" and _utc(1000 * s, 5000 * s) == ""  # sim time


def test_the_summary_of_a_long_replay_gives_clocks():
    from ltmap_cli.commands.replay import summary_line

    rep = {"frames_used": {"/scan": 10}, "frames_skipped": {}, "speed_vs_real_time": 4.9,
           "mapping_speed_vs_real_time": 5.0, "voxels": {"long_term_occupied": 7}}  # fmt: skip
    assert summary_line({**rep, "log_duration_s": 10800.0, "wall_time_s": 2204.1}).startswith(
        "replayed 3:00:00.0 of log in 36:44.1 (4.9x real time end to end; mapping alone 5.0x): 10 frames used")
    assert summary_line({**rep, "log_duration_s": 30.0, "wall_time_s": 6.2}).startswith(
        "replayed 30.0 s of log in 6.2 s (4.9x")
    # a first run: how much of it was compiling (under a second, a cache load: not said)
    first = {**rep, "log_duration_s": 50.0, "wall_time_s": 45.1, "kernels_compiled_s": 38.8}
    assert "mapping alone 5.0x; 39 s of it compiling kernels, first run only): 10 frames" in summary_line(first)
    assert "compiling" not in summary_line({**first, "kernels_compiled_s": 0.4})
