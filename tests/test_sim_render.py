"""Ray casting of the simulator against hand-computed geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ltmap_cli.sim.scenario import parse_scenario
from ltmap_cli.sim.scene import World, robot_pose
from ltmap_cli.sim.sensors import optical_matrix, render_depth, render_scan

# a 4 m square room: walls 0.1 m thick centred on x, y = 0 and 4, so the inner faces are at 0.05 and 3.95
ROOM = [{"points": [[0, 0], [4, 0], [4, 4], [0, 4], [0, 0]], "thickness": 0.1}]


def scenario(objects=(), robot=None, laser=None, depth=None, **extra):
    doc = {
        "walls": ROOM, "duration": 10, "seed": 0,
        "robot": robot or {"path": {"still": {"x": 2, "y": 2, "yaw": 0}}},
        "sensors": {"laser": laser or {"beams": 8, "mount": {"xyz": [0, 0, 0.25]}}},
        "objects": list(objects), **extra,
    }  # fmt: skip
    if depth is not None:
        doc["sensors"]["depth"] = depth
    return parse_scenario(doc, "test.yaml")


def scan_at(sc, t=0.0):
    return render_scan(World(sc).at(t), sc.laser, robot_pose(sc, t))


def test_laser_at_the_centre_of_a_square_room():
    # 8 beams over 360 deg start at -180 deg; robot yaw 10 deg: world angles -170, -125, ..., 145.
    # From (2, 2) every inner face is 1.95 m away: r = 1.95 / max(|cos a|, |sin a|).
    sc = scenario(robot={"path": {"still": {"x": 2, "y": 2, "yaw": 10}}})
    r = scan_at(sc)
    c10 = 1.95 / math.cos(math.radians(10))  # 1.95 / 0.9848078 = 1.9800819
    c35 = 1.95 / math.cos(math.radians(35))  # 1.95 / 0.8191520 = 2.3805104
    assert c10 == pytest.approx(1.9800819, abs=1e-6)
    assert c35 == pytest.approx(2.3805104, abs=1e-6)
    np.testing.assert_allclose(r, [c10, c35, c10, c35, c10, c35, c10, c35], atol=1e-9)


def test_laser_mounted_off_centre_and_turned():
    # laser 0.2 m ahead of base_link, turned +90 deg; robot at (1, 1) facing +y (yaw 90):
    # the laser is at (1, 1.2) and its 0 deg beam points to -x: the west wall face x = 0.05 is 0.95 m away.
    sc = scenario(
        robot={"path": {"still": {"x": 1, "y": 1, "yaw": 90}}},
        laser={"beams": 4, "mount": {"xyz": [0.2, 0, 0.3], "rpy": [0, 0, 90]}},
    )
    r = scan_at(sc)
    # beams at -180, -90, 0, 90 deg in the laser frame -> world +x, +y, -x, -y
    np.testing.assert_allclose(r, [3.95 - 1.0, 3.95 - 1.2, 1.0 - 0.05, 1.2 - 0.05], atol=1e-9)


@pytest.mark.parametrize("obj, expected", [
    ({"kind": "box", "pose": {"x": 3, "y": 2}, "size": [0.4, 0.4, 0.5]}, 2.8 - 2.0),
    ({"kind": "box", "pose": {"x": 3, "y": 2, "yaw": 45}, "size": [0.4, 0.4, 0.5]}, 1.0 - 0.2 * math.sqrt(2)),
    ({"kind": "cylinder", "pose": {"x": 3, "y": 2}, "radius": 0.2, "height": 0.5}, 0.8),
    ({"kind": "sphere", "pose": {"x": 3, "y": 2, "z": 0.25}, "radius": 0.2}, 0.8),
    ({"kind": "table", "pose": {"x": 3.5, "y": 2}, "size": [1.0, 0.8, 0.75], "leg": 0.05}, None),
])  # fmt: skip
def test_laser_hits_objects_at_the_right_distance(obj, expected):
    sc = scenario([obj], laser={"beams": 4, "mount": {"xyz": [0, 0, 0.25]}})
    r = scan_at(sc)  # beam 2 is straight ahead (+x) from (2, 2)
    if expected is None:  # table: the 0 deg beam passes between the legs (|y - 2| = 0.375 m) to the wall
        assert r[2] == pytest.approx(1.95, abs=1e-9)
    else:
        assert r[2] == pytest.approx(expected, abs=1e-9)
    assert r[0] == pytest.approx(1.95, abs=1e-9)  # behind: the wall


def test_table_legs_in_the_laser_plane():
    # table at (3.5, 2) turned 90 deg: a leg (0.05 square) centred on y = 2 at x = 3.5 - (0.8 - 0.05) / 2
    sc = scenario(
        [{"kind": "table", "pose": {"x": 3.5, "y": 2.0, "yaw": 90}, "size": [1.0, 0.8, 0.75]}],
        robot={"path": {"still": {"x": 2, "y": 1.775, "yaw": 0}}},
        laser={"beams": 4, "mount": {"xyz": [0, 0, 0.25]}},
    )
    # the legs' centres: local (+-0.475, +-0.375) -> world (3.5 -+ 0.375, 2 +- 0.475); y = 1.525 and 2.475.
    # Robot at y = 1.775: between them, the beam goes to the wall
    assert scan_at(sc)[2] == pytest.approx(1.95, abs=1e-9)
    sc2 = scenario(
        [{"kind": "table", "pose": {"x": 3.5, "y": 2.0, "yaw": 90}, "size": [1.0, 0.8, 0.75]}],
        robot={"path": {"still": {"x": 2, "y": 1.525, "yaw": 0}}},
        laser={"beams": 4, "mount": {"xyz": [0, 0, 0.25]}},
    )
    # the near leg's face: x = 3.5 - 0.375 - 0.025 = 3.1
    assert scan_at(sc2)[2] == pytest.approx(1.1, abs=1e-9)


def test_low_box_is_below_the_laser_plane():
    sc = scenario([{"kind": "box", "pose": {"x": 3, "y": 2}, "size": [0.4, 0.4, 0.2]}])
    assert scan_at(sc)[4] == pytest.approx(1.95, abs=1e-9)  # 8 beams: index 4 is 0 deg


def test_presence_intervals():
    sc = scenario(
        [{"kind": "box", "pose": {"x": 3, "y": 2}, "size": [0.4, 0.4, 0.5], "present": [[2, 5], [7, None]]}],
        laser={"beams": 4, "mount": {"xyz": [0, 0, 0.25]}},
    )
    for t, want in [
        (0.0, 1.95),
        (1.99, 1.95),
        (2.0, 0.8),
        (4.99, 0.8),
        (5.0, 1.95),
        (6.5, 1.95),
        (7.0, 0.8),
        (9.9, 0.8),
    ]:
        assert scan_at(sc, t)[2] == pytest.approx(want, abs=1e-9), t


def test_door_closed_only_in_its_intervals():
    sc = scenario(
        doors=[{"id": "d", "from": [3, 1], "to": [3, 3], "thickness": 0.04, "closed": [[1, 2]]}],
        laser={"beams": 4, "mount": {"xyz": [0, 0, 0.25]}},
    )
    assert scan_at(sc, 0.5)[2] == pytest.approx(1.95, abs=1e-9)
    assert scan_at(sc, 1.5)[2] == pytest.approx(1.0 - 0.02, abs=1e-9)


def test_person_walks_along_the_path():
    sc = scenario(
        people=[{"id": "p", "radius": 0.2, "path": [{"t": 1, "x": 3, "y": 0.5}, {"t": 3, "x": 3, "y": 3.5}]}],
        laser={"beams": 4, "mount": {"xyz": [0, 0, 0.25]}},
    )
    assert scan_at(sc, 0.5)[2] == pytest.approx(1.95, abs=1e-9)  # not yet there
    assert scan_at(sc, 2.0)[2] == pytest.approx(0.8, abs=1e-9)  # at (3, 2): 1 m - radius
    assert scan_at(sc, 3.5)[2] == pytest.approx(1.95, abs=1e-9)  # gone


def test_moving_robot_interpolates_waypoints():
    sc = scenario(
        robot={
            "path": {"waypoints": [{"t": 0, "x": 1, "y": 2, "yaw": 0}, {"t": 4, "x": 3, "y": 2, "yaw": 90}]}
        }
    )
    x, y, yaw = robot_pose(sc, 1.0)
    assert (x, y, math.degrees(yaw)) == pytest.approx((1.5, 2.0, 22.5))
    assert robot_pose(sc, 9.0)[0] == pytest.approx(3.0)  # holds the last pose


DEPTH = {
    "width": 640,
    "height": 480,
    "fx": 525,
    "fy": 525,
    "cx": 319.5,
    "cy": 239.5,
    "mount": {"xyz": [0, 0, 1.0]},
    "range_max": 8,
}


def test_depth_camera_facing_a_wall_two_metres_ahead():
    # the camera at x = 1.95 faces the east wall's inner face at x = 3.95: every pixel sees it
    # (half-angles atan(320/525) and atan(240/525): 1.22 m sideways, z 0.09..1.91 at 2 m) at z-depth 2.0
    sc = scenario(robot={"path": {"still": {"x": 1.95, "y": 2, "yaw": 0}}}, depth=DEPTH)
    z = render_depth(World(sc).at(0.0), sc.depth, robot_pose(sc, 0.0))
    assert z.shape == (480, 640)
    np.testing.assert_allclose(z, 2.0, atol=1e-9)


def test_depth_camera_optical_frame_axes():
    sc = scenario(depth=DEPTH)
    T = optical_matrix(sc.depth)
    # optical z is base x (forward), optical x is base -y (right), optical y is base -z (down)
    np.testing.assert_allclose(T[:3, 2], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(T[:3, 0], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(T[:3, 1], [0, 0, -1], atol=1e-12)


def test_depth_sees_floor_table_top_and_ball():
    # looking straight down (pitch 90) from 1.5 m: the floor at 1.5, a table top (0.75 m) at 0.75,
    # a ball of radius 0.1 on the floor at 1.5 - 0.2
    down = {
        **DEPTH,
        "width": 64,
        "height": 48,
        "fx": 52.5,
        "fy": 52.5,
        "cx": 31.5,
        "cy": 23.5,
        "mount": {"xyz": [0, 0, 1.5]},
        "pitch": 90,
    }
    robot = {"path": {"still": {"x": 2, "y": 2, "yaw": 0}}}
    sc = scenario(robot=robot, depth=down)
    z = render_depth(World(sc).at(0.0), sc.depth, robot_pose(sc, 0.0))
    np.testing.assert_allclose(z, 1.5, atol=1e-9)  # the floor plane, z-depth constant
    sc = scenario(
        [{"kind": "table", "pose": {"x": 2, "y": 2}, "size": [1.6, 1.6, 0.75]}], robot=robot, depth=down
    )
    z = render_depth(World(sc).at(0.0), sc.depth, robot_pose(sc, 0.0))
    assert z[23, 31] == pytest.approx(0.75, abs=1e-9)
    sc = scenario([{"kind": "sphere", "pose": {"x": 2, "y": 2}, "radius": 0.1}], robot=robot, depth=down)
    z = render_depth(World(sc).at(0.0), sc.depth, robot_pose(sc, 0.0))
    # pixel (31, 23) looks along (a, a, 1), a = 0.5 / 52.5, in the optical frame; the sphere's centre is
    # 1.4 m down the axis: |t (a, a, 1) - (0, 0, 1.4)| = 0.1 gives t = (1.4 - sqrt(1.96 - A 1.95)) / A,
    # A = 2 a^2 + 1: 1.3015485 (1.3 on the axis)
    a2 = 2 * (0.5 / 52.5) ** 2 + 1
    assert z[23, 31] == pytest.approx((1.4 - math.sqrt(1.96 - a2 * 1.95)) / a2, abs=1e-9)
    assert z[23, 31] == pytest.approx(1.3015485, abs=1e-7)
    assert z[0, 0] == pytest.approx(1.5, abs=1e-9)


def test_depth_camera_pitched_down_sees_the_floor_at_the_right_distance():
    # camera at 1.0 m pitched 30 deg down: the optical axis meets the floor at 1 / sin(30) = 2 m
    sc = scenario(robot={"path": {"still": {"x": 0.5, "y": 2, "yaw": 0}}}, depth={**DEPTH, "pitch": 30})
    z = render_depth(World(sc).at(0.0), sc.depth, robot_pose(sc, 0.0))
    # the centre pixel (319.5, 239.5) lies between four pixels; pixel (320, 240) is 0.5 px off axis
    v_off = 0.5 / 525
    expected = 1.0 / (
        math.sin(math.radians(30)) + v_off * math.cos(math.radians(30))
    )  # z-depth along the axis
    assert z[240, 320] == pytest.approx(expected, rel=1e-9)


def test_plan_walls_come_from_the_svg(tmp_path):
    svg = tmp_path / "room.svg"
    svg.write_text(
        '<svg xmlns="http://www.w3.org/2000/svg" width="4000mm" height="4000mm" viewBox="0 0 4000 4000">'
        '<g id="walls" style="fill:none;stroke:#000;stroke-width:100">'
        '<path d="M 0,0 H 4000 V 4000 H 0 Z"/></g>'
        '<g id="doors"><path d="M 0,1000 V 3000" style="stroke:#f00;stroke-width:20"/></g></svg>'
    )
    doc = {
        "plan": "room.svg",
        "duration": 1,
        "robot": {"path": {"still": {"x": 2, "y": 2, "yaw": 10}}},
        "sensors": {"laser": {"beams": 8, "mount": {"xyz": [0, 0, 0.25]}}},
    }
    sc = parse_scenario(doc, tmp_path / "s.yaml")
    r = render_scan(World(sc).at(0.0), sc.laser, robot_pose(sc, 0.0))
    c10 = 1.95 / math.cos(math.radians(10))
    c35 = 1.95 / math.cos(math.radians(35))
    np.testing.assert_allclose(r, [c10, c35, c10, c35, c10, c35, c10, c35], atol=1e-6)


# ----------------------------------------------------------------------------- moving doors

# an interior wall on x = 3 (faces at 2.95 and 3.05) with a 1 m opening at y 1.5..2.5; the door spans
# the opening, hinge at `from` = (3, 1.5); a door open for t < 5 closes over 2 s to be closed at 5..7
# and opens over 2 s after 7
OPENING = [{"points": [[3, 0], [3, 1.5]], "thickness": 0.1}, {"points": [[3, 2.5], [3, 4]], "thickness": 0.1}]


def door_scenario(**door):
    return scenario(
        walls=ROOM + OPENING,
        doors=[{"id": "d", "from": [3, 1.5], "to": [3, 2.5], "thickness": 0.04, "closed": [[5, 7]], **door}],
        laser={"beams": 4, "mount": {"xyz": [0, 0, 0.25]}},
    )


def across_the_opening(sc, t, ys):
    """Ranges of rays parallel to +x from x = 2 at the heights y, through the opening."""
    o = np.array([[2.0, y, 0.25] for y in ys])
    return World(sc).at(t).cast(o, np.tile([1.0, 0.0, 0.0], (len(ys), 1)))


@pytest.mark.parametrize("swing, t", [("right", 4.0), ("left", 4.0), (-1, 8.0), (1, 8.0)])
def test_hinged_door_halfway_through_its_swing(swing, t):
    # closed 5..7, motion_s 2: at t = 4 (1 s into the closing) and t = 8 (1 s into the opening) the
    # leaf is at 45 deg. Swing right (-1, clockwise seen from above, away from the robot): the leaf
    # from the hinge (3, 1.5) points along (sin 45, cos 45); the beam y = 2 meets its centre line 0.5 m
    # past the hinge along y, at x = 3.5, and its near face (0.02 m off, toward (-cos 45, sin 45))
    # 0.02 / cos 45 = 0.04 / sqrt 2 earlier: r = 1.5 - 0.0282843 = 1.4717157. Swing left (+1, toward
    # the robot): the leaf points along (-sin 45, cos 45), meets the beam at x = 2.5: r = 0.4717157.
    sc = door_scenario(kind="hinged", swing=swing, motion_s=2)
    want = {"right": 1.5, -1: 1.5, "left": 0.5, 1: 0.5}[swing] - 0.04 / math.sqrt(2)
    assert want == pytest.approx(1.4717157 if swing in ("right", -1) else 0.4717157, abs=1e-7)
    assert scan_at(sc, t)[2] == pytest.approx(want, abs=1e-9)


def test_hinged_door_closed_open_and_timing():
    sc = door_scenario(kind="hinged", swing="right", motion_s=2)
    ys = np.linspace(1.6, 2.4, 9)
    # closed (5 <= t < 7): the leaf fills the opening, its face at x = 2.98
    np.testing.assert_allclose(across_the_opening(sc, 5.0, ys), 0.98, atol=1e-9)
    np.testing.assert_allclose(across_the_opening(sc, 6.99, ys), 0.98, atol=1e-9)
    # fully open (t <= 3, t >= 9): the leaf lies along y = 1.5 (|y - 1.5| <= 0.02), every ray through
    # the opening reaches the room's east wall at 3.95
    for t in (0.0, 3.0, 9.0, 9.9):
        np.testing.assert_allclose(across_the_opening(sc, t, ys), 1.95, atol=1e-9)
    # the angle is linear in time: at t = 4.5 (three quarters of the closing), 22.5 deg open; the y = 2
    # ray meets the centre line at x = 3 + 0.5 tan(22.5 deg), the near face 0.02 / cos(22.5 deg) earlier
    a = math.radians(22.5)
    want = 1.0 + 0.5 * math.tan(a) - 0.02 / math.cos(a)
    assert want == pytest.approx(1.1854589, abs=1e-7)
    assert across_the_opening(sc, 4.5, [2.0])[0] == pytest.approx(want, abs=1e-9)
    # a smaller open angle: 30 deg right, fully open; the ray at y = 2 meets the leaf 0.5 m past the hinge
    # along y, at x = 3 + 0.5 tan 30 deg, near face 0.02 / cos 30 deg earlier
    sc = door_scenario(kind="hinged", swing="right", open_angle_deg=30, motion_s=0)
    a = math.radians(30)
    want = 1.0 + 0.5 * math.tan(a) - 0.02 / math.cos(a)
    assert across_the_opening(sc, 0.0, [2.0])[0] == pytest.approx(want, abs=1e-9)
    assert across_the_opening(sc, 5.0, [2.0])[0] == pytest.approx(0.98, abs=1e-9)  # motion_s 0: at once


def test_sliding_door_half_open_blocks_half_the_opening():
    sc = door_scenario(kind="sliding", motion_s=2)
    ys = np.array([1.6, 1.7, 1.8, 1.9, 2.1, 2.2, 2.3, 2.4])
    # t = 8: 1 s into the 2 s opening, the leaf has slid 0.5 m toward `from`: it spans y 1.0..2.0
    r = across_the_opening(sc, 8.0, ys)
    np.testing.assert_allclose(r[:4], 0.98, atol=1e-9)  # the leaf's face at x = 2.98
    np.testing.assert_allclose(r[4:], 1.95, atol=1e-9)  # through, to the east wall
    np.testing.assert_allclose(across_the_opening(sc, 6.0, ys), 0.98, atol=1e-9)  # closed
    # open: the leaf is inside the wall (y 0.5..1.5, thinner than it): the whole opening is free
    np.testing.assert_allclose(across_the_opening(sc, 0.0, ys), 1.95, atol=1e-9)
    np.testing.assert_allclose(across_the_opening(sc, 9.0, ys), 1.95, atol=1e-9)
    # closing, 1.5 s of 2 done at t = 4.5: a quarter open, the leaf spans y 1.25..2.25
    r = across_the_opening(sc, 4.5, [2.2, 2.3])
    np.testing.assert_allclose(r, [0.98, 1.95], atol=1e-9)


def test_box_door_kind_is_the_default():
    a = door_scenario()
    b = door_scenario(kind="box")
    assert a.doors[0].kind == b.doors[0].kind == "box"
    ys = np.linspace(1.6, 2.4, 9)
    for t in (0.0, 4.0, 4.99, 5.0, 6.99, 7.0, 8.0):
        want = 0.98 if 5 <= t < 7 else 1.95  # appears and disappears at once, no motion
        np.testing.assert_allclose(across_the_opening(a, t, ys), want, atol=1e-9)
        np.testing.assert_allclose(across_the_opening(b, t, ys), want, atol=1e-9)


def test_door_open_fraction_with_close_intervals():
    from ltmap_cli.sim.scene import door_motion, door_open_fraction

    sc = door_scenario(kind="sliding", motion_s=2, closed=[[1, 3], [4, 6]])
    d = sc.doors[0]
    # starts part way through the closing (1 s of 2 left at t = 0); between the intervals (1 s apart)
    # it opens for 0.5 s and closes again, never fully open
    got = [door_open_fraction(d, t) for t in (0.0, 0.5, 1.0, 3.0, 3.25, 3.5, 3.75, 4.0, 7.0, 8.0)]
    np.testing.assert_allclose(got, [0.5, 0.25, 0, 0, 0.125, 0.25, 0.125, 0, 0.5, 1.0])
    assert door_motion(d, 10.0) == [[0.0, 1.0], [3.0, 4.0], [6.0, 8.0]]


def test_moving_doors_in_the_ground_truth():
    from ltmap_cli.sim.simulate import Simulator

    sc = door_scenario(kind="hinged", swing="right", motion_s=2)
    gt = {o["id"]: o for o in Simulator(sc).ground_truth()["objects"]}["d"]
    assert (gt["kind"], gt["shape"], gt["category"]) == ("door", "hinged", "door")
    assert gt["present"] == [[5.0, 7.0]]  # fully closed
    assert (gt["hinge"], gt["swing"], gt["open_angle_deg"]) == ([3.0, 1.5], "right", 90.0)
    assert gt["motion_s"] == 2.0
    assert gt["moving"] == [[3.0, 5.0], [7.0, 9.0]]
    assert gt["parts"][0]["center"] == pytest.approx([3.0, 2.0, 1.0])  # closed: fills the opening
    assert gt["parts"][0]["size"] == pytest.approx([1.0, 0.04, 2.0])
    assert gt["open_parts"][0]["center"] == pytest.approx([3.5, 1.5, 1.0])  # turned 90 deg clockwise
    assert gt["open_parts"][0]["yaw_deg"] == pytest.approx(0.0)
    box = {o["id"]: o for o in Simulator(door_scenario()).ground_truth()["objects"]}["d"]
    assert sorted(box) == ["category", "from", "id", "kind", "parts", "present", "shape", "to"]
    assert box["shape"] == "box"


def test_depth_edges_by_hand():
    """A step from 2 m to 3 m between columns 4 and 5 (50 %: an edge), a 2 % step between rows
    2 and 3 (none), and a pixel without a return at the corner: width 1 marks the two pixels at
    each edge, width 2 one more on each side."""
    from ltmap_cli.sim.sensors import depth_edges

    z = np.full((5, 8), 2.0)
    z[:, 5:] = 3.0
    z[3:, :5] = 2.04
    z[0, 0] = np.inf
    one = np.zeros((5, 8), dtype=int)
    one[:, 4:6] = 1
    one[0, 0] = one[0, 1] = one[1, 0] = 1
    assert np.array_equal(depth_edges(z, 1).astype(int), one)
    two = one.copy()
    two[:, 3] = two[:, 6] = 1
    two[0, 2] = two[1, 1] = two[2, 0] = 1
    assert np.array_equal(depth_edges(z, 2).astype(int), two)
