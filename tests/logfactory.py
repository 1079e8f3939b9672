"""Write tiny, real robot logs in every format ltmap reads, for tests.

Messages are described once, format-neutrally, and written with the real writers:

- ``"ros1"``: ROS 1 bag v2.0 (rosbags' rosbag1 Writer);
- ``"ros2-sqlite3"`` / ``"ros2-mcap"``: ROS 2 bag folders (rosbags' rosbag2 Writer);
- ``"mcap-ros2"``: standalone MCAP, ros2 profile, CDR (the ``mcap_ros2`` writer);
- ``"mcap-ros1"``: standalone MCAP, ros1 profile (the ``mcap_ros1`` writer).

API::

    msgs = [scan("/scan", 1_000_000_000, ranges=[1.0, 2.0]), tf(1_000_000_000, [("odom", "base_link")])]
    path = write_log(tmp_path / "log.bag", "ros1", msgs)   # returns what to hand to open_logs

``Msg.fields`` use ROS 2 field names (``k``, ``d``); they are matched case-insensitively, so the
ROS 1 bag gets ``K``/``D``. Header stamps are integer nanoseconds (``{"stamp": ns}``). Custom
message types can be declared with ``extra_types={"pkg/msg/Name": "int32 a"}``: their definition
then lives only in the written log, as in real bags.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

FORMATS = ("ros1", "ros2-sqlite3", "ros2-mcap", "mcap-ros2", "mcap-ros1")
SUFFIX = {"ros1": ".bag", "ros2-sqlite3": "", "ros2-mcap": "", "mcap-ros2": ".mcap", "mcap-ros1": ".mcap"}


@dataclass
class Msg:
    topic: str
    log_time_ns: int
    msgtype: str  # ROS 2 style: "sensor_msgs/msg/LaserScan"
    fields: dict


# ----------------------------------------------------------------------------- message builders


def header(stamp_ns: int, frame_id: str) -> dict:
    return {"stamp": int(stamp_ns), "frame_id": frame_id}


def scan(topic: str, t_ns: int, ranges: Sequence[float], *, frame_id: str = "laser",
         angle_min: float = 0.0, angle_increment: float = 0.5, angle_max: float | None = None,
         range_min: float = 0.1, range_max: float = 10.0, stamp_ns: int | None = None) -> Msg:
    ranges = np.asarray(ranges, dtype=np.float32)
    if angle_max is None:
        angle_max = angle_min + angle_increment * max(len(ranges) - 1, 0)
    return Msg(topic, t_ns, "sensor_msgs/msg/LaserScan", {
        "header": header(t_ns if stamp_ns is None else stamp_ns, frame_id),
        "angle_min": angle_min, "angle_max": angle_max, "angle_increment": angle_increment,
        "range_min": range_min, "range_max": range_max, "ranges": ranges,
        "intensities": np.zeros(len(ranges), np.float32)})


_PF = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}


def cloud(topic: str, t_ns: int, points: Any, *, frame_id: str = "lidar", dtype: str = "f4",
          big_endian: bool = False, pad: int = 0, extra: Sequence[tuple[str, str]] = (),
          height: int = 1, row_pad: int = 0, xyz_offset: int = 0, stamp_ns: int | None = None) -> Msg:
    """A PointCloud2 with a chosen layout: x,y,z of ``dtype`` starting at ``xyz_offset`` (bytes
    before it are an extra field when ``extra`` names one there), ``extra`` fields after x,y,z,
    ``pad`` bytes of padding per point, ``height`` rows and ``row_pad`` bytes after each row."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    end = ">" if big_endian else "<"
    names, formats, offsets = [], [], []
    off = xyz_offset
    for n in "xyz":
        names.append(n)
        formats.append(end + dtype)
        offsets.append(off)
        off += np.dtype(dtype).itemsize
    pre = 0
    for name, fmt in extra:
        size = np.dtype(fmt).itemsize
        if pre + size <= xyz_offset:  # fits before x
            o, pre = pre, pre + size
        else:
            o, off = off, off + size
        names.append(name)
        formats.append(end + fmt)
        offsets.append(o)
    point_step = off + pad
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})
    n = len(pts)
    width = n // height
    assert width * height == n, "points must fill height rows"
    arr = np.zeros(n, dtype=dt)
    for i, c in enumerate("xyz"):
        arr[c] = pts[:, i]
    for k, (name, _) in enumerate(extra):
        arr[name] = np.arange(n) + k
    rows = arr.tobytes()
    row_len = width * point_step
    data = b"".join(rows[r * row_len:(r + 1) * row_len] + b"\xee" * row_pad for r in range(height))
    fields = [{"name": nm, "offset": o, "datatype": _PF[f[1:]], "count": 1}
              for nm, f, o in zip(names, formats, offsets)]
    return Msg(topic, t_ns, "sensor_msgs/msg/PointCloud2", {
        "header": header(t_ns if stamp_ns is None else stamp_ns, frame_id),
        "height": height, "width": width, "fields": fields, "is_bigendian": big_endian,
        "point_step": point_step, "row_step": row_len + row_pad,
        "data": np.frombuffer(data, np.uint8), "is_dense": False})


def image(topic: str, t_ns: int, array: Any, *, encoding: str = "16UC1", big_endian: bool = False,
          row_pad: int = 0, frame_id: str = "camera_optical", stamp_ns: int | None = None) -> Msg:
    """An Image; for 16UC1/32FC1 ``array`` (H, W) is converted to the encoding's dtype."""
    a = np.asarray(array)
    dt = {"16UC1": "u2", "32FC1": "f4", "mono16": "u2"}.get(encoding)
    if dt is not None:
        a = a.astype((">" if big_endian else "<") + dt)
    else:
        a = a.astype(np.uint8)
    h, w = a.shape[:2]
    row = a.reshape(h, -1).view(np.uint8).reshape(h, -1) if a.dtype != np.uint8 else a.reshape(h, -1)
    step = row.shape[1] + row_pad
    data = b"".join(row[r].tobytes() + b"\x00" * row_pad for r in range(h))
    return Msg(topic, t_ns, "sensor_msgs/msg/Image", {
        "header": header(t_ns if stamp_ns is None else stamp_ns, frame_id),
        "height": h, "width": w, "encoding": encoding, "is_bigendian": int(big_endian),
        "step": step, "data": np.frombuffer(data, np.uint8)})


def rvl_encode(pixels: Any) -> bytes:
    """RVL (A. D. Wilson, ISS 2017) as compressed_depth_image_transport's CompressRVL writes it:
    per run, the count of zeros and of non-zero pixels, then each non-zero pixel's zigzag delta
    from the previous one, every number in 3-bit groups (lowest first) of 4-bit nibbles whose top
    bit says another follows, 8 nibbles to a little-endian 32-bit word from its top. Written here
    from that description, apart from ltmap's decoder."""
    words: list[int] = []
    acc = [0, 0]  # the word being filled, nibbles in it

    def put(value: int) -> None:
        while True:
            nib = value & 7
            value >>= 3
            nib |= 8 if value else 0
            acc[0] = ((acc[0] << 4) | nib) & 0xFFFFFFFF
            acc[1] += 1
            if acc[1] == 8:
                words.append(acc[0])
                acc[0], acc[1] = 0, 0
            if not value:
                return

    flat = [int(x) for x in np.asarray(pixels, np.uint16).ravel()]
    i, prev, n = 0, 0, len(flat)
    while i < n:
        zeros = 0
        while i < n and flat[i] == 0:
            zeros, i = zeros + 1, i + 1
        put(zeros)
        nonzeros = 0
        while i + nonzeros < n and flat[i + nonzeros] != 0:
            nonzeros += 1
        put(nonzeros)
        for _ in range(nonzeros):
            delta = flat[i] - prev
            put(((delta << 1) ^ (delta >> 31)) & 0xFFFFFFFF)
            prev, i = flat[i], i + 1
    if acc[1]:
        words.append((acc[0] << (4 * (8 - acc[1]))) & 0xFFFFFFFF)
    return np.asarray(words, dtype="<u4").tobytes()


def png16(pixels: Any) -> bytes:
    """A 16-bit grey PNG of ``pixels`` (Pillow's writer)."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(pixels, dtype=np.uint16)).save(buf, format="PNG")
    return buf.getvalue()


def compressed_depth(topic: str, t_ns: int, array: Any, *, encoding: str = "16UC1", codec: str = "png",
                     depth_max: float = 10.0, depth_quantization: float = 100.0, frame_id: str = "camera_optical",
                     stamp_ns: int | None = None) -> Msg:
    """A CompressedImage as image_transport's plugins publish a depth image ``array`` (16UC1:
    millimetres, 0 invalid; 32FC1: metres, NaN invalid), by ``codec``:

    - ``"png"`` / ``"rvl"``: compressedDepth, a 12-byte ConfigHeader (int32 format 0, float32
      depthParam[2]) and a PNG or RVL (after 8 bytes of width, height) of the 16-bit pixels; 32FC1
      is quantized as the plugin does (inverse depth: A = q (q + 1), B = 1 - A / depth_max, the pixel
      A / d + B truncated, 0 for NaN or d >= depth_max), 16UC1 pixels above depth_max become 0;
    - ``"old"``: compressedDepth PNG with the older plugin's format string (``"16UC1; compressedDepth"``);
    - ``"plain-png"``: the compressed transport's PNG of a 16-bit image (``"16UC1; png compressed mono16"``);
    - ``"jpeg"``: a format string of the compressed transport's JPEG (the data is not a JPEG)."""
    import struct

    a = np.asarray(array)
    quant_a = quant_b = 0.0
    if encoding == "32FC1":
        d = a.astype(np.float32)
        quant_a = np.float32(depth_quantization * (depth_quantization + 1.0))
        quant_b = np.float32(1.0 - quant_a / np.float32(depth_max))
        ok = np.isfinite(d) & (d < depth_max) & (d > 0)
        px = np.zeros(d.shape, np.uint16)
        px[ok] = (quant_a / d[ok] + quant_b).astype(np.uint16)
    else:
        px = a.astype(np.uint16).copy()
        px[px.astype(np.int64) > depth_max * 1000.0] = 0
    h, w = px.shape
    head = struct.pack("<iff", 0, float(quant_a), float(quant_b))
    if codec in ("png", "old"):
        data, fmt = head + png16(px), f"{encoding}; compressedDepth" + (" png" if codec == "png" else "")
    elif codec == "rvl":
        data, fmt = head + struct.pack("<II", w, h) + rvl_encode(px), f"{encoding}; compressedDepth rvl"
    elif codec == "plain-png":
        data, fmt = png16(px), f"{encoding}; png compressed mono16"
    else:
        data, fmt = b"\xff\xd8\xff\xe0", f"{encoding}; jpeg compressed mono8"
    return Msg(topic, t_ns, "sensor_msgs/msg/CompressedImage", {
        "header": header(t_ns if stamp_ns is None else stamp_ns, frame_id), "format": fmt,
        "data": np.frombuffer(data, np.uint8)})


def camera_info(topic: str, t_ns: int, *, width: int, height: int, fx: float, fy: float, cx: float,
                cy: float, frame_id: str = "camera_optical", d: Sequence[float] = (0.0,) * 5,
                model: str = "plumb_bob", binning: tuple[int, int] = (0, 0),
                roi: tuple[int, int, int, int] = (0, 0, 0, 0)) -> Msg:
    """A CameraInfo; ``roi``: (x_offset, y_offset, width, height), full-resolution pixels."""
    k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
    p = [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return Msg(topic, t_ns, "sensor_msgs/msg/CameraInfo", {
        "header": header(t_ns, frame_id), "height": height, "width": width,
        "distortion_model": model, "d": list(d), "k": k,
        "r": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], "p": p, "binning_x": binning[0], "binning_y": binning[1],
        "roi": {"x_offset": roi[0], "y_offset": roi[1], "width": roi[2], "height": roi[3], "do_rectify": False}})


def tf(t_ns: int, transforms: Iterable[tuple], *, static: bool = False, topic: str | None = None) -> Msg:
    """TFMessage; each transform is (parent, child[, xyz[, xyzw[, stamp_ns]]])."""
    out = []
    for tr in transforms:
        parent, child = tr[0], tr[1]
        xyz = tr[2] if len(tr) > 2 else (0.0, 0.0, 0.0)
        q = tr[3] if len(tr) > 3 else (0.0, 0.0, 0.0, 1.0)
        stamp = tr[4] if len(tr) > 4 else t_ns
        out.append({"header": header(stamp, parent), "child_frame_id": child, "transform": {
            "translation": dict(zip("xyz", map(float, xyz))),
            "rotation": dict(zip("xyzw", map(float, q)))}})
    return Msg(topic or ("/tf_static" if static else "/tf"), t_ns, "tf2_msgs/msg/TFMessage",
               {"transforms": out})


def odometry(topic: str, t_ns: int, parent: str, child: str, xyz=(0.0, 0.0, 0.0),
             xyzw=(0.0, 0.0, 0.0, 1.0)) -> Msg:
    return Msg(topic, t_ns, "nav_msgs/msg/Odometry", {
        "header": header(t_ns, parent), "child_frame_id": child,
        "pose": {"pose": {"position": dict(zip("xyz", map(float, xyz))),
                          "orientation": dict(zip("xyzw", map(float, xyzw)))}}})


def string(topic: str, t_ns: int, text: str) -> Msg:
    return Msg(topic, t_ns, "std_msgs/msg/String", {"data": text})


def yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, float(np.sin(yaw / 2)), float(np.cos(yaw / 2)))


# ----------------------------------------------------------------------------- writing


def write_log(path: str | Path, fmt: str, messages: Iterable[Msg],
              extra_types: dict[str, str] | None = None, chunk_size: int = 1024 * 1024,
              compress: bool = True, ros1_chunk_size: int | None = None, ros2_compression: str | None = None) -> Path:
    """Write ``messages`` (in the given order) as a log of format ``fmt`` at ``path``.

    ``path`` is the bag file, the ROS 2 bag folder or the .mcap file; it must not exist.
    ``chunk_size`` (bytes) applies to standalone MCAP: small values give several chunks;
    ``compress=False`` writes ros2-profile MCAP chunks uncompressed (bytes to corrupt by hand);
    ``ros1_chunk_size`` (bytes) the ROS 1 bag's chunks (rosbags' default: 1 MB);
    ``ros2_compression`` ("file" or "message") a ROS 2 bag compressed with zstd as
    ``ros2 bag record --compression-mode`` does.
    Returns ``path``.
    """
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if fmt not in FORMATS:
        raise ValueError(f"fmt must be one of {FORMATS}")
    path = Path(path)
    messages = list(messages)
    ros1 = fmt in ("ros1", "mcap-ros1")
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in ts.fielddefs:  # the ROS 1 store lacks it
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                       "tf2_msgs/msg/TFMessage"))
    for name, text in (extra_types or {}).items():
        ts.register(get_types_from_msg(text, name))

    if fmt == "ros1":
        from rosbags.rosbag1 import Writer as Writer1

        with Writer1(path) as w:
            if ros1_chunk_size is not None:
                w.chunk_threshold = ros1_chunk_size
            conns: dict[str, Any] = {}
            for m in messages:
                if m.topic not in conns:
                    conns[m.topic] = w.add_connection(m.topic, m.msgtype, typestore=ts)
                obj = _to_rosbags(ts, m.msgtype, _plain(ts, m.msgtype, m.fields))
                w.write(conns[m.topic], m.log_time_ns, ts.serialize_ros1(obj, m.msgtype))
    elif fmt in ("ros2-sqlite3", "ros2-mcap"):
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2

        plugin = StoragePlugin.SQLITE3 if fmt == "ros2-sqlite3" else StoragePlugin.MCAP
        w = Writer2(path, version=9, storage_plugin=plugin)
        if ros2_compression is not None:
            from rosbags.rosbag2.writer import CompressionFormat, CompressionMode

            w.set_compression(CompressionMode[ros2_compression.upper()], CompressionFormat.ZSTD)
        with w:
            conns = {}
            for m in messages:
                if m.topic not in conns:
                    conns[m.topic] = w.add_connection(m.topic, m.msgtype, typestore=ts)
                obj = _to_rosbags(ts, m.msgtype, _plain(ts, m.msgtype, m.fields))
                w.write(conns[m.topic], m.log_time_ns, ts.serialize_cdr(obj, m.msgtype))
    elif fmt == "mcap-ros2":
        from mcap_ros2.writer import Writer as McapRos2Writer

        with path.open("wb") as f:
            from mcap.writer import CompressionType

            w = McapRos2Writer(f, chunk_size=chunk_size,
                               compression=CompressionType.ZSTD if compress else CompressionType.NONE)
            schemas: dict[str, Any] = {}
            for m in messages:
                if m.msgtype not in schemas:
                    text = ts.generate_msgdef(m.msgtype, ros_version=2)[0]
                    schemas[m.msgtype] = w.register_msgdef(m.msgtype, text)
                w.write_message(m.topic, schemas[m.msgtype],
                                _to_dict(_plain(ts, m.msgtype, m.fields)), log_time=m.log_time_ns)
            w.finish()
    else:  # mcap-ros1
        from mcap_ros1._vendor.genpy.dynamic import generate_dynamic
        from mcap_ros1.writer import Writer as McapRos1Writer

        classes: dict[str, Any] = {}
        with path.open("wb") as f:
            w = McapRos1Writer(f, chunk_size=chunk_size)
            for m in messages:
                r1 = _ros1_name(m.msgtype)
                if r1 not in classes:
                    classes.update(generate_dynamic(r1, ts.generate_msgdef(m.msgtype, ros_version=1)[0]))
                obj = _to_genpy(classes, ts, m.msgtype, _plain(ts, m.msgtype, m.fields))
                w.write_message(m.topic, obj, log_time=m.log_time_ns)
            w.finish()
    return path


def truncate(path: Path, keep_fraction: float = 0.6) -> Path:
    """Cut a log file to ``keep_fraction`` of its size (a recording that was killed)."""
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep_fraction)])
    return path


# ----------------------------------------------------------------------------- internals

_TIME = ("builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration")
_NUMPY = {"bool": np.bool_, "int8": np.int8, "uint8": np.uint8, "byte": np.uint8, "char": np.uint8,
          "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
          "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64}


class _Time(int):
    pass


def _ros1_name(msgtype: str) -> str:
    return msgtype.replace("/msg/", "/")


def _plain(ts: Any, msgtype: str, value: dict | None) -> dict:
    """Fill ``value`` to the full field tree of ``msgtype`` in ``ts`` (with its field names)."""
    from rosbags.typesys.base import Nodetype

    value = {k.lower(): v for k, v in (value or {}).items()}
    out: dict[str, Any] = {}
    for name, (node, desc) in ts.fielddefs[msgtype][1]:
        v = value.get(name.lower())
        if node == Nodetype.NAME:
            out[name] = _Time(v or 0) if desc in _TIME else _plain(ts, desc, v)
        elif node == Nodetype.BASE:
            typ = desc[0]
            out[name] = ("" if typ == "string" else 0) if v is None else v
        else:
            (enode, edesc), length = desc
            if enode == Nodetype.BASE:
                if edesc[0] == "string":
                    out[name] = list(v or [""] * length)
                else:
                    out[name] = np.asarray(v if v is not None else np.zeros(length), _NUMPY[edesc[0]])
            else:
                out[name] = [_plain(ts, edesc, x) for x in (v or [])]
    return out


def _to_rosbags(ts: Any, msgtype: str, plain: dict) -> Any:
    from rosbags.typesys.base import Nodetype

    kwargs = {}
    for name, (node, desc) in ts.fielddefs[msgtype][1]:
        v = plain[name]
        if node == Nodetype.NAME:
            if desc in _TIME:
                v = ts.types[desc](sec=int(v) // 10**9, nanosec=int(v) % 10**9)
            else:
                v = _to_rosbags(ts, desc, v)
        elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE) and desc[0][0] == Nodetype.NAME:
            v = [_to_rosbags(ts, desc[0][1], x) for x in v]
        kwargs[name] = v
    return ts.types[msgtype](**kwargs)


def _to_dict(plain: Any) -> Any:
    if isinstance(plain, _Time):
        return {"sec": int(plain) // 10**9, "nanosec": int(plain) % 10**9}
    if isinstance(plain, dict):
        return {k: _to_dict(v) for k, v in plain.items()}
    if isinstance(plain, np.ndarray):
        return plain.tobytes() if plain.dtype == np.uint8 else plain.tolist()
    if isinstance(plain, list):
        return [_to_dict(v) for v in plain]
    return plain


def _to_genpy(classes: dict, ts: Any, msgtype: str, plain: dict) -> Any:
    from mcap_ros1._vendor.genpy import Duration, Time
    from rosbags.typesys.base import Nodetype

    kwargs = {}
    for name, (node, desc) in ts.fielddefs[msgtype][1]:
        v = plain[name]
        if node == Nodetype.NAME:
            if desc in _TIME:
                cls = Time if desc.endswith("Time") else Duration
                v = cls(int(v) // 10**9, int(v) % 10**9)
            else:
                v = _to_genpy(classes, ts, desc, v)
        elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            if desc[0][0] == Nodetype.NAME:
                v = [_to_genpy(classes, ts, desc[0][1], x) for x in v]
            elif isinstance(v, np.ndarray):
                v = v.tobytes() if v.dtype == np.uint8 else v.tolist()
        kwargs[name] = v
    return classes[_ros1_name(msgtype)](**kwargs)
