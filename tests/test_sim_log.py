"""`ltmap simulate`: every format readable with the expected topics, counts and content; byte-identical
logs for a seed; ground truth."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from ltmap_cli.cli import cli
from ltmap_cli.io.frames import CloudFrame, DepthFrame, OdometrySample, ScanFrame, TfSample
from ltmap_cli.io.logs import open_logs

SCENARIO = {
    "name": "tiny",
    "walls": [{"points": [[0, 0], [4, 0], [4, 4], [0, 4], [0, 0]], "thickness": 0.1}],
    "duration": 2.0,
    "seed": 3,
    "robot": {"path": {"waypoints": [{"t": 0, "x": 1.95, "y": 2, "yaw": 0}, {"t": 2, "x": 1.95, "y": 2, "yaw": 0}]},
              "odometry_drift": [0.05, -0.02, 2.0]},
    "sensors": {
        "laser": {"beams": 90, "rate": 10, "noise": 0.01, "dropout": 0.05, "mount": {"xyz": [0, 0, 0.25]}},
        "depth": {"width": 32, "height": 24, "fx": 26.25, "fy": 26.25, "rate": 5, "mount": {"xyz": [0, 0, 1.0]}},
        "points": {"beams": 36, "channels": 4, "rate": 5, "vfov": [-10, 10], "mount": {"xyz": [0, 0, 0.5]}},
    },
    "objects": [{"id": "b", "kind": "box", "pose": {"x": 3, "y": 2}, "size": [0.4, 0.4, 0.5], "present": [[1, None]]}],
}  # fmt: skip

EXPECTED_COUNTS = {
    "/tf": 101,
    "/tf_static": 1,
    "/odom": 41,
    "/scan": 20,
    "/camera/depth/image_raw": 10,
    "/camera/depth/camera_info": 10,
    "/points": 10,
}
OUT = {"mcap": "log.mcap", "ros1": "log.bag", "ros2": "log_ros2"}


def write_scenario(tmp_path: Path, doc=None, name="scenario.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(doc or SCENARIO))
    return p


def simulate(tmp_path: Path, fmt: str, *extra: str, doc=None, sub="") -> Path:
    folder = tmp_path / sub if sub else tmp_path
    folder.mkdir(parents=True, exist_ok=True)
    scen = write_scenario(folder, doc)
    out = folder / OUT[fmt]
    res = CliRunner().invoke(cli, ["simulate", str(scen), "-o", str(out), "--format", fmt, *extra])
    assert res.exit_code == 0, res.output
    return out


def digest(path: Path) -> str:
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


@pytest.mark.parametrize("fmt", ["mcap", "ros1", "ros2"])
def test_each_format_is_readable_with_expected_topics_and_counts(tmp_path, fmt):
    out = simulate(tmp_path, fmt)
    with open_logs(out) as logs:
        assert {t: i.count for t, i in logs.topics.items()} == EXPECTED_COUNTS
        assert logs.topics["/scan"].msgtype == "sensor_msgs/msg/LaserScan"
        assert logs.topics["/points"].msgtype == "sensor_msgs/msg/PointCloud2"
        assert logs.start_ns == 1_700_000_000 * 10**9
        assert logs.end_ns == 1_700_000_002 * 10**9
        sel = logs.select()
        assert sel.scans == ["/scan"] and sel.clouds == ["/points"]
        assert sel.depths == {"/camera/depth/image_raw": "/camera/depth/camera_info"}
        scans, depths, clouds, tfs, odoms = [], [], [], [], []
        for _topic, t_ns, item in logs.messages(sel):
            if isinstance(item, ScanFrame):
                assert item.stamp_ns == t_ns
                scans.append(item)
            elif isinstance(item, DepthFrame):
                depths.append(item)
            elif isinstance(item, CloudFrame):
                clouds.append(item)
            elif isinstance(item, TfSample):
                tfs.append(item)
            elif isinstance(item, OdometrySample):
                odoms.append(item)
    assert len(scans) == 20 and len(depths) == 10 and len(clouds) == 10 and len(odoms) == 41
    # laser at (1.95, 2, 0.25) facing +x: 90 beams from -180 deg, beam 45 is 0 deg. Before t = 1 s it sees
    # the wall face at 3.95 (2.0 m), after it the box face at 2.8 (0.85 m); noise sigma 0.01, 5 % dropout
    ahead = np.array([s.ranges[45] for s in scans], dtype=np.float64)
    assert scans[0].frame_id == "laser" and scans[0].angle_min == pytest.approx(-math.pi)
    assert scans[0].angle_increment == pytest.approx(2 * math.pi / 90)
    fin = np.isfinite(ahead)
    np.testing.assert_allclose(ahead[:10][fin[:10]], 2.0, atol=0.05)
    np.testing.assert_allclose(ahead[10:][fin[10:]], 0.85, atol=0.05)
    all_r = np.concatenate([s.ranges for s in scans])
    assert 0.0 < np.isinf(all_r).mean() < 0.12  # dropout
    # depth 32x24 at 1 m facing the wall 2 m ahead: z-depth 2.0 (mm units) until the box shows up
    d0 = depths[0]
    assert d0.depth_m.shape == (24, 32) and d0.intrinsics.fx == pytest.approx(26.25)
    assert d0.frame_id == "camera_depth_optical_frame"
    np.testing.assert_allclose(d0.depth_m, 2.0, atol=1e-6)
    # then the bottom row (v = 23, (23 - 11.5) / 26.25 below the axis) meets the box top (0.5 m below
    # the camera) at z-depth 0.5 * 26.25 / 11.5 = 1.1413 m (x = 3.09, on the box): rounded to mm
    assert np.nanmin(depths[-1].depth_m) == pytest.approx(0.5 * 26.25 / 11.5, abs=6e-4)
    assert np.nanmin(depths[4].depth_m) == pytest.approx(2.0, abs=1e-6)
    # tf: map -> odom undoes the odometry drift, so map -> base_link is the truth
    statics = {(s.parent, s.child) for s in tfs if s.static}
    assert statics == {
        ("base_link", "laser"),
        ("base_link", "camera_link"),
        ("camera_link", "camera_depth_optical_frame"),
        ("base_link", "lidar"),
    }
    optical = next(s for s in tfs if s.child == "camera_depth_optical_frame")
    np.testing.assert_allclose(optical.rotation_xyzw, [-0.5, 0.5, -0.5, 0.5], atol=1e-12)
    last = [s for s in tfs if not s.static][-2:]
    (mo,) = [s for s in last if s.child == "odom"]
    (ob,) = [s for s in last if s.child == "base_link"]
    # odom -> base_link = D(t) * truth with D(2 s) = (0.1, -0.04, 4 deg)
    c4, s4 = math.cos(math.radians(4)), math.sin(math.radians(4))
    assert ob.translation[:2] == pytest.approx(
        (0.1 + c4 * 1.95 - s4 * 2.0, -0.04 + s4 * 1.95 + c4 * 2.0), abs=1e-9
    )
    yaw_mo = 2 * math.atan2(mo.rotation_xyzw[2], mo.rotation_xyzw[3])
    yaw_ob = 2 * math.atan2(ob.rotation_xyzw[2], ob.rotation_xyzw[3])
    assert math.degrees(yaw_ob) == pytest.approx(4.0)  # 2 deg/s for 2 s
    assert yaw_mo + yaw_ob == pytest.approx(0.0, abs=1e-12)  # the truth: yaw 0
    c, s = math.cos(yaw_mo), math.sin(yaw_mo)
    x = mo.translation[0] + c * ob.translation[0] - s * ob.translation[1]
    y = mo.translation[1] + s * ob.translation[0] + c * ob.translation[1]
    assert (x, y) == pytest.approx((1.95, 2.0), abs=1e-9)
    assert (ob.translation[0], ob.translation[1]) != pytest.approx((1.95, 2.0), abs=1e-3)  # drifted
    # the cloud: 4 rings x 36 beams, all returns in range
    assert 0 < len(clouds[0].points) <= 144


def test_same_seed_gives_identical_logs_another_seed_differs(tmp_path):
    a = simulate(tmp_path, "mcap", sub="a")
    b = simulate(tmp_path, "mcap", sub="b")
    c = simulate(tmp_path, "mcap", "--seed", "4", sub="c")
    assert digest(a) == digest(b)
    assert digest(a) != digest(c)
    assert (tmp_path / "a" / "ground_truth.json").read_bytes() == (
        tmp_path / "b" / "ground_truth.json"
    ).read_bytes()


@pytest.mark.parametrize("fmt", ["ros1", "ros2"])
def test_bags_are_deterministic_too(tmp_path, fmt):
    assert digest(simulate(tmp_path, fmt, sub="a")) == digest(simulate(tmp_path, fmt, sub="b"))


def test_depth_32fc1_and_invalid_pixels(tmp_path):
    doc = json.loads(json.dumps(SCENARIO))
    doc["sensors"] = {
        "depth": {
            "width": 32,
            "height": 24,
            "fx": 26.25,
            "rate": 5,
            "encoding": "32FC1",
            "range_max": 1.9,
            "mount": {"xyz": [0, 0, 1.0]},
        }
    }
    doc["objects"] = []
    out = simulate(tmp_path, "mcap", doc=doc)
    with open_logs(out) as logs:
        frames = [f for _, _, f in logs.messages() if isinstance(f, DepthFrame)]
    assert len(frames) == 10
    assert np.isnan(frames[0].depth_m).all()  # the wall at 2.0 m is beyond range_max 1.9: NaN


def _depth_images(tmp_path: Path, sub: str, **depth) -> tuple[Path, np.ndarray]:
    """The log of SCENARIO's depth camera alone (no noise; the box in front of the wall from
    t = 1 s) with ``depth``'s settings added, and its images (frames, H, W) in metres, NaN
    without a return."""
    doc = json.loads(json.dumps(SCENARIO))
    doc["sensors"] = {"depth": {**SCENARIO["sensors"]["depth"], **depth}}
    out = simulate(tmp_path, "mcap", doc=doc, sub=sub)
    with open_logs(out) as logs:
        return out, np.stack([f.depth_m for _, _, f in logs.messages() if isinstance(f, DepthFrame)])


def test_depth_holes_at_edges_and_at_random(tmp_path):
    """``edge_dropout`` takes the return of exactly the pixels ``depth_edges`` finds in the image
    without it (the box's outline against the wall); ``dropout`` that of a share of the pixels,
    at random; both 0 leave the log byte for byte as without them."""
    from ltmap_cli.sim.sensors import depth_edges

    plain, z = _depth_images(tmp_path, "plain")
    assert np.isfinite(z).all()  # the wall everywhere, the box from t = 1
    zero, _ = _depth_images(tmp_path, "zero", dropout=0, edge_dropout=0)
    assert digest(zero) == digest(plain)
    _, e1 = _depth_images(tmp_path, "edge1", edge_dropout=1)
    _, e3 = _depth_images(tmp_path, "edge3", edge_dropout=3)
    for width, got in ((1, e1), (3, e3)):
        want = np.stack([depth_edges(img, width) for img in z])
        assert np.array_equal(np.isnan(got), want)
        assert np.array_equal(got[~want], z[~want])
    assert not np.isnan(e1[0]).any()  # no box yet: no edge
    box = np.isnan(e1[-1])
    assert 30 <= box.sum() <= 80 and box[:, :5].sum() == 0  # its outline, not the wall's middle
    assert np.isnan(e3[-1]).sum() > box.sum()
    _, dropped = _depth_images(tmp_path, "drop", dropout=0.2)
    holes = np.isnan(dropped)
    n = holes.size
    assert abs(holes.sum() - 0.2 * n) < 5 * math.sqrt(n * 0.2 * 0.8)
    assert not np.array_equal(holes[0], holes[1])  # drawn for each image
    assert np.array_equal(dropped[~holes], z[~holes])
    _, noisy = _depth_images(tmp_path, "noisy", noise=0.01)
    _, noisy_dropped = _depth_images(tmp_path, "noisy_drop", noise=0.01, dropout=0.2)
    holes = np.isnan(noisy_dropped)
    assert holes.any() and np.array_equal(noisy_dropped[~holes], noisy[~holes])  # the noise drawn as without holes


def test_ground_truth_describes_objects_and_path(tmp_path):
    doc = json.loads(json.dumps(SCENARIO))
    doc["doors"] = [{"id": "door", "from": [3.5, 1], "to": [3.5, 3], "closed": [[0.5, 1.5]]}]
    doc["people"] = [{"id": "bob", "path": [{"t": 0.2, "x": 3, "y": 0.5}, {"t": 1.8, "x": 3, "y": 3.5}]}]
    simulate(tmp_path, "mcap", doc=doc)
    gt = json.loads((tmp_path / "ground_truth.json").read_text())
    objs = {o["id"]: o for o in gt["objects"]}
    assert objs["b"]["kind"] == "static object" and objs["b"]["present"] == [[1.0, 2.0]]
    assert objs["b"]["parts"] == [
        {"type": "box", "center": [3.0, 2.0, 0.25], "size": [0.4, 0.4, 0.5], "yaw_deg": 0.0}
    ]
    assert objs["door"]["category"] == "door" and objs["door"]["present"] == [[0.5, 1.5]]
    assert objs["door"]["parts"][0]["size"] == pytest.approx([2.0, 0.04, 2.0])
    assert objs["bob"]["kind"] == "person" and objs["bob"]["present"] == [[0.2, 1.8]]
    path = gt["robot"]["path"]
    assert path[0] == {"t": 0.0, "x": 1.95, "y": 2.0, "yaw_deg": 0.0} and len(path) == 21
    assert gt["start_time_ns"] == 1_700_000_000 * 10**9 and gt["duration_s"] == 2.0


def test_output_replaces_an_existing_log_and_leaves_no_temp_files(tmp_path):
    out = simulate(tmp_path, "ros2")
    out2 = simulate(tmp_path, "ros2")
    assert out == out2 and (out / "metadata.yaml").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ground_truth.json", "log_ros2", "scenario.yaml"]
    m = simulate(tmp_path, "mcap")
    simulate(tmp_path, "mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "ground_truth.json",
        "log.mcap",
        "log_ros2",
        "scenario.yaml",
    ]
    assert m.stat().st_mode & 0o444 == 0o444


def test_format_from_the_output_name(tmp_path):
    scen = write_scenario(tmp_path)
    res = CliRunner().invoke(cli, ["simulate", str(scen), "-o", str(tmp_path / "x.bag"), "-q"])
    assert res.exit_code == 0, res.output
    with open_logs(tmp_path / "x.bag") as logs:
        assert logs.formats == ["ros1"]
