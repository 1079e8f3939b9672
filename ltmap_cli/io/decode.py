"""Deserialized ROS messages -> plain frames (``ltmap_cli.io.frames``).

The messages come from three deserializers: rosbags (dataclasses, numpy arrays, ``sec`` /
``nanosec``), mcap_ros2 (objects, ``bytes`` and lists) and mcap_ros1 / genpy (objects, ``secs`` /
``nsecs``, ROS 1 field names such as ``K``). The functions here read all of them. Each takes
``where`` (a "topic ... message index N in FILE" text) for its one-line errors.

Everything is vectorized with numpy; there is no Python loop per point, beam or pixel.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import LogReadError
from .frames import CameraIntrinsics, CloudFrame, DepthFrame, OdometrySample, ScanFrame, TfSample

DEPTH_ENCODINGS = ("16UC1", "32FC1")  # mono16 is accepted as 16UC1

# sensor_msgs/PointField datatypes
_POINTFIELD = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def frame_name(name: str) -> str:
    """tf frame ids without a leading slash: ``/laser`` and ``laser`` are one frame."""
    return name.lstrip("/")


def stamp_ns(t: Any) -> int:
    """A ROS time (rosbags/mcap_ros2 ``sec``/``nanosec`` or genpy ``secs``/``nsecs``) in ns."""
    sec = getattr(t, "sec", None)
    if sec is None:
        return int(t.secs) * 1_000_000_000 + int(t.nsecs)
    return int(sec) * 1_000_000_000 + int(t.nanosec)


def _attr(msg: Any, *names: str) -> Any:
    for n in names:
        v = getattr(msg, n, None)
        if v is not None:
            return v
    raise AttributeError(f"message has none of the fields {', '.join(names)}")


def _bytes(data: Any) -> np.ndarray:
    if isinstance(data, np.ndarray):
        return data.view(np.uint8).reshape(-1)
    if isinstance(data, (bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.uint8)
    return np.asarray(data, dtype=np.uint8)


def decode_scan(msg: Any, topic: str, where: str) -> ScanFrame:
    ranges = np.asarray(msg.ranges, dtype=np.float32).reshape(-1)
    amin, amax, inc = float(msg.angle_min), float(msg.angle_max), float(msg.angle_increment)
    n = len(ranges)
    if n > 1:
        expected = (amax - amin) / inc + 1.0 if inc != 0.0 and np.isfinite(inc) else float("nan")
        # drivers disagree on whether angle_max is the last beam's angle: allow one beam either way
        if not np.isfinite(expected) or abs(n - expected) > 1.01:
            raise LogReadError(
                f"LaserScan {where}: {n} ranges do not match angle_min {amin:.6g}, angle_max {amax:.6g}, "
                f"angle_increment {inc:.6g} (expected about {expected:.1f}); the log is corrupt, "
                f"skip this topic with --scan-topic naming another")
    h = msg.header
    return ScanFrame(stamp_ns=stamp_ns(h.stamp), frame_id=frame_name(h.frame_id), angle_min=amin,
                     angle_increment=inc, range_min=float(msg.range_min), range_max=float(msg.range_max),
                     ranges=ranges, topic=topic)


def cloud_points(msg: Any, where: str) -> np.ndarray:
    """The (N, 3) float32 finite points of a PointCloud2 with any field layout."""
    fields = {f.name: f for f in msg.fields}
    missing = [c for c in "xyz" if c not in fields]
    if missing:
        raise LogReadError(f"PointCloud2 {where} has no field {', '.join(missing)} "
                           f"(fields: {', '.join(fields) or 'none'}); only x/y/z clouds can be mapped")
    end = ">" if msg.is_bigendian else "<"
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    height, width = int(msg.height), int(msg.width)
    names, formats, offsets = [], [], []
    for c in "xyz":
        f = fields[c]
        code = _POINTFIELD.get(int(f.datatype))
        if code not in ("f4", "f8"):
            raise LogReadError(f"PointCloud2 {where}: field {c} has datatype {int(f.datatype)}; "
                               f"supported are FLOAT32 (7) and FLOAT64 (8)")
        names.append(c)
        formats.append(end + code)
        offsets.append(int(f.offset))
    if height * width == 0:
        return np.zeros((0, 3), np.float32)
    need = max(o + np.dtype(f).itemsize for o, f in zip(offsets, formats))
    if point_step < need or row_step < width * point_step:
        raise LogReadError(f"PointCloud2 {where}: point_step {point_step} / row_step {row_step} are too "
                           f"small for its fields and width {width}; the log is corrupt")
    data = _bytes(msg.data)
    if len(data) < (height - 1) * row_step + width * point_step:
        raise LogReadError(f"PointCloud2 {where}: data has {len(data)} bytes, less than height {height} "
                           f"x row_step {row_step}; the log is corrupt")
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})
    arr = np.ndarray((height, width), dtype=dt, buffer=data, strides=(row_step, point_step))
    pts = np.empty((height * width, 3), np.float32)
    for i, c in enumerate("xyz"):
        pts[:, i] = arr[c].reshape(-1)
    return pts[np.isfinite(pts).all(axis=1)]


def decode_cloud(msg: Any, topic: str, where: str) -> CloudFrame:
    h = msg.header
    return CloudFrame(stamp_ns=stamp_ns(h.stamp), frame_id=frame_name(h.frame_id),
                      points=cloud_points(msg, where), topic=topic)


def intrinsics(info: Any) -> CameraIntrinsics:
    """CameraIntrinsics from a CameraInfo (ROS 1 ``K`` or ROS 2 ``k``)."""
    k = np.asarray(_attr(info, "k", "K"), dtype=np.float64).reshape(-1)
    return CameraIntrinsics(width=int(info.width), height=int(info.height), fx=float(k[0]), fy=float(k[4]),
                            cx=float(k[2]), cy=float(k[5]))


def depth_metres(msg: Any, where: str) -> np.ndarray:
    """An Image 16UC1 (mm, 0 invalid) or 32FC1 (m, NaN/0 invalid) as float32 metres, NaN invalid."""
    enc = str(msg.encoding)
    code = {"16UC1": "u2", "mono16": "u2", "32FC1": "f4"}.get(enc)
    if code is None:
        raise LogReadError(f"depth Image {where} has encoding {enc!r}; supported depth encodings are "
                           f"16UC1 (millimetres) and 32FC1 (metres): choose the depth topic with --depth-topic")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    dt = np.dtype((">" if msg.is_bigendian else "<") + code)
    data = _bytes(msg.data)
    if h * w and (step < w * dt.itemsize or len(data) < (h - 1) * step + w * dt.itemsize):
        raise LogReadError(f"depth Image {where}: {len(data)} bytes with step {step} cannot hold "
                           f"{h}x{w} {enc} pixels; the log is corrupt")
    if h * w == 0:
        return np.zeros((h, w), np.float32)
    raw = np.ndarray((h, w), dtype=dt, buffer=data, strides=(step, dt.itemsize))
    if code == "u2":
        depth = raw.astype(np.float32) * np.float32(0.001)
        depth[raw == 0] = np.nan
    else:
        depth = raw.astype(np.float32)
        depth[~(depth > 0) | ~np.isfinite(depth)] = np.nan
    return depth


def decode_depth(msg: Any, info: Any, topic: str, where: str) -> DepthFrame:
    depth = depth_metres(msg, where)
    intr = intrinsics(info)
    h, w = depth.shape
    if (intr.width, intr.height) == (0, 0):
        intr = CameraIntrinsics(w, h, intr.fx, intr.fy, intr.cx, intr.cy)
    elif (intr.width, intr.height) != (w, h):
        raise LogReadError(f"depth Image {where} is {w}x{h} but its CameraInfo says "
                           f"{intr.width}x{intr.height}; pair it with the right camera_info topic")
    if intr.fx <= 0 or intr.fy <= 0:
        raise LogReadError(f"CameraInfo for depth Image {where} has focal lengths fx={intr.fx}, fy={intr.fy}; "
                           f"the camera is uncalibrated and its depth cannot be placed")
    h0 = msg.header
    return DepthFrame(stamp_ns=stamp_ns(h0.stamp), frame_id=frame_name(h0.frame_id), depth_m=depth,
                      intrinsics=intr, topic=topic)


def decode_tf(msg: Any, static: bool) -> list[TfSample]:
    out = []
    for t in msg.transforms:
        tr, q = t.transform.translation, t.transform.rotation
        out.append(TfSample(stamp_ns=stamp_ns(t.header.stamp), parent=frame_name(t.header.frame_id),
                            child=frame_name(t.child_frame_id),
                            translation=(float(tr.x), float(tr.y), float(tr.z)),
                            rotation_xyzw=(float(q.x), float(q.y), float(q.z), float(q.w)), static=static))
    return out


def decode_odometry(msg: Any) -> OdometrySample:
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return OdometrySample(stamp_ns=stamp_ns(msg.header.stamp), parent=frame_name(msg.header.frame_id),
                          child=frame_name(msg.child_frame_id), translation=(float(p.x), float(p.y), float(p.z)),
                          rotation_xyzw=(float(q.x), float(q.y), float(q.z), float(q.w)))
