"""Stage timing: one context manager instead of hand-placed ``perf_counter`` pairs.

The stages (report.json ``stage_s``): ``warmup`` (the kernels' first calls: numba compiles them
after an install, then loads them from its disk cache), ``read`` (reading and decoding the log:
with the reader thread, the time the pipeline waited for it; ``read_thread`` its own busy time),
``tf`` (tf buffer and lookups), ``rays`` and ``cast`` (a frame's rays, and the voxels they pass,
with a depth image's projection in projective mode: busy time summed over the worker threads;
``rays_wait`` the time integration waited for them), ``integrate`` (the voxels' updates in O),
``ticks`` (ST/LT rules), ``projection`` (P, the planner, the virtual scan, the map files) and
``output`` (snapshots, events, plots, replay.mcap).
"""

from __future__ import annotations

import contextlib
import time
from collections import Counter
from collections.abc import Iterator


class StageTimer:
    """Wall seconds per stage. ``with timer("rays"): ...`` adds the block's time to ``rays``."""

    def __init__(self) -> None:
        self.seconds: Counter = Counter()

    @contextlib.contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] += time.perf_counter() - t0

    def add(self, stage: str, seconds: float) -> None:
        self.seconds[stage] += seconds

    def rounded(self) -> dict[str, float]:
        return {k: round(v, 3) for k, v in sorted(self.seconds.items())}
