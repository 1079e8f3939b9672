"""ROS 1 bags that rosbags refuses (issue 15): no index, damaged index records, damaged chunks.
ltmap reads its own way (``io.ros1bag``): the index when it is sound, else a scan of the records
as ``rosbag reindex`` does. The oracle is rosbags' reader on the intact bag: the same messages,
byte for byte, in the same order."""

from __future__ import annotations

import json
import struct
import warnings
from pathlib import Path

import pytest
from click.testing import CliRunner
from hostilefactory import (
    Chunk,
    bag_index_pos,
    build_chunk,
    damage_index,
    ros1_bag,
    scan_bytes,
    scans_bag,
    strip_index,
)

from ltmap_cli.cli import cli
from ltmap_cli.errors import LtmapWarning
from ltmap_cli.io.logs import TruncatedLogError, open_logs
from ltmap_cli.io.sources import open_source

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_logs" / "scenarios" / "01_static_object" / "log.bag"


def _real_logs() -> Path | None:
    for base in (ROOT.parent, ROOT.parent.parent):  # the repo beside shared/, or a worktree one level down
        if (base / "shared" / "real_logs").is_dir():
            return base / "shared" / "real_logs"
    return None


REAL = _real_logs()
PIONEER = REAL / "ist_pioneer3dx_test1.bag" if REAL else None
DAMAGES = ("idxdata-count", "chunk-info", "index-pos", "index-garbage")


def rosbags_messages(path: Path) -> list[tuple[str, int, bytes]]:
    from rosbags.rosbag1 import Reader

    with Reader(path) as r:
        return [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]


def ltmap_messages(path: Path) -> tuple[list[tuple[str, int, bytes]], dict, str | None, str | None]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LtmapWarning)
        (src,) = open_source(path)
    try:
        topics = {name: t.count for name, t in src.topics.items()}
        got = [(m.topic, m.log_time_ns, bytes(m.decode.data)) for m in src.iter(set(src.topics))]
        return got, topics, src.stopped_at, src.note
    finally:
        src.close()


def _ordered(msgs):
    """Sorted as a time-ordered merge may order equal times across topics."""
    return sorted(msgs, key=lambda m: (m[1], m[0], m[2]))


@pytest.fixture(params=["sample", "factory-bz2", "factory-lz4", "real"])
def bag(request, tmp_path) -> Path:
    if request.param == "sample":
        if not SAMPLE.is_file():
            pytest.skip(f"no sample bag at {SAMPLE}")
        return SAMPLE
    if request.param == "real":
        if PIONEER is None or not PIONEER.is_file():
            pytest.skip("real logs (../shared/real_logs) not present")
        return PIONEER
    return scans_bag(tmp_path / "f.bag", n=50, per_chunk=7, compression=request.param.split("-")[1])


def test_the_reader_agrees_with_rosbags_on_intact_bags(bag):
    want = rosbags_messages(bag)
    got, topics, stop, note = ltmap_messages(bag)
    assert stop is None and note is None
    assert _ordered(got) == _ordered(want) and len(got) == len(want) > 0
    assert [m[1] for m in got] == sorted(m[1] for m in got)  # time order
    for topic in {m[0] for m in want}:
        assert topics[topic] == sum(1 for m in want if m[0] == topic)


def test_a_bag_without_its_index_is_read_by_scanning(bag, tmp_path):
    want = rosbags_messages(bag)
    stripped = strip_index(bag, tmp_path / "stripped.bag")
    from rosbags.rosbag1 import Reader, ReaderError

    with pytest.raises(ReaderError):  # what rosbags does with it
        Reader(stripped).open()
    got, topics, stop, note = ltmap_messages(stripped)
    assert stop is None and "no index" in note and "rosbag reindex" in note
    assert _ordered(got) == _ordered(want)
    assert [m[1] for m in got] == sorted(m[1] for m in got)


@pytest.mark.parametrize("how", DAMAGES)
def test_damaged_index_records_fall_back_to_scanning(bag, tmp_path, how):
    want = rosbags_messages(bag)
    broken = damage_index(bag, tmp_path / f"{how}.bag", how)
    got, topics, stop, note = ltmap_messages(broken)
    assert note and "read by scanning its records" in note, note
    assert stop is None, stop
    assert _ordered(got) == _ordered(want)


def test_rosbags_asserts_on_the_damaged_index_data(tmp_path):
    """The case of the 2010 bag: rosbags' ``assert size == count * 12``."""
    bag = scans_bag(tmp_path / "f.bag", n=30, per_chunk=10)
    broken = damage_index(bag, tmp_path / "broken.bag", "idxdata-count")
    from rosbags.rosbag1 import Reader

    with pytest.raises(AssertionError):
        Reader(broken).open()
    got, _, stop, note = ltmap_messages(broken)
    assert len(got) == 30 and stop is None and "disagrees with its chunk info" in note


def test_info_and_replay_read_a_stripped_real_bag_like_the_original(tmp_path):
    if PIONEER is None or not PIONEER.is_file():
        pytest.skip("real logs (../shared/real_logs) not present")
    runner = CliRunner()
    base = runner.invoke(cli, ["info", str(PIONEER)])
    assert base.exit_code == 0, base.output
    mount = ["--tf", "base_link:laser=0.1,0,0.3,0,0,0", "-q", "--no-plots"]
    want = runner.invoke(cli, ["replay", str(PIONEER), "-o", str(tmp_path / "a"), *mount])
    assert want.exit_code == 0, want.output
    for name, path in (("stripped", strip_index(PIONEER, tmp_path / "stripped.bag")),
                       ("damaged", damage_index(PIONEER, tmp_path / "damaged.bag", "idxdata-count"))):
        res = runner.invoke(cli, ["info", str(path)])
        assert res.exit_code == 0, res.output
        lines = res.output.splitlines()
        assert lines[0].startswith("ltmap: warning: ") and "read by scanning its records" in lines[0]
        # everything info says is the same but the file name
        assert [x.replace(str(path), "LOG") for x in lines[1:]] == \
               [x.replace(str(PIONEER), "LOG") for x in base.output.splitlines()], name
        got = runner.invoke(cli, ["replay", str(path), "-o", str(tmp_path / name), *mount])
        assert got.exit_code == 0, got.output
        a = json.loads((tmp_path / "a" / "report.json").read_text())
        b = json.loads((tmp_path / name / "report.json").read_text())
        assert a["frames_used"] == b["frames_used"] and sum(a["frames_used"].values()) == 311
        assert a["voxels"] == b["voxels"]


# ----------------------------------------------------------------------------- damaged chunks


def _three_chunk_bag(tmp_path: Path, compression: str = "bz2", indexed: bool = True) -> tuple[Path, list[int]]:
    bag = scans_bag(tmp_path / "three.bag", n=30, per_chunk=10, compression=compression, indexed=indexed)
    data = bag.read_bytes()
    starts = []
    i = 0
    while (j := data.find(b"op=\x05", i)) >= 0:
        starts.append(j)
        i = j + 1
    return bag, starts


@pytest.mark.parametrize("indexed", [True, False])
def test_a_damaged_chunk_is_skipped_and_named(tmp_path, indexed):
    bag, starts = _three_chunk_bag(tmp_path, indexed=indexed)
    data = bytearray(bag.read_bytes())
    mid = starts[1] + 60  # inside the second chunk's bz2 data
    data[mid : mid + 30] = b"\xa5" * 30
    bag.write_bytes(bytes(data))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LtmapWarning)
        with open_logs(bag) as logs, pytest.raises(TruncatedLogError, match=r"the chunk at byte \d+ .*--allow-truncated"):
            list(logs.messages())
        with open_logs(bag, allow_truncated=True) as logs:
            got = [fr for _, _, fr in logs.messages()]
            assert [fr.ranges[0] for fr in got] == [1.0 + i for i in (*range(10), *range(20, 30))]
            assert "the chunk at byte" in logs.stats.stopped_at and "bz2 data is corrupt" in logs.stats.stopped_at


def test_broken_record_framing_resyncs_at_the_next_chunk(tmp_path):
    """A record header length of 2^31 (it gave struct.error) in a bag without index: the scan
    skips to the next chunk record and names the bytes it could not read."""
    bag, starts = _three_chunk_bag(tmp_path, indexed=False)
    data = bytearray(bag.read_bytes())
    hdr = starts[1] - 4 - 4  # the chunk record starts with its header length, then the op field's
    assert data[hdr + 4 : hdr + 8] == struct.pack("<I", 4)
    data[hdr : hdr + 4] = struct.pack("<I", 2**31)
    bag.write_bytes(bytes(data))
    got, _, stop, note = ltmap_messages(bag)
    assert [struct.unpack_from("<f", m[2], len(m[2]) - 4 - 36 * 4)[0] for m in got] == \
           [1.0 + i for i in (*range(10), *range(20, 30))]
    assert "unreadable records at bytes" in stop


def test_a_cut_off_uncompressed_chunk_gives_its_whole_messages(tmp_path):
    bag = scans_bag(tmp_path / "f.bag", n=20, per_chunk=20, indexed=False)
    data = bag.read_bytes()
    bag.write_bytes(data[: int(len(data) * 0.7)])
    got, _, stop, _ = ltmap_messages(bag)
    assert 5 < len(got) < 20 and "the file ends in the middle of a record" in stop


def test_a_message_of_an_unknown_connection_is_counted_as_damage(tmp_path):
    conns = {0: "/scan"}
    t = 10**12
    ch = build_chunk([(0, t, scan_bytes(0, t, [1.0] * 8)), (3, t + 1, b"x")], conns)
    bag = ros1_bag(tmp_path / "u.bag", [Chunk(ch.inner, messages=ch.messages[:1])], conns, indexed=False)
    got, topics, stop, _ = ltmap_messages(bag)
    assert len(got) == 1 and topics == {"/scan": 1}
    assert "1 messages of connections without a connection record" in stop


def test_index_pos_is_checked_against_the_file(tmp_path):
    bag = scans_bag(tmp_path / "f.bag", n=5)
    data = bytearray(bag.read_bytes())
    _, off = bag_index_pos(bytes(data))
    data[off : off + 8] = struct.pack("<Q", 2**62)
    bag.write_bytes(bytes(data))
    got, _, stop, note = ltmap_messages(bag)
    assert len(got) == 5 and stop is None and "outside the file" in note


def test_a_damaged_data_length_resumes_at_the_next_chunk(tmp_path):
    """A chunk's data length flipped to 2^31 - 1 (past the end of the file) in a bag without
    index: not a cut-off bag (a chunk follows); the scan resumes there and names the damage."""
    bag, starts = _three_chunk_bag(tmp_path, indexed=False)
    data = bytearray(bag.read_bytes())
    hdr = starts[1] - 8
    (hlen,) = struct.unpack_from("<I", data, hdr)
    data[hdr + 4 + hlen : hdr + 8 + hlen] = struct.pack("<I", 2**31 - 1)
    bag.write_bytes(bytes(data))
    got, _, stop, _ = ltmap_messages(bag)
    assert len(got) == 20 and "runs past the end of the file" in stop
