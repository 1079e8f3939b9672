"""Compile (or load from numba's disk cache) the kernels a replay calls, before the first frame."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..core.layers import LayeredMap
from ..core.projection import project, virtual_scan

CORE = Path(__file__).resolve().parent.parent / "core"


def warm_up(cfg, static=None) -> None:
    """Call every kernel of a replay once on a throw-away map, so that compiling them (first run
    after an install) or loading them from numba's disk cache happens here, not in the first
    frame's or tick's measured time: ray casting (points, and depth images in both encodings),
    the tick rules, the projection and the virtual scan."""
    m = LayeredMap(cfg, static=static)
    T = np.eye(4)
    T[2, 3] = 1.0
    m.integrate([0.0, 0.0, 1.0], [[1.0, 0.1, 0.5], [1.0, -0.1, 0.02]], [True, False], max_range=4.0, robot_pose=T)
    m.integrate([0.0, 0.0, 1.0], [[1.0, 0.1, 0.5]], None, max_range=4.0, robot_pose=None, dedupe=False)
    for depth in (np.full((2, 2), 1000, dtype=np.uint16), np.full((2, 2), 1.0, dtype=np.float32)):
        ends, kind = m.depth_rays(depth, 1.0, 1.0, 0.5, 0.5, T, 4.0, T)
        m.integrate_rays(T[:3, 3], ends, kind)
    m.end_tick()
    p = project(m)
    virtual_scan(m, p, (0.0, 0.0, 0.0), np.zeros(1), 0.05, 4.0, o_since_frame=1)


def kernels_cached() -> bool:
    """Whether numba's disk cache holds the map's kernels (else the first run compiles them):
    numba keeps an index file (``*.nbi``) per cached function, beside the module or under
    ``NUMBA_CACHE_DIR``."""
    root = os.environ.get("NUMBA_CACHE_DIR")
    folders = [Path(root)] if root else [CORE / "__pycache__"]
    return any(folder.is_dir() and any(folder.rglob("layers.*.nbi")) for folder in folders)
