"""Reading the log ahead of the pipeline: frames in log order, decoded in a background thread
(``ReaderThread``) or in the caller's (``TimedIter``), the time spent counted in a stage timer's
``read`` (and ``read_thread``) seconds."""

from __future__ import annotations

import threading
import time
from collections import Counter, deque

from ..io.frames import frame_nbytes


def open_reader(stream, stage: Counter, threads: bool):
    """The frame stream, read in a background thread when ``threads``."""
    return ReaderThread(stream, stage) if threads else TimedIter(stream, stage)


class TimedIter:
    """Iterate a frame stream in this thread, adding the time spent in it to ``stage["read"]``."""

    cpu_s = 0.0  # (its CPU time is the consumer's thread's)

    def __init__(self, stream, stage: Counter):
        self.stream = stream
        self.stage = stage

    def __iter__(self):
        it = iter(self.stream)
        while True:
            t0 = time.perf_counter()
            try:
                x = next(it)
            except StopIteration:
                self.stage["read"] += time.perf_counter() - t0
                return
            self.stage["read"] += time.perf_counter() - t0
            yield x

    def close(self) -> None:
        close = getattr(self.stream, "close", None)
        if close is not None:
            close()


def payload_bytes(item) -> int:
    """The bytes a stream item holds in arrays: its frame's (a ``(topic, log ns, frame)`` tuple's,
    or the item's own), ``io.frames.frame_nbytes``."""
    return frame_nbytes(item[2] if isinstance(item, tuple) and len(item) == 3 else item)


class ReaderThread:
    """Read and decode a frame stream in a background thread, handing batches to the consumer
    (log order kept; an exception of the stream is re-raised where the consumer reaches it).
    ``stage["read"]``: time the consumer waited; ``stage["read_thread"]``: the reader's busy time.

    What waits between the two is bounded by count (``DEPTH`` batches of ``BATCH`` items) and by
    bytes (``MAX_BYTES`` of frames' arrays, ``payload_bytes``; a batch is handed over once it holds
    ``BATCH_BYTES``): a count alone let large frames pile up (47 images of 1280x720 queued, 87 MB;
    256 images of a 4K float camera, 8 GB). One batch is always let through, however large, so a
    frame bigger than the budget still passes."""

    BATCH = 32
    DEPTH = 8  # batches queued at most
    MAX_BYTES = 48 << 20  # frames' arrays queued at most (about 80 images of 640x480 16UC1)
    BATCH_BYTES = 6 << 20  # a batch holding this much is handed over before it has BATCH items

    def __init__(self, stream, stage: Counter):
        self.stream = stream
        self.stage = stage
        self.cpu_s = 0.0  # the reader thread's CPU time, once it has ended
        self.q: deque = deque()  # (kind, payload, bytes)
        self.queued_bytes = 0
        self.peak_bytes = 0  # the most bytes ever queued (tests, benches)
        self.cond = threading.Condition()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="ltmap-reader", daemon=True)
        self.thread.start()

    def _put(self, item, nbytes: int = 0) -> bool:
        with self.cond:
            while not self.stop.is_set():
                if not self.q or (len(self.q) < self.DEPTH and self.queued_bytes + nbytes <= self.MAX_BYTES):
                    self.q.append((*item, nbytes))
                    self.queued_bytes += nbytes
                    self.peak_bytes = max(self.peak_bytes, self.queued_bytes)
                    self.cond.notify_all()
                    return True
                self.cond.wait(0.1)
        return False

    def _get(self):
        with self.cond:
            while not self.q:
                self.cond.wait()
            kind, payload, nbytes = self.q.popleft()
            self.queued_bytes -= nbytes
            self.cond.notify_all()
        return kind, payload

    def _run(self) -> None:
        busy = 0.0
        c0 = time.thread_time()
        batch: list = []
        nbytes = 0
        try:
            it = iter(self.stream)
            while not self.stop.is_set():
                t0 = time.perf_counter()
                try:
                    x = next(it)
                except StopIteration:
                    busy += time.perf_counter() - t0
                    break
                busy += time.perf_counter() - t0
                batch.append(x)
                nbytes += payload_bytes(x)
                if len(batch) >= self.BATCH or nbytes >= self.BATCH_BYTES:
                    if not self._put(("items", batch), nbytes):
                        return
                    batch, nbytes = [], 0
            if batch:
                self._put(("items", batch), nbytes)
            self._put(("end", None))
        except BaseException as err:  # noqa: BLE001 - handed to the consumer
            if batch:
                self._put(("items", batch), nbytes)
            self._put(("error", err))
        finally:
            self.stage["read_thread"] += busy
            self.cpu_s = time.thread_time() - c0
            close = getattr(self.stream, "close", None)
            if close is not None and self.stop.is_set():
                close()

    def __iter__(self):
        while True:
            t0 = time.perf_counter()
            kind, payload = self._get()
            self.stage["read"] += time.perf_counter() - t0
            if kind == "items":
                yield from payload
            elif kind == "end":
                return
            else:
                raise payload

    def close(self) -> None:
        self.stop.set()
        with self.cond:
            self.cond.notify_all()
        self.thread.join()
