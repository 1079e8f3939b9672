"""Scenario files: defaults, and one-line errors naming the key, exit status 2, through the CLI."""

from __future__ import annotations

import copy

import pytest
import yaml
from click.testing import CliRunner

from ltmap_cli.cli import cli
from ltmap_cli.errors import ConfigError
from ltmap_cli.sim.scenario import load_scenario, parse_scenario

GOOD = {
    "duration": 5,
    "robot": {"path": {"still": {"x": 1, "y": 1}}},
    "sensors": {"laser": {}},
    "objects": [{"kind": "box", "pose": {"x": 2, "y": 1}, "present": [[1, 3]]}],
}


def run(tmp_path, doc=None, text=None):
    p = tmp_path / "bad.yaml"
    p.write_text(text if text is not None else yaml.safe_dump(doc))
    return CliRunner().invoke(cli, ["simulate", str(p), "-o", str(tmp_path / "out.mcap")])


def edited(**changes):
    doc = copy.deepcopy(GOOD)
    for path, value in changes.items():
        keys = path.split("__")
        d = doc
        for k in keys[:-1]:
            d = d[int(k)] if isinstance(d, list) else d[k]
        if value is ...:
            del d[keys[-1]]
        else:
            d[keys[-1]] = value
    return doc


@pytest.mark.parametrize("doc, key, words", [
    (edited(duration=...), "duration", "missing"),
    (edited(robot=...), "robot", "missing"),
    (edited(objects__0__kind="cube"), "objects[0].kind", "unknown kind 'cube'; use one of box, cylinder"),
    (edited(objects__0__present=[[3, 1]]), "objects[0].present[0]", "not an interval"),
    (edited(objects__0__present=[[0, 2], [1, 3]]), "objects[0].present[1]", "before the previous interval"),
    (edited(objects__0__present=[5]), "objects[0].present[0]", "expected [t_on, t_off]"),
    (edited(objects__0__colour="red"), "objects[0].colour", "unknown key"),
    (edited(objects__0__pose={"y": 1}), "objects[0].pose.x", "missing"),
    (edited(objects__0__size=[1, 0, 1]), "objects[0].size", "non-positive"),
    (edited(sensors={}), "sensors", "no sensor"),
    (edited(sensors__laser={"beams": "many"}), "sensors.laser.beams", "expected a number"),
    (edited(sensors__depth={"encoding": "rgb8"}), "sensors.depth.encoding", "use one of 16UC1, 32FC1"),
    (edited(sensors__depth={"dropout": 1.5}), "sensors.depth.dropout", "too large"),
    (edited(sensors__depth={"edge_dropout": -1}), "sensors.depth.edge_dropout", "too small"),
    (edited(sensors__depth={"edge_dropout": 0.5}), "sensors.depth.edge_dropout", "not a whole number of pixels"),
    (edited(robot__path={"still": {"x": 1, "y": 1}, "waypoints": []}), "robot.path", "exactly one of"),
    (edited(robot__path={"waypoints": [{"t": 1, "x": 0, "y": 0}, {"t": 1, "x": 1, "y": 0}]}),
     "robot.path.waypoints[1].t", "not after the previous waypoint"),
    (edited(plan="nowhere.svg"), "plan", "no such file"),
    (edited(doors=[{"from": [0, 0], "to": [0, 0]}]), "doors[0].to", "zero width"),
    (edited(doors=[{"kind": "revolving", "from": [0, 0], "to": [1, 0]}]), "doors[0].kind",
     "unknown kind 'revolving'; use one of box, hinged, sliding"),
    (edited(doors=[{"kind": "hinged", "from": [0, 0], "to": [1, 0], "motion_s": -1}]), "doors[0].motion_s",
     "-1 is too small; use a value >= 0"),
    (edited(doors=[{"kind": "hinged", "from": [0, 0], "to": [1, 0], "swing": "up"}]), "doors[0].swing",
     "expected left, right, +1 or -1, got 'up'"),
    (edited(doors=[{"kind": "hinged", "from": [0, 0], "to": [1, 0], "swing": [1]}]), "doors[0].swing",
     "expected left, right, +1 or -1"),
    (edited(doors=[{"kind": "hinged", "from": [0, 0], "to": [1, 0], "open_angle_deg": 200}]),
     "doors[0].open_angle_deg", "too large"),
    (edited(doors=[{"kind": "sliding", "from": [0, 0], "to": [1, 0], "swing": "left"}]), "doors[0].swing",
     "only for a hinged door, not kind sliding"),
    (edited(doors=[{"from": [0, 0], "to": [1, 0], "motion_s": 2}]), "doors[0].motion_s",
     "only for a hinged or sliding door, not kind box"),
    (edited(people=[{"path": [{"t": 0, "x": 0, "y": 0}]}]), "people[0].path", "at least 2 points"),
    (edited(seed=-1), "seed", "non-negative integer"),
    (edited(duration=0), "duration", "too small"),
])  # fmt: skip
def test_bad_scenarios_give_one_line_naming_the_key(tmp_path, doc, key, words):
    res = run(tmp_path, doc)
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1, res.output
    assert lines[0].startswith(f"ltmap: error: {tmp_path / 'bad.yaml'}: {key}: "), lines[0]
    assert words in lines[0]
    assert "Traceback" not in res.output
    assert not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("", "empty file"),
        ("# only a comment\n", "empty file"),
        ("- a\n- b\n", "its top level is ['a', 'b'], not a mapping"),
        ("hello\n", "its top level is 'hello', not a mapping"),
    ],
)
def test_empty_or_non_mapping_scenario_names_the_file(tmp_path, text, words):
    res = run(tmp_path, text=text)
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    line = res.output.strip()
    assert line == (
        f"ltmap: error: {tmp_path / 'bad.yaml'}: {words}; write the scenario as key: value lines "
        "(duration, robot, sensors, ...; see docs/scenarios.md)"
    )
    assert not (tmp_path / "out.mcap").exists()


def test_not_yaml_and_missing_file(tmp_path):
    res = run(tmp_path, text="duration: [1,\n")
    assert res.exit_code == 2 and "not valid YAML at line" in res.output
    assert len(res.output.strip().splitlines()) == 1
    res = CliRunner().invoke(cli, ["simulate", str(tmp_path / "none.yaml"), "-o", str(tmp_path / "o.mcap")])
    assert res.exit_code == 2 and "no such scenario file" in res.output


def test_defaults(tmp_path):
    sc = parse_scenario(GOOD, tmp_path / "s.yaml")
    assert sc.seed == 0 and sc.wall_height == 2.5 and sc.plan is None
    assert sc.laser.beams == 360 and sc.laser.range_max == 10.0 and sc.laser.topic == "/scan"
    assert sc.depth is None and sc.points is None
    assert sc.robot.waypoints == [(0.0, 1.0, 1.0, 0.0)] and sc.robot.tf_rate == 50.0
    o = sc.objects[0]
    assert (o.id, o.label, o.size, o.present) == ("box0", "static object", (0.4, 0.4, 0.5), [(1.0, 3.0)])
    doc = edited(objects=[{"kind": "sphere", "pose": {"x": 1, "y": 1}, "present": [[2, None]]}])
    o = parse_scenario(doc, "s.yaml").objects[0]
    assert (o.label, o.radius, o.z, o.present) == ("ball", 0.1, 0.1, [(2.0, 5.0)])


def test_sample_scenarios_are_valid():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios"
    files = sorted(root.glob("*/scenario.yaml"))
    assert len(files) >= 6
    for f in files:
        load_scenario(f)


def test_duplicate_ids(tmp_path):
    doc = edited(doors=[{"id": "box0", "from": [0, 0], "to": [1, 0]}])
    with pytest.raises(ConfigError, match=r"doors\[0\]\.id: id 'box0' is used twice"):
        parse_scenario(doc, "s.yaml")


def test_door_kinds_and_defaults():
    doc = edited(doors=[
        {"id": "a", "from": [0, 0], "to": [1, 0], "closed": [[1, 2]]},
        {"id": "b", "kind": "hinged", "from": [0, 1], "to": [1, 1]},
        {"id": "c", "kind": "hinged", "from": [0, 2], "to": [1, 2], "swing": "right", "open_angle_deg": 110,
         "motion_s": 0},
        {"id": "d", "kind": "hinged", "from": [0, 3], "to": [1, 3], "swing": -1},
        {"id": "e", "kind": "sliding", "from": [0, 4], "to": [1, 4], "motion_s": 2.5},
    ])  # fmt: skip
    a, b, c, d, e = parse_scenario(doc, "s.yaml").doors
    assert (a.kind, a.closed, a.thickness, a.height) == ("box", [(1.0, 2.0)], 0.04, 2.0)
    assert (b.kind, b.motion_s, b.open_angle_deg, b.swing) == ("hinged", 1.0, 90.0, 1)
    assert (c.motion_s, c.open_angle_deg, c.swing) == (0.0, 110.0, -1)
    assert d.swing == -1
    assert (e.kind, e.motion_s) == ("sliding", 2.5)
