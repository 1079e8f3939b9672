"""Depth image filters applied before integration.

Flying pixels: at an object's edge a depth camera mixes foreground and background and returns
points floating between them. They are isolated in space, so open3d's radius outlier removal
drops them: a point is kept when at least ``min_neighbors`` other points lie within ``radius``.

They only occur at depth discontinuities, so the filter runs open3d's radius outlier removal on
the pixels near a depth jump (within ``band_px`` pixels of one) and drops only the jump pixels it
rejects. Surfaces away from edges are never touched, and the radius search covers a few thousand
points instead of 307,200 (see bench/bench_depth_filter.py for cost and effect).
"""

from __future__ import annotations

import numpy as np


def _shifted(a: np.ndarray, dy: int, dx: int, fill) -> np.ndarray:
    out = np.full_like(a, fill)
    h, w = a.shape
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    out[yd, xd] = a[ys, xs]
    return out


def depth_jump_mask(depth_m: np.ndarray, jump: float) -> np.ndarray:
    """bool (H, W): valid pixels whose depth differs from a valid 4-neighbour by more than ``jump``."""
    d = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, np.nan).astype(np.float32)
    out = np.zeros(d.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            out |= np.abs(d - _shifted(d, dy, dx, np.nan)) > jump
    return out


def flying_pixel_mask(
    depth_m: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    radius: float = 0.02,
    min_neighbors: int = 3,
    jump: float = 0.1,
    band_px: int = 4,
) -> np.ndarray:
    """bool (H, W): the pixels to drop, i.e. pixels at a depth jump that have fewer than
    ``min_neighbors`` other points within ``radius`` metres (open3d's remove_radius_outlier over
    the pixels within ``band_px`` of a jump)."""
    import open3d as o3d

    d = np.asarray(depth_m, dtype=np.float32)
    edge = depth_jump_mask(d, jump)
    drop = np.zeros(d.shape, dtype=bool)
    if not edge.any():
        return drop
    band = edge.copy()
    for dy in range(-band_px, band_px + 1):
        for dx in range(-band_px, band_px + 1):
            if dy or dx:
                band |= _shifted(edge, dy, dx, False)
    band &= np.isfinite(d) & (d > 0)
    v, u = np.nonzero(band)
    z = d[v, u].astype(np.float64)
    pts = np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], axis=1)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    _, kept = cloud.remove_radius_outlier(nb_points=int(min_neighbors), radius=float(radius))  # others, not self
    ok = np.zeros(len(pts), dtype=bool)
    ok[np.asarray(kept, dtype=np.int64)] = True
    rejected = ~ok & edge[v, u]
    drop[v[rejected], u[rejected]] = True
    return drop
