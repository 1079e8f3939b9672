"""ReplayMcapWriter: the replay.mcap is read back exactly by mcap + mcap_ros2 and by ltmap's reader."""

from __future__ import annotations

import io
import math
import os
from pathlib import Path

import numpy as np
import pytest

from ltmap_cli.io.frames import CloudFrame, ScanFrame, TfSample
from ltmap_cli.io.logs import open_logs
from ltmap_cli.io.mcap_out import ReplayMcapWriter, yaw_to_quaternion

S = 1_000_000_000
T0 = 1_700_000_000 * S + 123_456_789  # a real-looking epoch stamp with nanoseconds


def _grid() -> np.ndarray:
    g = np.full((5, 7), -1, dtype=np.int8)
    g[0, :] = 0  # row 0 = lowest y
    g[1, 2] = 100
    g[2, 3] = 37
    g[4, 6] = 100
    return g


def _cloud() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    pts = rng.uniform(-5, 5, (50, 3)).astype(np.float32)
    vals = rng.uniform(0, 1, 50).astype(np.float32)
    return pts, vals


RANGES = np.array([1.0, np.nan, np.inf, 2.5, -np.inf, 0.05, 9.75], dtype=np.float32)
MOUNT = ("base_link", "laser", (0.1, 0.0, 0.2), (0.0, 0.0, 0.0, 1.0))


def _write_all(path: Path, **kw) -> dict[str, int]:
    pts, vals = _cloud()
    with ReplayMcapWriter(path, **kw) as w:
        w.write_tf(T0 + 5 * S, [MOUNT], static=True)  # arrives late; must be latched at T0
        w.write_tf(T0, [("map", "odom", (1.0, 2.0, 0.0), yaw_to_quaternion(0.3)),
                        ("odom", "base_link", (0.5, -0.25, 0.0), (0.0, 0.0, 0.0, 1.0))])
        w.write_grid("/map", T0, _grid(), 0.05, (-1.5, 2.25, 0.5), "map")
        w.write_grid("/long_term_map", T0, _grid() // 2, 0.1, (0.0, 0.0, 0.0), "map")
        w.write_cloud("/ltmap/occupied_voxels", T0 + S // 2, pts, "map", values=vals, value_name="lt")
        w.write_cloud("/ltmap/plain", T0 + S // 2, pts[:3], "map")
        w.write_scan("/scan_fused", T0 + S, "laser", -1.5, 0.5, 0.05, 10.0, RANGES)
        w.write_tf(T0 + S, [("odom", "base_link", (0.75, -0.25, 0.0), yaw_to_quaternion(-0.2))])
        w.write_grid("/map", T0 + 2 * S, _grid(), 0.05, (-1.5, 2.25, 0.5), "map")
    return w.counts


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> tuple[Path, dict[str, int]]:
    path = tmp_path_factory.mktemp("mcap") / "replay.mcap"
    counts = _write_all(path)
    return path, counts


def _decoded(path: Path) -> list:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return list(reader.iter_decoded_messages(log_time_order=True))


def _ns(t) -> int:
    return t.sec * S + t.nanosec


def test_file_header_schemas_and_channels(written):
    from mcap.reader import make_reader

    path, counts = written
    with path.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
    schemas = {s.id: s for s in summary.schemas.values()}
    by_topic = {c.topic: c for c in summary.channels.values()}
    types = {t: schemas[c.schema_id].name for t, c in by_topic.items()}
    assert types == {"/map": "nav_msgs/msg/OccupancyGrid", "/long_term_map": "nav_msgs/msg/OccupancyGrid",
                     "/ltmap/occupied_voxels": "sensor_msgs/msg/PointCloud2",
                     "/ltmap/plain": "sensor_msgs/msg/PointCloud2",
                     "/scan_fused": "sensor_msgs/msg/LaserScan", "/tf": "tf2_msgs/msg/TFMessage",
                     "/tf_static": "tf2_msgs/msg/TFMessage"}
    assert {c.message_encoding for c in by_topic.values()} == {"cdr"}
    assert {s.encoding for s in schemas.values()} == {"ros2msg"}
    # full definitions, dependencies included (what Foxglove needs to decode without a ROS install)
    grid_text = next(s.data.decode() for s in schemas.values() if s.name.endswith("OccupancyGrid"))
    assert "MSG: nav_msgs/MapMetaData" in grid_text and "MSG: geometry_msgs/Pose" in grid_text
    stats = summary.statistics
    ids = {c.id: c.topic for c in summary.channels.values()}
    assert {ids[k]: v for k, v in stats.channel_message_counts.items()} == counts
    assert counts == {"/tf": 2, "/map": 2, "/long_term_map": 1, "/ltmap/occupied_voxels": 1,
                      "/ltmap/plain": 1, "/scan_fused": 1, "/tf_static": 1}
    assert all(ci.compression == "zstd" for ci in summary.chunk_indexes)
    assert stats.message_start_time == T0 and stats.message_end_time == T0 + 2 * S


def test_channels_offer_qos_for_ros2_bag_play(written):
    from mcap.reader import make_reader
    from rosbags.interfaces import QosDurability, QosReliability
    from rosbags.rosbag2.metadata import parse_qos

    path, _ = written
    with path.open("rb") as f:
        channels = make_reader(f).get_summary().channels.values()
    durability = {}
    for ch in channels:
        [qos] = parse_qos(ch.metadata["offered_qos_profiles"])
        assert qos.reliability == QosReliability.RELIABLE
        durability[ch.topic] = qos.durability
    latched = {t for t, d in durability.items() if d == QosDurability.TRANSIENT_LOCAL}
    assert latched == {"/tf_static", "/map", "/long_term_map"}
    assert {d for t, d in durability.items() if t not in latched} == {QosDurability.VOLATILE}


def test_mcap_ros2_decodes_everything_exactly(written):
    path, counts = written
    msgs = _decoded(path)
    seen: dict[str, int] = {}
    for _schema, ch, m, _d in msgs:
        seen[ch.topic] = seen.get(ch.topic, 0) + 1
        assert m.log_time == m.publish_time
    assert seen == counts
    by = {}
    for _schema, ch, m, d in msgs:
        by.setdefault(ch.topic, []).append((m, d))

    m, grid = by["/map"][0]
    assert m.log_time == T0 and _ns(grid.header.stamp) == T0 and grid.header.frame_id == "map"
    assert _ns(grid.info.map_load_time) == T0
    assert (grid.info.width, grid.info.height) == (7, 5)
    assert grid.info.resolution == float(np.float32(0.05))  # float32 in MapMetaData
    cells = np.frombuffer(bytes(np.asarray(grid.data, dtype=np.int8)), np.int8).reshape(5, 7)
    assert np.array_equal(cells, _grid())  # row 0 = lowest y, -1 kept
    o = grid.info.origin
    assert (o.position.x, o.position.y, o.position.z) == (-1.5, 2.25, 0.0)
    q = (o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w)
    assert q == yaw_to_quaternion(0.5)
    assert [mm.log_time for mm, _ in by["/map"]] == [T0, T0 + 2 * S]
    _, lt = by["/long_term_map"][0]
    assert np.array_equal(np.asarray(lt.data, np.int8).reshape(5, 7), _grid() // 2)
    assert lt.info.resolution == pytest.approx(0.1)

    pts, vals = _cloud()
    m, c = by["/ltmap/occupied_voxels"][0]
    assert m.log_time == T0 + S // 2 and c.header.frame_id == "map"
    assert (c.height, c.width, c.point_step, c.row_step) == (1, 50, 16, 16 * 50)
    assert not c.is_bigendian and c.is_dense
    assert [(f.name, f.offset, f.datatype, f.count) for f in c.fields] == [
        ("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("lt", 12, 7, 1)]
    rec = np.frombuffer(bytes(c.data), "<f4").reshape(50, 4)
    assert np.array_equal(rec[:, :3], pts) and np.array_equal(rec[:, 3], vals)
    _, c3 = by["/ltmap/plain"][0]
    assert c3.point_step == 12 and [f.name for f in c3.fields] == ["x", "y", "z"]
    assert np.array_equal(np.frombuffer(bytes(c3.data), "<f4").reshape(3, 3), pts[:3])

    m, s = by["/scan_fused"][0]
    assert m.log_time == T0 + S and _ns(s.header.stamp) == T0 + S and s.header.frame_id == "laser"
    r = np.asarray(s.ranges, dtype=np.float32)
    assert np.array_equal(r, RANGES, equal_nan=True)
    assert np.isposinf(r[2]) and np.isneginf(r[4])
    assert s.angle_min == -1.5 and s.angle_increment == 0.5 and s.angle_max == -1.5 + 0.5 * 6
    assert s.range_min == np.float32(0.05) and s.range_max == 10.0 and len(s.intensities) == 0

    tfs = [(mm.log_time, [(_ns(t.header.stamp), t.header.frame_id, t.child_frame_id,
                           (t.transform.translation.x, t.transform.translation.y, t.transform.translation.z),
                           (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
                            t.transform.rotation.w)) for t in d.transforms])
           for mm, d in by["/tf"]]
    assert tfs == [
        (T0, [(T0, "map", "odom", (1.0, 2.0, 0.0), yaw_to_quaternion(0.3)),
              (T0, "odom", "base_link", (0.5, -0.25, 0.0), (0.0, 0.0, 0.0, 1.0))]),
        (T0 + S, [(T0 + S, "odom", "base_link", (0.75, -0.25, 0.0), yaw_to_quaternion(-0.2))])]
    # /tf_static: one message at the file's first stamp, even though it was given at T0 + 5 s
    [(m, st)] = by["/tf_static"]
    assert m.log_time == T0
    assert [(_ns(t.header.stamp), t.header.frame_id, t.child_frame_id) for t in st.transforms] == [
        (T0, "base_link", "laser")]


def test_ltmap_reader_reads_it_back(written):
    path, _ = written
    pts, _vals = _cloud()
    with open_logs(path) as logs:
        assert logs.topics["/map"].msgtype == "nav_msgs/msg/OccupancyGrid"
        assert logs.topics["/map"].count == 2
        assert logs.topics["/scan_fused"].msgtype == "sensor_msgs/msg/LaserScan"
        assert logs.start_ns == T0 and logs.end_ns == T0 + 2 * S
        items = list(logs.messages())
    scans = [it for _, _, it in items if isinstance(it, ScanFrame)]
    clouds = {it.topic: it for _, _, it in items if isinstance(it, CloudFrame)}
    tfs = [it for _, _, it in items if isinstance(it, TfSample)]
    [sc] = scans
    assert (sc.stamp_ns, sc.frame_id, sc.topic) == (T0 + S, "laser", "/scan_fused")
    assert sc.angle_min == -1.5 and sc.angle_increment == 0.5
    assert sc.range_min == pytest.approx(0.05) and sc.range_max == 10.0
    assert np.array_equal(sc.ranges, RANGES, equal_nan=True)
    assert np.array_equal(clouds["/ltmap/occupied_voxels"].points, pts)
    assert clouds["/ltmap/occupied_voxels"].stamp_ns == T0 + S // 2
    assert np.array_equal(clouds["/ltmap/plain"].points, pts[:3])
    # the static mount shares the first stamp with the first /tf message (their order is a tie)
    assert [t for t in tfs if t.static] == [
        TfSample(T0, "base_link", "laser", (0.1, 0.0, 0.2), (0.0, 0.0, 0.0, 1.0), static=True)]
    assert [t for t in tfs if not t.static] == [
        TfSample(T0, "map", "odom", (1.0, 2.0, 0.0), yaw_to_quaternion(0.3)),
        TfSample(T0, "odom", "base_link", (0.5, -0.25, 0.0), (0.0, 0.0, 0.0, 1.0)),
        TfSample(T0 + S, "odom", "base_link", (0.75, -0.25, 0.0), yaw_to_quaternion(-0.2)),
    ]


def test_bytes_match_mcap_ros2_writer(written):
    """Our CDR (rosbags) is byte for byte what mcap_ros2.writer.Writer encodes from the same content."""
    from mcap.reader import make_reader
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    path, _ = written
    ts = get_typestore(Stores.ROS2_HUMBLE)
    ours: dict[str, bytes] = {}
    with path.open("rb") as f:
        for schema, ch, m in make_reader(f).iter_messages(log_time_order=True):
            ours.setdefault(ch.topic, m.data)
            assert schema.data.decode() == ts.generate_msgdef(schema.name, ros_version=2)[0]
    decoded: dict = {}
    for _s, ch, _m, d in _decoded(path):
        decoded.setdefault(ch.topic, d)

    def plain(obj):
        if hasattr(obj, "__slots__") and obj.__slots__:
            return {k: plain(getattr(obj, k)) for k in obj.__slots__}
        if isinstance(obj, list):
            return [plain(v) for v in obj]
        return obj

    buf = io.BytesIO()
    w = Writer(buf)
    schemas = {}
    for topic, d in decoded.items():
        name = {"/map": "nav_msgs/msg/OccupancyGrid", "/long_term_map": "nav_msgs/msg/OccupancyGrid",
                "/scan_fused": "sensor_msgs/msg/LaserScan", "/tf": "tf2_msgs/msg/TFMessage",
                "/tf_static": "tf2_msgs/msg/TFMessage"}.get(topic, "sensor_msgs/msg/PointCloud2")
        if name not in schemas:
            schemas[name] = w.register_msgdef(name, ts.generate_msgdef(name, ros_version=2)[0])
        w.write_message(topic, schemas[name], plain(d), log_time=1)
    w.finish()
    buf.seek(0)
    theirs = {ch.topic: m.data for _s, ch, m in make_reader(buf).iter_messages()}
    assert theirs.keys() == ours.keys()
    for topic in ours:
        assert theirs[topic] == ours[topic], topic


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_other_compressions(tmp_path, compression):
    from mcap.reader import make_reader

    path = tmp_path / "r.mcap"
    counts = _write_all(path, compression=compression)
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert {ci.compression for ci in summary.chunk_indexes} == {"" if compression == "none" else compression}
    assert sum(1 for _ in _decoded(path)) == sum(counts.values())


def test_empty_and_nan_clouds_and_static_only(tmp_path):
    path = tmp_path / "r.mcap"
    with ReplayMcapWriter(path) as w:
        w.write_cloud("/c", 5 * S, np.zeros((0, 3)), "map", values=np.zeros(0))
        w.write_cloud("/d", 6 * S, np.array([[1, 2, 3], [np.nan, 0, 0]]), "map")
        w.write_tf(7 * S, [MOUNT, ("base_link", "laser", (0.2, 0.0, 0.3), (0.0, 0.0, 0.0, 1.0))], static=True)
    by = {ch.topic: (m, d) for _s, ch, m, d in _decoded(path)}
    assert by["/c"][1].width == 0 and by["/c"][1].is_dense
    assert not by["/d"][1].is_dense
    m, st = by["/tf_static"]
    assert m.log_time == 5 * S and len(st.transforms) == 1  # latest per child wins
    assert st.transforms[0].transform.translation.x == 0.2
    with open_logs(path) as logs:
        clouds = [it for _, _, it in logs.messages() if isinstance(it, CloudFrame)]
    assert [len(c.points) for c in clouds] == [0, 1]  # ltmap's reader drops the NaN point


def test_failure_leaves_no_file(tmp_path):
    path = tmp_path / "out" / "replay.mcap"
    with pytest.raises(RuntimeError), ReplayMcapWriter(path) as w:
        w.write_grid("/map", S, _grid(), 0.05, (0, 0, 0), "map")
        raise RuntimeError("replay failed")
    assert not path.exists()
    assert os.listdir(path.parent) == []  # no temp file either


def test_failure_keeps_previous_file(tmp_path):
    path = tmp_path / "replay.mcap"
    path.write_bytes(b"old")
    with pytest.raises(ValueError), ReplayMcapWriter(path) as w:
        w.write_grid("/map", S, np.array([[0, 101]]), 0.05, (0, 0, 0), "map")
    assert path.read_bytes() == b"old" and os.listdir(tmp_path) == ["replay.mcap"]


def test_abort_and_dropped_writer_remove_temp(tmp_path):
    path = tmp_path / "replay.mcap"
    w = ReplayMcapWriter(path)
    w.write_scan("/s", S, "laser", 0.0, 0.1, 0.1, 5.0, np.ones(3))
    assert len(os.listdir(tmp_path)) == 1  # the temp file, hidden, beside the target
    w.abort()
    assert os.listdir(tmp_path) == []
    w2 = ReplayMcapWriter(path)
    del w2
    import gc

    gc.collect()
    assert os.listdir(tmp_path) == []


def test_close_gives_normal_permissions_and_is_idempotent(tmp_path):
    path = tmp_path / "replay.mcap"
    w = ReplayMcapWriter(path)
    w.write_scan("/s", S, "laser", 0.0, 0.1, 0.1, 5.0, np.ones(3))
    assert not path.exists()
    w.close()
    w.close()
    mask = os.umask(0)
    os.umask(mask)
    assert (path.stat().st_mode & 0o777) == 0o666 & ~mask
    with pytest.raises(ValueError, match="closed"):
        w.write_scan("/s", 2 * S, "laser", 0.0, 0.1, 0.1, 5.0, np.ones(3))


@pytest.mark.parametrize("call, match", [
    (lambda w: w.write_grid("/m", S, np.zeros(4, np.int8), 0.05, (0, 0, 0), "map"), "2-D"),
    (lambda w: w.write_grid("/m", S, np.zeros((2, 2)), 0.05, (0, 0, 0), "map"), "integer"),
    (lambda w: w.write_grid("/m", S, np.full((2, 2), -2), 0.05, (0, 0, 0), "map"), "outside"),
    (lambda w: w.write_grid("/m", S, np.zeros((2, 2), np.int8), 0.0, (0, 0, 0), "map"), "resolution"),
    (lambda w: w.write_cloud("/c", S, np.zeros((3, 2)), "map"), r"\(N, 3\)"),
    (lambda w: w.write_cloud("/c", S, np.zeros((3, 3)), "map", values=np.zeros(2)), "entries"),
    (lambda w: w.write_cloud("/c", S, np.zeros((3, 3)), "map", values=np.zeros(3), value_name="z"), "new field"),
    (lambda w: w.write_tf(S, [("a", "b", (0, 0), (0, 0, 0, 1))]), "need"),
    (lambda w: w.write_scan("s", S, "laser", 0, 0.1, 0.1, 5, np.ones(2)), "start with"),
    (lambda w: w.write_scan("/s", -1, "laser", 0, 0.1, 0.1, 5, np.ones(2)), ">= 0"),
])
def test_bad_input_is_rejected_before_writing(tmp_path, call, match):
    path = tmp_path / "r.mcap"
    with ReplayMcapWriter(path) as w:
        with pytest.raises(ValueError, match=match):
            call(w)
        assert w.counts == {}
        w.write_scan("/ok", S, "laser", 0.0, 0.1, 0.1, 5.0, np.ones(2))  # still usable
    assert w.counts == {"/ok": 1}
    assert [ch.topic for _s, ch, _m, _d in _decoded(path)] == ["/ok"]


def test_topic_keeps_its_type(tmp_path):
    with ReplayMcapWriter(tmp_path / "r.mcap") as w:
        w.write_scan("/x", S, "laser", 0.0, 0.1, 0.1, 5.0, np.ones(2))
        with pytest.raises(ValueError, match="already carries"):
            w.write_cloud("/x", S, np.zeros((1, 3)), "map")


def test_yaw_to_quaternion():
    assert yaw_to_quaternion(0.0) == (0.0, 0.0, 0.0, 1.0)
    x, y, z, w = yaw_to_quaternion(math.pi / 2)
    assert (x, y) == (0.0, 0.0) and z == pytest.approx(math.sqrt(0.5)) and w == pytest.approx(math.sqrt(0.5))
