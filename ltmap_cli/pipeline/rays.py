"""The rays of each sensor type, and the voxels they pass (SPEC 2.1).

``FrameCaster.cast(frame, T, robot)`` does for one placed frame what ``LayeredMap.integrate``
would do before touching the map: its rays (per sensor type), then the voxels it updates
(``LayeredMap.frame_voxels``). It reads no map state (but for a depth image's projection,
which reads the map's quiet and still voxels as a hint the map thread checks:
``LayeredMap._map_seen``), so it runs in a worker thread.

- LaserScan: a ray per beam at ``angle_min + i * angle_increment``; no return clears to
  ``max_range`` and marks nothing.
- Depth image: with ``fast`` (default), one fused kernel from raw pixels to deduplicated rays
  (``LayeredMap.depth_rays``), bit for bit the rays of points -> transform -> classify -> dedupe.
  The optional flying-pixel filter sets dropped pixels invalid first.
- PointCloud2: its points, as a depth camera's (``depth_max_range``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..core.layers import FrameMasks, LayeredMap
from ..core.sensors import depth_to_points, scan_to_points, transform_points
from ..io.decode import RawDepthFrame
from ..io.frames import CloudFrame, DepthFrame, ScanFrame
from .filters import flying_pixel_mask


@dataclass
class CastFrame:
    """A frame's voxels, ready to apply to O in order."""

    hits: np.ndarray
    misses: np.ndarray
    n_rays: int
    rays_s: float
    cast_s: float
    filtered_pixels: int  # flying pixels dropped, or -1 when the filter did not run
    cpu_s: float  # CPU time of the thread that cast it, for this frame
    masks: FrameMasks | None = None  # its voxels as block masks (then hits and misses are empty)


class FrameCaster:
    def __init__(self, lmap: LayeredMap, cfg, fast: bool = True):
        self.lmap = lmap
        self.sensor = cfg.map.sensor
        self.replay = cfg.replay
        self.fast = fast

    def cast(self, frame, T: np.ndarray, robot: np.ndarray | None) -> CastFrame:
        t0, c0 = time.perf_counter(), time.thread_time()
        dropped = -1
        if self.replay.depth_outlier_filter and isinstance(frame, (DepthFrame, RawDepthFrame)):
            frame, dropped = self.filter_depth(frame)
        if isinstance(frame, RawDepthFrame) and self.fast:
            ends, kind = self.depth_raw_rays(frame, T, robot)
        elif isinstance(frame, ScanFrame):
            ends, kind = self.scan_rays(frame, T, robot)
        elif isinstance(frame, (DepthFrame, RawDepthFrame)):
            ends, kind = self.depth_rays(frame, T, robot)
        elif isinstance(frame, CloudFrame):
            ends, kind = self.cloud_rays(frame, T, robot)
        else:  # pragma: no cover - the reader yields only these
            raise TypeError(type(frame).__name__)
        t1 = time.perf_counter()
        if isinstance(frame, (DepthFrame, RawDepthFrame)):  # by map.sensor.depth_integration
            k = frame.intrinsics
            depth = frame.raw if isinstance(frame, RawDepthFrame) else frame.depth_m
            hits, misses, masks = self.lmap.depth_voxels(depth, k.fx, k.fy, k.cx, k.cy, T,
                                                         self.sensor.depth_max_range, ends, kind)  # fmt: skip
        else:
            hits, misses, masks = self.lmap.ray_voxels(T[:3, 3], ends, kind)
        return CastFrame(hits, misses, int((kind > 0).sum()), t1 - t0, time.perf_counter() - t1, dropped,
                         time.thread_time() - c0, masks)  # fmt: skip

    def depth_raw_rays(self, frame: RawDepthFrame, T, robot):
        k, sc = frame.intrinsics, self.sensor
        return self.lmap.depth_rays(frame.raw, k.fx, k.fy, k.cx, k.cy, T, sc.depth_max_range, robot,
                                    dedupe=sc.dedupe_dense)  # fmt: skip

    def scan_rays(self, frame: ScanFrame, T, robot):
        pts, rets = scan_to_points(frame.ranges, frame.angle_min, frame.angle_increment, frame.range_min,
                                   frame.range_max, clear_no_return=self.sensor.clear_no_return)  # fmt: skip
        return self._rays(T, robot, pts, rets, float(frame.range_max), dedupe=False)

    def depth_rays(self, frame, T, robot):
        k = frame.intrinsics
        pts = depth_to_points(frame.depth_m, k.fx, k.fy, k.cx, k.cy)
        return self._rays(T, robot, pts, None, self.sensor.depth_max_range, dedupe=self.sensor.dedupe_dense)

    def cloud_rays(self, frame: CloudFrame, T, robot):
        pts = np.asarray(frame.points, dtype=np.float64)
        return self._rays(T, robot, pts, None, self.sensor.depth_max_range, dedupe=self.sensor.dedupe_dense)

    def _rays(self, T, robot, pts, rets, max_range: float, dedupe: bool):
        world = transform_points(T, pts)
        return self.lmap.rays(T[:3, 3], world, rets, max_range=max_range, robot_pose=robot, dedupe=dedupe)

    def filter_depth(self, frame) -> tuple[DepthFrame, int]:
        """The frame with its flying pixels set invalid (NaN), and how many."""
        rc = self.replay
        k = frame.intrinsics
        depth = np.array(frame.depth_m, dtype=np.float32)  # a copy: the message buffer stays as read
        drop = flying_pixel_mask(depth, k.fx, k.fy, k.cx, k.cy, radius=rc.depth_outlier_radius,
                                 min_neighbors=rc.depth_outlier_min_neighbors)  # fmt: skip
        depth[drop] = np.nan
        return DepthFrame(frame.stamp_ns, frame.frame_id, depth, k, frame.topic, log=frame.log), int(drop.sum())
