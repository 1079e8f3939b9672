"""An ordered parallel executor: the rays and voxels of the next frames are computed in worker
threads (the numba kernels release the GIL) while the main thread applies earlier frames to the
map, strictly in submission order, so the result is that of the serial path."""

from __future__ import annotations

import math
import os
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

IN_FLIGHT = 8  # frames the workers may compute ahead of integration (at least; 4 per worker)
IN_FLIGHT_BYTES = 64 << 20  # and no more frames' arrays than this, beyond one frame per worker
AUTO_WORKERS_MAX = 8  # replay.workers 0 takes one per usable core up to this: beyond, the map thread
# bounds the speed (bench_long_rays: a room's map thread allows about 12x, a hall's 9x), and each
# frame in flight holds its image and voxels (about 2 MB for 640x480 depth)
CGROUP_ROOT = Path("/sys/fs/cgroup")


def usable_cores(cgroup_root: Path = CGROUP_ROOT) -> int:
    """The cores this process may run on: its CPU affinity (taskset, a container's cpuset),
    lowered to a CPU quota's whole cores (cgroup v2 ``cpu.max``, v1 ``cpu.cfs_quota_us``: a
    container limited to 2 CPUs on a 64-core host has 2), at least 1."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    quota = None
    try:
        v2 = (cgroup_root / "cpu.max").read_text().split()
        if len(v2) == 2 and v2[0] != "max":
            quota = int(v2[0]) / int(v2[1])
    except (OSError, ValueError, ZeroDivisionError):
        pass
    if quota is None:
        try:
            q = int((cgroup_root / "cpu" / "cpu.cfs_quota_us").read_text())
            if q > 0:
                quota = q / int((cgroup_root / "cpu" / "cpu.cfs_period_us").read_text())
        except (OSError, ValueError, ZeroDivisionError):
            pass
    if quota is not None and quota > 0:
        n = min(n, max(1, math.ceil(quota - 1e-9)))
    return max(1, n)


class OrderedExecutor:
    """``submit(payload, fn, *args, nbytes=N)``, then ``ready()`` yields ``(payload, result,
    wait_s)`` in submission order: all jobs beyond ``in_flight`` (default: 4 per worker, at least
    ``IN_FLIGHT``) or beyond ``max_bytes`` of submitted frames (``nbytes`` each; one job per
    worker is always let run: large frames, a 4K image or a lidar's cloud, do not wait 32 at a
    time on a many-core machine), and finished ones at the head. Without threads, ``fn`` runs at
    submission and ``ready()`` yields it at once (``wait_s`` None)."""

    def __init__(self, threads: bool, workers: int = 0, in_flight: int = 0, max_bytes: int = IN_FLIGHT_BYTES):
        n = workers if workers > 0 else min(usable_cores(), AUTO_WORKERS_MAX)
        self.workers = n if threads else 0
        self.pool = ThreadPoolExecutor(n, thread_name_prefix="ltmap-rays") if threads else None
        self.keep = (in_flight or max(IN_FLIGHT, 4 * n)) if threads else 0
        self.max_bytes = max_bytes
        self.jobs: deque = deque()  # (payload, job, bytes)
        self.bytes = 0  # of the jobs in flight

    def submit(self, payload, fn: Callable, *args, nbytes: int = 0) -> None:
        job = self.pool.submit(fn, *args) if self.pool is not None else fn(*args)
        self.jobs.append((payload, job, nbytes))
        self.bytes += nbytes

    def ready(self) -> Iterator[tuple[object, object, float | None]]:
        return self._take(self.keep)

    def drain(self) -> Iterator[tuple[object, object, float | None]]:
        return self._take(0)

    def _take(self, keep: int):
        jobs = self.jobs
        while jobs and (len(jobs) > keep or (keep and jobs[0][1].done())
                        or (keep and self.bytes > self.max_bytes and len(jobs) > self.workers)):  # fmt: skip
            payload, job, nbytes = jobs.popleft()
            self.bytes -= nbytes
            if isinstance(job, Future):
                t0 = time.perf_counter()
                result = job.result()
                yield payload, result, time.perf_counter() - t0
            else:
                yield payload, job, None

    def close(self, wait: bool = True) -> None:
        """The workers stopped, the jobs not begun cancelled; ``wait``: their running jobs waited
        for (False for a run that is failing or interrupted: a second Ctrl-C raised while the
        map thread was inside the pool's own locks can leave one held, and the workers blocked
        on it would never be joined)."""
        if self.pool is not None:
            self.pool.shutdown(wait=wait, cancel_futures=True)
            self.pool = None
