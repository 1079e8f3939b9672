"""Reading the log ahead of the pipeline: frames in log order, decoded in a background thread
(``ReaderThread``) or in the caller's (``TimedIter``), the time spent counted in a stage timer's
``read`` (and ``read_thread``) seconds."""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections import Counter


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


class ReaderThread:
    """Read and decode a frame stream in a background thread, handing batches to the consumer
    through a bounded queue (log order kept; an exception of the stream is re-raised where the
    consumer reaches it). ``stage["read"]``: time the consumer waited; ``stage["read_thread"]``:
    the reader's busy time."""

    BATCH = 32
    DEPTH = 8  # batches queued at most

    def __init__(self, stream, stage: Counter):
        self.stream = stream
        self.stage = stage
        self.cpu_s = 0.0  # the reader thread's CPU time, once it has ended
        self.q: queue.Queue = queue.Queue(maxsize=self.DEPTH)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="ltmap-reader", daemon=True)
        self.thread.start()

    def _put(self, item) -> bool:
        while not self.stop.is_set():
            try:
                self.q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        busy = 0.0
        c0 = time.thread_time()
        batch: list = []
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
                if len(batch) >= self.BATCH:
                    if not self._put(("items", batch)):
                        return
                    batch = []
            if batch:
                self._put(("items", batch))
            self._put(("end", None))
        except BaseException as err:  # noqa: BLE001 - handed to the consumer
            if batch:
                self._put(("items", batch))
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
            kind, payload = self.q.get()
            self.stage["read"] += time.perf_counter() - t0
            if kind == "items":
                yield from payload
            elif kind == "end":
                return
            else:
                raise payload

    def close(self) -> None:
        self.stop.set()
        while self.thread.is_alive():
            with contextlib.suppress(queue.Empty):
                self.q.get(timeout=0.05)
        self.thread.join()
