"""The reader thread (``pipeline.reader.ReaderThread``): frames decoded ahead of the mapper, in
log order, with what waits between the two bounded in count and in bytes. Counted by items alone,
large frames piled up: 47 images of 1280x720 (87 MB) on the room720 bench log, and for a 4K float
camera it would be gigabytes."""

from __future__ import annotations

import threading
import time
from collections import Counter

import numpy as np
import pytest

from ltmap_cli.io.frames import CameraIntrinsics, CloudFrame, DepthFrame, ScanFrame
from ltmap_cli.pipeline.reader import ReaderThread, payload_bytes


def _depth(i: int, mb: float) -> tuple:
    n = int(mb * (1 << 20)) // 4
    k = CameraIntrinsics(n, 1, 100.0, 100.0, n / 2, 0.0)
    return ("/depth", i, DepthFrame(i, "cam", np.zeros((1, n), dtype=np.float32), k, "/depth"))


def _scan(i: int) -> tuple:
    return ("/scan", i, ScanFrame(i, "laser", -3.1, 0.01, 0.1, 10.0, np.zeros(720, dtype=np.float32), "/scan"))


class Counted:
    """A stream that counts the items it has handed out (what the reader has taken)."""

    def __init__(self, items):
        self.items = items
        self.taken = 0

    def __iter__(self):
        for x in self.items:
            self.taken += 1
            yield x


def test_payload_bytes_counts_the_frames_arrays():
    assert payload_bytes(_depth(0, 2.0)) == 2 << 20
    assert payload_bytes(_scan(0)) == 720 * 4
    cloud = CloudFrame(0, "lidar", np.zeros((1000, 3), dtype=np.float32))
    assert payload_bytes(("/points", 0, cloud)) == 12000
    assert payload_bytes(("/tf", 0, object())) == 0


def _consume_slowly(reader: ReaderThread, stream: Counted, delay: float) -> tuple[list, int]:
    """Every item, and the most items the reader had taken but the consumer not yet received."""
    got, ahead = [], 0
    for x in reader:
        ahead = max(ahead, stream.taken - len(got))
        got.append(x)
        time.sleep(delay)
    return got, ahead


def test_large_frames_wait_bounded_in_bytes(monkeypatch):
    """40 images of 12 MB each under a 40 MB budget: at most 3 of them wait in the queue, besides
    the one the reader holds while it waits for room and the one the consumer has (counted by
    batches alone: 8 of them, 96 MB); all arrive, in order."""
    monkeypatch.setattr(ReaderThread, "MAX_BYTES", 40 << 20)
    items = [_depth(i, 12.0) for i in range(40)]
    stream = Counted(items)
    reader = ReaderThread(stream, Counter())
    got, ahead = _consume_slowly(reader, stream, 0.01)
    reader.close()
    assert [x[1] for x in got] == list(range(40))
    assert reader.peak_bytes <= 36 << 20
    assert ahead <= 3 + 2


def test_small_frames_wait_bounded_in_count():
    """Scans (3 kB each): the count bound holds (DEPTH batches of BATCH items)."""
    items = [_scan(i) for i in range(2000)]
    stream = Counted(items)
    reader = ReaderThread(stream, Counter())
    got, ahead = _consume_slowly(reader, stream, 0.0002)
    reader.close()
    assert [x[1] for x in got] == list(range(2000))
    assert ahead <= (ReaderThread.DEPTH + 2) * ReaderThread.BATCH


def test_a_frame_larger_than_the_budget_still_passes():
    items = [_scan(0), _depth(1, ReaderThread.MAX_BYTES / (1 << 20) * 1.5), _scan(2), _depth(3, 1.0)]
    reader = ReaderThread(Counted(items), Counter())
    done = []
    t = threading.Thread(target=lambda: done.extend(reader), daemon=True)
    t.start()
    t.join(10)
    assert [x[1] for x in done] == [0, 1, 2, 3]


def test_a_stream_error_arrives_after_the_items_before_it():
    def stream():
        yield _scan(0)
        yield _depth(1, 7.0)  # a batch of its own (BATCH_BYTES)
        yield _scan(2)
        raise ValueError("chunk 3 is corrupt")

    reader = ReaderThread(stream(), Counter())
    got = []
    with pytest.raises(ValueError, match="chunk 3"):
        for x in reader:
            got.append(x[1])
    assert got == [0, 1, 2]


def test_close_ends_a_reader_that_waits_for_room():
    """The consumer stops early (a time window's end, an interrupt): the reader, blocked on a
    full queue, ends and closes its stream."""
    closed = threading.Event()

    class Endless:
        def __iter__(self):
            i = 0
            while True:
                yield _depth(i, 10.0)
                i += 1

        def close(self):
            closed.set()

    reader = ReaderThread(Endless(), Counter())
    it = iter(reader)
    assert next(it)[1] == 0
    time.sleep(0.2)  # the queue fills
    t0 = time.perf_counter()
    reader.close()
    assert time.perf_counter() - t0 < 2.0
    assert not reader.thread.is_alive() and closed.is_set()
