"""`replay --mcap-out --map-period P`: /map in replay.mcap is rate-limited to P seconds of log time
and only published when it changed. Read back with the mcap reader and the mcap_ros2 decoder.

Sample log 01_static_object (30 s, laser only): the walls enter LT at about 15 s, the box at about
18 s and leaves at about 25 s, so P changes over many ticks in the second half.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from ltmap_cli.cli import cli
from ltmap_cli.core.config import LayerConfig
from ltmap_cli.io.mapfile import read_map_yaml

LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "01_static_object" / "log.mcap"
NS = 10**9
TICK_NS = round(LayerConfig().tick * NS)


def read_grids(path: Path) -> dict[str, list[tuple[int, int, np.ndarray]]]:
    """topic -> [(log_time_ns, header stamp ns, grid (H, W) int8)] for the OccupancyGrid topics."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list] = {"/map": [], "/long_term_map": []}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, m in reader.iter_decoded_messages(topics=list(out)):
            assert schema.name == "nav_msgs/msg/OccupancyGrid"
            grid = np.asarray(m.data, dtype=np.int8).reshape(m.info.height, m.info.width)
            stamp = m.header.stamp.sec * NS + m.header.stamp.nanosec
            out[channel.topic].append((message.log_time, stamp, grid))
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("map_period")
    res = {}
    for period in (2.0, 0.5):
        out = tmp / f"p{period}"
        r = CliRunner().invoke(cli, ["replay", str(LOG), "-o", str(out), "-q", "--no-plots", "--mcap-out",
                                     "--map-period", str(period)], catch_exceptions=False)  # fmt: skip
        assert r.exit_code == 0, r.output
        res[period] = (out, read_grids(out / "replay.mcap"))
    return res


@pytest.mark.parametrize("period", [2.0, 0.5])
def test_map_messages_are_period_apart_and_each_one_changed(runs, period):
    out, grids = runs[period]
    maps = grids["/map"]
    assert len(maps) >= 5  # the walls and the box enter and leave: P changes many times
    times = [t for t, _, _ in maps]
    assert all(t == s for t, s, _ in maps)  # published at recorded time
    assert times == sorted(times)
    # every gap between periodic publications is at least P (the last message is the end-of-log
    # state, written whatever the period so that it equals map.pgm)
    gaps = np.diff(times[:-1])
    assert (gaps >= round(period * NS)).all(), gaps / NS
    assert times[-1] > times[-2]
    # published on tick ends only: every periodic stamp is a whole number of ticks after the first
    assert all((t - times[0]) % TICK_NS == 0 for t in times[:-1])
    # a grid is only published when it changed: no two consecutive grids are identical (P changes
    # as obstacles enter or leave LT and as free space grows)
    for (t0, _, a), (t1, _, b) in zip(maps, maps[1:]):
        assert a.shape != b.shape or not np.array_equal(a, b), f"same /map at {t0 / NS} and {t1 / NS}"
    # the last one is the map written to map.pgm
    g = read_map_yaml(out / "map.yaml")
    assert np.array_equal(maps[-1][2], g.data)
    assert int((g.data == 100).sum()) > 300
    # /long_term_map goes with it, at the same times
    assert [t for t, _, _ in grids["/long_term_map"]] == times


def test_smaller_period_gives_at_least_as_many_maps(runs):
    slow = runs[2.0][1]["/map"]
    fast = runs[0.5][1]["/map"]
    assert len(fast) >= len(slow)
    # P changes on most ticks between 15 s and 26 s, so 0.5 s (a publication every 3 ticks, 0.6 s)
    # gives clearly more than 2 s (every 10 ticks)
    assert len(fast) > len(slow) + 5
    # both end with the same final map
    assert np.array_equal(fast[-1][2], slow[-1][2])
