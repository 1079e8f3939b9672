"""`replay --mcap-out`: the MCAP read back with the mcap reader and the ROS 2 decoder.

The room of test_replay, plus a table top at 0.75 m seen only by a point cloud (a depth camera
1.2 m up): the laser at 0.3 m passes under it, the fused scan must stop at it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from logfactory import cloud, scan, tf, write_log, yaw_quat
from test_replay import MOUNT, ROBOT, T0, beam_angles, cast, laser_pose, run

from ltmap_cli.io.mapfile import read_map_yaml

TABLE = (-0.9, -0.3, -0.6, 0.3)  # x0, y0, x1, y1: top at 0.75 m, no legs the laser could see
CAM = (1.0, 0.5, 1.2)


def table_points() -> np.ndarray:
    xs = np.arange(TABLE[0] + 0.01, TABLE[2], 0.02)
    ys = np.arange(TABLE[1] + 0.01, TABLE[3], 0.02)
    gx, gy = np.meshgrid(xs, ys)
    world = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, 0.76)], axis=1)
    return (world - np.array(CAM)).astype(np.float32)  # in the camera frame (axes as odom)


def table_log(path, duration_s=17.0, rate_hz=5.0, cloud_until_s=None):
    msgs = [tf(T0, [("base_link", "laser", MOUNT, (0, 0, 0, 1))], static=True),
            tf(T0, [("odom", "camera", CAM, (0, 0, 0, 1))], static=True)]  # fmt: skip
    x, y, yaw = ROBOT
    amin, inc, _ = beam_angles()
    ranges, _ = cast(False)
    pts = table_points()
    n = int(round(duration_s * rate_hz))
    for i in range(-1, n + 2):
        ns = T0 + int(round(i / rate_hz * 1e9))
        msgs.append(tf(ns, [("odom", "base_link", (x, y, 0.0), yaw_quat(yaw))]))
        if 0 <= i < n:
            msgs.append(scan("/scan", ns, ranges, angle_min=amin, angle_increment=inc, range_min=0.05,
                             range_max=10.0))  # fmt: skip
            if cloud_until_s is None or i / rate_hz < cloud_until_s:
                msgs.append(cloud("/camera/points", ns + 1000, pts, frame_id="camera"))
    return write_log(path, "mcap-ros2", msgs)


def read_back(path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert channel.message_encoding == "cdr"
            out.setdefault(channel.topic, []).append((schema.name, message.log_time, decoded))
    return out


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("mcap")
    log = table_log(tmp / "table.mcap")
    out = tmp / "out"
    r = run(["replay", str(log), "-o", str(out), "-q", "--mcap-out"])
    assert r.exit_code == 0, r.output
    return out, read_back(out / "replay.mcap")


def test_topics_types_and_tf_copied_through(replayed):
    _, msgs = replayed
    assert {t: msgs[t][0][0] for t in msgs} == {
        "/map": "nav_msgs/msg/OccupancyGrid",
        "/long_term_map": "nav_msgs/msg/OccupancyGrid",
        "/ltmap/occupied_voxels": "sensor_msgs/msg/PointCloud2",
        "/scan_fused": "sensor_msgs/msg/LaserScan",
        "/tf": "tf2_msgs/msg/TFMessage",
        "/tf_static": "tf2_msgs/msg/TFMessage",
    }
    assert len(msgs["/scan_fused"]) == 85  # one per laser frame
    assert len(msgs["/tf"]) == 88
    static_children = {t.child_frame_id for _, _, m in msgs["/tf_static"] for t in m.transforms}
    assert static_children == {"laser", "camera"}


def test_final_grid_equals_map_pgm(replayed):
    out, msgs = replayed
    _, _, last = msgs["/map"][-1]
    g = read_map_yaml(out / "map.yaml")
    data = np.asarray(last.data, dtype=np.int8).reshape(last.info.height, last.info.width)
    assert last.info.resolution == pytest.approx(g.resolution)
    assert (last.info.origin.position.x, last.info.origin.position.y) == pytest.approx(g.origin[:2])
    assert np.array_equal(data, g.data)
    assert (data == 100).sum() > 100


def table_beams():
    """(beam index, distance into the table's xy box) of the beams that cross the table."""
    lx, ly, yaw = laser_pose()
    _, _, ang = beam_angles()
    hits_table = []
    for i, a in enumerate(ang):
        th = yaw + a
        dx, dy = math.cos(th), math.sin(th)
        # distance along the beam into the table's xy box (slab method), if it crosses it
        with np.errstate(divide="ignore"):
            tx = sorted(((TABLE[0] - lx) / dx, (TABLE[2] - lx) / dx)) if dx else [-np.inf, np.inf]
            ty = sorted(((TABLE[1] - ly) / dy, (TABLE[3] - ly) / dy)) if dy else [-np.inf, np.inf]
        t_in, t_out = max(tx[0], ty[0]), min(tx[1], ty[1])
        if 0 < t_in < t_out and t_out - t_in > 0.1:
            hits_table.append((i, t_in))
    return hits_table


def test_fused_scan_sees_the_table_top_the_laser_misses(replayed):
    _, msgs = replayed
    _, _, fused = msgs["/scan_fused"][-1]
    fused_r = np.asarray(fused.ranges)
    real_r, _ = cast(False)
    _, _, ang = beam_angles()
    hits_table = table_beams()
    assert len(hits_table) >= 5
    for i, t_in in hits_table:
        assert real_r[i] > t_in + 0.5  # the real laser passes under the table to the wall
        assert fused_r[i] == pytest.approx(t_in, abs=0.08)  # the fused scan stops at the table
    # elsewhere the fused scan sees the walls where the laser does
    others = [i for i in range(len(ang)) if i not in {h[0] for h in hits_table}]
    close = np.abs(fused_r[others] - real_r[others]) < 0.08
    assert close.mean() > 0.9


def test_fused_scan_drops_o_obstacles_no_sensor_updated_within_the_window(tmp_path):
    """The camera sees the table top for the first 2 s only (then looks away: no more clouds).
    Not yet in LT (st_rise_s 15 s), the top is a current obstacle in O while the window (1 s)
    holds a frame that updated it: the fused scan stops at it up to ~3 s, and sees through it
    to the wall from then on (before, a voxel stayed in the scan for as long as O said > 0)."""
    log = table_log(tmp_path / "t.mcap", duration_s=8.0, cloud_until_s=2.0)
    out = tmp_path / "out"
    r = run(["replay", str(log), "-o", str(out), "-q", "--mcap-out"])
    assert r.exit_code == 0, r.output
    fused = read_back(out / "replay.mcap")["/scan_fused"]
    real_r, _ = cast(False)
    beams = table_beams()
    t0 = fused[0][1]
    seen_at = []
    for _, log_time, msg in fused:
        rr = np.asarray(msg.ranges)
        on_table = [abs(rr[i] - t_in) < 0.08 for i, t_in in beams]
        through = [abs(rr[i] - real_r[i]) < 0.08 for i, _ in beams]
        t = (log_time - t0) / 1e9
        if all(on_table):
            seen_at.append(t)
        else:
            assert all(through), f"at {t:.1f} s the fused scan neither stops at the table nor sees the wall"
    assert seen_at and min(seen_at) < 0.5 and 1.8 <= max(seen_at) <= 3.0 + 1e-6


def test_tf_in_the_mcap_is_what_the_replay_used(tmp_path):
    """A log with odometry instead of /tf for odom -> base_link and a wrong laser mount on
    /tf_static, corrected with --tf: replay.mcap holds the odometry poses on /tf and the --tf
    mount (not the log's) on /tf_static, so a viewer places the laser where the replay did."""
    from logfactory import odometry
    from test_replay import room_messages

    msgs = []
    for m in room_messages(0.0, 3.0, pillar=False, static_mount=False):
        if m.topic == "/tf":  # odom -> base_link from nav_msgs/Odometry instead
            x, y, yaw = ROBOT
            msgs.append(odometry("/odom", m.log_time_ns, "odom", "base_link", (x, y, 0.0), yaw_quat(yaw)))
        else:
            msgs.append(m)
    msgs.insert(0, tf(T0, [("base_link", "laser", (5.0, 5.0, 5.0), (0, 0, 0, 1))], static=True))  # wrong
    log = write_log(tmp_path / "odom.mcap", "mcap-ros2", msgs)
    out = tmp_path / "out"
    mount = ",".join(str(v) for v in (*MOUNT, 0, 0, 0))
    r = run(["replay", str(log), "-o", str(out), "-q", "--mcap-out", "--tf", f"base_link:laser={mount}"])
    assert r.exit_code == 0, r.output
    got = read_back(out / "replay.mcap")
    (_, t_static, st), = got["/tf_static"]
    assert t_static == min(m.log_time_ns for m in msgs)  # at the log's start, not at time 0
    (laser,) = [t for t in st.transforms if t.child_frame_id == "laser"]
    assert laser.header.frame_id == "base_link"
    v = laser.transform.translation
    assert (v.x, v.y, v.z) == pytest.approx(MOUNT)
    dyn = [t for _, _, m in got["/tf"] for t in m.transforms]
    assert len(dyn) == sum(1 for m in msgs if m.topic == "/odom")
    assert {(t.header.frame_id, t.child_frame_id) for t in dyn} == {("odom", "base_link")}
    assert dyn[0].transform.translation.x == pytest.approx(ROBOT[0])
