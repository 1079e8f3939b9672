"""Logs as robots really record them (issue 15, SPEC 4 and 9): for each cause a log made by
changing just that in the tiny room log of test_replay (or a real log of ../shared/real_logs,
skipped when absent), and what `info` claims checked against what `replay` does on the same log.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from logfactory import Msg, cloud, odometry, scan, string, write_log
from test_replay import T0, occupied_cells, room_messages

from ltmap_cli.analysis.hints import replay_hints
from ltmap_cli.cli import cli
from ltmap_cli.commands.info import gather
from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.errors import bounded
from ltmap_cli.io.mapfile import read_map_yaml
from ltmap_cli.io.state import read_state

# LTMAP_REAL_LOGS: where the real logs are when the repository is not beside them (a worktree)
REAL = Path(os.environ.get("LTMAP_REAL_LOGS") or Path(__file__).resolve().parents[1].parent / "shared" / "real_logs")
REALSENSE = REAL / "realsense_d435_single_depth_640x480.bag"
COMPROBO_MAP = REAL / "comprobo22_maps" / "mac_1st_floor_final.yaml"


def invoke(*args):
    args = [str(a) for a in args]
    if args[0] == "replay":
        args += ["-q", "--no-plots"]
    return CliRunner().invoke(cli, args)


def errors(r) -> list[str]:
    return [ln for ln in r.stderr.splitlines() if ln.startswith("ltmap: error:")]


def warnings_of(r) -> list[str]:
    return [ln[len("ltmap: warning: "):] for ln in r.stderr.splitlines() if ln.startswith("ltmap: warning:")]


def report(out: Path) -> dict:
    return json.loads((out / "report.json").read_text())


def o_keys(out: Path) -> np.ndarray:
    arrays, _ = read_state(out / "snapshots" / "state_final.npz")
    m = LayeredMap(MapConfig())
    m.load_state_arrays(arrays)
    return m.occupied_keys("O")


def room_log(tmp_path: Path, name: str = "room.mcap", change=None) -> Path:
    msgs = room_messages(0.0, 2.0, False)
    if change is not None:
        msgs = [change(m) for m in msgs]
    return write_log(tmp_path / name, "mcap-ros2", msgs)


# ----------------------------------------------------------------------------- bounded errors, --debug


def test_bounded_cuts_a_long_list_with_the_count_of_the_rest():
    assert bounded([]) == "none"
    assert bounded(["a", "b"]) == "a, b"
    assert bounded([f"t{i}" for i in range(30)], limit=3) == "t0, t1, t2, ... 27 more"
    long = [f"/device_0/sensor_0/option/Option {i}/value (std_msgs/msg/Float32)" for i in range(70)]
    text = bounded(long)
    assert text.endswith(" more") and len(text) < 500
    assert int(text.rsplit("... ", 1)[1].split()[0]) == 70 - text.count("(std_msgs")


def test_an_error_listing_a_realsense_like_log_is_one_bounded_line(tmp_path):
    """~70 topics and no sensor: the error lists some topics and says how many more."""
    msgs = [string(f"/device_0/sensor_0/option/Option {i}/description", T0 + i, "x") for i in range(70)]
    log = write_log(tmp_path / "opts.mcap", "mcap-ros2", msgs)
    r = invoke("replay", log, "-o", tmp_path / "o")
    assert r.exit_code == 2
    (line,) = errors(r)
    assert "no usable LaserScan, PointCloud2 or depth Image topic" in line and "more" in line
    assert len(line) < 800, len(line)


def test_debug_keeps_the_exit_status(tmp_path):
    for args in (["info", tmp_path / "nope.bag"], ["replay", tmp_path / "nope.bag", "-o", tmp_path / "o"]):
        plain = invoke(*args)
        debug = CliRunner().invoke(cli, ["--debug", *map(str, args)])
        assert plain.exit_code == debug.exit_code == 2
        assert "Traceback" not in plain.stderr and "Traceback (most recent call last)" in debug.stderr
        assert errors(plain) == errors(debug) and len(errors(plain)) == 1


# ----------------------------------------------------------------------------- LaserScan angle_max


def _wrong_angle_max(m: Msg) -> Msg:
    if m.msgtype.endswith("LaserScan"):
        m.fields["angle_max"] = 3.4078  # as the log of the issue: a 360 degree scan with a wrong angle_max
    return m


def test_a_wrong_angle_max_changes_nothing_but_a_warning(tmp_path):
    good, bad = room_log(tmp_path, "good.mcap"), room_log(tmp_path, "bad.mcap", _wrong_angle_max)
    rg = invoke("replay", good, "-o", tmp_path / "og")
    rb = invoke("replay", bad, "-o", tmp_path / "ob")
    assert rg.exit_code == 0 and rb.exit_code == 0, rb.output
    assert occupied_cells(tmp_path / "ob" / "map.yaml") == occupied_cells(tmp_path / "og" / "map.yaml")
    assert (tmp_path / "ob" / "map.pgm").read_bytes() == (tmp_path / "og" / "map.pgm").read_bytes()
    n = report(tmp_path / "ob")["frames_used"]["/scan"]
    assert report(tmp_path / "ob")["scans_angle_max_off"] == {"/scan": n}
    assert [w for w in warnings_of(rb) if "angle_max" in w] == [
        f"{n} scans on /scan have an angle_max that disagrees with their ranges; their beams were placed at "
        f"angle_min + i * angle_increment, as ROS does"]
    assert not [w for w in warnings_of(rg) if "angle_max" in w]
    info = gather([bad])
    assert [w for w in info["warnings"] if "angle_max 3.4078 disagrees with its 180 ranges" in w]


# ----------------------------------------------------------------------------- frames: names and fixed frame


def _odometry_instead_of_tf(child: str):
    """The room log with the robot's pose on /odom (child ``child``) instead of /tf."""
    def change(m: Msg) -> Msg:
        if m.topic == "/tf":
            tr = m.fields["transforms"][0]["transform"]
            t, q = tr["translation"], tr["rotation"]
            return odometry("/odom", m.log_time_ns, "odom", child, (t["x"], t["y"], t["z"]),
                            (q["x"], q["y"], q["z"], q["w"]))
        return m
    return change


def test_frame_ids_with_a_slash_or_spaces_are_one_frame_for_info_and_replay(tmp_path):
    def untidy(m: Msg) -> Msg:
        if m.topic == "/scan":
            m.fields["header"]["frame_id"] = " /laser "
        elif m.topic == "/tf_static":
            m.fields["transforms"][0]["child_frame_id"] = "/laser"
        elif m.topic == "/tf":
            m.fields["transforms"][0]["header"]["frame_id"] = "/odom"
        return m

    log = room_log(tmp_path, change=untidy)
    claims = gather([log])
    assert claims["frames"] == ["base_link", "laser", "odom"] and claims["sensor_frames"] == ["laser"]
    assert claims["used"]["/scan"] == "laser, frame laser" and claims["warnings"] == []
    r = invoke("replay", log, "-o", tmp_path / "o")
    assert r.exit_code == 0, r.output
    rep = report(tmp_path / "o")
    assert rep["frames_skipped"] == {} and rep["fixed_frame"] == claims["fixed_frame"] == "odom"
    assert invoke("replay", room_log(tmp_path, "tidy.mcap"), "-o", tmp_path / "tidy").exit_code == 0
    assert (tmp_path / "o" / "map.pgm").read_bytes() == (tmp_path / "tidy" / "map.pgm").read_bytes()


def test_odometry_with_an_empty_child_frame(tmp_path):
    """info never prints a blank frame and names the empty child_frame_id; replay fails in one line
    naming --fixed-frame and --tf with frames that exist; --fixed-frame with them then works."""
    ok = room_log(tmp_path, "ok.mcap", _odometry_instead_of_tf("/base_link "))  # normalised to base_link
    r = invoke("replay", ok, "-o", tmp_path / "ok")
    assert r.exit_code == 0, r.output
    assert report(tmp_path / "ok")["fixed_frame"] == "odom"

    log = room_log(tmp_path, "empty.mcap", _odometry_instead_of_tf(""))
    r = invoke("info", log)
    assert r.exit_code == 0
    tree = r.stdout.split("tf tree:", 1)[1].split("fixed frame:", 1)[0]
    assert all(ln.strip() for ln in tree.splitlines()[1:]), tree  # no blank frame name
    assert ("samples nav_msgs/Odometry odom -> (empty child_frame_id) not used: it does not say which frame it "
            "moves") in r.stdout
    assert "--fixed-frame laser" in r.stdout
    r = invoke("replay", log, "-o", tmp_path / "o")
    assert r.exit_code == 2
    (line,) = errors(r)
    assert line == ("ltmap: error: tf has neither map nor odom (frames in tf: base_link, laser): choose the fixed "
                    "frame with --fixed-frame base_link (the root of the tf above the sensor), or give the transform "
                    "from a fixed frame with --tf odom:base_link=x,y,z,roll,pitch,yaw")
    for frame in ("base_link", "laser"):  # the root named, or the sensor's own frame
        r = invoke("replay", log, "-o", tmp_path / frame, "--fixed-frame", frame)
        assert r.exit_code == 0, r.output
        assert report(tmp_path / frame)["fixed_frame"] == frame


def test_no_tf_at_all_and_the_sensors_own_frame_as_fixed_frame(tmp_path):
    """A cloud without any tf: one error line naming --fixed-frame lidar and --tf; with
    --fixed-frame lidar the map is in the sensor frame (identity pose): the voxels are where the
    points are."""
    pts = np.array([[2.025 + 0.05 * i, -0.375 + 0.1 * j, 0.225] for i in range(3) for j in range(9)])  # centres
    msgs = [cloud("/points", T0 + k * 10**8, pts, frame_id="/lidar") for k in range(5)]
    log = write_log(tmp_path / "cloud.mcap", "mcap-ros2", msgs)
    r = invoke("replay", log, "-o", tmp_path / "o")
    assert r.exit_code == 2
    (line,) = errors(r)
    assert line == ("ltmap: error: tf has neither map nor odom (frames in tf: none): choose the fixed frame with "
                    "--fixed-frame lidar (the sensor's own frame: a map with it standing still), or give the "
                    "transform from a fixed frame with --tf odom:lidar=x,y,z,roll,pitch,yaw")
    info = gather([log])
    assert info["fixed_frame"] is None and info["warnings"][0] == line[len("ltmap: error: "):]
    r = invoke("replay", log, "-o", tmp_path / "o", "--fixed-frame", "lidar")
    assert r.exit_code == 0, r.output
    keys = {tuple(k) for k in o_keys(tmp_path / "o")}
    want = {tuple(int(v) for v in np.floor(p / 0.05)) for p in pts}
    assert want <= keys
    assert report(tmp_path / "o")["fixed_frame"] == gather([log], fixed_frame="lidar")["fixed_frame"] == "lidar"


# ----------------------------------------------------------------------------- info's claims = replay's


def test_every_claim_of_info_is_what_replay_does(tmp_path):
    """Topics used, fixed frame, base frame and warnings, on a log with a skipped colour camera,
    an unused laser frame and a wrong angle_max."""
    from logfactory import image

    msgs = room_messages(0.0, 2.0, False)
    msgs = [_wrong_angle_max(m) for m in msgs]
    msgs += [image("/cam/color/image_raw", T0 + 10**8, np.zeros((2, 2)), encoding="rgb8"),
             scan("/scan_rear", T0 + 2 * 10**8, [1.0, 1.0], frame_id="rear_laser")]
    msgs.sort(key=lambda m: m.log_time_ns)
    log = write_log(tmp_path / "l.mcap", "mcap-ros2", msgs)
    r = invoke("info", "--json", log)
    assert r.exit_code == 0, r.output
    claims = json.loads(r.stdout)
    rr = invoke("replay", log, "-o", tmp_path / "o")
    assert rr.exit_code == 0, rr.output
    rep = report(tmp_path / "o")
    # topics replay would use / does use
    assert sorted(claims["used"]) == sorted(rep["topics_used"]["scans"]) == ["/scan", "/scan_rear"]
    assert sorted(claims["skipped"]) == sorted(rep["topics_not_used"]) == ["/cam/color/image_raw"]
    # fixed and base frame
    assert claims["fixed_frame"] == rep["fixed_frame"] == "odom"
    assert claims["base_frame"] == rep["base_frame"] == "base_link"
    # warnings: the rear laser cannot be placed (replay skips its frame for that reason), the
    # colour camera is skipped, the scans' angle_max disagrees
    rear = [w for w in claims["warnings"] if w.startswith("/scan_rear: every frame would be skipped: ")]
    assert len(rear) == 1
    assert rep["frames_skipped"] == {rear[0].split("every frame would be skipped: ", 1)[1]: 1}
    assert any(w.startswith("/cam/color/image_raw would be skipped") for w in claims["warnings"])
    assert any(w.startswith("/cam/color/image_raw not used") for w in warnings_of(rr))
    assert any("/scan: angle_max 3.4078 disagrees" in w for w in claims["warnings"])
    assert any(w.startswith(f"{rep['scans_angle_max_off']['/scan']} scans on /scan have an angle_max")
               for w in warnings_of(rr))


def test_info_reports_header_stamps_against_record_time(tmp_path):
    year = 365 * 86400 * 10**9

    def shift(m: Msg) -> Msg:  # a bag re-recorded while another was played back: stamps a year old
        if "header" in m.fields:
            m.fields["header"]["stamp"] -= year
        for tr in m.fields.get("transforms", []):
            if m.topic == "/tf":
                tr["header"]["stamp"] -= year
        return m

    log = room_log(tmp_path, change=shift)
    r = invoke("info", log)
    assert r.exit_code == 0
    assert "  /scan: header stamps are 31536000 s (365.0 days) before record time" in r.stdout
    assert "  /tf: header stamps are 31536000 s (365.0 days) before record time" in r.stdout
    assert gather([log])["stamp_offset_s"]["/scan"] == pytest.approx(31536000.0)
    assert "header stamps against record time" not in invoke("info", room_log(tmp_path, "plain.mcap")).stdout


def test_a_sensor_on_its_own_clock_is_named_and_can_be_placed_at_record_time(tmp_path):
    """A laser whose driver stamps with the device's clock (an hour ahead of tf, which follows
    record time): every frame is skipped, and the one line says how far apart the clocks are and
    names replay.sensor_stamps=log, which places the frames at their record time: then the map is
    the one of the log stamped right. With a second laser on the right clock, the first is named
    in a warning."""
    hour = 3600 * 10**9

    def own_clock(m: Msg) -> Msg:
        if m.topic == "/scan":
            m.fields["header"]["stamp"] += hour
        return m

    log = room_log(tmp_path, change=own_clock)
    r = invoke("replay", log, "-o", tmp_path / "o", "--no-plots")
    assert errors(r) == ["ltmap: error: every sensor frame was skipped (10 x): transform odom -> base_link not "
                         "available (stamp after its last sample; no extrapolation); the header stamps of /scan are "
                         "3600 s after those of /tf (relative to record time): a sensor on its own clock? --set "
                         "replay.sensor_stamps=log places its frames at their record time"], r.stderr
    assert "  - /scan: its frames cannot be placed with that tf: the header stamps of /scan are 3600 s after those " \
        "of /tf" in invoke("info", log).stdout  # fmt: skip
    r = invoke("replay", log, "-o", tmp_path / "log_time", "--no-plots", "--set", "replay.sensor_stamps=log")
    assert r.exit_code == 0, r.stderr
    ref = invoke("replay", room_log(tmp_path, "right.mcap"), "-o", tmp_path / "right", "--no-plots")
    assert ref.exit_code == 0, ref.stderr
    a, _ = read_state(tmp_path / "log_time" / "snapshots" / "state_final.npz")
    b, _ = read_state(tmp_path / "right" / "snapshots" / "state_final.npz")
    assert all(np.array_equal(a[k], b[k]) for k in b)
    assert report(tmp_path / "log_time")["frames_used"] == {"/scan": 10}

    def second_laser(m: Msg) -> list[Msg]:
        if m.topic != "/scan":
            return [m]
        other = Msg("/scan_rear", m.log_time_ns, m.msgtype, {**m.fields, "header": dict(m.fields["header"])})
        other.fields["header"]["stamp"] += hour
        return [m, other]

    msgs = [x for m in room_messages(0.0, 2.0, False) for x in second_laser(m)]
    r = invoke("replay", write_log(tmp_path / "two.mcap", "mcap-ros2", msgs), "-o", tmp_path / "two", "--no-plots")
    assert r.exit_code == 0, r.stderr
    assert "ltmap: warning: no frame of /scan_rear was used: the header stamps of /scan_rear are 3600 s after " \
        "those of /tf (relative to record time)" in r.stderr, r.stderr  # fmt: skip
    assert report(tmp_path / "two")["header_stamp_offset_s"]["/scan_rear"] == -3600.0


# ----------------------------------------------------------------------------- several logs, short logs


def test_a_log_whose_frames_cannot_be_placed_is_named(tmp_path):
    """A pair: B is the room log; A's scans are in a frame that neither log's tf has."""
    a = write_log(tmp_path / "a.mcap", "mcap-ros2",
                  [scan("/front", T0 + k * 10**8, [1.0, 1.0], frame_id="front_laser") for k in range(8)])
    b = room_log(tmp_path, "b.mcap")
    r = invoke("replay", a, b, "-o", tmp_path / "o")
    assert r.exit_code == 0, r.output
    rep = report(tmp_path / "o")
    assert rep["frames_used_by_log"] == {str(a): 0, str(b): rep["frames_used"]["/scan"]}
    assert rep["frames_skipped_by_log"] == {str(a): 8, str(b): 0}
    (w,) = [w for w in warnings_of(r) if "contributed nothing" in w]
    assert w.startswith(f"log {a} contributed nothing to the map: all 8 of its sensor frames were skipped "
                        f"(the most common reason: no transform base_link -> front_laser")


def test_a_short_log_hints_at_st_rise_s(tmp_path):
    log = room_log(tmp_path)
    r = invoke("replay", log, "-o", tmp_path / "o")
    assert r.exit_code == 0
    rep = report(tmp_path / "o")
    assert rep["voxels"]["long_term_occupied"] == 0 and rep["voxels"]["occupied_O"] > 100
    (w,) = [w for w in warnings_of(r) if "st_rise_s" in w]
    assert w == (f"the long-term map is nearly empty (0 voxels; {rep['voxels']['occupied_O']} seen occupied): a "
                 f"voxel enters it after being seen for map.layers.st_rise_s = 15 s, and the log lasts "
                 f"{rep['log_duration_s']:.1f} s, shorter than that; for a short log lower it, e.g. --set "
                 f"map.layers.st_rise_s=5")
    r = invoke("replay", log, "-o", tmp_path / "o2", "--set", "map.layers.st_rise_s=0.5")
    assert r.exit_code == 0 and not [w for w in warnings_of(r) if "st_rise_s" in w]
    assert report(tmp_path / "o2")["voxels"]["long_term_occupied"] > 100
    # the hint is a pure function of the report
    assert replay_hints(rep, st_rise_s=15.0, resolution=0.05) == [w]
    assert replay_hints({**rep, "log_duration_s": 100.0}, st_rise_s=15.0, resolution=0.05)[0].endswith(
        "and the log lasts 100.0 s, and little stayed in view that long; for a short log lower it, e.g. "
        "--set map.layers.st_rise_s=5")


# ----------------------------------------------------------------------------- static maps with unknown cells


def _saver_map(folder: Path, resolution: float = 0.03, free_thresh: float = 0.25) -> Path:
    """A map as nav2's map_saver wrote it until 2025 (trinary, free_thresh 0.25): the room's
    floor free (254), its walls occupied (0), everything outside unknown (205)."""
    n, o = 200, -3.0
    c = (np.arange(n) + 0.5) * resolution + o
    x, y = np.meshgrid(c, c)
    pix = np.full((n, n), 205, np.uint8)
    pix[(abs(x) < 2.0) & (abs(y) < 2.0)] = 254
    pix[((abs(x) >= 2.0) | (abs(y) >= 2.0)) & (abs(x) < 2.06) & (abs(y) < 2.06)] = 0
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "m.pgm").write_bytes(b"P5\n%d %d\n255\n" % (n, n) + pix[::-1].tobytes())
    (folder / "m.yaml").write_text(f"image: m.pgm\nmode: trinary\nresolution: {resolution}\norigin: [{o}, {o}, "
                                   f"0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: {free_thresh}\n")
    return folder / "m.yaml"


def test_a_map_server_map_keeps_its_unknown_cells_in_s_static_pgm_and_p(tmp_path):
    static = _saver_map(tmp_path / "map")
    r = invoke("replay", room_log(tmp_path), "--static", static, "-o", tmp_path / "o")
    assert r.exit_code == 0, r.output
    rep = report(tmp_path / "o")
    w = warnings_of(r)
    assert any(f"{static}: 20956 cells of map_saver's unknown grey 205 are kept unknown although free_thresh 0.25"
               in x for x in w)
    (res,) = [x for x in w if "resampled" in x]
    assert res.startswith(f"the static map {static} has 0.03 m cells; it was resampled to the map's 0.05 m")
    # the expected lattice: a 0.05 cell is unknown exactly when no known 0.03 source cell centre is in
    # it and the source cell under its centre is unknown: outside the 2.06 m square
    s = read_map_yaml(tmp_path / "o" / "static.yaml")
    p = read_map_yaml(tmp_path / "o" / "map.yaml")
    assert (s.data == -1).sum() == rep["static"]["unknown_cells"] > 5000
    rows, cols = np.nonzero(s.data == -1)
    cx = s.origin[0] + (cols + 0.5) * s.resolution
    cy = s.origin[1] + (rows + 0.5) * s.resolution
    assert (np.maximum(abs(cx), abs(cy)) > 2.06).all()
    ring = (np.maximum(abs(cx), abs(cy)) > 2.2)
    assert ring.sum() > 0.9 * len(cx)
    # P: the static map's unknown stays unknown where the robot saw nothing (outside the room)
    assert p.data.shape == s.data.shape and p.origin == s.origin
    assert (p.data[s.data == -1] == -1).all()
    # and the walls stay occupied
    assert ((s.data == 100) & (p.data != 100)).sum() == 0


def test_the_same_map_with_free_thresh_0196_reads_alike_without_a_warning(tmp_path):
    a = read_map_yaml(_saver_map(tmp_path / "a", resolution=0.05, free_thresh=0.196))
    with pytest.warns(Warning, match="kept unknown"):
        from ltmap_cli.io.static_layer import load_static_input

        b = load_static_input(_saver_map(tmp_path / "b", resolution=0.05)).grid
    assert np.array_equal(a.data, b.data) and (a.data == -1).sum() > 0


@pytest.mark.skipif(not COMPROBO_MAP.is_file(), reason=f"real map not present at {COMPROBO_MAP}")
def test_the_comprobo_slam_map_keeps_its_unknown_cells(tmp_path):
    from ltmap_cli.core.layers import StaticGrid
    from ltmap_cli.io.static_layer import load_static_input

    with pytest.warns(Warning, match="1220114 cells of map_saver's unknown grey 205 are kept unknown"):
        layer = load_static_input(COMPROBO_MAP)
    assert (layer.grid.data == -1).sum() == 1220114
    s = StaticGrid.from_height_map(layer.grid.data, layer.height, 0.03, layer.grid.origin, 0.05)
    assert (s.occ == -1).sum() > 400_000 and (s.occ == 100).sum() > 9000


# ----------------------------------------------------------------------------- RealSense SDK recording


def _plane(points: np.ndarray, tol: float, seed: int = 0) -> tuple[np.ndarray, float, np.ndarray]:
    """The plane (unit normal n, offset d: n.p = d) with most points within ``tol`` (RANSAC, then
    a least squares refit on its inliers), and its inlier mask."""
    rng = np.random.default_rng(seed)
    sample = points[rng.choice(len(points), min(len(points), 20000), replace=False)]
    best, best_n = None, -1
    for _ in range(300):
        a, b, c = sample[rng.choice(len(sample), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-9:
            continue
        n /= np.linalg.norm(n)
        k = int((abs(sample @ n - n @ a) < tol).sum())
        if k > best_n:
            best, best_n = (n, float(n @ a)), k
    n, d = best
    inl = abs(points @ n - d) < tol
    centre = points[inl].mean(axis=0)
    _, _, vt = np.linalg.svd(points[inl] - centre, full_matrices=False)
    n = vt[2]
    d = float(n @ centre)
    return n, d, abs(points @ n - d) < tol


@pytest.mark.skipif(not REALSENSE.is_file(), reason=f"RealSense recording not present at {REALSENSE}")
def test_the_realsense_recording_replays_in_its_depth_frame_and_its_voxels_lie_on_the_seen_plane(tmp_path):
    from rosbags.highlevel import AnyReader

    r = invoke("info", REALSENSE)
    assert "uses: depth, frame 0 (CameraInfo /device_0/sensor_0/Depth_0/info/camera_info)" in r.stdout
    assert "--fixed-frame 0" in r.stdout
    out = tmp_path / "o"
    r = invoke("replay", REALSENSE, "--fixed-frame", "0", "-o", out)
    assert r.exit_code == 0, r.output
    assert "faces straight up" not in r.stderr  # (mapped in its own frame: no up to face)
    rep = report(out)
    assert rep["frames_used"] == {"/device_0/sensor_0/Depth_0/image/data": 2} and rep["fixed_frame"] == "0"
    keys = o_keys(out)
    print(f"RealSense D435: {len(keys)} occupied voxels in O from 2 depth images")  # noqa: T201
    assert len(keys) > 1000

    with AnyReader([REALSENSE]) as reader:
        conns = {c.topic: c for c in reader.connections}
        info = next(reader.deserialize(raw, c.msgtype) for c, _, raw in
                    reader.messages([conns["/device_0/sensor_0/Depth_0/info/camera_info"]]))
        img = next(reader.deserialize(raw, c.msgtype) for c, _, raw in
                   reader.messages([conns["/device_0/sensor_0/Depth_0/image/data"]]))
        units = next(reader.deserialize(raw, c.msgtype).data for c, _, raw in
                     reader.messages([conns["/device_0/sensor_0/option/Depth Units/value"]]))
    fx, cx, fy, cy = info.K[0], info.K[2], info.K[4], info.K[5]
    depth = np.frombuffer(img.data, "<u2").reshape(img.height, img.width).astype(np.float64) * units
    v, u = np.nonzero(depth > 0)
    z = depth[v, u]
    pts = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], axis=1)
    n, d, inl = _plane(pts[z < 3.0], tol=0.02)
    mask = np.zeros(depth.shape, bool)
    mask[v[z < 3.0][inl], u[z < 3.0][inl]] = True
    assert mask.sum() > 0.15 * len(z), "no large flat region in view"
    # erode the region by 6 px: its edges see other surfaces
    core = mask.copy()
    for dv in range(-6, 7, 3):
        for du in range(-6, 7, 3):
            core &= np.roll(np.roll(mask, dv, 0), du, 1)
    centres = (keys + 0.5) * 0.05
    front = centres[:, 2] > 0.1
    c = centres[front]
    pu = np.floor(fx * c[:, 0] / c[:, 2] + cx).astype(int)
    pv = np.floor(fy * c[:, 1] / c[:, 2] + cy).astype(int)
    ok = (pu >= 0) & (pu < img.width) & (pv >= 0) & (pv < img.height)
    on = np.zeros(len(c), bool)
    on[ok] = core[pv[ok], pu[ok]]
    dist = abs(c[on] @ n - d)
    print(f"{on.sum()} voxels seen through the plane region: median {np.median(dist) * 100:.1f} cm, "  # noqa: T201
          f"95th percentile {np.percentile(dist, 95) * 100:.1f} cm from the plane")
    assert on.sum() > 200
    assert np.median(dist) < 0.03 and np.percentile(dist, 95) < 0.06


def test_a_map_frame_that_comes_late_is_said_and_can_be_chosen(tmp_path):
    """A localizer that starts publishing map -> odom 1.5 s into the log: replay chooses its fixed
    frame at its first frame (odom), and info says so; --fixed-frame map maps in map, skipping the
    frames before map -> odom exists."""
    from logfactory import tf

    msgs = room_messages(0.0, 3.0, False)
    t_map = T0 + 1_500_000_000
    msgs += [tf(t, [("map", "odom")]) for t in range(t_map, T0 + 3_300_000_000, 100_000_000)]
    msgs.sort(key=lambda m: m.log_time_ns)
    log = write_log(tmp_path / "late.mcap", "mcap-ros2", msgs)
    claims = gather([log])
    r = invoke("replay", log, "-o", tmp_path / "o")
    assert r.exit_code == 0, r.output
    assert claims["fixed_frame"] == report(tmp_path / "o")["fixed_frame"] == "odom"
    assert any(w.startswith("tf has map only after the first sensor frames") for w in claims["warnings"])
    assert gather([log], fixed_frame="map")["fixed_frame"] == "map"
    r = invoke("replay", log, "-o", tmp_path / "m", "--fixed-frame", "map")
    assert r.exit_code == 0, r.output
    rep = report(tmp_path / "m")
    assert rep["fixed_frame"] == "map"
    early = sum(1 for m in msgs if m.topic == "/scan" and m.log_time_ns < t_map)
    assert sum(rep["frames_skipped"].values()) == early and rep["frames_used"]["/scan"] == 15 - early


# ----------------------------------------------------------------------------- the real logs, changed


PIONEER = REAL / "ist_pioneer3dx_test1.bag"
COMPROBO = REAL / "comprobo22_macfirst_floor_take_2"


def _rewrite_ros1(src: Path, dst: Path, change) -> Path:
    """Copy a ROS 1 bag message by message; ``change(topic, msg)`` edits a deserialized
    Odometry / LaserScan and returns False to drop a message (other types are copied as bytes)."""
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Reader(src) as r, Writer(dst) as w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest,
                                        callerid=c.ext.callerid, latching=c.ext.latching) for c in r.connections}
        for c, t, raw in r.messages():
            if c.msgtype == "tf2_msgs/msg/TFMessage" and change(c.topic, None) is False:
                continue
            if c.msgtype in ("nav_msgs/msg/Odometry", "sensor_msgs/msg/LaserScan"):
                msg = ts.deserialize_ros1(raw, c.msgtype)
                if change(c.topic, msg) is False:
                    continue
                raw = ts.serialize_ros1(msg, c.msgtype)
            w.write(conns[c.id], t, raw)
    return dst


def _rewrite_ros2(src: Path, dst: Path, change) -> Path:
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(src) as r, Writer(dst, version=9) as w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in r.connections}
        for c, t, raw in r.messages():
            if c.msgtype == "sensor_msgs/msg/LaserScan":
                msg = ts.deserialize_cdr(raw, c.msgtype)
                change(c.topic, msg)
                raw = ts.serialize_cdr(msg, c.msgtype)
            w.write(conns[c.id], t, raw)
    return dst


@pytest.mark.slow
@pytest.mark.skipif(not COMPROBO.is_dir(), reason=f"real log not present at {COMPROBO}")
def test_comprobo_with_a_wrong_angle_max_gives_the_same_map(tmp_path):
    def wrong(topic, msg):
        msg.angle_max = msg.angle_min + 1.5 * (msg.angle_max - msg.angle_min)

    bad = _rewrite_ros2(COMPROBO, tmp_path / "bad", wrong)
    rg = invoke("replay", COMPROBO, "-o", tmp_path / "og")
    rb = invoke("replay", bad, "-o", tmp_path / "ob")
    assert rg.exit_code == 0 and rb.exit_code == 0, rb.output
    assert (tmp_path / "ob" / "map.pgm").read_bytes() == (tmp_path / "og" / "map.pgm").read_bytes()
    assert report(tmp_path / "ob")["scans_angle_max_off"] == {"/scan": 357}
    assert [w for w in warnings_of(rb) if "angle_max" in w] == [
        "357 scans on /scan have an angle_max that disagrees with their ranges; their beams were placed at "
        "angle_min + i * angle_increment, as ROS does"]


@pytest.mark.slow
@pytest.mark.skipif(not PIONEER.is_file(), reason=f"real log not present at {PIONEER}")
def test_pioneer_without_tf_and_with_empty_odometry_child_frames(tmp_path):
    """The Pioneer log with /tf dropped and its /pose odometry's child_frame_id emptied."""
    def strip(topic, msg):
        if topic == "/tf":
            return False
        if hasattr(msg, "child_frame_id"):
            msg.child_frame_id = ""
        return True

    log = _rewrite_ros1(PIONEER, tmp_path / "stripped.bag", strip)
    r = invoke("info", log)
    assert r.exit_code == 0
    assert "313 samples nav_msgs/Odometry odom -> (empty child_frame_id) not used" in r.stdout
    assert "tf tree:   (no transforms)" in r.stdout and "fixed frame: - (none)" in r.stdout
    r = invoke("replay", log, "-o", tmp_path / "o")
    assert r.exit_code == 2
    assert errors(r) == ["ltmap: error: tf has neither map nor odom (frames in tf: none): choose the fixed frame "
                         "with --fixed-frame laser (the sensor's own frame: a map with it standing still), or give "
                         "the transform from a fixed frame with --tf odom:laser=x,y,z,roll,pitch,yaw"]
    r = invoke("replay", log, "-o", tmp_path / "o", "--fixed-frame", "laser")
    assert r.exit_code == 0, r.output
    rep = report(tmp_path / "o")
    assert rep["frames_used"] == {"/scan": 311} and rep["fixed_frame"] == "laser"


@pytest.mark.slow
@pytest.mark.skipif(not (PIONEER.is_file() and COMPROBO.is_dir()), reason=f"real logs not present in {REAL}")
def test_a_real_log_whose_frames_cannot_be_placed_is_named_in_a_pair(tmp_path):
    """Pioneer (no base_link -> laser) with comprobo: the Pioneer contributes nothing, and says so."""
    r = invoke("replay", PIONEER, COMPROBO, "-o", tmp_path / "o")
    assert r.exit_code == 0, r.output
    rep = report(tmp_path / "o")
    used = rep["frames_used_by_log"]
    # comprobo's frames still held when the Pioneer's tf (a year later) arrives are placed before
    # that tf pushes comprobo's samples out of the tf window: 356 used, as alone
    assert used[str(PIONEER)] == 0 and used[str(COMPROBO)] == 356
    assert rep["frames_skipped_by_log"][str(PIONEER)] == 311
    (w,) = [w for w in warnings_of(r) if "contributed nothing" in w]
    assert w.startswith(f"log {PIONEER} contributed nothing to the map: all 311 of its sensor frames were skipped")


def test_depth_images_in_a_body_frame_are_named_and_can_be_read_so(tmp_path):
    """A simulated camera whose images carry its link frame (x forward, z up: Gazebo's default)
    instead of its optical frame: read as optical, it faces straight up (a wall 3 m ahead becomes
    a ceiling): replay warns, once, naming replay.depth_frame_axes=body, and so does info; with
    it, the map is that of the same images in a proper optical frame (tf camera_link ->
    camera_optical, REP 103)."""
    from logfactory import camera_info, image, tf

    S = 1_000_000_000

    def log(frame: str, name: str) -> Path:
        msgs = [tf(S // 2, [("base_link", "camera_link", (0.2, 0.0, 0.5))], static=True),
                tf(S // 2, [("camera_link", "camera_optical", (0.0, 0.0, 0.0), (-0.5, 0.5, -0.5, 0.5))], static=True)]
        for i in range(6):
            t = S + i * S // 10
            msgs.append(tf(t, [("odom", "base_link")]))
            msgs.append(camera_info("/cam/depth/camera_info", t, width=40, height=30, fx=30, fy=30, cx=19.5, cy=14.5,
                                    frame_id=frame))  # fmt: skip
            msgs.append(image("/cam/depth/image_raw", t + 1, np.full((30, 40), 3000, np.uint16), frame_id=frame))
        return write_log(tmp_path / name, "mcap-ros2", msgs)

    body, optical = log("camera_link", "body.mcap"), log("camera_optical", "optical.mcap")
    r = invoke("replay", body, "-o", tmp_path / "as_optical", "--no-plots")
    assert r.exit_code == 0, r.stderr
    warned = [ln for ln in warnings_of(r) if "faces straight up" in ln]
    assert warned == ["depth images on /cam/depth/image_raw are in frame camera_link, which as an "
                      "optical frame (z forward, x right, y down) faces straight up: is it the camera's body frame "
                      "(x forward, z up; a Gazebo camera link) rather than its optical frame? --set "
                      "replay.depth_frame_axes=body reads them so; if the camera does face up, ignore this"], r.stderr
    info = invoke("info", body).stdout  # (info says it too, from the camera's mount on the robot's base)
    assert f"  - {warned[0]}" in info and "faces straight up" not in invoke("info", optical).stdout, info
    up = o_keys(tmp_path / "as_optical")
    assert len(up) and (up[:, 2] * 0.05 > 3.0).all()  # the wall became a ceiling 3 m over the camera
    for args, out in (([body, "--set", "replay.depth_frame_axes=body"], "as_body"), ([optical], "ref")):
        r = invoke("replay", *args, "-o", tmp_path / out, "--no-plots")
        assert r.exit_code == 0 and "faces straight up" not in r.stderr, r.stderr
    got, ref = o_keys(tmp_path / "as_body"), o_keys(tmp_path / "ref")
    assert len(ref) > 100 and np.array_equal(got, ref)
    assert (abs((ref[:, 0] + 0.5) * 0.05 - 3.2) < 0.06).all()  # the wall, 3 m ahead of the camera at x = 0.2


def test_tf_samples_tf2_refuses_are_ignored_not_fatal(tmp_path):
    """A zeroed quaternion and a NaN translation among the robot's /tf samples (before: the run
    failed, "sensor origin is not finite"): ignored as tf2 ignores them, counted in report.json
    and named in a warning (and by info); the robot stands still, so the map is that of the log
    without them."""
    k = [0]

    def zeroed(m: Msg) -> Msg:
        if m.topic == "/tf":
            k[0] += 1
            tr = m.fields["transforms"][0]["transform"]
            if k[0] == 5:
                tr["rotation"] = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0}
            elif k[0] == 12:
                tr["translation"] = {"x": float("nan"), "y": 0.0, "z": 0.0}
        return m

    log = room_log(tmp_path, "zeroed.mcap", change=zeroed)
    r = invoke("replay", log, "-o", tmp_path / "o", "--no-plots")
    assert r.exit_code == 0, r.stderr
    assert "ltmap: warning: tf samples ignored, as tf2 ignores them (a NaN or infinite value, or a quaternion that " \
        "is not of unit length: a message left zeroed?): 2 of odom -> base_link; the edges' other samples were " \
        "used" in r.stderr, r.stderr  # fmt: skip
    assert report(tmp_path / "o")["tf_samples_invalid"] == {"odom -> base_link": 2}
    assert "  - 2 samples of odom -> base_link not used: a NaN or infinite value" in invoke("info", log).stdout
    assert invoke("replay", room_log(tmp_path), "-o", tmp_path / "clean", "--no-plots").exit_code == 0
    a, _ = read_state(tmp_path / "o" / "snapshots" / "state_final.npz")
    b, _ = read_state(tmp_path / "clean" / "snapshots" / "state_final.npz")
    assert all(np.array_equal(a[key], b[key]) for key in b)


def test_a_clock_reset_inside_a_log_is_named_with_the_windows_to_map_apart(tmp_path):
    """A simulation reset 15 s into a 30 s log: every header stamp (tf and laser) goes back 1000 s.
    The pipeline's ticks follow the sensor frames' stamps, so the parts must be mapped apart: one
    warning says where the stamps jump and gives the --end / --start that split the log there;
    each part so mapped has no jump (tf read around a window may: tf is keyed by stamp)."""
    from logfactory import write_log as write

    S = 1_000_000_000
    msgs = room_messages(0.0, 30.0, False)
    t0 = min(m.log_time_ns for m in msgs)

    def reset(m: Msg) -> Msg:
        if m.log_time_ns - t0 > 15 * S:
            if "header" in m.fields:
                m.fields["header"]["stamp"] -= 1000 * S
            for tr in m.fields.get("transforms", []) if m.topic == "/tf" else []:
                tr["header"]["stamp"] -= 1000 * S
        return m

    log = write(tmp_path / "reset.mcap", "mcap-ros2", [reset(m) for m in msgs])
    r = invoke("replay", log, "-o", tmp_path / "o", "--no-plots")
    assert r.exit_code == 0, r.stderr
    assert "ltmap: warning: header stamps on /scan jump back by 999.8 s at 15.1 s of log time: a clock or " \
        "simulation reset? Frames after it are placed with tf of the same clock only; map the parts apart with " \
        "--end 15 and --start 15" in r.stderr, r.stderr  # fmt: skip
    assert report(tmp_path / "o")["stamp_jumps_back"] == {"/scan": {"at_s": 15.1, "by_s": 999.8, "split_s": 15.0}}
    for part, args in (("a", ["--end", "15"]), ("b", ["--start", "15"])):
        r = invoke("replay", log, "-o", tmp_path / part, "--no-plots", *args)
        assert r.exit_code == 0 and "jump back" not in r.stderr, r.stderr
        assert report(tmp_path / part)["stamp_jumps_back"] == {}
