"""Sensor geometry: LaserScan ranges and depth images to end points (REP 117 / REP 118).

Pure numpy on plain arrays; the readers in ``ltmap_cli.io`` produce the arrays, these turn them
into end points in the sensor frame with a per-point ``returns`` flag for ``LayeredMap.integrate``.
"""

from __future__ import annotations

import numpy as np


def scan_to_points(
    ranges: np.ndarray,
    angle_min: float,
    angle_increment: float,
    range_min: float,
    range_max: float,
    clear_no_return: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """End points (N, 3) in the laser frame and ``returns`` (N,) for a LaserScan.

    - NaN, -inf and ranges below ``range_min`` are dropped;
    - +inf or ranges above ``range_max`` are no return: with ``clear_no_return`` the beam clears
      up to ``range_max`` and marks nothing, else it is dropped;
    - ranges in [range_min, range_max] are returns (hits).
    """
    r = np.asarray(ranges, dtype=np.float64)
    ang = angle_min + angle_increment * np.arange(len(r), dtype=np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(r) & (r >= range_min) & (r <= range_max)
        no_return = (np.isposinf(r) | (np.isfinite(r) & (r > range_max))) if clear_no_return else np.zeros(len(r), bool)
    use = valid | no_return
    dist = np.where(valid, r, range_max)[use]
    a = ang[use]
    pts = np.stack([dist * np.cos(a), dist * np.sin(a), np.zeros_like(dist)], axis=1)
    return pts, valid[use]


def depth_to_points(
    depth_m: np.ndarray, fx: float, fy: float, cx: float, cy: float, stride: int = 1
) -> np.ndarray:
    """End points (N, 3) in the optical frame (x right, y down, z forward) of the valid pixels
    (finite, > 0) of a depth image in metres; ``stride`` keeps every n-th row and column."""
    d = np.asarray(depth_m, dtype=np.float32)
    if stride > 1:
        d = d[::stride, ::stride]
    h, w = d.shape
    v, u = np.nonzero(np.isfinite(d) & (d > 0))
    z = d[v, u].astype(np.float64)
    # x = z (u - cx) / fx, as ((u - cx) / fx) * z: the ratio per column and row, as the fused
    # kernel core.raycast.depth_image_rays computes it (bit for bit the same points)
    xr = (np.arange(w, dtype=np.float64) * stride - cx) / fx
    yr = (np.arange(h, dtype=np.float64) * stride - cy) / fy
    return np.stack([xr[u] * z, yr[v] * z, z], axis=1)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 rigid transform to points (N, 3).

    Row by row as ``T[r,0] x + T[r,1] y + T[r,2] z + T[r,3]``, summed left to right (not a BLAS
    matmul, whose summation order is not fixed): the same numbers as the fused depth kernel
    ``core.raycast.depth_image_rays`` (a compiled loop; the numpy expression of the same sums
    gives the same bits, see tests/test_speed_fused.py)."""
    from .raycast import transform_points_kernel

    T = np.ascontiguousarray(T, dtype=np.float64)
    p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    return transform_points_kernel(T, p)


def transform_points_numpy(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``transform_points`` in plain numpy (the reference the kernel is tested against)."""
    T = np.asarray(T, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    out = np.empty((len(p), 3), dtype=np.float64)
    for r in range(3):
        out[:, r] = T[r, 0] * x + T[r, 1] * y + T[r, 2] * z + T[r, 3]
    return out
