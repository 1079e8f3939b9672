"""`ltmap info` through the real CLI on tiny logs and on the real logs."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner
from logfactory import SUFFIX, camera_info, image, odometry, scan, string, tf, truncate, write_log

from ltmap_cli.cli import cli

S = 1_000_000_000
REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real_logs"


def _run(*args):
    return CliRunner().invoke(cli, ["info", *map(str, args)])


def _robot_log(tmp_path, fmt="mcap-ros2"):
    msgs = []
    for i in range(11):  # 10 Hz laser and tf for 1 s
        t = S + i * S // 10
        msgs.append(tf(t, [("odom", "base_link", (0.1 * i, 0.0, 0.0))]))
        msgs.append(scan("/scan", t + 1, [1.0, 2.0, 3.0]))
    msgs.append(string("/chatter", 2 * S, "hi"))
    msgs.append(image("/camera/color/image_raw", 2 * S, [[1, 2, 3]], encoding="rgb8"))
    msgs.append(odometry("/odom", 2 * S, "odom", "base_link"))
    msgs.sort(key=lambda m: m.log_time_ns)
    return write_log(tmp_path / ("log" + SUFFIX[fmt]), fmt, msgs)


@pytest.mark.parametrize("fmt", ["mcap-ros2", "ros1"])
def test_info_on_a_tiny_log(tmp_path, fmt):
    res = _run(_robot_log(tmp_path, fmt))
    assert res.exit_code == 0, res.output
    out = res.output
    assert f"({fmt})" in out
    assert "duration:  1.00 s" in out
    lines = {ln.split()[0]: ln for ln in out.splitlines() if ln.startswith("/")}
    assert lines["/scan"].split()[1:5] == ["sensor_msgs/msg/LaserScan", "11", "10.0", "Hz"]
    assert lines["/scan"].endswith("uses: laser, frame laser")
    assert lines["/tf"].split()[2] == "11" and lines["/tf"].endswith("uses: tf")
    assert lines["/odom"].endswith("uses: odometry")
    assert lines["/chatter"].split()[1:3] == ["std_msgs/msg/String", "1"]
    assert lines["/camera/color/image_raw"].endswith("skips")
    assert "tf tree:\n  odom\n    base_link  [tf, 11 samples]" in out
    assert "fixed frame: odom" in out
    assert ("/scan: every frame would be skipped: no transform base_link -> laser: frame laser is not in tf; "
            "give its mount with --tf base_link:laser=x,y,z,roll,pitch,yaw") in out
    assert "/camera/color/image_raw would be skipped: Image whose name does not say depth" in out
    assert "(encoding rgb8)" in out


def test_info_with_mount_and_depth_pairing(tmp_path):
    msgs = [tf(S, [("odom", "base_link")]), scan("/scan", S + 1, [1.0]),
            camera_info("/cam/depth/camera_info", S, width=1, height=1, fx=1, fy=1, cx=0, cy=0),
            image("/cam/depth/image_raw", S + 2, [[1000]], frame_id="cam_optical")]
    path = write_log(tmp_path / "log.bag", "ros1", msgs)
    res = _run(path, "--tf", "base_link:laser=0.1,0,0.2,0,0,0", "--tf",
               "/base_link:/cam_optical=0,0,0.5,-1.5708,0,-1.5708")  # (REP 103: the optical axes)
    assert res.exit_code == 0, res.output
    assert "      laser  [user mount]" in res.output
    assert "uses: depth, frame cam_optical (CameraInfo /cam/depth/camera_info)" in res.output
    assert "warnings: none" in res.output
    res = _run(path, "--scan-topic", "/scan")
    assert "/cam/depth/image_raw would be skipped: Image not chosen" in res.output


def test_info_errors_are_one_line_with_status_2(tmp_path):
    res = _run(tmp_path / "missing.bag")
    assert res.exit_code == 2
    assert res.output.strip().splitlines() == [
        f"ltmap: error: log not found: {tmp_path / 'missing.bag'}; give a ROS 1 .bag file, a ROS 2 bag folder "
        f"(with metadata.yaml) or an .mcap file"]
    bad = _robot_log(tmp_path)
    res = _run(bad, "--scan-topic", "/laser")
    assert res.exit_code == 2 and "--scan-topic /laser:" in res.output and "its LaserScan topics: /scan" in res.output
    res = _run(bad, "--tf", "base_link:laser=1,2")
    assert res.exit_code == 2 and "expected parent:child=x,y,z,roll,pitch,yaw" in res.output


def test_info_on_a_truncated_log(tmp_path):
    msgs = [scan("/scan", (i + 1) * S // 10, [1.0] * 20) for i in range(60)]
    path = write_log(tmp_path / "cut.mcap", "mcap-ros2", msgs, chunk_size=600)
    truncate(path, 0.5)
    res = _run(path)
    assert res.exit_code == 2
    assert "log is truncated or corrupt: " in res.output and "--allow-truncated" in res.output.splitlines()[-1]
    res = _run(path, "--allow-truncated")
    assert res.exit_code == 0
    count = int(next(ln for ln in res.output.splitlines() if ln.startswith("/scan")).split()[2])
    assert 0 < count < 60
    assert f"reading stopped after {count} messages" in res.output


@pytest.mark.skipif(not (REAL / "ist_pioneer3dx_test1.bag").exists(), reason=f"real logs not in {REAL}")
def test_info_real_pioneer_bag():
    res = _run(REAL / "ist_pioneer3dx_test1.bag")
    assert res.exit_code == 0, res.output
    lines = {ln.split()[0]: ln.split() for ln in res.output.splitlines() if ln.startswith("/")}
    assert lines["/scan"][1:3] == ["sensor_msgs/msg/LaserScan", "311"]
    assert lines["/pose"][1:3] == ["nav_msgs/msg/Odometry", "313"]
    assert lines["/tf"][2] == "317"
    assert "    base_link  [tf, 317 samples]" in res.output  # every sample, not the 10 s window
    assert lines["/sonar"][1] == "p2os_msgs/msg/SonarArray"
    assert "duration:  31.3" in res.output
    assert "give its mount with --tf base_link:laser=x,y,z,roll,pitch,yaw" in res.output
    res = _run(REAL / "ist_pioneer3dx_test1.bag", "--tf", "base_link:laser=0.1,0,0.3,0,0,0")
    assert res.exit_code == 0 and "warnings: none" in res.output


@pytest.mark.skipif(not (REAL / "comprobo22_macfirst_floor_take_2").exists(), reason=f"real logs not in {REAL}")
def test_info_real_comprobo_bag():
    res = _run(REAL / "comprobo22_macfirst_floor_take_2")
    assert res.exit_code == 0, res.output
    lines = {ln.split()[0]: ln.split() for ln in res.output.splitlines() if ln.startswith("/")}
    assert lines["/scan"][1:3] == ["sensor_msgs/msg/LaserScan", "357"]
    assert lines["/odom"][2] == "920" and lines["/tf"][2] == "953" and lines["/tf_static"][2] == "2"
    assert "(ros2-sqlite3)" in res.output and "duration:  46.2" in res.output
    assert "      rplidar_link  [static]" in res.output
    assert "fixed frame: odom" in res.output
    assert "warnings: none" in res.output


def test_info_and_replay_on_a_scan_whose_angle_max_disagrees_with_its_ranges(tmp_path):
    """Replay places beam i at angle_min + i * angle_increment (as ROS does) and warns once with
    the count; info says so on the first scan."""
    msgs = [tf(S, [("odom", "laser")]), tf(S + 5 * S // 10, [("odom", "laser")])]
    msgs += [scan("/scan", S + i * S // 10, [1.0, 1.0, 1.0], angle_min=0.0, angle_increment=0.1, angle_max=1.0)
             for i in range(1, 4)]
    msgs += [scan("/laser2", S + 2, [1.0, 1.0, 1.0], angle_min=0.0, angle_increment=0.1, frame_id="laser")]
    msgs.sort(key=lambda m: m.log_time_ns)
    path = write_log(tmp_path / "bad.mcap", "mcap-ros2", msgs)
    res = _run(path)
    assert res.exit_code == 0, res.output
    warned = [ln for ln in res.output.splitlines() if "disagrees with its" in ln]
    assert len(warned) == 1, res.output  # /laser2 is consistent
    assert warned[0].startswith("  - /scan: angle_max 1 disagrees with its 3 ranges from angle_min 0 by "
                                "angle_increment 0.1 (last beam at 0.2); replay places beam i at angle_min")
    replay = CliRunner().invoke(cli, ["replay", str(path), "-o", str(tmp_path / "o"), "--no-plots", "-q"])
    assert replay.exit_code == 0, replay.output
    lines = [ln for ln in replay.stderr.splitlines() if "angle_max" in ln]
    assert lines == ["ltmap: warning: 3 scans on /scan have an angle_max that disagrees with their ranges; "
                     "their beams were placed at angle_min + i * angle_increment, as ROS does"]


def test_info_fixed_frame_not_in_tf_fails_as_replay_does(tmp_path):
    path = _robot_log(tmp_path)
    mount = ["--tf", "base_link:laser=0.1,0,0.2,0,0,0"]
    res = _run(path, "--fixed-frame", "world", *mount)
    replay = CliRunner().invoke(cli, ["replay", str(path), "--fixed-frame", "world", *mount,
                                      "-o", str(tmp_path / "o"), "--no-plots", "-q"])
    assert res.exit_code == 2 and replay.exit_code == 2
    line = ("ltmap: error: --fixed-frame world: no frame world in tf (frames: base_link, laser, odom) nor among the "
            "sensors' frames (laser); choose one of them")
    assert res.stderr.splitlines() == [line] and replay.stderr.splitlines() == [line]
    assert "world" not in res.stdout.split("warnings:")[1]  # said once, as the error
    assert _run(path, "--fixed-frame", "odom", *mount).exit_code == 0
    # no --fixed-frame and neither map nor odom: a warning, the listing shows what to choose from
    other = write_log(tmp_path / "w.mcap", "mcap-ros2", [tf(S, [("world", "base_link")]), scan("/scan", S, [1.0])])
    res = _run(other)
    assert res.exit_code == 0
    assert ("  - tf has neither map nor odom (frames in tf: base_link, world): choose the fixed frame with "
            "--fixed-frame laser (the sensor's own frame: a map with it standing still) or --fixed-frame world (the "
            "root of tf; then give the sensor's mount with --tf), or give the transform from a fixed frame with "
            "--tf odom:laser=x,y,z,roll,pitch,yaw\n") in res.output


def test_info_tf_tree_counts_every_sample_of_the_log(tmp_path):
    """30 s of tf at 10 Hz: the tree says 301 samples, not what the 10 s window still holds."""
    msgs = [tf(S + i * S // 10, [("odom", "base_link", (0.01 * i, 0.0, 0.0))]) for i in range(301)]
    msgs += [tf(S, [("base_link", "laser")], static=True), scan("/scan", 2 * S, [1.0, 2.0])]
    msgs.sort(key=lambda m: m.log_time_ns)
    res = _run(write_log(tmp_path / "long.bag", "ros1", msgs))
    assert res.exit_code == 0, res.output
    assert "tf tree:\n  odom\n    base_link  [tf, 301 samples]\n      laser  [static]\n" in res.output


def test_info_takes_replays_config_and_set(tmp_path):
    """`info --config F --set K=V` says what `replay --config F --set K=V` would use: here the
    base frame (``map.robot.base_frame``, which no option of info could give before) and the
    fixed frame, where --set wins over --fixed-frame as in replay."""
    import json

    msgs = []
    for i in range(11):
        t = S + i * S // 10
        msgs.append(tf(t, [("odom", "base_link", (0.1 * i, 0.0, 0.0)), ("base_link", "chassis", (0.0, 0.0, 0.1))]))
        msgs.append(scan("/scan", t + 1, [1.0, 2.0, 3.0], frame_id="chassis"))
    path = write_log(tmp_path / "log.mcap", "mcap-ros2", msgs)
    assert "base frame:  base_link\n" in _run(path).output
    res = _run(path, "--set", "map.robot.base_frame=chassis")
    assert res.exit_code == 0, res.output
    assert "base frame:  chassis\n" in res.output
    cfg = tmp_path / "c.yaml"
    cfg.write_text("map:\n  robot:\n    base_frame: chassis\nreplay:\n  fixed_frame: base_link\n")
    res = _run(path, "--config", cfg, "--json")
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)
    assert (got["base_frame"], got["fixed_frame"]) == ("chassis", "base_link")
    rep = CliRunner().invoke(cli, ["replay", str(path), "--config", str(cfg), "-o", str(tmp_path / "o"), "--no-plots",
                                   "-q"])  # fmt: skip
    assert rep.exit_code == 0, rep.output
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert (report["base_frame"], report["fixed_frame"]) == (got["base_frame"], got["fixed_frame"])
    # --set after the options, as replay applies them
    res = _run(path, "--fixed-frame", "base_link", "--set", "replay.fixed_frame=odom")
    assert "fixed frame: odom\n" in res.output
    bad = _run(path, "--set", "map.robot.base_frame")
    assert bad.exit_code == 2 and "expected KEY=VALUE" in bad.stderr


@pytest.mark.parametrize("fmt", ["mcap-ros2", "ros1", "ros2-sqlite3"])
def test_info_on_a_big_log_reads_its_first_part_and_counts_from_the_index(tmp_path, monkeypatch, fmt):
    """A log over INFO_FULL_BYTES (hours of depth images: the whole pass would take minutes) is
    read for its first INFO_HEAD_S of log time: counts, duration and rates come from its index and
    equal the whole pass's, the tf tree's samples are those of the part read, and the output
    says so; --full reads it all. (Thresholds lowered here: the log is 40 s of 10 Hz tf and 5 Hz
    laser, read for 10 s.)"""
    import ltmap_cli.commands.info as info_mod

    msgs = [tf(S + i * S // 10, [("odom", "base_link", (0.01 * i, 0.0, 0.0))]) for i in range(401)]
    msgs += [tf(S, [("base_link", "laser")], static=True)]
    msgs += [scan("/scan", S + i * S // 5 + 1, [1.0, 2.0]) for i in range(200)]
    msgs.sort(key=lambda m: m.log_time_ns)
    log = write_log(tmp_path / ("big" + SUFFIX[fmt]), fmt, msgs)
    whole = info_mod.gather([log])
    monkeypatch.setattr(info_mod, "INFO_FULL_BYTES", 0)
    monkeypatch.setattr(info_mod, "INFO_HEAD_S", 10.0)
    head = info_mod.gather([log])
    assert whole["read_s"] is None and head["read_s"] == 10.0
    assert {n: t["count"] for n, t in head["topics"].items()} == {n: t["count"] for n, t in whole["topics"].items()} \
        == {"/tf": 401, "/tf_static": 1, "/scan": 200}  # fmt: skip
    assert (head["start_ns"], head["end_ns"]) == (whole["start_ns"], whole["end_ns"]) == (S, 41 * S)
    assert "base_link  [tf, 401 samples]" in whole["tree"] and "base_link  [tf, 101 samples]" in head["tree"]
    res = _run(log)
    assert res.exit_code == 0, res.output
    assert "read:      the first 10 s of log time (counts and times from the index; the tf tree, frames and " \
        "warnings from that part): --full reads it all" in res.output  # fmt: skip
    assert "/scan       sensor_msgs/msg/LaserScan      200     5.0 Hz  uses: laser, frame laser" in res.output, res.output
    full = _run(log, "--full")
    assert "read:" not in full.output and "base_link  [tf, 401 samples]" in full.output
