"""Simulator features without a test of their own: the standing robot's yaw sweep and the chair.

The room: walls 0.1 m thick centred on x, y = 0 and 4, so the inner faces are at 0.05 and 3.95.
Sweep (docs/scenarios.md): `still: {x, y, yaw, sweep, period}` gives
yaw(t) = yaw + sweep / 2 * sin(2 pi t / period) degrees.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ltmap_cli.sim.scenario import parse_scenario
from ltmap_cli.sim.scene import World, robot_pose
from ltmap_cli.sim.sensors import render_scan
from ltmap_cli.sim.simulate import Simulator

ROOM = [{"points": [[0, 0], [4, 0], [4, 4], [0, 4], [0, 0]], "thickness": 0.1}]
START_NS = 1_700_000_000 * 10**9  # the default start_time


def make(objects=(), robot=None, laser=None, duration=8):
    return parse_scenario({
        "walls": ROOM, "duration": duration, "seed": 0,
        "robot": robot or {"path": {"still": {"x": 2, "y": 2, "yaw": 0}}},
        "sensors": {"laser": laser or {"beams": 4, "mount": {"xyz": [0, 0, 0.25]}}},
        "objects": list(objects),
    }, "test.yaml")  # fmt: skip


def quat_yaw(q: dict) -> float:
    assert q["x"] == pytest.approx(0.0, abs=1e-12) and q["y"] == pytest.approx(0.0, abs=1e-12)
    return 2 * math.atan2(q["z"], q["w"])


# ----------------------------------------------------------------------------- yaw sweep

SWEEP = {"path": {"still": {"x": 2, "y": 2, "yaw": 30, "sweep": 60, "period": 8}}}
# yaw = 30 + 30 sin(2 pi t / 8) degrees
YAW_AT = {
    0.0: 30.0,
    1.0: 30.0 + 30.0 * math.sqrt(0.5),
    2.0: 60.0,
    4.0: 30.0,
    6.0: 0.0,
    7.0: 30.0 - 30.0 * math.sqrt(0.5),
}


def test_sweep_poses_at_given_times():
    sc = make(robot=SWEEP)
    assert YAW_AT[1.0] == pytest.approx(51.2132034, abs=1e-7)
    for t, yaw in YAW_AT.items():
        x, y, a = robot_pose(sc, t)
        assert (x, y) == (2.0, 2.0)
        assert math.degrees(a) == pytest.approx(yaw, abs=1e-9), t
    # no sweep: the yaw stays put
    still = make(robot={"path": {"still": {"x": 2, "y": 2, "yaw": 30}}})
    assert math.degrees(robot_pose(still, 2.0)[2]) == pytest.approx(30.0, abs=1e-12)


def test_sweep_in_the_log_tf_odom_and_ground_truth():
    sc = make(robot=SWEEP)
    sim = Simulator(sc)
    tf_yaw, odom_wz, scans = {}, {}, {}
    for topic, _, stamp, fields in sim.messages():
        t = round((stamp - START_NS) / 1e9, 6)
        if topic == "/tf":
            for tr in fields["transforms"]:
                if tr["child_frame_id"] == "base_link":
                    assert tr["header"]["frame_id"] == "odom"
                    assert (tr["transform"]["translation"]["x"], tr["transform"]["translation"]["y"]) == \
                        pytest.approx((2.0, 2.0), abs=1e-12)  # fmt: skip
                    tf_yaw[t] = math.degrees(quat_yaw(tr["transform"]["rotation"]))
                else:  # map -> odom: no drift, identity
                    assert quat_yaw(tr["transform"]["rotation"]) == pytest.approx(0.0, abs=1e-12)
        elif topic == "/odom":
            odom_wz[t] = fields["twist"]["twist"]["angular"]["z"]
        elif topic == "/scan":
            scans[t] = np.asarray(fields["ranges"], dtype=np.float64)
    for t, yaw in YAW_AT.items():
        assert tf_yaw[t] == pytest.approx(yaw, abs=1e-9), t
    # d yaw / dt = 30 deg * 2 pi / 8 s * cos(2 pi t / 8): 7.5 pi deg/s at t = 0, 0 at t = 2, -7.5 pi at t = 4
    w0 = math.radians(7.5 * math.pi)
    assert w0 == pytest.approx(0.4112335, abs=1e-7)
    assert odom_wz[0.0] == pytest.approx(w0, rel=1e-4)
    assert odom_wz[2.0] == pytest.approx(0.0, abs=1e-3)
    assert odom_wz[4.0] == pytest.approx(-w0, rel=1e-4)
    # the laser's 0 deg beam (index 2 of 4) turns with the robot: at t = 2 (yaw 60) it meets the north
    # face y = 3.95 at 1.95 / sin 60 = 2.2516660; at t = 6 (yaw 0) the east face at 1.95
    assert 1.95 / math.sin(math.radians(60)) == pytest.approx(2.2516660, abs=1e-7)
    assert scans[2.0][2] == pytest.approx(1.95 / math.sin(math.radians(60)), abs=1e-5)  # float32
    assert scans[6.0][2] == pytest.approx(1.95, abs=1e-5)
    assert scans[1.0][2] == pytest.approx(1.95 / math.sin(math.radians(YAW_AT[1.0])), abs=1e-5)
    gt = {p["t"]: p for p in sim.ground_truth()["robot"]["path"]}
    for t, yaw in YAW_AT.items():
        assert (gt[t]["x"], gt[t]["y"]) == (2.0, 2.0)
        assert gt[t]["yaw_deg"] == pytest.approx(yaw, abs=1e-6), t


# ----------------------------------------------------------------------------- chair

# default chair: 0.45 x 0.45, seat 0.45 m high and 0.04 thick (z 0.41..0.45), legs 0.04 square at
# local (+-0.205, +-0.205) from z 0 to 0.41, backrest 0.04 x 0.45 on the local -x side (x = -0.205)
# from z 0.45 to 0.9. At (3, 2) turned 180 deg the backrest is on the world +x side: x 3.185..3.225.
CHAIR = {"id": "chair", "kind": "chair", "pose": {"x": 3, "y": 2, "yaw": 180}}


def east(sc, y: float, z: float) -> float:
    """Range of a ray from (2, y, z) toward +x at t = 0."""
    return float(World(sc).at(0.0).cast(np.array([[2.0, y, z]]), np.array([[1.0, 0.0, 0.0]]))[0])


@pytest.mark.parametrize("y, z, want, what", [
    (2.0, 0.25, 1.95, "between the legs, under the seat: the east wall"),
    (2.0 - 0.205, 0.25, 0.775, "a front leg (x 2.775..2.815)"),
    (2.0 + 0.205, 0.25, 0.775, "the other front leg"),
    (2.0 - 0.23, 0.25, 1.95, "just beside the leg (outside the chair's 2.225..1.775 span)"),
    (2.0, 0.43, 0.775, "the seat's edge at x = 3 - 0.225"),
    (2.0, 0.40, 1.95, "just under the seat (0.41)"),
    (2.0, 0.70, 1.185, "over the seat: the backrest's face at 3 + 0.205 - 0.02"),
    (2.0, 0.95, 1.95, "over the backrest (0.9)"),
])  # fmt: skip
def test_chair_parts_by_hand(y, z, want, what):
    sc = make([CHAIR])
    assert east(sc, y, z) == pytest.approx(want, abs=1e-9), what


def test_chair_sized_and_turned_90():
    # 0.5 (local x -> world y) x 0.4 (local y -> world -x), seat 0.5 high and 0.05 thick, legs 0.05,
    # backrest to 1.0 m on the local -x side: world y = 2 - 0.225 = 1.775, spanning x 2.8..3.2.
    chair = {"id": "c", "kind": "chair", "pose": {"x": 3, "y": 2, "yaw": 90}, "size": [0.5, 0.4, 0.5],
             "leg": 0.05, "top_thickness": 0.05, "back_height": 1.0}  # fmt: skip
    sc = make([chair])
    assert east(sc, 2.0, 0.3) == pytest.approx(1.95, abs=1e-9)  # between the legs (y 1.775, 2.225)
    assert east(sc, 1.775, 0.3) == pytest.approx(0.8, abs=1e-9)  # leg at x 2.825 +- 0.025
    assert east(sc, 2.0, 0.47) == pytest.approx(0.8, abs=1e-9)  # seat (z 0.45..0.5) edge at x 2.8
    assert east(sc, 2.0, 0.8) == pytest.approx(1.95, abs=1e-9)  # the backrest is not at y = 2
    assert east(sc, 1.775, 0.8) == pytest.approx(0.8, abs=1e-9)  # but at y 1.75..1.8
    assert east(sc, 1.775, 1.05) == pytest.approx(1.95, abs=1e-9)  # over it
    gt = {o["id"]: o for o in Simulator(sc).ground_truth()["objects"]}["c"]
    assert gt["kind"] == "chair" and len(gt["parts"]) == 6  # seat, four legs, backrest
    seat, back = gt["parts"][0], gt["parts"][-1]
    assert seat["center"] == pytest.approx([3.0, 2.0, 0.475])
    assert seat["size"] == pytest.approx([0.5, 0.4, 0.05])
    assert back["center"] == pytest.approx([3.0, 1.775, 0.75])
    assert back["size"] == pytest.approx([0.05, 0.4, 0.5])


@pytest.mark.parametrize("robot_y, mount_z, want", [
    (2.0 - 0.205, 0.25, 0.775),  # laser at leg height in line with a leg
    (2.0, 0.25, 1.95),  # at leg height between the legs
    (2.0, 0.43, 0.775),  # at seat height
])  # fmt: skip
def test_rendered_scan_sees_the_chair(robot_y, mount_z, want):
    sc = make([CHAIR], robot={"path": {"still": {"x": 2, "y": robot_y, "yaw": 0}}},
              laser={"beams": 4, "mount": {"xyz": [0, 0, mount_z]}})  # fmt: skip
    r = render_scan(World(sc).at(0.0), sc.laser, robot_pose(sc, 0.0))
    assert r[2] == pytest.approx(want, abs=1e-9)  # beam 2 of 4 points +x
    assert r[0] == pytest.approx(1.95, abs=1e-9)  # behind: the west wall face at 0.05
