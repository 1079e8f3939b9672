"""Log readers: tiny real logs in every format read back exactly; layouts; merging; bad input."""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from logfactory import (
    FORMATS,
    SUFFIX,
    camera_info,
    cloud,
    compressed_depth,
    image,
    odometry,
    scan,
    string,
    tf,
    truncate,
    write_log,
    yaw_quat,
)

from ltmap_cli.errors import InputError, LogReadError
from ltmap_cli.io.frames import CloudFrame, DepthFrame, OdometrySample, ScanFrame, TfSample
from ltmap_cli.io.logs import TruncatedLogError, open_logs, select_topics
from ltmap_cli.io.sources import TopicInfo

S = 1_000_000_000
REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real_logs"


def _log(tmp_path: Path, fmt: str, msgs, name: str = "log", **kw) -> Path:
    return write_log(tmp_path / (name + SUFFIX[fmt]), fmt, msgs, **kw)


def _all(path, **kw):
    with open_logs(path, **kw) as logs:
        return list(logs.messages())


def _mixed():
    return [
        tf(1 * S, [("odom", "base_link", (1.0, 2.0, 0.0), yaw_quat(0.5))]),
        tf(1 * S + 1, [("base_link", "/laser", (0.1, 0.0, 0.2))], static=True),
        scan("/scan", 2 * S, [1.0, float("nan"), float("inf"), 0.05], angle_min=-0.5, angle_increment=0.25,
             stamp_ns=2 * S - 7),
        odometry("/odom", 3 * S, "odom", "base_link", (4.0, 5.0, 0.0), yaw_quat(1.0)),
        string("/chatter", 3 * S + 1, "hello"),
    ]


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_reads_back_exactly(tmp_path, fmt):
    path = _log(tmp_path, fmt, _mixed())
    with open_logs(path) as logs:
        assert logs.formats == [fmt]
        assert {n: (t.msgtype, t.count) for n, t in logs.topics.items()} == {
            "/tf": ("tf2_msgs/msg/TFMessage", 1), "/tf_static": ("tf2_msgs/msg/TFMessage", 1),
            "/scan": ("sensor_msgs/msg/LaserScan", 1), "/odom": ("nav_msgs/msg/Odometry", 1),
            "/chatter": ("std_msgs/msg/String", 1)}
        assert (logs.start_ns, logs.end_ns) == (1 * S, 3 * S + 1)
        out = list(logs.messages())
        assert logs.stats.messages_per_topic == {"/tf": 1, "/tf_static": 1, "/scan": 1, "/odom": 1}
        assert logs.stats.stopped_at is None
    assert [(t, lt) for t, lt, _ in out] == [("/tf", S), ("/tf_static", S + 1), ("/scan", 2 * S), ("/odom", 3 * S)]
    assert out[0][2] == TfSample(S, "odom", "base_link", (1.0, 2.0, 0.0), yaw_quat(0.5), static=False)
    assert out[1][2] == TfSample(S + 1, "base_link", "laser", (0.1, 0.0, 0.2), (0.0, 0.0, 0.0, 1.0), static=True)
    sc = out[2][2]
    assert isinstance(sc, ScanFrame)
    assert (sc.stamp_ns, sc.frame_id, sc.topic) == (2 * S - 7, "laser", "/scan")
    assert sc.ranges.dtype == np.float32
    np.testing.assert_array_equal(sc.ranges, np.array([1.0, np.nan, np.inf, 0.05], np.float32))
    np.testing.assert_allclose(sc.angles, [-0.5, -0.25, 0.0, 0.25])
    assert (sc.range_min, sc.range_max) == (pytest.approx(0.1), 10.0)
    assert out[3][2] == OdometrySample(3 * S, "odom", "base_link", (4.0, 5.0, 0.0), yaw_quat(1.0))


CLOUD_PTS = [[1.0, 2.0, 3.0], [-4.5, 0.25, 6.0], [np.nan, 1.0, 1.0], [7.0, 8.0, np.inf], [0.0, 0.0, -1.0],
             [1e3, -2e3, 3.5]]
FINITE = np.array([CLOUD_PTS[i] for i in (0, 1, 4, 5)], np.float32)


@pytest.mark.parametrize("layout", [
    dict(),
    dict(dtype="f8"),
    dict(big_endian=True),
    dict(dtype="f8", big_endian=True, pad=5),
    dict(extra=[("intensity", "f4"), ("t", "u4")], pad=2),
    dict(xyz_offset=4, extra=[("ring", "u2")], pad=3),  # x not at offset 0
    dict(height=2, row_pad=6, pad=4),  # organized, padded rows
    dict(height=3, dtype="f8", big_endian=True, row_pad=1, extra=[("intensity", "f4")]),
])
@pytest.mark.parametrize("fmt", ["ros1", "mcap-ros2"])
def test_pointcloud2_layouts(tmp_path, fmt, layout):
    path = _log(tmp_path, fmt, [cloud("/points", S, CLOUD_PTS, **layout)])
    (topic, _, fr), = _all(path)
    assert isinstance(fr, CloudFrame) and fr.frame_id == "lidar" and fr.points.dtype == np.float32
    np.testing.assert_array_equal(fr.points, FINITE)


@pytest.mark.parametrize("fmt", FORMATS)
def test_depth_16uc1_and_32fc1_with_row_padding(tmp_path, fmt):
    mm = np.array([[1000, 0, 2500], [65535, 1, 300]])
    m = np.array([[1.5, np.nan, 0.0], [np.inf, 0.25, 3.0]])
    msgs = [camera_info("/cam/depth/camera_info", S, width=3, height=2, fx=500.0, fy=501.0, cx=1.5, cy=0.75),
            image("/cam/depth/image_raw", 2 * S, mm, encoding="16UC1", row_pad=3),
            image("/cam/depth/image_raw", 3 * S, m, encoding="32FC1", row_pad=4, big_endian=True),
            image("/cam/depth/image_raw", 4 * S, mm, encoding="16UC1", big_endian=True)]
    path = _log(tmp_path, fmt, msgs)
    out = _all(path)
    assert [t for t, _, _ in out] == ["/cam/depth/image_raw"] * 3
    a, b, c = (fr for _, _, fr in out)
    assert isinstance(a, DepthFrame) and a.depth_m.dtype == np.float32 and a.frame_id == "camera_optical"
    np.testing.assert_allclose(a.depth_m, [[1.0, np.nan, 2.5], [65.535, 0.001, 0.3]], rtol=1e-6)
    np.testing.assert_array_equal(b.depth_m, np.array([[1.5, np.nan, np.nan], [np.nan, 0.25, 3.0]], np.float32))
    np.testing.assert_allclose(c.depth_m, a.depth_m, rtol=1e-6)
    i = a.intrinsics
    assert (i.width, i.height, i.fx, i.fy, i.cx, i.cy) == (3, 2, 500.0, 501.0, 1.5, 0.75)


@pytest.mark.parametrize("fmt", ["ros1", "mcap-ros1", "ros2-sqlite3"])
def test_depth_before_camera_info_is_counted_and_colour_encoding_is_an_error(tmp_path, fmt):
    msgs = [image("/cam/depth/image_raw", S, [[1000]]),
            camera_info("/cam/depth/camera_info", 2 * S, width=1, height=1, fx=1, fy=1, cx=0, cy=0),
            image("/cam/depth/image_raw", 3 * S, [[1000]]),
            image("/cam/depth/image_raw", 4 * S, [[1, 2, 3]], encoding="rgb8")]
    path = _log(tmp_path, fmt, msgs)
    with open_logs(path) as logs:
        it = logs.messages()
        assert next(it)[1] == 3 * S
        with pytest.raises(LogReadError, match=r"'rgb8'.*16UC1.*32FC1.*--depth-topic") as e:
            next(it)
        assert "/cam/depth/image_raw, message index 2" in str(e.value) and path.name in str(e.value)
        assert logs.skipped == {"depth image on /cam/depth/image_raw before any CameraInfo on "
                                "/cam/depth/camera_info": 1}


def test_several_logs_merge_in_time_order(tmp_path):
    a = _log(tmp_path, "ros1", [scan("/scan", t * S, [1.0]) for t in (1, 4, 6)], name="a")
    b = _log(tmp_path, "mcap-ros2", [scan("/scan", t * S, [2.0]) for t in (2, 3, 7)], name="b")
    c = _log(tmp_path, "ros2-sqlite3", [tf(t * S, [("odom", "base_link")]) for t in (0, 5)], name="c")
    with open_logs([a, b, c]) as logs:
        assert logs.topics["/scan"].count == 6 and (logs.start_ns, logs.end_ns) == (0, 7 * S)
        got = [(t, lt, getattr(fr, "ranges", [None])[0]) for t, lt, fr in logs.messages()]
    assert got == [("/tf", 0, None), ("/scan", S, 1.0), ("/scan", 2 * S, 2.0), ("/scan", 3 * S, 2.0),
                   ("/scan", 4 * S, 1.0), ("/tf", 5 * S, None), ("/scan", 6 * S, 1.0), ("/scan", 7 * S, 2.0)]


def test_a_recording_split_into_many_files_is_read_a_file_or_two_at_a_time(tmp_path, monkeypatch):
    """rosbag2 --max-bag-duration / rosbag record --split: the files follow each other in time.
    The merge starts a file's stream when it reaches the file's first message, so at most the
    file being read and the next are open in the stream (before: every file's first chunk at
    once), and the order is still that of the whole log (by log time, then by file given)."""
    from ltmap_cli.io import logs as logs_mod

    fmts = ["ros1", "mcap-ros2", "ros2-sqlite3"]
    paths = []
    for i in range(9):  # 1 s a file, 4 scans and 2 tf each; the last one overlaps its predecessor
        t0 = i * S if i < 8 else 7 * S + S // 8
        msgs = [scan("/scan", t0 + j * S // 4, [float(i)]) for j in range(4)]
        msgs += [tf(t0 + j * S // 2, [("odom", "base_link")]) for j in range(2)]
        paths.append(_log(tmp_path, fmts[i % 3], sorted(msgs, key=lambda m: m.log_time_ns), name=f"part_{i}"))
    live, most = set(), [0]
    tagged = logs_mod.LogSet._tagged

    def counting(src, wanted, k, skip=None):
        live.add(k)
        most[0] = max(most[0], len(live))
        try:
            yield from tagged(src, wanted, k, skip)
        finally:
            live.discard(k)

    monkeypatch.setattr(logs_mod.LogSet, "_tagged", staticmethod(counting))
    with open_logs(paths[::-1]) as logs:  # given in any order
        got = [(lt, fr.ranges[0] if isinstance(fr, ScanFrame) else None) for _, lt, fr in logs.messages()]
    assert most[0] == 2  # the overlapping pair; never all nine
    want = sorted([(i * S + j * S // 4, float(i)) for i in range(8) for j in range(4)]
                  + [(7 * S + S // 8 + j * S // 4, 8.0) for j in range(4)]
                  + [(i * S + j * S // 2, None) for i in range(8) for j in range(2)]
                  + [(7 * S + S // 8 + j * S // 2, None) for j in range(2)],
                  key=lambda x: x[0])
    assert [t for t, _ in got] == [t for t, _ in want]
    assert [r for _, r in got if r is not None] == [r for _, r in want if r is not None]


def test_merge_order_and_lazy_starts_by_hand():
    from ltmap_cli.io.logs import _merge

    started = []

    def stream(k, times):
        started.append(k)
        for t in times:
            yield (t, k)

    # stream 1 says it starts at 5 but holds 3 (a wrong summary): it is only late, nothing is lost
    streams = [stream(0, [1, 4, 9]), stream(1, [3, 6]), stream(2, [2, 4]), stream(3, [10])]
    out = []
    for item in _merge(streams, [0, 5, None, 9]):
        out.append(item)
        if item == (4, 2):
            assert started == [2, 0]  # 1 and 3 not started yet
    assert started == [2, 0, 1, 3]
    assert out == [(1, 0), (2, 2), (4, 0), (4, 2), (3, 1), (6, 1), (9, 0), (10, 3)]


@pytest.mark.parametrize("fmt", ["ros2-sqlite3", "ros2-mcap"])
@pytest.mark.parametrize("mode", ["file", "message"])
def test_ros2_bags_recorded_compressed_read_back_exactly(tmp_path, fmt, mode):
    """``ros2 bag record --compression-mode file|message --compression-format zstd``, in both
    storages: the same frames as the bag recorded plain. (ltmap reads mcap storage itself: each
    message of a message-compressed one is decompressed, within replay.max_message_mb; before,
    every message of such a bag was "damaged".) A damaged compressed message is skipped and
    counted; another compressor named in metadata.yaml is one line."""
    plain = _all(_log(tmp_path, fmt, _mixed(), name="plain"))
    packed = _log(tmp_path, fmt, _mixed(), name="packed", ros2_compression=mode)
    got = _all(packed)
    assert [(t, lt, type(f)) for t, lt, f in got] == [(t, lt, type(f)) for t, lt, f in plain]
    a, b = got[2][2], plain[2][2]  # the scan, field for field
    assert (a.stamp_ns, a.frame_id, a.angle_min, a.angle_increment) == (b.stamp_ns, b.frame_id, b.angle_min,
                                                                      b.angle_increment)  # fmt: skip
    assert np.array_equal(a.ranges, b.ranges, equal_nan=True)
    if fmt == "ros2-mcap" and mode == "message":
        import yaml

        meta = packed / "metadata.yaml"
        doc = yaml.safe_load(meta.read_text())
        doc["rosbag2_bagfile_information"]["compression_format"] = "lz4"
        meta.write_text(yaml.safe_dump(doc))
        with pytest.raises(InputError, match="its messages are compressed with 'lz4'; ltmap reads zstd"):
            open_logs(packed)


@pytest.fixture
def tmpdir_here(tmp_path, monkeypatch):
    """TMPDIR pointed at a folder of this test (tempfile reads it again)."""
    import tempfile

    d = tmp_path / "tmpdir"
    d.mkdir()
    monkeypatch.setenv("TMPDIR", str(d))
    monkeypatch.setattr(tempfile, "tempdir", None)
    return d


def _without_file_entries(bag: Path) -> None:
    """metadata.yaml as rosbag2 wrote it before its per-file entries (``files``)."""
    import yaml

    meta = bag / "metadata.yaml"
    doc = yaml.safe_load(meta.read_text())
    del doc["rosbag2_bagfile_information"]["files"]
    meta.write_text(yaml.safe_dump(doc))


@pytest.mark.parametrize("fmt", ["ros2-sqlite3", "ros2-mcap"])
def test_a_bag_compressed_file_by_file_is_read_from_a_copy_removed_at_the_end(tmp_path, fmt, tmpdir_here,
                                                                              monkeypatch):
    """--compression-mode file: every storage file one zstd stream. ltmap decompresses each file
    into a folder under TMPDIR when reading reaches it (an MCAP storage then goes through ltmap's
    own MCAP reader), reads the same frames as the plain bag, and removes the copy once the file
    is read. Without metadata.yaml's per-file entries (older rosbag2) the whole bag is copied
    when opened, removed when the log is closed."""
    from ltmap_cli.io import sources

    plain = _all(_log(tmp_path, fmt, _mixed(), name="plain"))
    packed = _log(tmp_path, fmt, _mixed(), name="packed", ros2_compression="file")
    assert not list(packed.glob("*.db3")) and not list(packed.glob("*.mcap"))
    with open_logs(packed) as logs:
        assert not list(tmpdir_here.iterdir())  # nothing decompressed before reading reaches it
        assert [type(s) for s in logs.sources] == [sources.CompressedFileSource]
        assert logs.topics["/scan"].count == 1 and logs.start_ns == S and logs.end_ns == 3 * S + 1
        got = []
        for item in logs.messages():
            copies = list(tmpdir_here.glob("ltmap-bag-*/*"))
            assert [c.suffix for c in copies] == [".mcap" if fmt == "ros2-mcap" else ".db3"]
            got.append(item)
        assert not list(tmpdir_here.iterdir())  # removed once read
    assert [(t, lt, type(f)) for t, lt, f in got] == [(t, lt, type(f)) for t, lt, f in plain]
    # a big one is said before it is read (where it goes, what chooses it)
    monkeypatch.setattr(sources, "DECOMPRESS_NOTE", 0)
    with pytest.warns(Warning, match=f"compressed file by file: each of its 1 files is decompressed into "
                                     f"{tmpdir_here} when reading reaches it"):
        open_logs(packed).close()
    _without_file_entries(packed)
    with pytest.warns(Warning, match=f"compressed file by file: decompressing its 1 file .* into {tmpdir_here} first"):
        logs = open_logs(packed)
    with logs:
        copies = list(tmpdir_here.glob("ltmap-bag-*"))
        assert len(copies) == 1 and (copies[0] / "metadata.yaml").is_file()
        assert all(isinstance(s, sources.McapSource if fmt == "ros2-mcap" else sources.Ros2BagSource)
                   for s in logs.sources)  # fmt: skip
        got = list(logs.messages())
    assert [(t, lt, type(f)) for t, lt, f in got] == [(t, lt, type(f)) for t, lt, f in plain]
    assert not list(tmpdir_here.iterdir())  # the copy is gone


@pytest.mark.parametrize("entries", [True, False])
def test_a_copy_that_would_fill_the_disk_stops_with_one_line(tmp_path, tmpdir_here, monkeypatch, entries):
    """The copy watches the disk as it fills: once it would leave less than KEEP_FREE_BYTES
    (here: all but 1 kB of what is free), one line says where, how much, and what to do (TMPDIR,
    `ros2 bag convert`), and nothing is left in TMPDIR. (rosbags' own copy ran into ENOSPC,
    reported as a corrupt bag; a few kB of zstd can claim terabytes.) When the bag is read a
    file at a time, that is when reading reaches the file; else when it is opened."""
    import shutil

    from ltmap_cli.io import sources

    packed = _log(tmp_path, "ros2-sqlite3", _mixed(), name="packed", ros2_compression="file")
    if not entries:
        _without_file_entries(packed)
    monkeypatch.setattr(sources, "KEEP_FREE_BYTES", shutil.disk_usage(tmpdir_here).free - 1024)
    with pytest.raises(LogReadError) as err:
        _all(packed)
    text = str(err.value)
    assert "compressed file by file" in text and str(tmpdir_here) in text and "set TMPDIR" in text
    assert "ros2 bag convert" in text and "\n" not in text and "packed.db3.zstd" in text
    assert not list(tmpdir_here.iterdir())


def test_a_file_left_uncompressed_in_a_bag_compressed_file_by_file_is_read_as_it_is(tmp_path, tmpdir_here):
    """A recorder stopped before compressing its last file leaves it plain (listed without .zstd)."""
    import yaml
    import zstandard

    plain = _all(_log(tmp_path, "ros2-sqlite3", _mixed(), name="plain"))
    packed = _log(tmp_path, "ros2-sqlite3", _mixed(), name="packed", ros2_compression="file")
    z = next(packed.glob("*.zstd"))
    with z.open("rb") as fi, (packed / z.stem).open("wb") as fo:
        zstandard.ZstdDecompressor().copy_stream(fi, fo)
    z.unlink()
    meta = packed / "metadata.yaml"
    doc = yaml.safe_load(meta.read_text())
    doc["rosbag2_bagfile_information"]["relative_file_paths"] = [z.stem]
    doc["rosbag2_bagfile_information"]["files"][0]["path"] = z.stem
    meta.write_text(yaml.safe_dump(doc))
    got = _all(packed)
    assert [(t, lt, type(f)) for t, lt, f in got] == [(t, lt, type(f)) for t, lt, f in plain]
    assert not list(tmpdir_here.iterdir())


def test_a_damaged_or_missing_file_of_a_bag_compressed_file_by_file_is_one_line(tmp_path, tmpdir_here):
    import yaml

    plain = _all(_log(tmp_path, "ros2-sqlite3", _mixed(), name="plain"))
    packed = _log(tmp_path, "ros2-sqlite3", _mixed(), name="packed", ros2_compression="file")
    z = next(packed.glob("*.zstd"))
    # a hostile metadata.yaml listing one file 100,000 times, by paths out of the folder: each
    # name is the file of that name in the folder, decompressed once
    meta = packed / "metadata.yaml"
    doc = yaml.safe_load(meta.read_text())
    doc["rosbag2_bagfile_information"]["relative_file_paths"] = ["../../etc/" + z.name] * 100_000
    meta.write_text(yaml.safe_dump(doc))
    with open_logs(packed) as logs:
        assert [s.path for s in logs.sources] == [z]
        got = list(logs.messages())
    assert [(t, lt, type(f)) for t, lt, f in got] == [(t, lt, type(f)) for t, lt, f in plain]
    # metadata.yaml's topics and per-file entries are not trusted further than their types:
    # damaged ones read the bag as a copy made when it is opened
    doc["rosbag2_bagfile_information"]["relative_file_paths"] = [z.name]
    for bad in ("oops", [{"path": z.name, "starting_time": {"nanoseconds_since_epoch": -5}}]):
        doc["rosbag2_bagfile_information"]["files"] = bad
        meta.write_text(yaml.safe_dump(doc))
        got = _all(packed)
        assert [(t, lt, type(f)) for t, lt, f in got] == [(t, lt, type(f)) for t, lt, f in plain]
    data = bytearray(z.read_bytes())
    data[:4] = b"\x00\x01\x02\x03"  # not a zstd frame
    z.write_bytes(bytes(data))
    with pytest.raises(LogReadError, match=f"{z.name} is not a readable zstd stream"):
        open_logs(packed)  # (the copy made when opened)
    doc = yaml.safe_load(meta.read_text())
    doc["rosbag2_bagfile_information"]["files"] = [{"path": z.name, "starting_time": {"nanoseconds_since_epoch": S},
                                                    "duration": {"nanoseconds": 2 * S}}]  # fmt: skip
    meta.write_text(yaml.safe_dump(doc))
    with pytest.raises(LogReadError, match=f"{z.name} is not a readable zstd stream"):
        _all(packed)  # (when reading reaches it)
    z.unlink()
    with pytest.raises(InputError, match=f"{z.name} .in metadata.yaml. is missing"):
        open_logs(packed)
    assert not list(tmpdir_here.iterdir())


def test_no_room_for_a_folder_to_decompress_into_is_one_line(tmp_path, tmpdir_here, monkeypatch):
    import errno
    import tempfile

    packed = _log(tmp_path, "ros2-sqlite3", _mixed(), name="packed", ros2_compression="file")

    def full(*_a, **_k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(tempfile, "mkdtemp", full)
    with pytest.raises(LogReadError, match=f"cannot make a folder in {tmpdir_here} to decompress packed.db3.zstd "
                                           f"into .*No space left on device.; set TMPDIR"):  # fmt: skip
        _all(packed)


def _split_compressed_bag(tmp_path: Path, parts: int = 3) -> tuple[Path, list]:
    """A sqlite3 bag recorded in ``parts`` files of 10 s (rosbag2 --max-bag-duration 10), each
    compressed (--compression-mode file), with metadata.yaml's per-file entries as rosbag2 writes
    them; and the messages."""
    import yaml
    import zstandard
    from test_replay import room_messages

    msgs = room_messages(0.0, 10.0 * parts, pillar=True)
    t_first = min(m.log_time_ns for m in msgs)
    bag = tmp_path / "split"
    bag.mkdir()
    files, topics, start, end = [], {}, None, None
    for k in range(parts):
        part = [m for m in msgs if (k == 0 or k * 10 * S <= m.log_time_ns - t_first)
                and (k == parts - 1 or m.log_time_ns - t_first < (k + 1) * 10 * S)]
        one = write_log(tmp_path / f"part{k}", "ros2-sqlite3", part)
        info = yaml.safe_load((one / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        name = f"split_{k}.db3.zstd"
        with next(one.glob("*.db3")).open("rb") as fi, (bag / name).open("wb") as fo:
            zstandard.ZstdCompressor().copy_stream(fi, fo)
        t0, dur = info["starting_time"]["nanoseconds_since_epoch"], info["duration"]["nanoseconds"]
        files.append({"path": name, "starting_time": {"nanoseconds_since_epoch": t0},
                      "duration": {"nanoseconds": dur}, "message_count": info["message_count"]})  # fmt: skip
        start, end = t0 if start is None else min(start, t0), max(end or 0, t0 + dur)
        for t in info["topics_with_message_count"]:
            name_t = t["topic_metadata"]["name"]
            if name_t in topics:
                topics[name_t]["message_count"] += t["message_count"]
            else:
                topics[name_t] = dict(t)
    info.update(relative_file_paths=[f["path"] for f in files], files=files, compression_mode="FILE",
                compression_format="zstd", starting_time={"nanoseconds_since_epoch": start},
                duration={"nanoseconds": end - start}, message_count=sum(f["message_count"] for f in files),
                topics_with_message_count=list(topics.values()))  # fmt: skip
    (bag / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))
    return bag, msgs


def test_a_bag_compressed_file_by_file_is_decompressed_a_file_at_a_time(tmp_path, tmpdir_here, monkeypatch):
    """A bag recorded in files of 10 s, each compressed: reading holds at most two files
    decompressed (an hour of RGB-D log needs room for two files, not the whole bag): each is
    decompressed when reading reaches it, or, once reading is half way through the file before,
    in a read-ahead thread; it is removed once read. The messages are the plain bag's; message
    indexes count in each file. `ltmap info` on a log over 1 GiB reads its first 30 s: it
    decompresses only the files it reaches, and its counts and times are still the whole bag's
    (metadata.yaml's). (Here: 3 files of 10 s, the head 3 s, the size bound lowered.)"""
    import threading

    from ltmap_cli.commands import info as info_cmd
    from ltmap_cli.io import sources

    bag, msgs = _split_compressed_bag(tmp_path)
    plain_bag = _log(tmp_path, "ros2-sqlite3", msgs, name="plain")
    plain = _all(plain_bag)
    made = []  # (file, thread)
    real = sources._decompress_file

    def watched(folder, src, dst, stop=None):
        made.append((src.name, threading.current_thread().name))
        real(folder, src, dst, stop)

    def on_disk():
        return sorted(f.name for f in tmpdir_here.glob("ltmap-bag-*/*"))

    monkeypatch.setattr(sources, "_decompress_file", watched)
    with open_logs([bag, plain_bag]) as logs:  # (info's formats: one per log given, not per file)
        assert logs.formats == ["ros2-sqlite3, 3 files", "ros2-sqlite3"]
    with open_logs(bag) as logs:
        s0, s1, s2 = logs.sources
        assert [s.path.name for s in logs.sources] == [f"split_{k}.db3.zstd" for k in range(3)]
        assert logs.topics["/scan"].count == sum(m.topic == "/scan" for m in msgs)
        # file 0 when reached; file 1 read ahead once file 0 is read half way, beside it
        half = s0.start_ns + (s0.end_ns - s0.start_ns) // 2
        it0 = s0.iter({"/scan"})
        for m in it0:  # (the read-ahead starts before the message that passes half way is yielded)
            assert (s1._ahead is None) == (m.log_time_ns < half)
            if s1._ahead is not None:
                break
            assert on_disk() == ["split_0.db3"]
        s1._ahead.join()
        assert on_disk() == ["split_0.db3", "split_1.db3"] and s2._ahead is None
        assert len(list(it0)) > 0 and on_disk() == ["split_1.db3"]  # file 0 read: removed
        assert made == [("split_0.db3.zstd", "MainThread"), ("split_1.db3.zstd", "ltmap-bag-ahead")]
        assert len(list(s1.iter({"/scan"}))) > 0 and s2._ahead is not None  # (file 1 not decompressed again)
        s2._ahead.join()
        assert on_disk() == ["split_2.db3"] and made[2:] == [("split_2.db3.zstd", "ltmap-bag-ahead")]
        logs.close()  # a read-ahead never read is removed
        assert not list(tmpdir_here.iterdir())
    made.clear()
    with open_logs(bag) as logs:
        where = [w for _, _, _, w in logs.raw(["/scan"])]
    assert [m[0] for m in made] == [f"split_{k}.db3.zstd" for k in range(3)]
    assert where[0].endswith("message index 0 in " + str(bag / "split_0.db3.zstd"))
    assert where[-1].endswith(" in " + str(bag / "split_2.db3.zstd"))
    assert not list(tmpdir_here.iterdir())
    made.clear()
    got = _all(bag)
    assert [(t, lt, type(f)) for t, lt, f in got] == [(t, lt, type(f)) for t, lt, f in plain]
    assert len(made) == 3 and not list(tmpdir_here.iterdir())
    # without room for a second file beside the first, each is decompressed when reached, after
    # the one before is gone
    import collections

    import zstandard

    made.clear()
    one = max(len(zstandard.ZstdDecompressor().decompress(f.read_bytes(), max_output_size=2**26))
              for f in bag.glob("*.zstd"))  # fmt: skip
    usage = collections.namedtuple("usage", "total used free")

    def room_for_one_and_a_half(path):  # a disk with room for 1.5 decompressed files
        used = sum(f.stat().st_size for f in tmpdir_here.glob("ltmap-bag-*/*"))
        return usage(2**40, used, sources.KEEP_FREE_BYTES + int(1.5 * one) - used)

    monkeypatch.setattr(shutil, "disk_usage", room_for_one_and_a_half)
    assert len(_all(bag)) == len(plain)
    assert made == [(f"split_{k}.db3.zstd", "MainThread") for k in range(3)]
    monkeypatch.undo()
    made.clear()
    monkeypatch.setattr(sources, "_decompress_file", watched)
    monkeypatch.setattr(sources, "DECOMPRESS_NOTE", 0)
    monkeypatch.setattr(info_cmd, "INFO_FULL_BYTES", 0)
    monkeypatch.setattr(info_cmd, "INFO_HEAD_S", 3.0)
    with pytest.warns(Warning, match="each of its 3 files is decompressed"):
        r = info_cmd.gather([bag])
    assert r["read_s"] == 3.0 and [m[0] for m in made] == ["split_0.db3.zstd"] and not list(tmpdir_here.iterdir())
    full = info_cmd.gather([bag], full=True)  # every file
    assert len(made) == 4
    assert {n: t["count"] for n, t in r["topics"].items()} == {n: t["count"] for n, t in full["topics"].items()}
    assert r["topics"]["/scan"]["count"] == sum(m.topic == "/scan" for m in msgs)
    assert (r["start_ns"], r["end_ns"]) == (full["start_ns"], full["end_ns"])


def test_replay_of_a_bag_compressed_file_by_file_and_a_disk_that_fills_on_its_second_file(tmp_path, tmpdir_here,
                                                                                         monkeypatch):
    """`ltmap replay` of the 3-file compressed bag gives the plain bag's map, byte for byte, and
    leaves TMPDIR empty. When the disk would fill while the second file is decompressed, mid-run:
    one error line (exit 2) naming that file and TMPDIR, no output folder, TMPDIR empty."""
    import shutil

    from click.testing import CliRunner

    from ltmap_cli.cli import cli
    from ltmap_cli.io import sources

    bag, msgs = _split_compressed_bag(tmp_path)
    plain = _log(tmp_path, "ros2-sqlite3", msgs, name="plain")
    runs = {}
    for name, log in (("plain", plain), ("packed", bag)):
        r = CliRunner().invoke(cli, ["replay", str(log), "-o", str(tmp_path / f"out_{name}"), "-q", "--no-plots"])
        assert r.exit_code == 0, r.output
        runs[name] = (tmp_path / f"out_{name}" / "map.pgm").read_bytes()
    assert runs["packed"] == runs["plain"] and not list(tmpdir_here.iterdir())
    real = sources._decompress_file

    def tight(folder, src, dst):
        if src.name == "split_1.db3.zstd":  # leaves too little free from here on
            monkeypatch.setattr(sources, "KEEP_FREE_BYTES", shutil.disk_usage(dst.parent).free + 1)
        real(folder, src, dst)

    monkeypatch.setattr(sources, "_decompress_file", tight)
    r = CliRunner().invoke(cli, ["replay", str(bag), "-o", str(tmp_path / "full"), "-q", "--no-plots"])
    errors = [x for x in r.output.splitlines() if x.startswith("ltmap: error: ")]
    assert r.exit_code == 2 and len(errors) == 1, r.output
    assert "split_1.db3.zstd" in errors[0] and f"free in {tmpdir_here}" in errors[0] and "set TMPDIR" in errors[0]
    assert not (tmp_path / "full").exists() and not list(tmpdir_here.iterdir())


def test_a_damaged_message_of_a_message_compressed_ros2_mcap_bag_is_skipped(tmp_path):
    msgs = [scan("/scan", t * S, [float(t)]) for t in (1, 2, 3)]
    bag = _log(tmp_path, "ros2-mcap", msgs, ros2_compression="message")
    m = next(bag.glob("*.mcap"))
    data = bytearray(m.read_bytes())
    import zstandard

    first = zstandard.ZstdCompressor().compress(b"")[:4]  # the zstd magic: the first message's data
    at = data.find(first)
    data[at + 8 : at + 12] = b"\xff\xff\xff\xff"
    m.write_bytes(bytes(data))
    with pytest.warns(Warning, match="compressed by rosbag2, cannot be decompressed"), open_logs(bag) as logs:
        got = [f.ranges[0] for _, _, f in logs.messages()]
        assert logs.skipped == {"cannot decode the message on /scan": 1}
    assert len(got) == 2


def test_ros2_bag_paths_inside_the_folder_and_custom_types(tmp_path):
    bag = _log(tmp_path, "ros2-sqlite3", [scan("/scan", S, [1.0])])
    for p in (bag, bag / "metadata.yaml", next(bag.glob("*.db3"))):
        assert [t for t, _, _ in _all(p)] == ["/scan"]
    custom = {"my_msgs/msg/Gadget": "std_msgs/Header header\nint32 level\nfloat64[] values"}
    msgs = [scan("/scan", S, [1.0]),
            type(scan("/x", 0, []))("/gadget", S + 1, "my_msgs/msg/Gadget", {"level": 3})]
    path = _log(tmp_path, "ros1", msgs, name="custom", extra_types=custom)
    with open_logs(path) as logs:
        assert logs.topics["/gadget"].msgtype == "my_msgs/msg/Gadget"
        raw = list(logs.raw(["/gadget"]))
        assert raw[0][2]().level == 3  # the definition lives only in the bag


def test_select_topics_by_type_names_and_reasons():
    ti = {n: TopicInfo(n, t, 5) for n, t in [
        ("/scan", "sensor_msgs/msg/LaserScan"), ("/scan_rear", "sensor_msgs/msg/LaserScan"),
        ("/points", "sensor_msgs/msg/PointCloud2"), ("/cam/color/image_raw", "sensor_msgs/msg/Image"),
        ("/cam/depth/image_raw", "sensor_msgs/msg/Image"), ("/cam/depth/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/ir/depth/image", "sensor_msgs/msg/Image"), ("/ir/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/tf", "tf2_msgs/msg/TFMessage"), ("/tf_static", "tf2_msgs/msg/TFMessage"),
        ("/odom", "nav_msgs/msg/Odometry")]}
    sel = select_topics(ti)
    assert sel.scans == ["/scan", "/scan_rear"] and sel.clouds == ["/points"]
    assert sel.depths == {"/cam/depth/image_raw": "/cam/depth/camera_info"}
    assert sel.tf == ["/tf", "/tf_static"] and sel.static_tf == ["/tf_static"] and sel.odometry == ["/odom"]
    assert "does not say depth" in sel.skipped["/cam/color/image_raw"]
    assert "without CameraInfo" in sel.skipped["/ir/depth/image"]
    sel = select_topics(ti, scan_topics=["scan"])  # exclusive; leading slash optional
    assert sel.scans == ["/scan"] and sel.clouds == [] and sel.depths == {}
    assert "not chosen" in sel.skipped["/scan_rear"] and "not chosen" in sel.skipped["/points"]
    assert sel.topics == {"/scan", "/tf", "/tf_static", "/odom"}
    with pytest.raises(InputError, match=r"--scan-topic /laser: .* no topic /laser; its LaserScan topics: "
                                         r"/scan, /scan_rear; all topics: "):
        select_topics(ti, scan_topics=["/laser"])
    with pytest.raises(InputError, match=r"--cloud-topic /scan: topic /scan .* is sensor_msgs/msg/LaserScan"):
        select_topics(ti, cloud_topics=["/scan"])
    with pytest.raises(InputError, match=r"--depth-topic /ir/depth/image: depth Image without CameraInfo"):
        select_topics(ti, depth_topics=["/ir/depth/image"])
    with pytest.raises(InputError, match=r"no usable LaserScan.*/tf \(tf2_msgs/msg/TFMessage\)"):
        select_topics({"/tf": ti["/tf"]}, source="x.bag")


def test_laserscan_angles_come_from_the_increment_whatever_angle_max_says(tmp_path):
    bad = scan("/scan", 2 * S, [1.0] * 10, angle_min=0.0, angle_increment=0.1, angle_max=3.0)
    path = _log(tmp_path, "mcap-ros2", [scan("/scan", S, [1.0] * 10), bad])
    frames = [f for _, _, f in _all(path)]
    assert [f.angle_max_off for f in frames] == [False, True]
    np.testing.assert_allclose(frames[1].angles, 0.1 * np.arange(10))
    broken = scan("/scan", S, [1.0] * 10, angle_min=0.0, angle_increment=0.0, angle_max=0.0)
    with pytest.raises(LogReadError, match=r"LaserScan on /scan, message index 0 in .*broken.mcap: angle_min 0 and "
                                           r"angle_increment 0 cannot place its 10 beams"):
        _all(_log(tmp_path, "mcap-ros2", [broken], name="broken"))


def test_missing_empty_and_not_a_log(tmp_path):
    with pytest.raises(InputError, match=r"log not found: .*nope.bag; give a ROS 1 .bag"):
        open_logs(tmp_path / "nope.bag")
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(InputError, match=r"empty.mcap is empty \(0 bytes\)"):
        open_logs(tmp_path / "empty.mcap")
    (tmp_path / "notes.bag").write_text("hello, this is text\n")
    with pytest.raises(InputError, match=r"notes.bag is not a robot log"):
        open_logs(tmp_path / "notes.bag")
    (tmp_path / "folder").mkdir()
    with pytest.raises(InputError, match=r"folder without metadata.yaml"):
        open_logs(tmp_path / "folder")
    with pytest.raises(InputError, match=r"no log given"):
        open_logs([])


def _scans(n):
    return [scan("/scan", (i + 1) * S // 10, [1.0 + i] * 20) for i in range(n)]


@pytest.mark.parametrize("fmt", ["ros1", "mcap-ros2", "mcap-ros1"])
def test_truncated_logs_yield_what_can_be_read_then_fail(tmp_path, fmt):
    path = _log(tmp_path, fmt, _scans(60), chunk_size=600)
    f = path if path.is_file() else next(path.glob("*.mcap"))
    truncate(f, 0.5)
    read = []
    with open_logs(path) as logs, pytest.raises(TruncatedLogError) as e:
        for item in logs.messages():
            read.append(item)
    msg = str(e.value)
    assert f.name in msg and "reading stopped after" in msg and "--allow-truncated" in msg
    assert "\n" not in msg
    assert 0 < len(read) < 60
    # what was read is exact and in order
    assert [fr.ranges[0] for _, _, fr in read] == [1.0 + i for i in range(len(read))]
    with open_logs(path, allow_truncated=True) as logs:
        again = list(logs.messages())
        assert len(again) == len(read) and "reading stopped after" in logs.stats.stopped_at


def test_truncated_ros2_mcap_bag_with_nothing_readable(tmp_path):
    bag = _log(tmp_path, "ros2-mcap", _scans(60))  # rosbags writes a single chunk
    truncate(next(bag.glob("*.mcap")), 0.5)
    with open_logs(bag, allow_truncated=True) as logs, \
            pytest.raises(TruncatedLogError, match=r"no usable sensor topic before the damage: .*log.mcap: "
                                                   r"reading stopped after 0 messages near byte \d+ \(the file "
                                                   r"ends in the middle of a record\)"):
        logs.select()


def test_corrupt_sqlite_bag_and_corrupt_mcap_chunk(tmp_path):
    bag = _log(tmp_path, "ros2-sqlite3", _scans(30))
    truncate(next(bag.glob("*.db3")), 0.5)
    with pytest.raises(LogReadError, match=r"cannot read ROS 2 bag .*corrupt or cut off"):
        open_logs(bag)
    path = _log(tmp_path, "mcap-ros2", _scans(60), chunk_size=600)
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 40] = b"\xff" * 40  # garbage inside a chunk in the middle
    path.write_bytes(bytes(data))
    with open_logs(path, allow_truncated=True) as logs:
        got = list(logs.messages())
        assert 0 < len(got) < 60 and logs.stats.stopped_at


def test_flipped_bytes_that_still_decode_are_caught_by_the_chunk_crc(tmp_path):
    """Uncompressed chunks: bytes changed inside a scan's ranges still parse as a scan, so only
    the CRC tells; the damage is named (near which byte) instead of a wrong map."""
    path = _log(tmp_path, "mcap-ros2", _scans(60), chunk_size=600, compress=False)
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 4] = b"\x00\x00\x80\x3f"  # a float32 1.0 where a range was
    path.write_bytes(bytes(data))
    with open_logs(path, allow_truncated=True) as logs:
        got = list(logs.messages())
        # the damaged chunk's few scans are lost; the chunks after it are read (the last scan too)
        assert 50 < len(got) < 60 and got[-1][2].stamp_ns == max(fr.stamp_ns for _, _, fr in got)
        last = _scans(60)[-1]
        assert got[-1][1] == last.log_time_ns
        assert re.search(r"skipped 1 damaged chunk and read the rest \(\d+ messages\): the chunk at byte \d+ "
                         r"\(log time [\d.]+ to [\d.]+ s: its messages are lost; crc validation failed",
                         logs.stats.stopped_at)  # fmt: skip
    with open_logs(path) as logs, pytest.raises(TruncatedLogError, match="--allow-truncated"):
        list(logs.messages())


def test_chunk_crc_is_zlibs_crc32_computed_by_zlib_ng():
    """The chunks' CRC is computed by zlib-ng (a dependency: 15x zlib's speed), and is zlib's
    CRC-32 (what MCAP writers store) on any length, the empty and the unaligned included."""
    import zlib

    from ltmap_cli.io import sources

    assert sources._crc32_function() is not zlib.crc32  # the fast one is installed and used
    rng = np.random.default_rng(7)
    for n in (0, 1, 7, 64, 4099, 1 << 20):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert sources.crc32(data) == zlib.crc32(data)
    assert sources.crc32(b"123456789") == 0xCBF43926  # CRC-32's check value


@pytest.mark.skipif(not (REAL / "ist_pioneer3dx_test1.bag").exists(), reason=f"real logs not in {REAL}")
def test_real_pioneer_ros1_bag_scan_decodes():
    with open_logs(REAL / "ist_pioneer3dx_test1.bag") as logs:
        assert logs.topics["/scan"].count == 311 and logs.topics["/pose"].count == 313
        assert logs.topics["/tf"].count == 317
        assert logs.topics["/sonar"].msgtype == "p2os_msgs/msg/SonarArray"
        sel = logs.select()
        assert sel.scans == ["/scan"] and sel.odometry == ["/pose"]
        scans = [fr for t, _, fr in logs.messages(sel) if t == "/scan"]
    assert len(scans) == 311
    s = scans[0]
    assert s.frame_id == "laser" and len(s.ranges) == 726
    assert s.angle_min == pytest.approx(-2.356, abs=1e-3) and s.angles[-1] == pytest.approx(2.092, abs=1e-3)
    assert np.isnan(s.ranges).any()  # invalid beams are NaN, kept as recorded


@pytest.mark.skipif(not (REAL / "comprobo22_macfirst_floor_take_2").exists(), reason=f"real logs not in {REAL}")
def test_real_comprobo_ros2_bag():
    from ltmap_cli.io.transforms import TfBuffer

    buf = TfBuffer()
    with open_logs(REAL / "comprobo22_macfirst_floor_take_2") as logs:
        assert logs.topics["/scan"].count == 357 and logs.topics["/odom"].count == 920
        stamps = []
        for _topic, _, fr in logs.messages():
            if isinstance(fr, (TfSample, OdometrySample)):
                buf.add(fr)
            elif isinstance(fr, ScanFrame):
                assert fr.frame_id == "rplidar_link" and len(fr.ranges) == 720
                stamps.append(fr.stamp_ns)
    assert len(stamps) == 357
    # tf arrives after the scans it places: look up once tf has passed the stamps
    placed = sum(buf.try_lookup("odom", "rplidar_link", t)[0] is not None for t in stamps)
    assert placed > 340  # static tf ~4 h older than the log is timeless
    assert math.isclose(buf.lookup("base_link", "rplidar_link", 0)[3, 3], 1.0)


def test_ros1_bag_with_old_roslib_header_definition(tmp_path):
    old = {"roslib/msg/Header": "uint32 seq\ntime stamp\nstring frame_id",
           "old_msgs/msg/Ping": "roslib/Header header\nint32 level"}
    msg = type(scan("/x", 0, []))("/ping", S, "old_msgs/msg/Ping",
                                  {"header": {"stamp": 5 * S + 7, "frame_id": "base"}, "level": 4})
    path = _log(tmp_path, "ros1", [msg], name="old", extra_types=old)
    with open_logs(path) as logs:
        (topic, t, decode, where), = list(logs.raw(["/ping"]))
        m = decode()
    assert (m.level, m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec) == (4, "base", 5, 7)


@pytest.mark.parametrize("k", [
    [0.0, 0, 320, 0, 0.0, 240, 0, 0, 1],  # an uncalibrated camera's all-zero K
    [float("nan"), 0, 320, 0, 500.0, 240, 0, 0, 1],
    [500.0, 0, 320, 0, float("inf"), 240, 0, 0, 1],
    [500.0, 0, float("nan"), 0, 500.0, 240, 0, 0, 1],
])  # fmt: skip
def test_depth_camera_info_without_a_usable_calibration_is_refused(k):
    from types import SimpleNamespace

    from ltmap_cli.io.decode import _checked_intrinsics

    info = SimpleNamespace(k=k, width=640, height=480)
    with pytest.raises(LogReadError, match="uncalibrated"):
        _checked_intrinsics(info, (480, 640), "at 1.0 s")
    ok = SimpleNamespace(k=[500.0, 0, 320, 0, 500.0, 240, 0, 0, 1], width=640, height=480)
    assert _checked_intrinsics(ok, (480, 640), "at 1.0 s").fx == 500.0


@pytest.mark.parametrize("binning, roi, want", [
    ((0, 0), (0, 0, 0, 0), (64, 48, 60.0, 62.0, 31.5, 23.5)),  # neither: K and the size as they are
    ((2, 2), (0, 0, 0, 0), (32, 24, 30.0, 31.0, 15.75, 11.75)),  # binned: fx / 2, cx / 2, size / 2
    ((1, 1), (8, 4, 32, 24), (32, 24, 60.0, 62.0, 23.5, 19.5)),  # cropped: cx - x_offset
    ((2, 2), (8, 4, 32, 24), (16, 12, 30.0, 31.0, 11.75, 9.75)),  # both: (cx - x_offset) / 2
    ((1, 2), (8, 0, 0, 0), (56, 24, 60.0, 31.0, 23.5, 11.75)),  # a zero ROI size: to the image's edge
])  # fmt: skip
def test_depth_camera_info_binning_and_roi_as_image_geometry_applies_them(tmp_path, binning, roi, want):
    """A CameraInfo's K and size are the full camera's; the images are its ROI divided by its
    binning (image_geometry's PinholeCameraModel; by hand, from K fx 60, fy 62, cx 31.5, cy 23.5
    of a 64 x 48 camera). Read back from a log of every format (the direct CDR parser of ROS 2
    messages and the generic deserializers), the frames' intrinsics are those, and the pixels
    the images'."""
    from ltmap_cli.io.decode import RawDepthFrame

    w, h = want[:2]
    px = (1000 + np.arange(w * h) % 500).astype(np.uint16).reshape(h, w)
    msgs = [tf(S // 2, [("map", "camera_optical", (0.0, 0.0, 1.0))], static=True),
            camera_info("/cam/depth/camera_info", S, width=64, height=48, fx=60.0, fy=62.0, cx=31.5, cy=23.5,
                        binning=binning, roi=roi),
            image("/cam/depth/image_raw", S + 1, px),
            # the same through compressedDepth (its PNG's size is checked against the CameraInfo's)
            camera_info("/cam2/depth/camera_info", S, width=64, height=48, fx=60.0, fy=62.0, cx=31.5, cy=23.5,
                        binning=binning, roi=roi),
            compressed_depth("/cam2/depth/image_raw/compressedDepth", S + 2, px)]  # fmt: skip
    for fmt in FORMATS:
        path = _log(tmp_path, fmt, msgs, name=f"binned_{fmt}")
        with open_logs(path) as logs:
            frames = [f for _, _, f in logs.messages(logs.select(), fast=True) if isinstance(f, RawDepthFrame)]
        assert len(frames) == 2, fmt
        for f in frames:
            c = f.intrinsics
            assert (c.width, c.height, c.fx, c.fy, c.cx, c.cy) == want, fmt
            assert np.array_equal(f.raw, px)
    # an image of another size: refused in one line that says what the CameraInfo describes
    other = msgs[:2] + [image("/cam/depth/image_raw", S + 1, px[:-1])]
    with open_logs(_log(tmp_path, "mcap-ros2", other, name="other")) as logs, \
            pytest.raises(LogReadError, match=f"is {w}x{h - 1} but its CameraInfo says {w}x{h}") as e:
        list(logs.messages(logs.select(), fast=True))
    if binning != (0, 0):
        assert f"64x48 with binning {binning[0]}x{binning[1]}" in str(e.value)


def _window_log():
    """20 s: /tf_static and a latched CameraInfo at 0 s only, /tf at 20 Hz, scans and depth at 10 Hz."""
    msgs = [tf(0, [("base_link", "camera_optical", (0.1, 0.0, 0.5))], static=True),
            camera_info("/cam/depth/camera_info", 1, width=3, height=2, fx=500.0, fy=500.0, cx=1.0, cy=0.5)]
    for k in range(400):
        msgs.append(tf(k * S // 20 + 2, [("odom", "base_link", (0.01 * k, 0.0, 0.0))]))
    for k in range(200):
        t = k * S // 10 + 3
        msgs.append(scan("/scan", t, [1.0 + k] * 8))
        msgs.append(image("/cam/depth/image_raw", t + 1, np.full((2, 3), 1000 + k), encoding="16UC1"))
    return sorted(msgs, key=lambda m: m.log_time_ns)


@pytest.mark.parametrize("fmt", FORMATS)
def test_time_window_maps_its_frames_with_the_poses_and_calibration_from_before(tmp_path, fmt):
    """``messages(start_ns, end_ns)``: sensor frames logged in the window only; /tf from
    WINDOW_LEAD_S before it to as long after it, /tf_static and the CameraInfo from the log's start
    (here logged once, at 0 s); what lies before the start is not decoded, and reading stops after
    the trail."""
    from ltmap_cli.io.logs import WINDOW_LEAD_S

    path = _log(tmp_path, fmt, _window_log(), chunk_size=4000, ros1_chunk_size=4000)
    with open_logs(path) as logs:
        t0 = logs.start_ns
        start, end = t0 + 8 * S + S // 20, t0 + 10 * S + S // 20  # 8.05 s .. 10.05 s
        got = list(logs.messages(start_ns=start, end_ns=end))
        read = dict(logs.stats.messages_per_topic)
        before = dict(logs.before_start)
    sensors = [(topic, t, fr) for topic, t, fr in got if isinstance(fr, (ScanFrame, DepthFrame))]
    assert {topic for topic, _, _ in sensors} == {"/scan", "/cam/depth/image_raw"}
    assert all(start <= t <= end for _, t, _ in sensors)
    # scans 81..100 (8.1 .. 10.0 s): every one in the window, none outside
    assert [fr.ranges[0] for topic, _, fr in sensors if topic == "/scan"] == [1.0 + k for k in range(81, 101)]
    depth = [fr for topic, _, fr in sensors if topic == "/cam/depth/image_raw"]
    assert len(depth) == 20 and depth[0].intrinsics.fx == 500.0  # the CameraInfo of 0 s
    statics = [s for _, _, s in got if isinstance(s, TfSample) and s.static]
    dynamic = [t for _, t, s in got if isinstance(s, TfSample) and not s.static]
    assert len(statics) == 1
    assert min(dynamic) >= start - WINDOW_LEAD_S * S and min(dynamic) <= start - WINDOW_LEAD_S * S + S // 20
    # tf up to WINDOW_LEAD_S after the end (the last frames' poses), no further
    assert end + WINDOW_LEAD_S * S - S // 20 <= max(dynamic) <= end + WINDOW_LEAD_S * S
    # reading stopped after that trail (15.05 s): at most one message per topic past it was read
    assert read["/scan"] <= 152 and read["/tf"] <= 303
    if fmt in ("mcap-ros2", "mcap-ros1", "ros1", "ros2-sqlite3"):  # those before the lead are not even read
        assert read["/scan"] <= 152 - 10 and read["/scan"] - before["/scan"] in (70, 71) and read["/tf"] <= 303 - 20
    else:  # read (up to the start without decoding the sensor messages)
        assert before["/scan"] == 81 and before["/cam/depth/image_raw"] == 81


@pytest.mark.parametrize("fmt", ["mcap-ros2", "ros1", "ros2-sqlite3"])
def test_time_window_in_an_indexed_log_reads_only_the_chunks_it_needs(tmp_path, monkeypatch, fmt):
    """Chunks before the lead are left unread (an MCAP's message index records, a bag's chunk
    infos say what they hold), except those holding /tf_static and the last one holding the
    CameraInfo; an error inside the window still names the message by its index in the whole log."""
    from ltmap_cli.io import ros1bag, sources
    from ltmap_cli.io.logs import WINDOW_LEAD_S

    path = _log(tmp_path, fmt, _window_log(), chunk_size=4000, ros1_chunk_size=4000)
    read_at = []
    if fmt == "ros2-sqlite3":  # no chunks: a query from the lead on, the messages it returns counted
        from rosbags.rosbag2 import Reader

        real_messages = Reader.messages

        def spy(self, connections=(), start=None, stop=None):
            for row in real_messages(self, connections, start, stop):
                read_at.append(row[1])
                yield row

        monkeypatch.setattr(Reader, "messages", spy)
    elif fmt == "ros1":
        real_read = ros1bag.Ros1Bag._read_chunk

        def spy(self, ch):
            read_at.append(ch.start_ns)
            return real_read(self, ch)

        monkeypatch.setattr(ros1bag.Ros1Bag, "_read_chunk", spy)
    else:
        real_read = sources.McapSource._chunk_records

        def spy(self, chunk, pos):
            read_at.append(chunk.message_start_time)
            return real_read(self, chunk, pos)

        monkeypatch.setattr(sources.McapSource, "_chunk_records", spy)
    with open_logs(path) as logs:
        src = logs.sources[0]
        t0 = logs.start_ns
        n_chunks = (len(src.bag.layout.chunks) if fmt == "ros1" else 1000 if fmt == "ros2-sqlite3"
                    else len(src.reader.get_summary().chunk_indexes))  # (sqlite3: the bag's 1000 messages)
        start = t0 + 10 * S + S // 20
        got = list(logs.messages(start_ns=start, end_ns=start + S))
    n_read = len(read_at)
    with open_logs(path) as logs:  # every chunk read: the index of each scan in the whole log
        where = [w for _, _, _, w in logs.raw(["/scan"])]
    early = [t for t in read_at[:n_read] if t < start - WINDOW_LEAD_S * S]
    assert n_chunks > 10 and n_read < n_chunks - 3
    assert min(read_at[:n_read]) == t0  # the first chunk (message): /tf_static and the CameraInfo
    assert len(early) <= 2
    depth = [fr for _, _, fr in got if isinstance(fr, DepthFrame)]
    assert len(depth) == 10 and depth[0].intrinsics.fx == 500.0

    # message indexes across unread chunks: the same as when every chunk is read
    seen = {}
    cls = {"ros1": sources.Ros1Source, "ros2-sqlite3": sources.Ros2BagSource}.get(fmt, sources.McapSource)
    real_iter = cls.iter

    def indexes(self, topics, skip=None):
        for m in real_iter(self, topics, skip):
            if m.topic == "/scan":
                seen[m.log_time_ns] = m.index
            yield m

    monkeypatch.setattr(cls, "iter", indexes)
    with open_logs(path) as logs:
        list(logs.messages(start_ns=start, end_ns=start + S))
    assert seen and all(f"message index {i} " in where[i] for i in seen.values())
    assert 101 in seen.values() and len(seen) < 150  # the window's first scan (10.1 s), after unread ones


@pytest.mark.parametrize("scan_k, fails", [(20, True), (100, False)])
def test_time_window_reports_damage_up_to_its_end_only(tmp_path, scan_k, fails):
    """A damaged chunk inside the part read (up to WINDOW_LEAD_S after the window's end) fails as
    for the whole log; one after that is never read. The damage: a range of scan k (logged at
    (k + 1) / 10 s) changed inside an uncompressed chunk, which only its CRC tells."""
    import struct

    path = _log(tmp_path, "mcap-ros2", _scans(120), chunk_size=600, compress=False)
    data = bytearray(path.read_bytes())
    at = data.index(struct.pack("<f", 1.0 + scan_k) * 2)
    data[at:at + 4] = struct.pack("<f", 99.0)
    path.write_bytes(bytes(data))
    with open_logs(path) as logs:
        t0 = logs.start_ns
        if fails:
            with pytest.raises(TruncatedLogError, match="skipped 1 damaged chunk"):
                list(logs.messages(start_ns=t0 + S, end_ns=t0 + 3 * S))
        else:
            got = list(logs.messages(start_ns=t0 + S, end_ns=t0 + 3 * S))
            assert [fr.ranges[0] for _, _, fr in got] == [1.0 + i for i in range(10, 31)]  # 1.1 .. 3.1 s
            assert logs.stats.stopped_at is None
    with open_logs(path) as logs, pytest.raises(TruncatedLogError):  # the whole log meets it either way
        list(logs.messages())


def test_which_chunks_before_the_start_are_left_unread():
    from ltmap_cli.io.skip import unread_chunks

    # chunks before the skip time, in file order: (topics held, end time)
    early = [({"/tf_static", "/info", "/scan"}, 1), ({"/scan", "/info"}, 2), ({"/scan"}, 3),
             ({"/info", "/tf"}, 5), ({"/scan"}, 4)]
    got = unread_chunks(early, lambda c: c[0], lambda c: c[1], frozenset({"/tf_static"}), frozenset({"/info"}))
    assert got == {1, 2, 4}  # kept: 0 (/tf_static), 3 (the last holding /info, by end time)
    assert unread_chunks(early, lambda c: c[0], lambda c: c[1], frozenset(), frozenset()) == {0, 1, 2, 3, 4}


def test_an_mcap_cut_before_its_summary_is_counted_from_its_message_indexes(tmp_path, monkeypatch):
    """A recording killed before it wrote its summary: the counts, first and last times and the
    place reading stops come from the chunks' headers and message index records, as reading
    every chunk gives them (40 cuts at random places, the summary's included), and only the
    chunks that define channels or whose index was cut off are decompressed."""
    import random
    import re

    import ltmap_cli.io.sources as src

    msgs = [scan("/scan", S + i * S // 10, [float(i)]) for i in range(60)]
    msgs += [tf(S + i * S // 5, [("odom", "base_link")]) for i in range(30)]
    msgs.sort(key=lambda m: m.log_time_ns)
    data = _log(tmp_path, "mcap-ros2", msgs, chunk_size=512).read_bytes()
    rng = random.Random(5)
    decompressed = []
    real = src.decompress
    monkeypatch.setattr(src, "decompress", lambda *a: decompressed.append(1) or real(*a))

    def summary(p: Path, scan_indexes: bool):
        if not scan_indexes:
            monkeypatch.setattr(src.McapSource, "_scan_indexes", lambda self: None)
        decompressed.clear()
        s = src.McapSource(p)
        monkeypatch.undo()
        monkeypatch.setattr(src, "decompress", lambda *a: decompressed.append(1) or real(*a))
        stop = re.search(r"after (\d+) messages", s.stopped_at or "")
        return ({k: (v.count, v.first_ns, v.last_ns) for k, v in s.topics.items()}, s.start_ns, s.end_ns,
                stop and stop.group(1)), len(decompressed)  # fmt: skip

    totals = [0, 0]
    for k in range(40):
        cut = tmp_path / f"cut{k}.mcap"
        cut.write_bytes(data[: rng.randrange(len(data) // 4, len(data))])
        fast, n_fast = summary(cut, True)
        whole, n_whole = summary(cut, False)
        assert fast == whole, cut
        assert n_fast <= 3, n_fast  # the chunks defining the two channels, and the one whose index was cut
        totals[0], totals[1] = totals[0] + n_fast, totals[1] + n_whole
    assert totals[1] > 5 * totals[0], totals  # every chunk, against a few


def test_time_window_in_an_mcap_cut_before_its_summary_decompresses_only_what_it_needs(tmp_path, monkeypatch):
    """The same window in an MCAP without its summary (cut at its data section's end): the chunk
    table of the message index scan lets the chunks before the lead go undecompressed (but those
    holding /tf_static and the last with the CameraInfo), and gives the frames and message
    indexes of reading every chunk."""
    from ltmap_cli.io import sources
    from ltmap_cli.io.logs import WINDOW_LEAD_S

    whole = _log(tmp_path, "mcap-ros2", _window_log(), chunk_size=4000)
    from mcap.reader import make_reader

    with whole.open("rb") as f:
        info = make_reader(f).get_summary()
    end = max(ci.chunk_start_offset + ci.chunk_length for ci in info.chunk_indexes)
    data = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: end + 2000])  # (the last chunk's index records, and no summary)
    read_at = []
    real_read = sources.McapSource._chunk_records

    def spy(self, chunk, pos):
        read_at.append(chunk.message_start_time)
        return real_read(self, chunk, pos)

    monkeypatch.setattr(sources.McapSource, "_chunk_records", spy)
    real_iter = sources.McapSource.iter
    indexes: list = []

    def iter_spy(self, topics, skip=None):  # the message indexes (per topic, in the whole log) read
        for m in real_iter(self, topics, skip):
            indexes.append((m.topic, m.log_time_ns, m.index))
            yield m

    monkeypatch.setattr(sources.McapSource, "iter", iter_spy)

    def window(path, scan: bool):
        if not scan:
            monkeypatch.setattr(sources.McapSource, "_scan_indexes", lambda self: None)
        read_at.clear()
        indexes.clear()
        with open_logs(path, allow_truncated=True) as logs:
            assert not logs.sources[0].indexed
            t0 = logs.start_ns
            start = t0 + 10 * S + S // 20
            got = [(t, lt, type(fr).__name__, getattr(fr, "stamp_ns", None)) for t, lt, fr in
                   logs.messages(start_ns=start, end_ns=start + S)]  # fmt: skip
        monkeypatch.setattr(sources.McapSource, "_scan_indexes", real_scan)
        kept = {(t, lt): i for t, lt, i in indexes if lt >= start - WINDOW_LEAD_S * S}
        return (got, kept), list(read_at), start, t0

    real_scan = sources.McapSource._scan_indexes
    fast, read_fast, start, t0 = window(cut, True)
    slow, read_slow, _, _ = window(cut, False)
    assert fast == slow and len([x for x in fast[0] if x[2] == "DepthFrame"]) == 10
    early = [t for t in read_fast if t < start - WINDOW_LEAD_S * S]
    # the first chunk twice (its channels learnt when the file is opened; read for /tf_static and
    # the CameraInfo) and the chunk that spans the lead
    assert len(early) <= 3 and len(read_fast) < len(read_slow) - 10, (early, len(read_fast), len(read_slow))
    assert min(read_fast) == t0  # the first chunk: /tf_static and the CameraInfo
