"""An ordered parallel executor: the rays and voxels of the next frames are computed in worker
threads (the numba kernels release the GIL) while the main thread applies earlier frames to the
map, strictly in submission order, so the result is that of the serial path."""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor

RAY_WORKERS = 2  # worker threads (at most the machine's cores)
IN_FLIGHT = 8  # frames the workers may compute ahead of integration


class OrderedExecutor:
    """``submit(payload, fn, *args)``, then ``ready()`` yields ``(payload, result, wait_s)`` in
    submission order: all jobs beyond ``IN_FLIGHT``, and finished ones at the head. Without
    threads, ``fn`` runs at submission and ``ready()`` yields it at once (``wait_s`` None)."""

    def __init__(self, threads: bool, workers: int = RAY_WORKERS, in_flight: int = IN_FLIGHT):
        n = max(1, min(workers, os.cpu_count() or 1))
        self.pool = ThreadPoolExecutor(n, thread_name_prefix="ltmap-rays") if threads else None
        self.keep = in_flight if threads else 0
        self.jobs: deque = deque()

    def submit(self, payload, fn: Callable, *args) -> None:
        job = self.pool.submit(fn, *args) if self.pool is not None else fn(*args)
        self.jobs.append((payload, job))

    def ready(self) -> Iterator[tuple[object, object, float | None]]:
        return self._take(self.keep)

    def drain(self) -> Iterator[tuple[object, object, float | None]]:
        return self._take(0)

    def _take(self, keep: int):
        jobs = self.jobs
        while jobs and (len(jobs) > keep or (keep and jobs[0][1].done())):
            payload, job = jobs.popleft()
            if isinstance(job, Future):
                t0 = time.perf_counter()
                result = job.result()
                yield payload, result, time.perf_counter() - t0
            else:
                yield payload, job, None

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None
