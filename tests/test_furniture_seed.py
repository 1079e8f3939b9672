"""`build-static --furniture long-term` seeds LT, and `replay --static` starts from that seed (SPEC 3).

The plan: a 4 x 4 m canvas in millimetres, one walls layer (a square path, 100 mm stroke, centred on
0.1 and 3.9 m, so the walls cover x, y in [0.05, 0.15] and [3.85, 3.95]) and one furniture layer: a
cupboard drawn at SVG (500, 2500) 500 x 1000 mm, 0.75 m tall. SVG y points down, the canvas is 4 m
tall, so in the map the cupboard covers x in [0.5, 1.0], y in [4 - 3.5, 4 - 2.5] = [0.5, 1.5]: 10 x 20
cells at 0.05 m, each a column of 0.75 / 0.05 = 15 voxels (z 0 .. 0.75): 3000 seed voxels.

The log: the robot stands at (3, 3) facing +x with a laser 0.3 m up that covers only +-20 degrees,
so it sees the east wall and never looks toward the cupboard (at about -138 degrees from it).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from click.testing import CliRunner
from logfactory import scan, tf, write_log, yaw_quat

from ltmap_cli.cli import cli
from ltmap_cli.io.mapfile import read_map_yaml

R = 0.05
T0 = 1_000_000_000
SVG = """<svg xmlns="http://www.w3.org/2000/svg" width="4000mm" height="4000mm" viewBox="0 0 4000 4000">
<g id="walls" style="fill:none;stroke:#000;stroke-width:100"><path d="M 100,100 H 3900 V 3900 H 100 Z"/></g>
<g id="furniture" style="fill:#a80;stroke:none">
<rect id="cupboard" x="500" y="2500" width="500" height="1000" data-height-m="0.75"/></g>
</svg>
"""
CUPBOARD = (0.5, 0.5, 1.0, 1.5)  # x0, y0, x1, y1 in the map
ROBOT = (3.0, 3.0)
MOUNT_Z = 0.3
N_BEAMS = 21
AMIN, INC = math.radians(-20), math.radians(2)


def ltmap(*args) -> object:
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def log_messages(duration_s: float = 3.0, rate_hz: float = 5.0) -> list:
    # the east wall's inner face is x = 3.85: range 0.85 / cos(angle) from the laser at (3, 3)
    ang = AMIN + INC * np.arange(N_BEAMS)
    ranges = (3.85 - ROBOT[0]) / np.cos(ang)
    msgs = [tf(T0, [("base_link", "laser", (0.0, 0.0, MOUNT_Z), (0, 0, 0, 1))], static=True)]
    n = int(round(duration_s * rate_hz))
    for i in range(-1, n + 2):
        ns = T0 + int(round(i / rate_hz * 1e9))
        msgs.append(tf(ns, [("odom", "base_link", (*ROBOT, 0.0), yaw_quat(0.0))]))
        if 0 <= i < n:
            msgs.append(scan("/scan", ns + 1000, ranges, angle_min=AMIN, angle_increment=INC,
                             range_min=0.05, range_max=10.0))  # fmt: skip
    return msgs


def cell_value(g, x: float, y: float) -> int:
    """The value of the cell holding world point (x, y) (origin yaw 0; row 0 = lowest y)."""
    assert g.origin[2] == 0.0
    col = math.floor((x - g.origin[0]) / g.resolution)
    row = math.floor((y - g.origin[1]) / g.resolution)
    assert 0 <= row < g.data.shape[0] and 0 <= col < g.data.shape[1], (x, y)
    return int(g.data[row, col])


def cupboard_centres() -> list[tuple[float, float]]:
    x0, y0, x1, y1 = CUPBOARD
    xs = np.arange(x0 + R / 2, x1, R)
    ys = np.arange(y0 + R / 2, y1, R)
    return [(float(x), float(y)) for x in xs for y in ys]


def build_and_replay(tmp_path: Path, furniture: str) -> tuple[Path, Path]:
    plan = tmp_path / "room.svg"
    plan.write_text(SVG)
    static = tmp_path / f"static_{furniture}"
    r = ltmap("build-static", plan, "-o", static, "--furniture", furniture)
    assert r.exit_code == 0, r.output
    log = tmp_path / "log.mcap"
    if not log.exists():
        write_log(log, "mcap-ros2", log_messages())
    out = tmp_path / f"out_{furniture}"
    r = ltmap("replay", log, "--static", static, "-o", out, "-q", "--no-plots")
    assert r.exit_code == 0, r.output
    return static, out


def test_long_term_furniture_is_in_lt_from_the_start_where_the_robot_never_looked(tmp_path):
    static, out = build_and_replay(tmp_path, "long-term")
    assert len(cupboard_centres()) == 10 * 20
    report = json.loads((out / "report.json").read_text())
    assert report["static"]["long_term_seed_voxels"] == 10 * 20 * 15
    assert report["frames_used"] == {"/scan": 15}

    # the plan's 2D static map keeps the cupboard out of S: its cells are free there
    s = read_map_yaml(static / "static.yaml")
    assert all(cell_value(s, x, y) == 0 for x, y in cupboard_centres())
    assert cell_value(s, 0.1, 2.0) == 100  # the west wall is S

    lt = read_map_yaml(out / "long_term.yaml")
    p = read_map_yaml(out / "map.yaml")
    for x, y in cupboard_centres():
        assert cell_value(lt, x, y) == 100, (x, y)
        assert cell_value(p, x, y) == 100, (x, y)
    # just outside the cupboard nothing was seeded: the neighbouring cells are not occupied in LT
    for x, y in [(0.475, 1.0), (1.025, 1.0), (0.75, 0.475), (0.75, 1.525)]:
        assert cell_value(lt, x, y) != 100, (x, y)
    # the robot did look ahead: free between it and the east wall, the wall itself occupied in P
    assert cell_value(p, 3.4, 3.0) == 0
    assert cell_value(p, 3.875, 3.0) == 100
    lt_occ = int((lt.data == 100).sum())
    assert lt_occ == 200  # only the cupboard: 3 s of sight is far below st_rise_s for the wall


def test_without_the_flag_the_furniture_is_not_in_the_map(tmp_path):
    _, out = build_and_replay(tmp_path, "none")
    report = json.loads((out / "report.json").read_text())
    assert not report["static"].get("long_term_seed_voxels")
    lt = read_map_yaml(out / "long_term.yaml")
    p = read_map_yaml(out / "map.yaml")
    assert int((lt.data == 100).sum()) == 0
    for x, y in cupboard_centres():
        assert cell_value(p, x, y) == 0, (x, y)  # S says free there, nothing occupies it


def test_resume_does_not_seed_again_what_day_one_saw_gone(tmp_path):
    """Day 1 looks at the cupboard's place (the cupboard is gone): the laser plane's seed voxels
    are seen free and leave LT. Day 2 resumes from day 1 with the same --static: its LT starts
    from day 1's, without the seeds coming back."""
    static, _ = build_and_replay(tmp_path, "long-term")
    yaw = math.atan2(1.0 - ROBOT[1], 0.75 - ROBOT[0])  # toward the cupboard's centre
    ang = AMIN + INC * np.arange(N_BEAMS)
    th = yaw + ang
    # the room's inner faces are x, y = 0.15: every beam passes over the cupboard's place to them
    ranges = np.minimum((0.15 - ROBOT[0]) / np.cos(th), (0.15 - ROBOT[1]) / np.sin(th))
    msgs = [tf(T0, [("base_link", "laser", (0.0, 0.0, MOUNT_Z), (0, 0, 0, 1))], static=True)]
    for i in range(-1, 32):
        ns = T0 + int(round(i / 5.0 * 1e9))
        msgs.append(tf(ns, [("odom", "base_link", (*ROBOT, 0.0), yaw_quat(yaw))]))
        if 0 <= i < 30:
            msgs.append(scan("/scan", ns + 1000, ranges, angle_min=AMIN, angle_increment=INC, range_min=0.05,
                             range_max=10.0))  # fmt: skip
    day1_log = write_log(tmp_path / "day1.mcap", "mcap-ros2", msgs)
    day1 = tmp_path / "day1"
    r = ltmap("replay", day1_log, "--static", static, "-o", day1, "-q", "--no-plots")
    assert r.exit_code == 0, r.output
    lt1 = json.loads((day1 / "report.json").read_text())["voxels"]["long_term_occupied"]
    assert 3000 - 200 <= lt1 < 3000  # the seed minus the laser plane's voxels seen free (<= 10 x 20)
    day2 = tmp_path / "day2"
    r = ltmap("replay", tmp_path / "log.mcap", "--static", static, "--resume", day1, "-o", day2, "-q", "--no-plots")
    assert r.exit_code == 0, r.output
    rep2 = json.loads((day2 / "report.json").read_text())
    assert rep2["static"]["long_term_seed_voxels"] == 0 and "resume" in rep2["static"]["long_term_seed_note"]
    assert rep2["voxels"]["long_term_occupied"] == lt1  # day 2 looks away: day 1's LT as it was
