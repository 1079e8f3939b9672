"""Deserialized ROS messages -> plain frames (``ltmap_cli.io.frames``).

The messages come from three deserializers: rosbags (dataclasses, numpy arrays, ``sec`` /
``nanosec``), mcap_ros2 (objects, ``bytes`` and lists) and mcap_ros1 / genpy (objects, ``secs`` /
``nsecs``, ROS 1 field names such as ``K``). The functions here read all of them. Each takes
``where`` (a "topic ... message index N in FILE" text) for its one-line errors.

Everything is vectorized with numpy; there is no Python loop per point, beam or pixel.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import LogReadError
from . import rectify
from .frames import CameraIntrinsics, CloudFrame, DepthFrame, OdometrySample, ScanFrame, TfSample
from .transforms import norm

# sensor_msgs/PointField datatypes
_POINTFIELD = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def frame_name(name: Any) -> str:
    """A header's frame id as tf knows it (``transforms.norm``: no leading ``/``, no whitespace):
    ``/laser``, ``laser`` and `` laser `` are one frame."""
    return norm(str(name))


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


def scan_angle_max_off(n: int, amin: float, amax: float, inc: float) -> bool:
    """Whether a LaserScan's ``angle_max`` disagrees with its ``n`` ranges (more than one beam
    off: drivers differ on whether ``angle_max`` is the last beam's angle). Harmless: the angles
    are ``angle_min + i * angle_increment``, as ROS' own projection computes them."""
    if n < 2 or not math.isfinite(amax):
        return n >= 2
    return abs(n - ((amax - amin) / inc + 1.0)) > 1.01


def decode_scan(msg: Any, topic: str, where: str) -> ScanFrame:
    """A ScanFrame whose beam i is at ``angle_min + i * angle_increment`` whatever ``angle_max``
    says (``angle_max_off`` tells when it disagrees); an increment that is zero or not finite
    (with more than one range) cannot place the beams: LogReadError."""
    ranges = np.asarray(msg.ranges, dtype=np.float32).reshape(-1)
    amin, amax, inc = float(msg.angle_min), float(msg.angle_max), float(msg.angle_increment)
    n = len(ranges)
    if not math.isfinite(amin) or (n > 1 and (inc == 0.0 or not math.isfinite(inc))):
        raise LogReadError(
            f"LaserScan {where}: angle_min {amin:.6g} and angle_increment {inc:.6g} cannot place its {n} "
            f"beams; the log is corrupt, skip this topic with --scan-topic naming another")
    h = msg.header
    return ScanFrame(stamp_ns=stamp_ns(h.stamp), frame_id=frame_name(h.frame_id), angle_min=amin,
                     angle_increment=inc, range_min=float(msg.range_min), range_max=float(msg.range_max),
                     ranges=ranges, topic=topic, angle_max_off=scan_angle_max_off(n, amin, amax, inc))


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


def binning_roi(info: Any) -> tuple[int, int, tuple[int, int, int, int] | None]:
    """A CameraInfo's binning (0 means 1: none) and region of interest (x_offset, y_offset,
    width, height in full-resolution pixels; None when all zero: the whole image)."""
    bx = int(getattr(info, "binning_x", 0) or 0) or 1
    by = int(getattr(info, "binning_y", 0) or 0) or 1
    roi = getattr(info, "roi", None)
    box = None if roi is None else (int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height))
    return bx, by, (None if box == (0, 0, 0, 0) else box)


def full_camera(info: Any) -> str:
    """What a CameraInfo with binning or a ROI describes before them, for messages (e.g.
    ``64x48 with binning 2x2 and ROI 32x24 at (8, 4)``); "" without either."""
    bx, by, roi = binning_roi(info)
    if bx == 1 and by == 1 and roi is None:
        return ""
    crop = f" and ROI {roi[2]}x{roi[3]} at ({roi[0]}, {roi[1]})" if roi else ""
    return f"{int(info.width)}x{int(info.height)} with binning {bx}x{by}{crop}"


def intrinsics(info: Any) -> CameraIntrinsics:
    """CameraIntrinsics of the images a CameraInfo describes (ROS 1 ``K`` or ROS 2 ``k``), with its
    binning and region of interest applied as image_geometry's PinholeCameraModel applies them:
    K, width and height are the full camera's; an image is the ROI (all zero: the whole image; a
    zero width or height: to the image's edge) divided by the binning, so its principal point is
    (cx - x_offset) / binning_x, its focal length fx / binning_x, its width the ROI's // binning_x
    (and so in y). Without either, K and the size as they are."""
    k = np.asarray(_attr(info, "k", "K"), dtype=np.float64).reshape(-1)
    fx, fy, cx, cy = float(k[0]), float(k[4]), float(k[2]), float(k[5])
    w, h = int(info.width), int(info.height)
    bx, by, roi = binning_roi(info)
    if roi is not None:
        xo, yo, rw, rh = roi
        cx, cy = cx - xo, cy - yo
        w, h = rw or max(w - xo, 0), rh or max(h - yo, 0)
    if bx > 1:
        fx, cx, w = fx / bx, cx / bx, w // bx
    if by > 1:
        fy, cy, h = fy / by, cy / by, h // by
    return CameraIntrinsics(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy)


MM = 0.001  # metres per unit of a 16-bit depth image (16UC1 / mono16) unless the log says otherwise


def depth_metres(msg: Any, where: str, units: float | None = None) -> np.ndarray:
    """An Image 16UC1 / mono16 (``units`` metres per unit, default mm; 0 invalid) or 32FC1 (m,
    NaN/0 invalid) as float32 metres, NaN invalid."""
    enc = str(msg.encoding)
    code = {"16UC1": "u2", "mono16": "u2", "32FC1": "f4"}.get(enc)
    if code is None:
        raise LogReadError(f"depth Image {where} has encoding {enc!r}; supported depth encodings are "
                           f"16UC1 / mono16 (millimetres) and 32FC1 (metres): choose the depth topic with "
                           f"--depth-topic")
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
        depth = raw.astype(np.float32) * np.float32(units or MM)
        depth[raw == 0] = np.nan
    else:
        depth = raw.astype(np.float32)
        depth[~(depth > 0) | ~np.isfinite(depth)] = np.nan
    return depth


def _checked_intrinsics(info: Any, shape: tuple[int, int], where: str) -> CameraIntrinsics:
    intr = intrinsics(info)
    h, w = shape
    if (intr.width, intr.height) == (0, 0):
        intr = CameraIntrinsics(w, h, intr.fx, intr.fy, intr.cx, intr.cy)
    elif (intr.width, intr.height) != (w, h):
        full = full_camera(info)
        how = f" ({full})" if full else ""
        raise LogReadError(f"depth Image {where} is {w}x{h} but its CameraInfo says "
                           f"{intr.width}x{intr.height}{how}; pair it with the right camera_info topic")
    if not (0 < intr.fx < np.inf and 0 < intr.fy < np.inf):  # (NaN fails too)
        raise LogReadError(f"CameraInfo for depth Image {where} has focal lengths fx={intr.fx}, fy={intr.fy}; "
                           f"the camera is uncalibrated and its depth cannot be placed")
    if not (np.isfinite(intr.cx) and np.isfinite(intr.cy)):
        raise LogReadError(f"CameraInfo for depth Image {where} has principal point cx={intr.cx}, cy={intr.cy}; "
                           f"the camera is uncalibrated and its depth cannot be placed")
    return intr


def decode_depth(msg: Any, info: Any, topic: str, where: str, units: float | None = None) -> DepthFrame:
    """A DepthFrame; ``units``: metres per unit of a 16-bit image (a RealSense ``Depth Units``)."""
    return depth_frame(msg.header, depth_raw(msg, where), info, topic, where, units, fast=False)


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


# ----------------------------------------------------------------------------- fast CDR path
# The generic deserializers build every field in Python (mcap_ros2: one call per number). For the
# types a replay reads at high rate, the CDR bytes (XCDR1 little endian: the ROS 2 default) are
# read here directly, into light message objects with the fields the decoders above use, which
# then build the frames: the same frames, the same checks and errors. Anything unexpected (big
# endian, short buffer, odd lengths) raises ``_NotFast`` and the caller falls back to the
# generic deserializer, so the fast path can only be faster, never different.


class _NotFast(Exception):
    pass


class _Obj:
    """A message (or sub-message) with plain attributes."""

    def __init__(self, **kw: Any):
        self.__dict__.update(kw)


_U32 = struct.Struct("<I")
_I32U32 = struct.Struct("<iI")
_F32x7 = struct.Struct("<7f")
_F64x3 = struct.Struct("<3d")
_F64x4 = struct.Struct("<4d")
_F64x9 = struct.Struct("<9d")
_F64x12 = struct.Struct("<12d")
_U32x6 = struct.Struct("<6I")


class _Cdr:
    __slots__ = ("buf", "pos", "end")

    def __init__(self, buf: bytes | memoryview):
        if len(buf) < 4 or buf[0] != 0 or buf[1] != 1:  # CDR_LE (plain or parameter list: not ours)
            raise _NotFast
        self.buf = buf
        self.pos = 4
        self.end = len(buf)

    def align(self, n: int) -> None:
        self.pos += (-(self.pos - 4)) % n

    def take(self, st: struct.Struct, align: int) -> tuple:
        self.align(align)
        p = self.pos
        if p + st.size > self.end:
            raise _NotFast
        self.pos = p + st.size
        return st.unpack_from(self.buf, p)

    def u32(self) -> int:
        return self.take(_U32, 4)[0]

    def u8(self) -> int:
        if self.pos >= self.end:
            raise _NotFast
        v = self.buf[self.pos]
        self.pos += 1
        return v

    def string(self) -> str:
        n = self.u32()
        p = self.pos
        if n == 0 or p + n > self.end:
            raise _NotFast
        self.pos = p + n
        return bytes(self.buf[p : p + n - 1]).decode("utf-8")

    def header(self) -> _Obj:
        sec, nanosec = self.take(_I32U32, 4)
        return _Obj(stamp=_Obj(sec=sec, nanosec=nanosec), frame_id=self.string())

    def array(self, dtype: str, itemsize: int) -> np.ndarray:
        n = self.u32()
        self.align(itemsize)
        p = self.pos
        if p + n * itemsize > self.end:
            raise _NotFast
        self.pos = p + n * itemsize
        return np.frombuffer(self.buf, dtype=dtype, count=n, offset=p)


def cdr_stamp_ns(data: bytes | memoryview) -> int:
    """The header stamp of a CDR message that starts with a std_msgs/Header (raises _NotFast)."""
    sec, nanosec = _Cdr(data).take(_I32U32, 4)
    return sec * 1_000_000_000 + nanosec


def cdr_scan(data: bytes | memoryview) -> _Obj:
    c = _Cdr(data)
    h = c.header()
    amin, amax, inc, tinc, stime, rmin, rmax = c.take(_F32x7, 4)
    ranges = c.array("<f4", 4)
    return _Obj(header=h, angle_min=amin, angle_max=amax, angle_increment=inc, range_min=rmin, range_max=rmax,
                ranges=ranges)


def cdr_image(data: bytes | memoryview) -> _Obj:
    c = _Cdr(data)
    h = c.header()
    height, width = c.u32(), c.u32()
    enc = c.string()
    big = c.u8()
    step = c.u32()
    n = c.u32()
    p = c.pos
    if p + n > c.end:
        raise _NotFast
    return _Obj(header=h, height=height, width=width, encoding=enc, is_bigendian=big, step=step,
                data=np.frombuffer(data, dtype=np.uint8, count=n, offset=p))


def cdr_camera_info(data: bytes | memoryview) -> _Obj:
    c = _Cdr(data)
    h = c.header()
    height, width = c.u32(), c.u32()
    model = c.string()
    d = c.array("<f8", 8)
    k = c.take(_F64x9, 8)
    c.take(_F64x9, 8)  # r
    c.take(_F64x12, 8)  # p
    bx, by, xo, yo, rh, rw = c.take(_U32x6, 4)  # binning_x, binning_y, roi: x_offset, y_offset, height, width
    return _Obj(header=h, height=height, width=width, distortion_model=model, d=d, k=k, binning_x=bx,
                binning_y=by, roi=_Obj(x_offset=xo, y_offset=yo, height=rh, width=rw))


def cdr_tf(data: bytes | memoryview) -> _Obj:
    c = _Cdr(data)
    n = c.u32()
    if n > c.end:
        raise _NotFast
    out = []
    for _ in range(n):
        h = c.header()
        child = c.string()
        tx, ty, tz = c.take(_F64x3, 8)
        qx, qy, qz, qw = c.take(_F64x4, 8)
        out.append(_Obj(header=h, child_frame_id=child,
                        transform=_Obj(translation=_Obj(x=tx, y=ty, z=tz), rotation=_Obj(x=qx, y=qy, z=qz, w=qw))))
    return _Obj(transforms=out)


def cdr_odometry(data: bytes | memoryview) -> _Obj:
    c = _Cdr(data)
    h = c.header()
    child = c.string()
    px, py, pz = c.take(_F64x3, 8)
    qx, qy, qz, qw = c.take(_F64x4, 8)
    return _Obj(header=h, child_frame_id=child,
                pose=_Obj(pose=_Obj(position=_Obj(x=px, y=py, z=pz), orientation=_Obj(x=qx, y=qy, z=qz, w=qw))))


CDR_PARSERS = {
    "sensor_msgs/msg/LaserScan": cdr_scan,
    "sensor_msgs/msg/Image": cdr_image,
    "sensor_msgs/msg/CameraInfo": cdr_camera_info,
    "tf2_msgs/msg/TFMessage": cdr_tf,
    "nav_msgs/msg/Odometry": cdr_odometry,
}


@dataclass(frozen=True)
class RawDepthFrame:
    """A depth image as recorded (what the fused depth kernel reads): ``raw`` (H, W) is uint16
    millimetres (0 invalid) or float32 metres, native byte order, possibly a strided view of the
    message buffer. ``depth_m`` gives what ``DepthFrame.depth_m`` holds."""

    stamp_ns: int
    frame_id: str
    raw: np.ndarray
    intrinsics: CameraIntrinsics
    topic: str = ""
    log: int = 0  # index of the log it comes from

    @property
    def depth_m(self) -> np.ndarray:
        raw = self.raw
        if raw.dtype == np.uint16:
            depth = raw.astype(np.float32) * np.float32(MM)
            depth[raw == 0] = np.nan
        else:
            depth = raw.astype(np.float32)
            depth[~(depth > 0) | ~np.isfinite(depth)] = np.nan
        return depth


def depth_raw(msg: Any, where: str) -> np.ndarray:
    """An Image 16UC1 / 32FC1 as its raw (H, W) pixels in native byte order (checks as
    ``depth_metres``)."""
    enc = str(msg.encoding)
    code = {"16UC1": "u2", "mono16": "u2", "32FC1": "f4"}.get(enc)
    if code is None:
        return depth_metres(msg, where)  # raises the encoding error
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    dt = np.dtype((">" if msg.is_bigendian else "<") + code)
    data = _bytes(msg.data)
    if h * w and (step < w * dt.itemsize or len(data) < (h - 1) * step + w * dt.itemsize):
        return depth_metres(msg, where)  # raises the size error
    if h * w == 0:
        return np.zeros((h, w), dt.newbyteorder("="))
    raw = np.ndarray((h, w), dtype=dt, buffer=data, strides=(step, dt.itemsize))
    return raw if dt.isnative else raw.astype(dt.newbyteorder("="))


def intrinsics_size(info: Any) -> tuple[int, int] | None:
    """(width, height) of the images a CameraInfo describes (``intrinsics``: its binning and ROI
    applied), None when it gives none (0 x 0)."""
    intr = intrinsics(info)
    return (intr.width, intr.height) if (intr.width, intr.height) != (0, 0) else None


def depth_frame(header: Any, raw: np.ndarray, info: Any, topic: str, where: str, units: float | None,
                fast: bool) -> RawDepthFrame | DepthFrame:
    """The frame of decoded depth pixels (uint16 in ``units`` m, default mm, 0 invalid; or
    float32 m, NaN invalid): a ``RawDepthFrame`` (``fast``) or a ``DepthFrame``."""
    if units is not None and units != MM and raw.dtype == np.uint16:
        raw = raw.astype(np.float32) * np.float32(units)  # (0 stays 0: invalid)
    intr = _checked_intrinsics(info, raw.shape, where)
    lens = rectify.distortion(info)
    if lens is not None:  # a pinhole image of the same K (io.rectify)
        raw = rectify.rectify(raw, intr.fx, intr.fy, intr.cx, intr.cy, lens, where)
    frame = RawDepthFrame(stamp_ns=stamp_ns(header.stamp), frame_id=frame_name(header.frame_id), raw=raw,
                          intrinsics=intr, topic=topic)
    if fast:
        return frame
    return DepthFrame(stamp_ns=frame.stamp_ns, frame_id=frame.frame_id, depth_m=frame.depth_m, intrinsics=intr,
                      topic=topic)


def decode_depth_raw(msg: Any, info: Any, topic: str, where: str, units: float | None = None) -> RawDepthFrame:
    """As ``decode_depth``, keeping the raw pixels (a ``RawDepthFrame``); 16-bit pixels in
    ``units`` other than millimetres become float32 metres."""
    return depth_frame(msg.header, depth_raw(msg, where), info, topic, where, units, fast=True)
