"""Small hostile files, written in a test's tmp_path: each is under 1 MB on disk and asks for
gigabytes (or forever) when read naively. Used by test_hostile_inputs and test_ros1_scan.

- ``ros1_bag(path, chunks)``: a ROS 1 bag v2.0 written record by record (as rosbag does: bag
  header padded to 4096 bytes, chunks each followed by its index data, then the connection
  and chunk info records), so that tests can write chunks that lie about their sizes.
- ``zstd_rle(n)``: a zstd frame of RLE blocks that expands to ``n`` zero bytes (3 GB in 98 kB).
- ``bz2_bomb(n_streams)``: concatenated bz2 streams of 50 MB of zeros each (81 bytes a stream).
- ``mcap_with_chunk(path, ...)``: an MCAP whose one chunk has the given compression, data and
  declared uncompressed size, with or without a summary (indexed or streamed reading).
- ``yaml_bomb()``: the "billion laughs" document (9^9 strings from 341 bytes).
- ``png(path, w, h)``: a grey PNG of w x h pixels, all white, compressed to a few hundred kB.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

# ----------------------------------------------------------------------------- ROS 1


def field(name: str, value: bytes) -> bytes:
    item = name.encode() + b"=" + value
    return struct.pack("<I", len(item)) + item


def record(fields: list[tuple[str, bytes]], data: bytes) -> bytes:
    head = b"".join(field(n, v) for n, v in fields)
    return struct.pack("<I", len(head)) + head + struct.pack("<I", len(data)) + data


def u32(v: int) -> bytes:
    return struct.pack("<I", v)


def time_b(ns: int) -> bytes:
    return struct.pack("<II", ns // 1_000_000_000, ns % 1_000_000_000)


SCAN_DEF = """std_msgs/Header header
float32 angle_min
float32 angle_max
float32 angle_increment
float32 time_increment
float32 scan_time
float32 range_min
float32 range_max
float32[] ranges
float32[] intensities
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
"""


def connection_record(conn: int, topic: str, msgtype: str = "sensor_msgs/LaserScan",
                      msgdef: str = SCAN_DEF) -> bytes:
    inner = (field("topic", topic.encode()) + field("type", msgtype.encode())
             + field("md5sum", b"90c7ef2dc6895d81024acba2ac42f369")
             + field("message_definition", msgdef.encode()))
    return record([("op", b"\x07"), ("conn", u32(conn)), ("topic", topic.encode())], inner)


def message_record(conn: int, t_ns: int, data: bytes) -> bytes:
    return record([("op", b"\x02"), ("conn", u32(conn)), ("time", time_b(t_ns))], data)


def scan_bytes(seq: int, t_ns: int, ranges: list[float], frame: str = "laser") -> bytes:
    """A ROS 1 serialized sensor_msgs/LaserScan."""
    import math

    n = len(ranges)
    head = struct.pack("<III", seq, t_ns // 1_000_000_000, t_ns % 1_000_000_000)
    head += u32(len(frame)) + frame.encode()
    inc = 2 * math.pi / n
    body = struct.pack("<7f", -math.pi, -math.pi + (n - 1) * inc, inc, 0.0, 0.1, 0.05, 10.0)
    body += u32(n) + struct.pack(f"<{n}f", *ranges) + u32(0)
    return head + body


class Chunk:
    """One chunk to write: its records (uncompressed), and how to store them."""

    def __init__(self, inner: bytes, compression: str = "none", data: bytes | None = None,
                 declared: int | None = None, messages: list[tuple[int, int, int]] | None = None):
        self.inner = inner
        self.compression = compression
        self.data = data  # stored bytes (None: compress ``inner``)
        self.declared = len(inner) if declared is None else declared
        self.messages = messages or []  # (conn, time, offset in inner) for the index


def build_chunk(records: list[tuple[int, int, bytes]], conns: dict[int, str], compression: str = "none",
                with_connections: bool = True) -> Chunk:
    """A chunk of (conn, time, message bytes); its connection records first (as rosbag writes
    a connection into the first chunk that uses it)."""
    inner = b""
    if with_connections:
        for cid, topic in conns.items():
            inner += connection_record(cid, topic)
    msgs = []
    for conn, t, data in records:
        msgs.append((conn, t, len(inner)))
        inner += message_record(conn, t, data)
    if compression == "bz2":
        import bz2

        stored = bz2.compress(inner)
    elif compression == "lz4":
        import lz4.frame

        stored = lz4.frame.compress(inner)
    else:
        stored = inner
    return Chunk(inner, compression, stored, len(inner), msgs)


def ros1_bag(path: Path, chunks: list[Chunk], conns: dict[int, str], indexed: bool = True) -> Path:
    """Write a bag: header, chunks (each with its index data records), then the index
    (connection records and chunk infos) unless ``indexed`` is False (index_pos 0, no index)."""
    body = b""
    infos = []
    start = len(b"#ROSBAG V2.0\n") + 4096  # the first chunk follows the bag header record
    for ch in chunks:
        pos = start + len(body)
        data = ch.data if ch.data is not None else ch.inner
        body += record([("op", b"\x05"), ("compression", ch.compression.encode()), ("size", u32(ch.declared))], data)
        per_conn: dict[int, list[tuple[int, int]]] = {}
        for conn, t, off in ch.messages:
            per_conn.setdefault(conn, []).append((t, off))
        for conn, items in per_conn.items():
            entries = b"".join(time_b(t) + u32(off) for t, off in items)
            body += record([("op", b"\x04"), ("ver", u32(1)), ("conn", u32(conn)), ("count", u32(len(items)))],
                           entries)
        times = [t for _, t, _ in ch.messages] or [0]
        infos.append((pos, min(times), max(times), {c: len(v) for c, v in per_conn.items()}))
    index = b""
    if indexed:
        for cid, topic in conns.items():
            index += connection_record(cid, topic)
        for pos, t0, t1, counts in infos:
            data = b"".join(u32(c) + u32(n) for c, n in counts.items())
            index += record([("op", b"\x06"), ("ver", u32(1)), ("chunk_pos", struct.pack("<Q", pos)),
                             ("start_time", time_b(t0)), ("end_time", time_b(t1)), ("count", u32(len(counts)))],
                            data)
    index_pos = start + len(body) if indexed else 0
    fields = [("op", b"\x03"), ("index_pos", struct.pack("<Q", index_pos)),
              ("conn_count", u32(len(conns) if indexed else 0)), ("chunk_count", u32(len(chunks) if indexed else 0))]
    head = b"".join(field(n, v) for n, v in fields)
    pad = 4096 - 8 - len(head)  # the bag header record is 4096 bytes, as rosbag writes it
    header = struct.pack("<I", len(head)) + head + struct.pack("<I", pad) + b" " * pad
    path.write_bytes(b"#ROSBAG V2.0\n" + header + body + index)
    return path


def scans_bag(path: Path, n: int = 40, per_chunk: int = 10, compression: str = "none", indexed: bool = True,
              t0: int = 1_000_000_000_000) -> Path:
    """A bag of ``n`` scans on /scan (10 Hz, ranges 1 + i), ``per_chunk`` to a chunk."""
    conns = {0: "/scan"}
    chunks = []
    for c0 in range(0, n, per_chunk):
        recs = [(0, t0 + i * 100_000_000, scan_bytes(i, t0 + i * 100_000_000, [1.0 + i] * 36))
                for i in range(c0, min(n, c0 + per_chunk))]
        chunks.append(build_chunk(recs, conns, compression, with_connections=c0 == 0))
    return ros1_bag(path, chunks, conns, indexed)


def bz2_bomb(n_streams: int) -> bytes:
    """``n_streams`` concatenated bz2 streams of 50 MB of zeros each (81 bytes per stream)."""
    import bz2

    one = bz2.compress(bytes(50 * 2**20), 9)
    return one * n_streams


def bz2_bomb_bag(path: Path, declared: int) -> Path:
    """A bag whose only chunk is bz2 data expanding to 3 GB, declaring ``declared`` bytes."""
    ch = Chunk(b"", "bz2", bz2_bomb(60), declared, [(0, 1_000_000_000_000, 0)])
    return ros1_bag(path, [ch], {0: "/scan"})


# ----------------------------------------------------------------------------- MCAP


def zstd_rle(n: int, value: int = 0) -> bytes:
    """A zstd frame expanding to ``n`` bytes of ``value``: RLE blocks of 128 kB, 4 bytes each."""
    out = struct.pack("<I", 0xFD2FB528) + bytes([0xE0]) + struct.pack("<Q", n)  # single segment, 8-byte size
    block = 128 * 1024
    left = n
    while left > 0:
        size = min(block, left)
        left -= size
        last = 1 if left == 0 else 0
        out += (last | (1 << 1) | (size << 3)).to_bytes(3, "little") + bytes([value])
    return out


def mcap_with_chunk(path: Path, compression: str, data: bytes, declared: int, summary: bool = True) -> Path:
    """An MCAP (ros2 profile, one /scan channel) whose one chunk stores ``data`` with
    ``compression`` and declares ``declared`` uncompressed bytes."""
    from mcap.data_stream import RecordBuilder
    from mcap.records import (
        Channel,
        ChunkIndex,
        DataEnd,
        Footer,
        Header,
        Schema,
        Statistics,
    )
    from mcap.records import (
        Chunk as McapChunk,
    )

    b = RecordBuilder()
    b.write(b"\x89MCAP0\r\n")
    Header(profile="ros2", library="hostile").write(b)
    schema = Schema(id=1, name="sensor_msgs/msg/LaserScan", encoding="ros2msg", data=b"float32 range_min")
    channel = Channel(id=1, schema_id=1, topic="/scan", message_encoding="cdr", metadata={})
    schema.write(b)
    channel.write(b)
    chunk_start = b.count
    McapChunk(message_start_time=1, message_end_time=2, uncompressed_size=declared, uncompressed_crc=0,
              compression=compression, data=data).write(b)
    chunk_len = b.count - chunk_start
    DataEnd(data_section_crc=0).write(b)
    summary_start = 0
    if summary:
        summary_start = b.count
        schema.write(b)
        channel.write(b)
        Statistics(message_count=1, schema_count=1, channel_count=1, attachment_count=0, metadata_count=0,
                   chunk_count=1, message_start_time=1, message_end_time=2,
                   channel_message_counts={1: 1}).write(b)
        ChunkIndex(message_start_time=1, message_end_time=2, chunk_start_offset=chunk_start,
                   chunk_length=chunk_len, message_index_offsets={}, message_index_length=0,
                   compression=compression, compressed_size=len(data), uncompressed_size=declared).write(b)
    Footer(summary_start=summary_start, summary_offset_start=0, summary_crc=0).write(b)
    b.write(b"\x89MCAP0\r\n")
    path.write_bytes(b.end())
    return path


# ----------------------------------------------------------------------------- YAML, images


def yaml_bomb(key: str | None = None) -> str:
    """The billion laughs: 9 levels of 9 aliases. ``key``: nest it under that key."""
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for i in range(8):
        name, prev = chr(98 + i), chr(97 + i)
        lines.append(f"{name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]")
    if key:
        lines.append(f"{key}: *i")
    return "\n".join(lines) + "\n"


def png(path: Path, width: int, height: int, grey: int = 254) -> Path:
    """A grey (mode L) PNG of width x height pixels, all ``grey``, written row by row with zlib
    (no image of that size in memory): 12000 x 12000 is about 140 kB."""
    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    comp = zlib.compressobj(9)
    row = b"\x00" + bytes([grey]) * width
    raw = b"".join(comp.compress(row) for _ in range(height)) + comp.flush()
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", raw) + chunk(b"IEND", b""))
    return path


def map_yaml(path: Path, image: str, resolution: float = 0.05) -> Path:
    path.write_text(f"image: {image}\nresolution: {resolution}\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
                    "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return path


# ----------------------------------------------------------------------------- a bag's index


def bag_index_pos(data: bytes) -> tuple[int, int]:
    """(index_pos, offset of its 8 bytes in the file) of a ROS 1 bag."""
    off = data.index(b"index_pos=") + len(b"index_pos=")
    return struct.unpack_from("<Q", data, off)[0], off


def strip_index(src: Path, dst: Path) -> Path:
    """The bag as a recorder killed before closing it leaves it: no index (index_pos 0, the
    connection and chunk info records at the end cut off)."""
    data = src.read_bytes()
    pos, off = bag_index_pos(data)
    out = bytearray(data[:pos])
    out[off : off + 8] = bytes(8)
    dst.write_bytes(bytes(out))
    return dst


def damage_index(src: Path, dst: Path, how: str) -> Path:
    """The bag with its index records damaged:

    - ``idxdata-count``: every index data record (op 4) gets a wrong ``count`` (rosbags asserts
      ``size == count * 12``, as on an old 2010 bag);
    - ``chunk-info``: the chunk info records (op 6) name chunk positions outside the file;
    - ``index-pos``: the bag header points into the middle of a chunk;
    - ``index-garbage``: the index at the end overwritten with garbage bytes.
    """
    data = bytearray(src.read_bytes())
    pos, off = bag_index_pos(bytes(data))
    if how == "idxdata-count":
        i = 0
        while (j := data.find(b"op=\x04", i)) >= 0:
            k = data.find(b"count=", max(0, j - 64), j + 64)
            if k >= 0:
                data[k + 6] ^= 0x05
            i = j + 1
    elif how == "chunk-info":
        i = pos
        while (j := data.find(b"chunk_pos=", i)) >= 0:
            data[j + 10 : j + 18] = struct.pack("<Q", len(data) * 7)
            i = j + 1
    elif how == "index-pos":
        data[off : off + 8] = struct.pack("<Q", (4109 + pos) // 2)
    elif how == "index-garbage":
        import random

        rng = random.Random(7)
        for k in range(pos, len(data)):
            data[k] = rng.randrange(256)
    else:
        raise ValueError(how)
    dst.write_bytes(bytes(data))
    return dst
