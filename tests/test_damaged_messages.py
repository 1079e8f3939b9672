"""A damaged message inside an intact log is skipped and counted, not the end of the replay.

Tiny real logs (a ROS 1 bag, a ROS 2 sqlite3 bag) are written with the real writers, then one or
more messages are damaged by hand: in the .bag the length of one scan's ``ranges`` array is set
far beyond the message (the bag's own records stay intact), in the .db3 a row's data is replaced
by garbage. Replay must go on, count each damaged message in report.json under
``messages_not_decoded`` and say so once per topic on stderr.
"""

from __future__ import annotations

import json
import sqlite3
import struct
import warnings

import pytest
from logfactory import write_log
from test_replay import N_BEAMS, assert_one_line_error, cast, room_messages, run

from ltmap_cli.errors import LtmapWarning
from ltmap_cli.io.logs import open_logs

N_SCANS = 85  # room_messages(0, 17): 5 Hz for 17 s


def _damage_ros1_scans(bag, which):
    """Set the ``ranges`` length of the scans at the given 0-based indices to 0x7FFFFF00."""
    r, _ = cast(False)
    pattern = struct.pack("<I", N_BEAMS) + r[:4].tobytes()
    data = bytearray(bag.read_bytes())
    at, found = 0, []
    while (at := data.find(pattern, at)) >= 0:
        found.append(at)
        at += 1
    assert len(found) == N_SCANS  # uncompressed chunks: every scan's bytes are in the file as written
    for i in which:
        data[found[i]:found[i] + 4] = struct.pack("<I", 0x7FFFFF00)
    bag.write_bytes(bytes(data))


def _damage_db3_rows(folder, topic, which):
    """Replace the data of the messages of ``topic`` at the given 0-based indices by garbage."""
    db = next(folder.glob("*.db3"))
    con = sqlite3.connect(db)
    (tid,) = con.execute("SELECT id FROM topics WHERE name = ?", (topic,)).fetchone()
    ids = [i for (i,) in con.execute("SELECT id FROM messages WHERE topic_id = ? ORDER BY timestamp", (tid,))]
    for i in which:
        con.execute("UPDATE messages SET data = ? WHERE id = ?", (b"\x00\x01\xff\xfe garbage", ids[i]))
    con.commit()
    con.close()


def _warnings(result):
    """The warnings, without the hint that a short log's long-term map is nearly empty (hints.py)."""
    return [ln for ln in result.output.splitlines() if ln.startswith("ltmap: warning:") and "st_rise_s" not in ln]


def _report(out):
    return json.loads((out / "report.json").read_text())


def test_a_damaged_scan_in_a_ros1_bag_is_skipped_and_counted(tmp_path):
    bag = write_log(tmp_path / "log.bag", "ros1", room_messages(0.0, 17.0, False))
    good = run(["replay", str(bag), "-o", str(tmp_path / "good"), "-q"])
    assert good.exit_code == 0, good.output
    _damage_ros1_scans(bag, [40, 60])
    out = tmp_path / "o"
    r = run(["replay", str(bag), "-o", str(out), "-q"])
    assert r.exit_code == 0, r.output
    warn = _warnings(r)
    assert len(warn) == 1, r.output  # once per topic, not per message
    assert "cannot decode the message on /scan, message index 40 in " in warn[0] and "log.bag" in warn[0]
    report = _report(out)
    assert report["messages_not_decoded"] == {"cannot decode the message on /scan": 2}
    assert report["frames_used"] == {"/scan": N_SCANS - 2}
    assert _report(tmp_path / "good")["frames_used"] == {"/scan": N_SCANS}
    # the two lost scans see what the others see: the map is the same
    assert (out / "map.pgm").read_bytes() == (tmp_path / "good" / "map.pgm").read_bytes()


def test_damaged_tf_and_scan_rows_in_a_ros2_sqlite3_bag(tmp_path):
    msgs = room_messages(0.0, 17.0, False)
    bag = write_log(tmp_path / "bag", "ros2-sqlite3", msgs)
    _damage_db3_rows(bag, "/scan", [3])
    _damage_db3_rows(bag, "/tf", [10, 11, 12])
    out = tmp_path / "o"
    r = run(["replay", str(bag), "-o", str(out), "-q"])
    assert r.exit_code == 0, r.output
    warn = sorted(_warnings(r))
    assert len(warn) == 2, r.output
    assert "cannot decode the message on /scan, message index 3 in " in warn[0]
    assert "cannot decode the message on /tf, message index 10 in " in warn[1]
    report = _report(out)
    assert report["messages_not_decoded"] == {"cannot decode the message on /scan": 1,
                                              "cannot decode the message on /tf": 3}
    assert report["frames_used"] == {"/scan": N_SCANS - 1}
    assert report["messages_per_topic"]["/tf"] == sum(m.topic == "/tf" for m in msgs)  # read, then skipped


def test_the_reader_counts_and_warns_without_the_cli(tmp_path):
    bag = write_log(tmp_path / "bag", "ros2-sqlite3", room_messages(0.0, 3.0, False))
    _damage_db3_rows(bag, "/scan", [0, 5])
    with warnings.catch_warnings(record=True) as caught, open_logs(bag) as logs:
        warnings.simplefilter("always")
        scans = [item for topic, _, item in logs.messages() if topic == "/scan"]
        skipped = dict(logs.skipped)
    assert len(scans) == 15 - 2
    assert skipped == {"cannot decode the message on /scan": 2}
    ours = [w for w in caught if issubclass(w.category, LtmapWarning)]
    assert len(ours) == 1 and "/scan, message index 0 in " in str(ours[0].message)


def test_every_scan_damaged_still_fails(tmp_path):
    bag = write_log(tmp_path / "log.bag", "ros1", room_messages(0.0, 17.0, False))
    _damage_ros1_scans(bag, range(N_SCANS))
    out = tmp_path / "o"
    r = run(["replay", str(bag), "-o", str(out), "-q"])
    assert_one_line_error(r, "no usable sensor frame", "cannot decode the message on /scan", "every one")
    assert len(_warnings(r)) == 1 and "cannot decode the message on /scan" in _warnings(r)[0]
    assert not out.exists()


@pytest.mark.parametrize("fmt", ["ros1", "ros2-sqlite3"])
def test_an_intact_log_gives_no_warning(tmp_path, fmt):
    bag = write_log(tmp_path / "log", fmt, room_messages(0.0, 2.0, False))
    r = run(["replay", str(bag), "-o", str(tmp_path / "o"), "-q"])
    assert r.exit_code == 0 and not _warnings(r), r.output
    assert _report(tmp_path / "o")["messages_not_decoded"] == {}
