"""The replay pipeline's stages on their own: the scheduler (no map), the tick clock, the ordered
executor, the layering of packages, and header stamps far from record times end to end."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from ltmap_cli.io.frames import ScanFrame, TfSample
from ltmap_cli.io.transforms import TfBuffer
from ltmap_cli.pipeline.clock import Ticker
from ltmap_cli.pipeline.executor import OrderedExecutor
from ltmap_cli.pipeline.scheduler import Placed, Scheduler, Skipped, TfSeen

NS = 1_000_000_000
YEAR_NS = 33_194_330 * NS  # the offset of the re-recorded bag of issue 15
ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_logs" / "scenarios" / "01_static_object"


def _scan(stamp_ns: int) -> ScanFrame:
    return ScanFrame(stamp_ns, "laser", -0.1, 0.1, 0.1, 10.0, np.ones(3, dtype=np.float32), "/scan")


def _odom(stamp_ns: int, x: float) -> TfSample:
    return TfSample(stamp_ns, "odom", "base_link", (x, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))


def _run(messages, wait_s=0.5):
    """Feed (log_ns, item) in order; return the events and the scheduler."""
    tf = TfBuffer()
    tf.add(TfSample(0, "base_link", "laser", (0.1, 0.0, 0.2), (0.0, 0.0, 0.0, 1.0), static=True))
    s = Scheduler(tf, wait_ns=int(wait_s * NS))
    events = []
    for log_ns, item in messages:
        topic = "/scan" if isinstance(item, ScanFrame) else "/tf"
        events += list(s.feed(topic, log_ns, item))
    events += list(s.flush())
    return events, s


def _log(offset_ns: int, n: int = 20, tf_lag_ns: int = 0):
    """A 10 Hz scan and a 20 Hz odometry tf recorded at log times t; header stamps t - offset. The
    tf is recorded ``tf_lag_ns`` after its stamp."""
    msgs = []
    for i in range(2 * n):
        t = 10 * NS + i * NS // 20
        msgs.append((t + tf_lag_ns, _odom(t - offset_ns, x=0.01 * i)))
        if i % 2 == 1:
            msgs.append((t, _scan(t - offset_ns)))
    return sorted(msgs, key=lambda m: m[0])


@pytest.mark.parametrize("offset_ns", [0, YEAR_NS, -YEAR_NS, 7 * NS])
def test_frames_are_placed_whatever_the_offset_of_header_stamps_to_record_time(offset_ns):
    events, s = _run(_log(offset_ns))
    placed = [e for e in events if isinstance(e, Placed)]
    skipped = [e for e in events if isinstance(e, Skipped)]
    # every scan but the last is bracketed by odometry samples: placed, at its header stamp's pose
    assert len(placed) >= 19 and len(skipped) <= 1, [e.reason for e in skipped]
    assert s.fixed_frame == "odom" and s.base_frame == "base_link"
    for e in placed:
        i = round((e.frame.stamp_ns + offset_ns - 10 * NS) / (NS / 20))
        assert e.T[0, 3] == pytest.approx(0.01 * i + 0.1, abs=1e-9)  # odom x + the laser mount
    stamps = [e.frame.stamp_ns for e in placed]
    assert stamps == sorted(stamps)


def test_a_frame_waits_for_tf_recorded_after_it():
    # tf recorded 0.3 s after its stamp (a slow tf publisher): with a 0.5 s wait every scan is
    # placed with its bracketing samples; with no wait the scans are released before them
    events, _ = _run(_log(0, tf_lag_ns=3 * NS // 10), wait_s=0.5)
    assert sum(isinstance(e, Placed) for e in events) >= 19
    early = [(0, _odom(9 * NS, 0.0))] + _log(0, tf_lag_ns=3 * NS // 10)  # tf has odom from the start
    events, _ = _run(early, wait_s=0.0)
    assert sum(isinstance(e, Skipped) for e in events) >= 15


def test_release_waits_in_header_time_and_in_record_time():
    # header stamps a year behind: a scan is held until tf stamped 0.5 s after it has arrived
    tf_stamps = []
    msgs = _log(YEAR_NS)
    tf = TfBuffer()
    tf.add(TfSample(0, "base_link", "laser", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), static=True))
    s = Scheduler(tf, wait_ns=NS // 2)
    for log_ns, item in msgs:
        for e in s.feed("/scan" if isinstance(item, ScanFrame) else "/tf", log_ns, item):
            if isinstance(e, TfSeen):
                tf_stamps.append(e.sample.stamp_ns)
            elif isinstance(e, Placed):
                assert max(tf_stamps) >= e.frame.stamp_ns + NS // 2  # held until tf passed stamp + wait
                assert log_ns >= e.frame.stamp_ns + YEAR_NS + NS // 2 - NS // 20


def test_the_backlog_is_bounded_in_bytes_too():
    """Large frames (10 MB scans here) whose tf never comes: no more than 35 MB of them are held,
    the earliest stamp released first; small ones up to the count."""
    from ltmap_cli.pipeline.scheduler import FrameHold

    hold = FrameHold(NS, max_pending=100, max_bytes=35 << 20)
    out, most = [], 0
    for i in range(12):
        hold.push(100 - i, i, 100 - i, nbytes=10 << 20)
        out += list(hold.release(i))  # (no record time passes: only the bounds release)
        most = max(most, len(hold))
        assert hold.bytes <= 35 << 20
    assert most == 3
    assert out == [97, 96, 95, 94, 93, 92, 91, 90, 89]
    assert list(hold.flush()) == [98, 99, 100] and hold.bytes == 0
    for i in range(50):
        hold.push(i, 0, i, nbytes=1000)
        assert list(hold.release(0)) == []


def test_frames_are_released_in_stamp_order_and_the_backlog_is_bounded():
    tf = TfBuffer()
    tf.add(TfSample(0, "odom", "laser", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), static=True))
    s = Scheduler(tf, wait_ns=NS, max_pending=5)
    out = []
    for i in range(12):  # no dynamic tf and no record time passing: only the bound releases frames
        out += [e.frame.stamp_ns for e in s.feed("/scan", i, _scan(100 - i))]
    assert out == [95, 94, 93, 92, 91, 90, 89]  # the earliest stamp held, each time one too many is held
    assert [e.frame.stamp_ns for e in s.flush()] == [96, 97, 98, 99, 100]


def test_ticks_close_on_the_first_stamp_at_or_after_their_end():
    t = Ticker(0.2)
    assert list(t.advance(1_000_000_000)) == []  # starts tick 0
    assert list(t.advance(1_100_000_000)) == []
    assert list(t.advance(1_200_000_000)) == [1_200_000_000]
    assert list(t.advance(1_850_000_000)) == [1_400_000_000, 1_600_000_000, 1_800_000_000]
    assert t.since_start_s(1_850_000_000) == pytest.approx(0.85)
    clock = t.analysis_clock(log_start_ns=500_000_000)
    assert clock.start(0) == pytest.approx(0.5) and clock.end(2) == pytest.approx(1.1)


@pytest.mark.parametrize("threads", [False, True])
def test_the_executor_hands_results_back_in_submission_order(threads):
    ex = OrderedExecutor(threads, workers=2, in_flight=3)
    got = []
    lock = threading.Lock()

    def job(i):  # later jobs finish first
        time.sleep(0.002 * (10 - i))
        with lock:
            return i * i

    try:
        for i in range(10):
            ex.submit(i, job, i)
            got += [(p, r) for p, r, _ in ex.ready()]
            assert len(ex.jobs) <= (3 if threads else 0)
        got += [(p, r) for p, r, _ in ex.drain()]
    finally:
        ex.close()
    assert got == [(i, i * i) for i in range(10)]


def test_the_executor_keeps_large_frames_in_flight_by_bytes_not_only_by_count():
    """Frames of 30 MB under a 64 MB budget with 3 workers: at most 3 in flight (one per worker,
    whatever their size), not the 12 the count allows; small ones up to the count; results in order."""
    ex = OrderedExecutor(True, workers=3, in_flight=12, max_bytes=64 << 20)
    got, most = [], 0
    try:
        for i in range(20):
            big = i < 10
            ex.submit(i, lambda i: time.sleep(0.001) or i, i, nbytes=(30 << 20) if big else 1000)
            got += [p for p, _, _ in ex.ready()]
            most = max(most, len(ex.jobs)) if big else most
            assert ex.bytes <= max(64 << 20, 3 * (30 << 20))
            if big:
                assert len(ex.jobs) <= 3
        assert len(ex.jobs) > 3  # the small ones: by count
        got += [p for p, _, _ in ex.drain()]
    finally:
        ex.close()
    assert got == list(range(20)) and most == 3 and ex.bytes == 0


def test_io_never_imports_core_and_pipeline_imports_no_cli():
    code = (
        "import sys, pkgutil, importlib, ltmap_cli.io\n"
        "for m in pkgutil.iter_modules(ltmap_cli.io.__path__): importlib.import_module('ltmap_cli.io.' + m.name)\n"
        "a = [m for m in sys.modules if m.startswith('ltmap_cli.core')]\n"
        "import ltmap_cli.pipeline.replay\n"
        "b = [m for m in ('click', 'matplotlib', 'ltmap_cli.cli', 'ltmap_cli.commands') if m in sys.modules]\n"
        "print(','.join(a) + '|' + ','.join(b))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "|"


def _shift_ros2_bag(src: Path, dst: Path, offset_ns: int) -> int:
    """Copy a ROS 2 bag with every header stamp (tf's included) moved by -offset_ns; record times
    unchanged, as when a bag is re-recorded while another is played back."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    n = 0

    def shift(stamp):
        t = stamp.sec * NS + stamp.nanosec - offset_ns
        return type(stamp)(sec=t // NS, nanosec=t % NS)

    with AnyReader([src], default_typestore=store) as reader, Writer(dst, version=8) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store) for c in reader.connections}
        for conn, t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if hasattr(msg, "header"):
                msg.header.stamp = shift(msg.header.stamp)
                n += 1
            for tr in getattr(msg, "transforms", []):
                tr.header.stamp = shift(tr.header.stamp)
                n += 1
            writer.write(conns[conn.id], t, store.serialize_cdr(msg, conn.msgtype))
    return n


@pytest.mark.slow
def test_a_bag_whose_header_stamps_are_a_year_older_gives_the_same_map(tmp_path):
    src = SAMPLE / "log_ros2"
    if not src.exists():
        pytest.skip("sample ROS 2 bag missing")
    shifted = tmp_path / "shifted"
    assert _shift_ros2_bag(src, shifted, YEAR_NS) > 100
    outs = {}
    for name, log in (("orig", src), ("shifted", shifted)):
        outs[name] = tmp_path / f"out_{name}"
        r = subprocess.run([sys.executable, "-m", "ltmap_cli", "replay", str(log), "-o", str(outs[name]), "--no-plots",
                            "-q"], capture_output=True, text=True)  # fmt: skip
        assert r.returncode == 0, r.stderr
        assert "skipped" not in r.stdout.split(":")[1].split(",")[1] or " 0 skipped" in r.stdout, r.stdout
    for f in ("map.pgm", "long_term.pgm"):
        assert (outs["orig"] / f).read_bytes() == (outs["shifted"] / f).read_bytes(), f


def test_frames_held_when_a_much_later_log_starts_are_placed_before_its_tf_arrives():
    # two logs replayed as one stream, the second recorded a year after the first: the first's
    # frames still held for tf (a long wait) are placed before the second's tf would push the
    # first's samples out of the tf buffer's window
    first = _log(0, n=40)
    later = [(t + YEAR_NS, x) for t, x in _log(-YEAR_NS, n=5)]
    events, _ = _run(first + later, wait_s=30.0)
    placed = [e for e in events if isinstance(e, Placed)]
    skipped = [e for e in events if isinstance(e, Skipped)]
    assert len([e for e in placed if e.frame.stamp_ns < YEAR_NS]) >= 39  # all but the last one
    assert len(skipped) <= 2, [e.reason for e in skipped]


def test_usable_cores_reads_the_affinity_and_a_cgroup_quota(tmp_path, monkeypatch):
    """replay.workers 0 means one worker per usable core: the CPU affinity, lowered to a
    container's CPU quota (cgroup v2 cpu.max, v1 cfs quota) rounded up, and at least 1."""
    from ltmap_cli.pipeline.executor import usable_cores

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(16)))
    assert usable_cores(tmp_path / "none") == 16  # no cgroup files: the affinity
    v2 = tmp_path / "v2"
    v2.mkdir()
    for text, want in (("max 100000\n", 16), ("200000 100000\n", 2), ("150000 100000", 2), ("50000 100000", 1),
                       ("3200000 100000", 16), ("garbage", 16)):
        (v2 / "cpu.max").write_text(text)
        assert usable_cores(v2) == want, text
    v1 = tmp_path / "v1"
    (v1 / "cpu").mkdir(parents=True)
    (v1 / "cpu" / "cpu.cfs_period_us").write_text("100000\n")
    for quota, want in (("-1", 16), ("400000", 4), ("10000", 1)):
        (v1 / "cpu" / "cpu.cfs_quota_us").write_text(quota + "\n")
        assert usable_cores(v1) == want, quota
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3})
    assert usable_cores(v1) == 1


def test_the_executor_takes_a_worker_per_usable_core_by_default(monkeypatch):
    from ltmap_cli.pipeline import executor

    monkeypatch.setattr(executor, "usable_cores", lambda: 6)
    ex = OrderedExecutor(True)
    try:
        assert ex.workers == 6 and ex.pool._max_workers == 6
        assert ex.keep == 24  # 4 frames in flight per worker
    finally:
        ex.close()
    ex = OrderedExecutor(True, workers=2)
    assert ex.workers == 2 and ex.keep == executor.IN_FLIGHT  # at least 8 in flight
    ex.close()
    monkeypatch.setattr(executor, "usable_cores", lambda: 64)  # at most AUTO_WORKERS_MAX by default ...
    ex = OrderedExecutor(True)
    assert ex.workers == executor.AUTO_WORKERS_MAX == 8 and ex.keep == 32
    ex.close()
    ex = OrderedExecutor(True, workers=12)  # ... as many as asked for
    assert ex.workers == 12 and ex.keep == 48
    ex.close()
    assert OrderedExecutor(False).workers == 0
