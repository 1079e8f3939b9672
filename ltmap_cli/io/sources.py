"""One log file or bag folder as a stream of raw messages (internal to ``ltmap_cli.io.logs``).

Each source knows its topics (name, type, count) and yields ``RawMessage`` items in log-time
order (file order for damaged files that have lost their index), each with a thunk that
deserializes the message only when called. A source whose file ends early or is corrupt stops
yielding and sets ``stopped_at`` to where reading stopped; it never raises mid-stream for that.

- ROS 1 bag: ltmap's own record reader (``ros1bag``): the index when it is sound, else a scan of
  every record (bags without an index, cut off, or with damaged index records), damaged chunks
  skipped and named. Types are registered from the connections' message definitions, so custom
  types that exist only in the bag decode, and the old ``roslib/Header`` is read as
  ``std_msgs/Header``.

Every chunk and record is checked against ``max_bytes`` (``replay.max_message_mb``) before it is
read or decompressed, and decompression stops at the size a chunk declares (``bounded``): a log
that declares more raises ``TooLargeError`` (a ``LogReadError``, even with --allow-truncated).
- ROS 2 bag folder (sqlite3 or mcap storage): rosbags' rosbag2 Reader; definitions from the bag
  when it has them, else the ROS 2 Humble type store. A bag compressed file by file is one
  ``CompressedFileSource`` per file, each decompressed into TMPDIR when reading reaches it.
- standalone MCAP: the ``mcap`` package, indexed reading in log-time order when the summary is
  intact, else a streaming pass; decoding by mcap_ros2 (ros2 profile, CDR) or mcap_ros1 (ros1).
"""

from __future__ import annotations

import errno
import functools
import shutil
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from ..errors import InputError, LogReadError, first_line, human, shown
from .atomic import KEEP_FREE_BYTES
from .bounded import (
    DEFAULT_MAX_MESSAGE_MB,
    DecompressError,
    TooLargeError,
    decompress,
    decompress_zstd_message,
)
from .skip import SkipBefore, unread_chunks

ROS1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"


def crc32(data: bytes) -> int:
    """CRC-32 (zlib's, the one MCAP's records carry) of ``data``: zlib-ng's, carry-less multiply on
    vectors, about 15x zlib's on a 4 MB chunk (0.18 s of CPU on a 30 s log of 640x480 depth at
    30 Hz, 2 % of its replay), else zlib's (the same value)."""
    return _crc32_function()(data)


@functools.cache
def _crc32_function() -> Callable[[bytes], int]:
    try:
        from zlib_ng.zlib_ng import crc32 as fast
    except ImportError:  # (a platform without its wheel)
        from zlib import crc32 as fast
    return fast


@dataclass
class TopicInfo:
    """A topic of a log (or of several logs merged). Stamps are log times in ns (None: unknown)."""

    name: str
    msgtype: str  # ROS 2 style: sensor_msgs/msg/LaserScan
    count: int
    first_ns: int | None = None
    last_ns: int | None = None


class RawMessage(NamedTuple):
    log_time_ns: int
    topic: str
    index: int  # 0-based index of this message among its topic's messages in this source
    decode: Callable[[], Any]


def normalize_type(name: str) -> str:
    """``sensor_msgs/LaserScan`` -> ``sensor_msgs/msg/LaserScan``."""
    parts = name.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name


def _fix_ros1_msgdef(text: str) -> str:
    # Bags recorded before ROS Groovy name the header type roslib/Header.
    return text.replace("roslib/Header", "std_msgs/Header")


def _stop_text(path: Path, count: int, offset: int | None, err: BaseException) -> str:
    where = f" near byte {offset}" if offset is not None else ""
    # an MCAP record longer than what is left of the file (the reader's record_size_limit)
    if isinstance(err, (struct.error, EOFError)) or type(err).__name__ in ("EndOfFile", "RecordLengthLimitExceeded"):
        reason = "the file ends in the middle of a record"
    else:
        reason = first_line(err)
    return f"{path}: reading stopped after {count} messages{where} ({reason})"


class SharedDir:
    """A temporary folder several sources read from: removed when the last one lets go."""

    def __init__(self, path: Path, users: int):
        self.path, self.users = path, users

    def release(self) -> None:
        self.users -= 1
        if self.users <= 0:
            shutil.rmtree(self.path, ignore_errors=True)


class Source:
    note: str | None = None  # said once when opened (a ROS 1 bag read by scanning)
    path: Path
    fmt: str
    topics: dict[str, TopicInfo]
    start_ns: int | None
    end_ns: int | None
    stopped_at: str | None = None
    end_stop: str | None = None  # where the file's end stops reading, when known before reading it (an unindexed MCAP)

    temp_dir: SharedDir | None = None  # a folder it reads from (a decompressed copy), removed after its last reader

    def iter(self, topics: set[str], skip: SkipBefore | None = None) -> Iterator[RawMessage]:  # pragma: no cover
        raise NotImplementedError

    def close(self) -> None:
        try:
            self._close()
        finally:
            if self.temp_dir is not None:
                self.temp_dir.release()
                self.temp_dir = None

    def _close(self) -> None:
        pass


# the types ltmap reads fields of, and their standard fields (ROS 1 and 2 alike, compared without
# case: CameraInfo's K is k in ROS 2): a log's own definition of one of them must have them all
# (a damaged or foreign definition would give objects without them)
_READ_FIELDS = {
    "std_msgs/msg/Header": "stamp frame_id",
    "sensor_msgs/msg/LaserScan": "header angle_min angle_max angle_increment time_increment scan_time range_min "
                                 "range_max ranges intensities",
    "sensor_msgs/msg/PointCloud2": "header height width fields is_bigendian point_step row_step data is_dense",
    "sensor_msgs/msg/PointField": "name offset datatype count",
    "sensor_msgs/msg/Image": "header height width encoding is_bigendian step data",
    "sensor_msgs/msg/CameraInfo": "header height width distortion_model d k r p",
    "tf2_msgs/msg/TFMessage": "transforms",
    "tf/msg/tfMessage": "transforms",
    "geometry_msgs/msg/TransformStamped": "header child_frame_id transform",
    "geometry_msgs/msg/Transform": "translation rotation",
    "geometry_msgs/msg/Vector3": "x y z",
    "geometry_msgs/msg/Quaternion": "x y z w",
    "geometry_msgs/msg/Point": "x y z",
    "geometry_msgs/msg/Pose": "position orientation",
    "geometry_msgs/msg/PoseWithCovariance": "pose covariance",
    "nav_msgs/msg/Odometry": "header child_frame_id pose",
}
_READ_TYPES = tuple(_READ_FIELDS)


def check_definitions(types: dict[str, Any]) -> None:
    """``LogReadError`` when the log defines a type ltmap reads without one of its standard
    fields (``types``: name -> rosbags field definitions)."""
    for name, fdef in types.items():
        want = _READ_FIELDS.get(name)
        if want is None:
            continue
        have = {f[0].lower() for f in fdef[1]}
        missing = [f for f in want.split() if f not in have]
        if missing:
            raise LogReadError(f"the log's definition of {name} lacks the field{'s' if len(missing) > 1 else ''} "
                               f"{', '.join(missing[:5])}: the definition is damaged or not the standard one")


class _TypeRegistry:
    """A rosbags type store filled lazily from a log's message definitions."""

    def __init__(self, defs: dict[str, tuple[str, str]], default_store: str | None):
        self.defs = defs  # msgtype -> (format 'msg'|'idl'|'', text)
        self.default_store = default_store
        self.done: dict[str, str | None] = {}
        self._store = None
        self._default = None

    # the type stores are built on first use: importing a rosbags store creates hundreds of
    # dataclasses (~0.15 s), which a reader that parses its messages directly never needs
    @property
    def store(self) -> Any:
        if self._store is None:
            from rosbags.typesys import Stores, get_typestore

            self._store = get_typestore(Stores.EMPTY)
        return self._store

    @property
    def default(self) -> Any:
        if self._default is None and self.default_store:
            from rosbags.typesys import Stores, get_typestore

            self._default = get_typestore(getattr(Stores, self.default_store))
        return self._default

    def ensure(self, msgtype: str) -> None:
        if msgtype in self.done:
            if self.done[msgtype]:
                raise LogReadError(self.done[msgtype])
            return
        from rosbags.typesys import get_types_from_idl, get_types_from_msg

        fmt, text = self.defs.get(msgtype, ("", ""))
        try:
            if fmt == "msg" and text:
                types = get_types_from_msg(_fix_ros1_msgdef(text), msgtype)
            elif fmt == "idl" and text:
                types = {}
                sep = "=" * 80 + "\n"
                chunks = text.split(sep)[1:] if text.startswith(sep + "IDL: ") else [text]
                for chunk in chunks:
                    types.update(get_types_from_idl(chunk.split("\n", 1)[1] if chunk.startswith("IDL: ")
                                                    else chunk))
            elif self.default is not None and msgtype in self.default.fielddefs:
                types = {k: v for k, v in self.default.fielddefs.items()}
            else:
                raise LogReadError(f"no definition of message type {msgtype} in the log")
            if fmt in ("msg", "idl"):
                check_definitions(types)
            for name, fdef in types.items():
                if name not in self.store.fielddefs:
                    self.store.register({name: fdef})
            self.done[msgtype] = None
        except LogReadError as err:
            self.done[msgtype] = str(err)
            raise
        except Exception as err:  # noqa: BLE001 - any parser failure is a bad definition
            self.done[msgtype] = f"cannot parse the definition of {msgtype} in the log: {err}"
            raise LogReadError(self.done[msgtype]) from None


# ----------------------------------------------------------------------------- ROS 1 bags


class Ros1Source(Source):
    """A ROS 1 bag through ``ros1bag.Ros1Bag``: its index when it is sound, else a scan of its
    records (as ``rosbag reindex``). Chunks that cannot be read are skipped and named in
    ``stopped_at``; a bag whose index had to be rebuilt says so in ``note``."""

    fmt = "ros1"

    def __init__(self, path: Path, max_bytes: int):
        from .ros1bag import Ros1Bag

        self.path = path
        self.bag = Ros1Bag(path, max_bytes)
        lay = self.bag.layout
        defs: dict[str, tuple[str, str]] = {}
        self.conns: dict[int, tuple[str, str]] = {}
        totals: dict[int, int] = {}
        for ch in lay.chunks:
            for cid, n in ch.counts.items():
                totals[cid] = totals.get(cid, 0) + n
        self.topics = {}
        for cid, c in sorted(lay.connections.items()):
            msgtype = normalize_type(c.msgtype)
            self.conns[cid] = (c.topic, msgtype)
            defs.setdefault(msgtype, ("msg", c.msgdef))
            _merge_topic(self.topics, TopicInfo(c.topic, msgtype, totals.get(cid, 0), lay.first.get(cid),
                                                lay.last.get(cid)))
        self.types = _TypeRegistry(defs, None)
        firsts = [t for cid, t in lay.first.items() if cid in self.conns]
        lasts = [t for cid, t in lay.last.items() if cid in self.conns]
        self.start_ns = min(firsts) if firsts else None
        self.end_ns = max(lasts) if lasts else None
        self.note = None if lay.indexed else (
            f"{path}: {lay.index_problem}; read by scanning its records instead (as `rosbag reindex` does)")
        self.stopped_at = self._damage(lay.problems, None)

    def _damage(self, problems: list[str], n: int | None) -> str | None:
        stop = self.bag.layout.stop
        parts = []
        if problems:
            what = "; ".join(problems[:3]) + (f"; and {len(problems) - 3} more" if len(problems) > 3 else "")
            read = f" ({n} messages)" if n is not None else ""
            parts.append(f"{self.path}: skipped damaged parts and read the rest{read}: {what}")
        if stop is not None:
            if n is None:
                n = sum(sum(ch.counts.values()) for ch in self.bag.layout.chunks)
            parts.append(f"{self.path}: reading stopped after {n} messages near byte {stop[0]} (the file ends "
                         f"in the middle of a record)")
        return "; ".join(parts) or None

    def iter(self, topics: set[str], skip: SkipBefore | None = None) -> Iterator[RawMessage]:
        wanted = {cid for cid, (topic, _) in self.conns.items() if topic in topics}
        if not wanted:
            return
        counts: dict[str, int] = {}
        damaged: list[str] = list(self.bag.layout.problems)
        n = 0
        by_topic: dict[str, set[int]] = {}
        for cid, (topic, _) in self.conns.items():
            by_topic.setdefault(topic, set()).add(cid)
        conn_skip = None if skip is None else SkipBefore(  # the same, by connection ids
            skip.ns, frozenset(c for t in skip.keep_all for c in by_topic.get(t, ())),
            frozenset(c for t in skip.keep_last for c in by_topic.get(t, ())))  # fmt: skip
        try:
            for t, cid, body in self.bag.messages(wanted, damaged, conn_skip):
                if cid < 0:  # a chunk left unread: its messages per connection (the indexes stay those of the bag)
                    for c, k in body.items():
                        counts[self.conns[c][0]] = counts.get(self.conns[c][0], 0) + k
                    continue
                topic, msgtype = self.conns[cid]
                i = counts.get(topic, 0)
                counts[topic] = i + 1
                n += 1
                yield RawMessage(t, topic, i, _deser(self.types, bytes(body), msgtype, ros1=True))
        finally:  # also when the reader stops early (a time window's end): the damage met so far
            self.stopped_at = self._damage(list(dict.fromkeys(damaged)), n)

    def _close(self) -> None:
        self.bag.close()


class Thunk:
    """Deserializes one message when called; ``data`` is its serialized bytes and ``encoding``
    their format ("cdr", "ros1"), for readers that parse known types directly."""

    __slots__ = ("fn", "data", "encoding")

    def __init__(self, fn: Callable[[bytes], Any], data: Any, encoding: str):
        self.fn = fn
        self.data = data
        self.encoding = encoding

    def __call__(self) -> Any:
        return self.fn(self.data)


def _deser(reg: _TypeRegistry, raw: Any, msgtype: str, ros1: bool) -> Callable[[], Any]:
    def decode(data: Any) -> Any:
        reg.ensure(msgtype)
        if ros1:
            return reg.store.deserialize_ros1(data, msgtype)
        return reg.store.deserialize_cdr(data, msgtype)

    return Thunk(decode, raw, "ros1" if ros1 else "cdr")


# ----------------------------------------------------------------------------- ROS 2 bags


class _SafeYAML:
    """Stand-in for ``ruamel.yaml.YAML(typ="safe")`` in rosbags' rosbag2 reader and metadata
    parser: ltmap's one YAML loader (``io.safe_yaml``: libyaml's C parser, ~20x faster than
    ruamel's pure Python one on metadata.yaml and its QoS strings; aliases bounded). Errors are
    re-raised as ruamel's YAMLError, which rosbags reports."""

    def __init__(self, typ: str = "safe", **_kw: Any):
        self.typ = typ

    def load(self, text: str) -> Any:
        from ruamel.yaml.error import YAMLError

        from . import safe_yaml

        try:
            return safe_yaml.loads(text)
        except Exception as err:  # noqa: BLE001 - yaml.YAMLError and YamlLimitError
            raise YAMLError(shown(str(err), 200)) from None


def _use_safe_yaml() -> None:
    try:
        from rosbags.rosbag2 import metadata, reader
    except ImportError:  # pragma: no cover - rosbags is a dependency
        return
    for module in (reader, metadata):
        if getattr(module, "YAML", None) is not _SafeYAML:
            module.YAML = _SafeYAML


class Ros2BagSource(Source):
    def __init__(self, path: Path):
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.rosbag2 import Reader

        _use_safe_yaml()
        self.path = path
        self.reader = Reader(path)
        self.reader.open()  # errors handled by the caller
        self.fmt = "ros2-sqlite3"
        defs: dict[str, tuple[str, str]] = {}
        self.topics = {}
        for c in self.reader.connections:
            fmt = {MessageDefinitionFormat.MSG: "msg", MessageDefinitionFormat.IDL: "idl"}.get(c.msgdef.format, "")
            if fmt and c.msgdef.data:
                defs.setdefault(c.msgtype, (fmt, c.msgdef.data))
            _merge_topic(self.topics, TopicInfo(c.topic, c.msgtype, int(c.msgcount)))
        self.types = _TypeRegistry(defs, "ROS2_HUMBLE")
        count = self.reader.message_count
        self.start_ns = self.reader.start_time if count else None
        self.end_ns = self.reader.end_time - 1 if count else None

    def iter(self, topics: set[str], skip: SkipBefore | None = None) -> Iterator[RawMessage]:
        conns = [c for c in self.reader.connections if c.topic in topics]
        if not conns:
            return
        counts: dict[str, int] = {}
        n = 0
        try:
            for conn, t, raw in self._rows(conns, skip, counts):
                i = counts.get(conn.topic, 0)
                counts[conn.topic] = i + 1
                n += 1
                yield RawMessage(t, conn.topic, i, _deser(self.types, raw, conn.msgtype, ros1=False))
        except Exception as err:  # noqa: BLE001 - damaged storage: stop here, report where
            self.stopped_at = _stop_text(self.path, n, None, err)

    def _rows(self, conns: list, skip: SkipBefore | None, counts: dict[str, int]) -> Iterator[tuple[Any, int, bytes]]:
        """(connection, time, bytes) of ``conns`` in time order. With ``skip``: from ``skip.ns``
        on (a query from that time), plus every message of the ``keep_all`` topics and the last
        one before it of each ``keep_last`` topic; ``counts`` then starts at the messages before
        it per topic (counted in the database), so message indexes stay those of the bag. When
        they cannot be counted, every message is read."""
        import heapq

        before = self._counts_before(skip.ns) if skip is not None else None
        if before is None:
            yield from self.reader.messages(connections=conns)
            return
        whole = [c for c in conns if c.topic in skip.keep_all]
        rest = [c for c in conns if c.topic not in skip.keep_all]
        last: dict[Any, tuple[Any, int, bytes]] = {}  # the keep_last topics' message last before skip.ns
        lasting = [c for c in rest if c.topic in skip.keep_last]
        if lasting:
            for row in self.reader.messages(connections=lasting, stop=skip.ns):
                last[(row[0].topic, row[0].id)] = row
        for c in rest:
            counts[c.topic] = before.get(c.topic, 0)
        for row in last.values():  # the last one counts as read: its index is the one before
            counts[row[0].topic] -= 1
        streams = [iter(sorted(last.values(), key=lambda r: r[1]))]
        if whole:
            streams.append(self.reader.messages(connections=whole))
        if rest:
            streams.append(self.reader.messages(connections=rest, start=skip.ns))
        yield from heapq.merge(*streams, key=lambda r: r[1])

    def _counts_before(self, ns: int) -> dict[str, int] | None:
        """Messages per topic logged before ``ns``, counted in the bag's sqlite3 files (rosbag2's
        schema: ``messages(topic_id, timestamp)``, ``topics(id, name)``); None when they cannot be."""
        import sqlite3

        out: dict[str, int] = {}
        dbs = storage_files(self.path, ".db3") if self.path.is_dir() else [self.path]
        try:
            for db in dbs:
                con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
                try:
                    rows = con.execute("SELECT topics.name, COUNT(*) FROM messages JOIN topics ON "
                                       "messages.topic_id = topics.id WHERE messages.timestamp < ? "
                                       "GROUP BY topics.name", (int(ns),)).fetchall()  # fmt: skip
                finally:
                    con.close()
                for name, k in rows:
                    out[str(name)] = out.get(str(name), 0) + int(k)
        except (sqlite3.Error, OSError, ValueError, OverflowError):
            return None
        return out if dbs else None

    def _close(self) -> None:
        self.reader.close()


# ----------------------------------------------------------------------------- MCAP


class McapSource(Source):
    _chunks: list | None = None  # an MCAP without a summary: its chunks as _scan_indexes found them

    def __init__(self, path: Path, fmt: str | None = None, max_bytes: int = int(DEFAULT_MAX_MESSAGE_MB * 2**20),
                 message_codec: str | None = None):
        """``message_codec``: "zstd" when each message is compressed by itself (a ROS 2 bag
        recorded with ``--compression-mode message``: its metadata.yaml says so)."""
        from mcap.reader import SeekingReader

        self.path = path
        self.max_bytes = max_bytes
        self.message_codec = message_codec
        self.file = path.open("rb")
        self.size = path.stat().st_size
        self._decoders: dict[int, Callable[[bytes], Any] | None] = {}
        self._bad: dict[int, str] = {}  # channel -> why its schema cannot be used
        self._factories = _mcap_factories()
        summary = None
        try:
            self.reader = SeekingReader(self.file, validate_crcs=True, decoder_factories=self._factories,
                                        record_size_limit=min(max_bytes, self.size))
            summary = self.reader.get_summary()
            if summary is not None and any(ci.chunk_start_offset + ci.chunk_length > self.size
                                           for ci in summary.chunk_indexes):
                summary = None  # the summary points outside the file: not to be trusted
        except Exception:  # noqa: BLE001 - no usable summary: stream instead
            summary = None
        self.topics = {}
        self.indexed = bool(summary and summary.statistics and summary.chunk_indexes)
        if self.indexed:
            self.schemas, self.channels = summary.schemas, summary.channels
            stats = summary.statistics
            for cid, ch in self.channels.items():
                _merge_topic(self.topics, TopicInfo(ch.topic, self._type(ch),
                                                    int(stats.channel_message_counts.get(cid, 0))))
            self.start_ns = stats.message_start_time if stats.message_count else None
            self.end_ns = stats.message_end_time if stats.message_count else None
        else:
            self.schemas, self.channels = {}, {}
            first: dict[str, int] = {}
            last: dict[str, int] = {}
            counts: dict[str, int] = {}
            try:
                scanned = self._scan_indexes()
            except TooLargeError:
                raise
            except Exception:  # noqa: BLE001 - records the scan cannot parse: every chunk is read
                scanned = None
            if scanned is not None:  # counts from the chunks' message index records (no decompressing)
                counts, first, last, self.stopped_at = scanned
            else:
                self.schemas, self.channels = {}, {}
                for item in self._stream(None):  # noqa: B007 - counting
                    counts[item.topic] = counts.get(item.topic, 0) + 1
                    first.setdefault(item.topic, item.log_time_ns)
                    last[item.topic] = item.log_time_ns
                self.stopped_at = self._stop
            self.end_stop = self.stopped_at  # where the file ends, known before reading (iter() resets stopped_at)
            for ch in self.channels.values():
                _merge_topic(self.topics, TopicInfo(ch.topic, self._type(ch), counts.get(ch.topic, 0),
                                                    first.get(ch.topic), last.get(ch.topic)))
            self.start_ns = min(first.values()) if first else None
            self.end_ns = max(last.values()) if last else None
        profiles = {"ros1" if ch.message_encoding == "ros1" else "ros2" for ch in self.channels.values()}
        self.fmt = fmt or ("mcap-ros1" if profiles == {"ros1"} else "mcap-ros2")

    def _scan_indexes(self) -> tuple[dict, dict, dict, str | None] | None:
        """(counts, first, last log time per topic, where reading would stop) of an MCAP without
        a summary (a recording killed before it wrote one), from the data section's chunk headers
        and the message index records after each chunk, skipping the chunks' bytes: a 2-minute
        1.4 GB log of depth images is counted in 0.1 s instead of 4.3 s of decompressing. A
        chunk is decompressed only to learn channels its index names that are not known yet
        (writers put the Schema and Channel records in the chunk that first uses them), or to
        count the messages of the last whole chunk when the file is cut in its index records.
        None when the file does not lend itself to it (messages outside chunks, a chunk without
        index records in the middle of the file, a channel no record defines): then every chunk
        is read (``_stream``). Damage inside a chunk's compressed bytes is found when the chunks
        are read."""
        import io

        import numpy as np
        from mcap.data_stream import ReadDataStream
        from mcap.records import Channel, Schema

        counts: dict[str, int] = {}
        first: dict[str, tuple[int, int, int]] = {}  # topic -> (chunk, offset in it, log time): file order
        last: dict[str, tuple[int, int, int]] = {}
        total = [0]

        table: list[tuple[int, int, dict[int, int]]] = []  # per chunk: (end offset, last log time, messages by channel)

        def commit(chunk_at: int, per_channel: dict[int, np.ndarray]) -> None:
            if per_channel:
                times = [int(e[:, 0].max()) for e in per_channel.values() if len(e)]
                table.append((chunk_ends[chunk_at], max(times) if times else 0,
                              {cid: len(e) for cid, e in per_channel.items()}))  # fmt: skip
            for cid, entries in per_channel.items():  # entries: (log time, offset) rows
                if not len(entries):
                    continue
                topic = self.channels[cid].topic
                counts[topic] = counts.get(topic, 0) + len(entries)
                total[0] += len(entries)
                lo, hi = int(entries[:, 1].argmin()), int(entries[:, 1].argmax())
                key = (chunk_at, int(entries[lo, 1]), int(entries[lo, 0]))
                if topic not in first or key[:2] < first[topic][:2]:
                    first[topic] = key
                key = (chunk_at, int(entries[hi, 1]), int(entries[hi, 0]))
                if topic not in last or key[:2] > last[topic][:2]:
                    last[topic] = key

        stop = None
        chunk_ends: dict[int, int] = {}  # chunk offset -> the offset after it
        chunk_at: int | None = None  # the last chunk's offset ...
        pending: dict[int, np.ndarray] | None = None  # ... and its index records so far (None: none yet)
        with self.path.open("rb") as f:
            if f.read(8) != MCAP_MAGIC:
                return None
            while True:
                at = f.tell()
                head = f.read(9)
                op = head[0] if head else 0x0F
                length = struct.unpack_from("<Q", head, 1)[0] if len(head) == 9 else 0
                cut = 0 < len(head) < 9 or at + 9 + length > self.size
                if (cut or op != 0x07) and chunk_at is not None:  # the last chunk's index records end here
                    if pending is None and head and not cut and op != 0x0F:
                        return None  # a chunk without index records in the middle of the file
                    if pending is None or (cut and (op == 0x07 or len(head) < 9)):  # none, or cut off:
                        pending = self._count_chunk(chunk_at)  # the chunk (whole) is read
                        if pending is None:
                            return None
                    commit(chunk_at, pending)
                    chunk_at, pending = None, None
                if cut:
                    stop = _stop_text(self.path, total[0], at, EOFError())
                    break
                if not head:  # (a file without its footer: reading stops there too)
                    stop = _stop_text(self.path, total[0], at, EOFError())
                    break
                if op == 0x02:  # the Footer, then the closing magic: the file's end
                    f.seek(length, 1)
                    if f.read(8) != MCAP_MAGIC:
                        stop = _stop_text(self.path, total[0], f.tell(), EOFError())
                    break
                if op == 0x06:  # Chunk: its bytes are skipped
                    chunk_at, pending = at, None
                    chunk_ends[at] = at + 9 + length
                    f.seek(length, 1)
                elif op == 0x07:  # MessageIndex: channel id, (log time, offset) pairs
                    body = f.read(length)
                    if chunk_at is None or len(body) < 6:
                        return None
                    cid, size = struct.unpack_from("<HI", body, 0)
                    if size % 16 or 6 + size > len(body):
                        return None
                    if cid not in self.channels and (self._count_chunk(chunk_at) is None or cid not in self.channels):
                        return None  # (reading the chunk learns its Schema and Channel records)
                    pending = {} if pending is None else pending
                    pending[cid] = np.frombuffer(body, dtype="<u8", count=size // 8, offset=6).reshape(-1, 2)
                elif op in (0x03, 0x04):  # Schema, Channel outside chunks
                    rec = (Schema if op == 0x03 else Channel).read(ReadDataStream(io.BytesIO(f.read(length))))
                    (self.schemas if op == 0x03 else self.channels)[rec.id] = rec
                elif op == 0x05:  # a Message outside any chunk
                    return None
                else:  # Header, Attachment, Metadata, DataEnd, the summary's records: skipped
                    f.seek(length, 1)
        self._chunks = table
        return (counts, {t: v[2] for t, v in first.items()}, {t: v[2] for t, v in last.items()}, stop)

    def _chunk_at(self, f: Any, offset: int) -> list[Any]:
        """The records of the chunk whose record starts at ``offset`` in ``f`` (``_chunk_records``;
        the record read within its declared length and the file's end), for the chunk index
        (``_indexed_messages``) and the unindexed scan (``_count_chunk``) alike."""
        from mcap.data_stream import ReadDataStream
        from mcap.records import Chunk

        f.seek(offset + 1)
        head = f.read(8)
        if len(head) != 8:
            raise EOFError("the chunk's record is cut off")
        length = min(struct.unpack("<Q", head)[0], max(self.size - offset - 9, 0))  # (never past the file's end)
        chunk = Chunk.read(ReadDataStream(_Bounded(f, length)))
        return self._chunk_records(chunk, offset)

    def _count_chunk(self, chunk_at: int):
        """{channel: (log time, offset) rows} of the messages of the chunk at ``chunk_at``, read
        whole (and its Schema and Channel records learnt); None when it cannot be read."""
        import numpy as np
        from mcap.records import Channel, Message, Schema

        out: dict[int, list] = {}
        try:
            with self.path.open("rb") as f:
                for k, record in enumerate(self._chunk_at(f, chunk_at)):
                    if isinstance(record, Schema):
                        self.schemas[record.id] = record
                    elif isinstance(record, Channel):
                        self.channels[record.id] = record
                    elif isinstance(record, Message):
                        if record.channel_id not in self.channels:
                            return None
                        out.setdefault(record.channel_id, []).append((record.log_time, k))
        except TooLargeError:
            raise
        except Exception:  # noqa: BLE001 - a damaged chunk: every chunk is read instead
            return None
        return {cid: np.array(rows, dtype=np.uint64).reshape(-1, 2) for cid, rows in out.items()}

    def _type(self, ch: Any) -> str:
        schema = self.schemas.get(ch.schema_id)
        return normalize_type(schema.name) if schema is not None else "(no schema)"

    def _decoder(self, ch: Any) -> Callable[[bytes], Any] | None:
        if ch.id in self._bad:
            raise LogReadError(self._bad[ch.id])
        if ch.id not in self._decoders:
            schema = self.schemas.get(ch.schema_id)
            if schema is not None and schema.encoding in ("ros1msg", "ros2msg"):
                try:
                    _check_schema(schema)
                except LogReadError as err:
                    self._bad[ch.id] = str(err)
                    raise
            dec = None
            for factory in self._factories:
                dec = factory.decoder_for(ch.message_encoding, schema)
                if dec is not None:
                    break
            self._decoders[ch.id] = dec
        return self._decoders[ch.id]

    def _thunk(self, ch: Any, data: bytes) -> Callable[[], Any]:
        if self.message_codec is not None:
            try:
                data = decompress_zstd_message(data, self.max_bytes, f"a message on {ch.topic} in {self.path}")
            except DecompressError as err:
                reason = str(err)

                def damaged(_: Any) -> Any:
                    raise ValueError(f"its bytes, compressed by rosbag2, cannot be decompressed: {reason}")

                return Thunk(damaged, b"", ch.message_encoding)

        def decode(data: bytes) -> Any:
            dec = self._decoder(ch)
            if dec is None:
                raise LogReadError(f"no decoder for message encoding {ch.message_encoding!r} "
                                   f"(ltmap reads ros1 and cdr)")
            return dec(data)

        return Thunk(decode, data, ch.message_encoding)

    def _stream(self, wanted: set[str] | None, skip: SkipBefore | None = None) -> Iterator[RawMessage]:
        """Every record in file order. ``skip``: with the chunk table of ``_scan_indexes`` (an
        MCAP without a summary), the chunks ``io.skip.unread_chunks`` lets go before the skip
        time are read but not decompressed, their messages counted from the table (the message
        indexes stay those of the whole log)."""
        from mcap.records import Channel, Chunk, Message, Schema
        from mcap.stream_reader import StreamReader

        self._stop = None
        n = 0
        counts: dict[str, int] = {}
        unread = self._unread_table(skip) if skip is not None and self._chunks else {}
        with self.path.open("rb") as f:
            try:
                reader = StreamReader(f, skip_magic=False, validate_crcs=True, emit_chunks=True,
                                      record_size_limit=min(self.max_bytes, self.size))
                for top in reader.records:
                    if isinstance(top, Chunk) and unread and _tell(f) in unread:
                        for cid, k in unread[_tell(f)].items():
                            topic = self.channels[cid].topic
                            if wanted is None or topic in wanted:
                                counts[topic] = counts.get(topic, 0) + k
                        continue
                    inner = self._chunk_records(top, _tell(f)) if isinstance(top, Chunk) else [top]
                    for record in inner:
                        if isinstance(record, Schema):
                            self.schemas[record.id] = record
                        elif isinstance(record, Channel):
                            self.channels[record.id] = record
                        elif isinstance(record, Message):
                            ch = self.channels.get(record.channel_id)
                            if ch is None:
                                raise LogReadError(f"message on unknown channel {record.channel_id}")
                            if wanted is not None and ch.topic not in wanted:
                                continue
                            i = counts.get(ch.topic, 0)
                            counts[ch.topic] = i + 1
                            n += 1
                            yield RawMessage(record.log_time, ch.topic, i, self._thunk(ch, record.data))
            except TooLargeError:
                raise
            except Exception as err:  # noqa: BLE001 - truncated or corrupt: stop here
                self._stop = _stop_text(self.path, n, _tell(f), err)

    def _unread_table(self, skip: SkipBefore) -> dict[int, dict[int, int]]:
        """{chunk end offset: {channel: messages}} of the chunks of ``_chunks`` that ``skip`` lets
        go unread (``io.skip.unread_chunks``, as for an indexed MCAP)."""
        early = [c for c in self._chunks if c[1] < skip.ns and all(cid in self.channels for cid in c[2])]
        keep_out = unread_chunks(early, lambda c: (self.channels[cid].topic for cid in c[2]),
                                 lambda c: (c[1], c[0]), skip.keep_all, skip.keep_last)  # fmt: skip
        return {early[k][0]: early[k][2] for k in keep_out}

    def _chunk_records(self, chunk: Any, pos: int | None) -> list[Any]:
        """The records of an MCAP chunk, decompressed within its declared size and the limit
        (``TooLargeError``), its CRC checked."""
        from mcap.records import Chunk
        from mcap.stream_reader import CRCValidationError, breakup_chunk

        where = f"{self.path}: the chunk" + (f" before byte {pos}" if pos is not None else "")
        data = decompress(chunk.compression, chunk.data, chunk.uncompressed_size, self.max_bytes, where)
        plain = Chunk(compression="", data=data, message_end_time=chunk.message_end_time,
                      message_start_time=chunk.message_start_time, uncompressed_crc=chunk.uncompressed_crc,
                      uncompressed_size=chunk.uncompressed_size)
        if chunk.uncompressed_crc != 0:  # (0: the writer computed none, as mcap's own check reads it)
            crc = crc32(data)
            if crc != chunk.uncompressed_crc:
                raise CRCValidationError(expected=chunk.uncompressed_crc, actual=crc, record=plain)
        return breakup_chunk(plain, validate_crc=False)

    def iter(self, topics: set[str], skip: SkipBefore | None = None) -> Iterator[RawMessage]:
        if not topics:
            return
        if not self.indexed:
            try:
                yield from self._stream(topics, skip)
            finally:  # also when the reader stops early (a time window's end)
                self.stopped_at = self._stop
            return
        counts: dict[str, int] = {}
        n = 0
        damaged: list[str] = []
        try:
            for ch, msg in self._indexed_messages(topics, damaged, skip):
                if ch is None:  # a chunk left unread: its messages per topic (the indexes stay those of the log)
                    for topic, k in msg.items():
                        counts[topic] = counts.get(topic, 0) + k
                    continue
                i = counts.get(ch.topic, 0)
                counts[ch.topic] = i + 1
                n += 1
                yield RawMessage(msg.log_time, ch.topic, i, self._thunk(ch, msg.data))
        finally:  # also when the reader stops early (a time window's end): the damage met so far
            if damaged:
                self.stopped_at = (f"{self.path}: skipped {len(damaged)} damaged chunk{'s' if len(damaged) > 1 else ''}"
                                   f" and read the rest ({n} messages): {'; '.join(damaged[:3])}"
                                   + (f"; and {len(damaged) - 3} more" if len(damaged) > 3 else ""))  # fmt: skip

    def _indexed_messages(self, topics: set[str], damaged: list[str],
                          skip: SkipBefore | None = None) -> Iterator[tuple[Any, Any]]:
        """(channel, message) of ``topics`` in log-time order, chunk by chunk through the summary's
        chunk indexes (as mcap's SeekingReader does). A chunk that cannot be read (CRC mismatch,
        bad compression, cut short) is skipped and described in ``damaged``: the chunks after it
        are still read, so one bad block of the disk loses its own seconds of log only.

        ``skip``: the chunks whose messages all lie before ``skip.ns`` are not read (nor their
        damage seen), unless one holds a ``keep_all`` topic or is the last such chunk holding a
        ``keep_last`` topic, or its message index records (which name its channels) cannot be
        read; for each, (None, {topic: messages}) is yielded in its place, from those records."""
        import heapq

        from mcap.records import Message

        summary = self.reader.get_summary()
        ids = {cid for cid, ch in summary.channels.items() if ch.topic in topics}
        chunks = [ci for ci in summary.chunk_indexes
                  if not ci.message_index_offsets or ids.intersection(ci.message_index_offsets)]  # fmt: skip
        unread = self._unread(chunks, ids, summary.channels, skip) if skip is not None else {}
        heap: list[tuple] = []
        for ci in chunks:
            if ci.chunk_start_offset in unread:  # its place in time: the per-topic message counts go on
                heap.append((ci.message_start_time, -1, ci.chunk_start_offset, 0, (None, unread[ci.chunk_start_offset])))
            else:
                heap.append((ci.message_start_time, 0, ci.chunk_start_offset, 0, ci))
        heapq.heapify(heap)
        t0 = self.start_ns or 0
        while heap:
            item = heapq.heappop(heap)
            if item[1] != 0:  # a message, or an unread chunk's counts
                yield item[4]
                continue
            ci = item[4]
            try:
                records = self._chunk_at(self.file, ci.chunk_start_offset)
            except TooLargeError:
                raise
            except Exception as err:  # noqa: BLE001 - a damaged chunk: skip it, say which
                reason = first_line(err)
                damaged.append(f"the chunk at byte {ci.chunk_start_offset} (log time "
                               f"{(ci.message_start_time - t0) / 1e9:.1f} to {(ci.message_end_time - t0) / 1e9:.1f} s: "
                               f"its messages are lost; {reason})")  # fmt: skip
                continue
            for index, record in enumerate(records):
                if isinstance(record, Message) and record.channel_id in ids:
                    heapq.heappush(heap, (record.log_time, 1, ci.chunk_start_offset, index,
                                          (summary.channels[record.channel_id], record)))  # fmt: skip

    def _unread(self, chunks: list, ids: set[int], channels: dict, skip: SkipBefore) -> dict[int, dict[str, int]]:
        """{chunk offset: {topic: messages}} of the chunks ``skip`` lets go unread."""
        early = [ci for ci in chunks if ci.message_end_time < skip.ns and ci.message_index_offsets]
        skipped = unread_chunks(early, lambda ci: (channels[c].topic for c in ci.message_index_offsets if c in channels),
                                lambda ci: (ci.message_end_time, ci.chunk_start_offset), skip.keep_all,
                                skip.keep_last)  # fmt: skip
        out = {}
        for k in sorted(skipped):
            ci = early[k]
            counts = self._index_counts(ci, ids, channels)
            if counts is not None:  # (else it is read: its channels are not known for sure)
                out[ci.chunk_start_offset] = counts
        return out

    def _index_counts(self, ci: Any, ids: set[int], channels: dict) -> dict[str, int] | None:
        """Messages per topic (of channels ``ids``) in the chunk of ``ci``, from its message index
        records (15 bytes a channel: the chunk itself is not read); None when one cannot be read."""
        out: dict[str, int] = {}
        try:
            for cid, off in ci.message_index_offsets.items():
                if cid not in ids:
                    continue
                self.file.seek(off)
                head = self.file.read(15)  # opcode, record length, channel id, records' length
                if len(head) != 15 or head[0] != 0x07:
                    return None
                ch_id, rec_len = struct.unpack_from("<HI", head, 9)
                if ch_id != cid or rec_len % 16 or cid not in channels:
                    return None
                topic = channels[cid].topic
                out[topic] = out.get(topic, 0) + rec_len // 16
        except (OSError, ValueError):  # (an offset no file has)
            return None
        return out

    def _close(self) -> None:
        self.file.close()


class _Bounded:
    """A file seen through a window of ``limit`` bytes: a record cannot make ``read`` ask
    for more than its chunk's length (a flipped length field would allocate gigabytes)."""

    def __init__(self, f: Any, limit: int):
        self.f = f
        self.left = limit

    def read(self, n: int = -1) -> bytes:
        n = self.left if n < 0 else min(n, self.left)
        data = self.f.read(n)
        self.left -= len(data)
        return data


def _check_schema(schema: Any) -> None:
    """An MCAP schema of a type ltmap reads must define its standard fields (``check_definitions``)."""
    from rosbags.typesys import get_types_from_msg

    name = normalize_type(schema.name)
    if name not in _READ_TYPES:
        return
    try:
        text = schema.data.decode("utf-8")
        types = get_types_from_msg(_fix_ros1_msgdef(text), name)
    except Exception:  # noqa: BLE001 - a dialect rosbags does not parse: the decoder decides
        return
    check_definitions(types)


def _tell(f: Any) -> int | None:
    try:
        return f.tell()
    except (OSError, ValueError):
        return None


def _mcap_factories() -> list[Any]:
    from mcap_ros1.decoder import DecoderFactory as Ros1Factory
    from mcap_ros2.decoder import DecoderFactory as Ros2Factory

    return [Ros2Factory(), Ros1Factory()]


# ----------------------------------------------------------------------------- opening


def _merge_topic(topics: dict[str, TopicInfo], info: TopicInfo) -> None:
    have = topics.get(info.name)
    if have is None:
        topics[info.name] = TopicInfo(info.name, info.msgtype, info.count, info.first_ns, info.last_ns)
        return
    have.count += info.count
    if info.first_ns is not None:
        have.first_ns = info.first_ns if have.first_ns is None else min(have.first_ns, info.first_ns)
    if info.last_ns is not None:
        have.last_ns = info.last_ns if have.last_ns is None else max(have.last_ns, info.last_ns)


_KINDS = "give a ROS 1 .bag file, a ROS 2 bag folder (with metadata.yaml) or an .mcap file"


def open_source(path: Path, max_bytes: int = int(DEFAULT_MAX_MESSAGE_MB * 2**20)) -> list[Source]:
    """Open one log (a ROS 2 bag folder may give several sources); ``InputError`` / ``LogReadError`` name the file and what to do."""
    if not path.exists():
        raise InputError(f"log not found: {path}; {_KINDS}")
    if path.is_file() and (path.name == "metadata.yaml" or path.suffix == ".db3") \
            and (path.parent / "metadata.yaml").is_file():
        path = path.parent
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise InputError(f"{path} is a folder without metadata.yaml, not a ROS 2 bag; {_KINDS}")
        return _open_ros2(path, max_bytes)
    from .safe_yaml import check_regular_file

    if check_regular_file(path, "log", InputError) == 0:
        raise InputError(f"log {path} is empty (0 bytes); the recording did not write anything")
    with path.open("rb") as f:
        head = f.read(16)
    if head.startswith(ROS1_MAGIC[:9]):
        if not head.startswith(ROS1_MAGIC[:12]):
            raise InputError(f"{path} is a ROS 1 bag of an unsupported version ({head[:12]!r}); "
                             f"only bag format 2.0 is read: migrate it with `rosbag fix`")
        try:
            return [Ros1Source(path, max_bytes)]
        except TooLargeError:
            raise
        except (ValueError, OSError, struct.error) as err:
            raise LogReadError(f"cannot read ROS 1 bag {path}: {err}; the file is not a readable bag") from None
    if head.startswith(MCAP_MAGIC[:6]):
        return [McapSource(path, max_bytes=max_bytes)]
    if head.startswith(SQLITE_MAGIC):
        return _open_ros2(path, max_bytes)
    raise InputError(f"{path} is not a robot log (it starts with {head[:8]!r}); {_KINDS}")


STORAGE_SUFFIXES = (".mcap", ".db3")  # the files of a ROS 2 bag folder that hold its messages


def storage_files(folder: Path, suffix: str | None = None) -> list[Path]:
    """The files of a ROS 2 bag folder that hold its messages (of one ``suffix``), sorted."""
    return sorted(f for f in Path(folder).iterdir() if f.suffix in ((suffix,) if suffix else STORAGE_SUFFIXES))


def _bag_info(folder: Path) -> dict:
    """rosbag2_bagfile_information of a ROS 2 bag folder's metadata.yaml ({} when it says nothing
    readable: its files are read as they are)."""
    from . import safe_yaml

    meta = folder / "metadata.yaml"
    try:
        safe_yaml.check_regular_file(meta, "ROS 2 bag metadata.yaml", InputError, safe_yaml.MAX_YAML_BYTES)
        info = (safe_yaml.loads(meta.read_text(errors="replace")) or {}).get("rosbag2_bagfile_information") or {}
    except (OSError, ValueError, AttributeError, safe_yaml.yaml.YAMLError):
        return {}
    return info if isinstance(info, dict) else {}


def _compression(info: dict) -> tuple[str, str]:
    return str(info.get("compression_mode") or "").lower(), str(info.get("compression_format") or "").lower()


def _message_compression(folder: Path, info: dict) -> str | None:
    """The compression of each message of a ROS 2 bag (``ros2 bag record --compression-mode
    message``: each message's bytes compressed by themselves, in any storage), from its
    metadata.yaml's ``info``: "zstd", or None (none, or the whole file compressed:
    ``_decompressed_copy``)."""
    mode, fmt = _compression(info)
    if mode != "message":
        return None
    if fmt != "zstd":
        raise InputError(f"ROS 2 bag {folder}: its messages are compressed with {fmt or '(no format named)'!r}; ltmap "
                         f"reads zstd, rosbag2's compressor: decompress it with `ros2 bag convert`")  # fmt: skip
    return "zstd"


DECOMPRESS_CHUNK = 8 << 20
DECOMPRESS_NOTE = 256 << 20  # a copy of about this much or more is said before it is made


class _Stopped(Exception):
    """A decompression told to stop (``_decompress_file``'s ``stop``)."""


def _decompress_file(folder: Path, src: Path, dst: Path, stop: Any = None) -> None:
    """Decompress one storage file of a ROS 2 bag compressed file by file (a zstd stream) into
    ``dst`` (a file listed without ``.zstd``, as a recorder stopped before compressing its last
    one leaves it, is copied as it is), watching the disk as it fills: the copy stops with one
    line when it would leave less than ``KEEP_FREE_BYTES`` free (a few kB of zstd can claim
    terabytes), instead of filling it (rosbags' own copy failed with ENOSPC, read as a corrupt
    bag). A damaged stream is one line too; ``dst`` is removed on failure. ``stop``: a
    ``threading.Event`` that ends the copy (``_Stopped``) when set."""
    import zstandard

    base = dst.parent
    written = 0
    try:
        with src.open("rb") as fi, dst.open("wb") as fo:
            reader = zstandard.ZstdDecompressor().stream_reader(fi, read_across_frames=True) \
                if src.suffix == ".zstd" else fi  # fmt: skip
            while chunk := reader.read(DECOMPRESS_CHUNK):
                if stop is not None and stop.is_set():
                    raise _Stopped
                free = shutil.disk_usage(base).free
                if free - len(chunk) < KEEP_FREE_BYTES:
                    raise LogReadError(
                        f"ROS 2 bag {folder} is compressed file by file and is read from decompressed copies: "
                        f"after {human(written + len(chunk))} of {src.name}, the copy would leave less than "
                        f"{human(KEEP_FREE_BYTES)} free in {base.parent} ({human(free)} free); set TMPDIR to a folder "
                        f"on a disk with room, or convert the bag once to an uncompressed one (`ros2 bag convert`)")
                fo.write(chunk)
                written += len(chunk)
    except BaseException as err:
        dst.unlink(missing_ok=True)
        if isinstance(err, zstandard.ZstdError):
            raise LogReadError(f"ROS 2 bag {folder}: {src.name} is not a readable zstd stream ({first_line(err, 120)}); "
                               f"the file is damaged") from None  # fmt: skip
        if isinstance(err, OSError) and err.errno == errno.ENOSPC:
            raise LogReadError(f"ROS 2 bag {folder} is compressed file by file and is read from decompressed copies: "
                               f"the disk of {base.parent} is full; set TMPDIR to a folder on a disk with room, or "
                               f"convert the bag once to an uncompressed one (`ros2 bag convert`)") from None  # fmt: skip
        raise


def _compressed_files(folder: Path, info: dict) -> list[Path]:
    """The storage files of a ROS 2 bag compressed file by file, in metadata.yaml's order: each
    name listed is the file of that name in the folder, once (rosbag2 lists names in the folder:
    a path elsewhere is not read; a hostile list naming one file 100,000 times reads it once)."""
    fmt = _compression(info)[1]
    if fmt != "zstd":
        raise InputError(f"ROS 2 bag {folder}: its files are compressed with {fmt or '(no format named)'!r}; ltmap "
                         f"reads zstd, rosbag2's compressor: decompress it with `ros2 bag convert`")  # fmt: skip
    names = info.get("relative_file_paths")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        raise LogReadError(f"ROS 2 bag {folder}: metadata.yaml lists no relative_file_paths; the bag folder is "
                           f"incomplete")  # fmt: skip
    files = []
    for name in dict.fromkeys(Path(n).name for n in names):
        src = folder / name
        if not src.is_file():
            raise InputError(f"ROS 2 bag {folder}: {name} (in metadata.yaml) is missing; the bag folder "
                             f"is incomplete")  # fmt: skip
        files.append(src)
    return files


def _note_decompressing(folder: Path, files: list[Path], lazily: bool) -> None:
    """Say, before it is made, a decompressed copy of about ``DECOMPRESS_NOTE`` or more (minutes
    for tens of GB), and where it goes: of the largest file when ``lazily`` (a file at a time),
    else of them all."""
    sizes = [f.stat().st_size for f in files]
    size = max(sizes) if lazily else sum(sizes)
    if size * 2 < DECOMPRESS_NOTE:
        return
    import tempfile
    import warnings

    from ..errors import LtmapWarning

    base = Path(tempfile.gettempdir())
    n = len(files)
    if lazily:
        what = (f"each of its {n} files is decompressed into {base} when reading reaches it and removed once read "
                f"(the largest {human(size)} compressed")  # fmt: skip
    else:
        what = f"decompressing its {n} file{'s' if n > 1 else ''} ({human(size)} compressed) into {base} first " \
               f"(removed at the end"  # fmt: skip
    warnings.warn(LtmapWarning(f"ROS 2 bag {folder} is compressed file by file: {what}; TMPDIR chooses the folder)"),
                  stacklevel=3)


def _decompressed_copy(folder: Path, info: dict, files: list[Path]) -> Path:
    """A ROS 2 bag compressed file by file whose metadata.yaml does not say when each file
    begins (``_file_sources`` needs that): all its ``files`` (``_compressed_files``) decompressed
    into a new folder under the temporary directory (``TMPDIR``), beside a metadata.yaml that says
    they are not compressed; returns it. sqlite3 cannot read a stream, and an MCAP is read by
    seeking."""
    import tempfile

    _note_decompressing(folder, files, lazily=False)
    tmp = Path(tempfile.mkdtemp(prefix="ltmap-bag-", dir=tempfile.gettempdir()))
    try:
        for src in files:
            _decompress_file(folder, src, tmp / src.name.removesuffix(".zstd"))
        meta = dict(info)
        meta["compression_mode"], meta["compression_format"] = "", ""
        meta["relative_file_paths"] = [f.name.removesuffix(".zstd") for f in files]
        meta.pop("files", None)
        import yaml

        (tmp / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": meta}, sort_keys=False))
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp


class CompressedFileSource(Source):
    """One storage file of a ROS 2 bag compressed file by file (``ros2 bag record
    --compression-mode file``: ``*.db3.zstd`` / ``*.mcap.zstd``, split by ``--max-bag-size`` or
    ``--max-bag-duration``), decompressed into the temporary directory (``TMPDIR``) only when
    reading reaches it (the merge starts it at its first message, which metadata.yaml's ``files``
    entry gives) and removed as soon as it is read: the disk holds at most two files of the bag
    decompressed, not the whole bag, and an hour of RGB-D log starts mapping at once instead of
    after minutes of decompressing. The bag's topics and counts are metadata.yaml's (``topics``
    of the first file; the others add none); the messages, their definitions and indexes
    (counted in each file) are the file's own.

    Read-ahead: once reading is half way through a file's time span, the next file (``next``) is
    decompressed in a thread, when the disk has room for it beside this one (its size estimated
    from this file's ratio) and ``KEEP_FREE_BYTES``; so on a machine with cores to spare the
    replay does not wait for each file's decompressing. It is best effort: whatever stops it
    (the disk, a damaged stream, the run's end), the file is decompressed when reached, as
    without it. (Not at a file's start: ``ltmap info`` reads a big log's first seconds only.)"""

    next: CompressedFileSource | None = None  # the bag's next file

    def __init__(self, folder: Path, src: Path, fmt: str, start_ns: int, end_ns: int,
                 topics: dict[str, TopicInfo], max_bytes: int):
        import threading

        self.folder, self.path, self.fmt = folder, src, fmt
        self.start_ns, self.end_ns, self.topics = start_ns, end_ns, topics
        self.max_bytes = max_bytes
        self._tmp: Path | None = None
        self._ahead: Any = None  # the read-ahead thread
        self._ahead_done = False  # it decompressed the file whole
        self._stop = threading.Event()  # set: the read-ahead stops

    def _dst(self) -> Path:
        import tempfile

        if self._tmp is None:
            try:
                self._tmp = Path(tempfile.mkdtemp(prefix="ltmap-bag-", dir=tempfile.gettempdir()))
            except OSError as err:
                raise LogReadError(f"ROS 2 bag {self.folder} is compressed file by file: cannot make a folder in "
                                   f"{tempfile.gettempdir()} to decompress {self.path.name} into ({first_line(err)}); "
                                   f"set TMPDIR to a folder on a disk with room") from None  # fmt: skip
        return self._tmp / self.path.name.removesuffix(".zstd")

    def read_ahead(self, ratio: float) -> None:
        """Start decompressing this file in a thread (see the class), ``ratio``: decompressed
        over compressed size of the file before."""
        import threading

        if self._ahead is not None or self._tmp is not None:
            return
        self._stop = threading.Event()
        try:
            dst = self._dst()
        except LogReadError:
            return  # (said when reading reaches the file)
        need = self.path.stat().st_size * max(ratio, 1.0)
        if shutil.disk_usage(dst.parent).free - need < KEEP_FREE_BYTES:
            self._close()
            return

        def work() -> None:
            try:
                _decompress_file(self.folder, self.path, dst, self._stop)
                self._ahead_done = True
            except BaseException:  # noqa: BLE001 - best effort: iter() decompresses it itself
                pass

        self._ahead = threading.Thread(target=work, name="ltmap-bag-ahead", daemon=True)
        self._ahead.start()

    def iter(self, topics: set[str], skip: SkipBefore | None = None) -> Iterator[RawMessage]:
        inner: Source | None = None
        dst = self._dst()
        try:
            if self._ahead is not None:
                self._ahead.join()
                self._ahead = None
            if not self._ahead_done:
                _decompress_file(self.folder, self.path, dst)
            ratio = dst.stat().st_size / max(1, self.path.stat().st_size)
            try:
                inner = McapSource(dst, fmt=self.fmt, max_bytes=self.max_bytes) if self.fmt == "ros2-mcap" \
                    else Ros2BagSource(dst)  # fmt: skip
            except (TooLargeError, InputError):
                raise
            except Exception as err:  # noqa: BLE001 - rosbags and sqlite3 raise several kinds
                self.stopped_at = f"{self.path}: cannot be read ({first_line(err, 200)})"
                return
            half = self.start_ns + (self.end_ns - self.start_ns) // 2
            ahead = self.next
            for m in inner.iter(topics, skip):
                if ahead is not None and m.log_time_ns >= half:
                    ahead.read_ahead(ratio)
                    ahead = None
                yield m
        finally:
            if inner is not None:
                if inner.stopped_at:
                    self.stopped_at = inner.stopped_at.replace(str(dst), str(self.path))
                inner.close()
            self._close()

    def _close(self) -> None:
        if self._ahead is not None:
            self._stop.set()
            self._ahead.join()
            self._ahead = None
        self._ahead_done = False
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None


def _ns(entry: Any, key: str, unit: str) -> int:
    value = entry[key][unit]
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < 2**63:
        raise ValueError(key)
    return value


def _file_sources(folder: Path, info: dict, files: list[Path], max_bytes: int) -> list[Source] | None:
    """The ``files`` of a ROS 2 bag compressed file by file (``_compressed_files``) as
    ``CompressedFileSource`` items, each decompressed when reached; None when metadata.yaml lacks
    what that needs (each file's starting time and duration, the topics and their types: rosbag2
    writes them since Foxy's successors; ``_decompressed_copy`` then copies the whole bag first)."""
    storage = str(info.get("storage_identifier", ""))
    if storage not in ("sqlite3", "mcap"):
        return None
    try:
        entries = {Path(str(f["path"])).name: f for f in info["files"]}
        spans = [(_ns(entries[f.name], "starting_time", "nanoseconds_since_epoch"),
                  _ns(entries[f.name], "duration", "nanoseconds")) for f in files]  # fmt: skip
        topics: dict[str, TopicInfo] = {}
        for t in info["topics_with_message_count"]:
            meta, count = t["topic_metadata"], t["message_count"]
            if not (isinstance(meta["name"], str) and isinstance(meta["type"], str) and isinstance(count, int)):
                return None
            _merge_topic(topics, TopicInfo(meta["name"], normalize_type(meta["type"]), max(count, 0)))
    except (KeyError, TypeError, ValueError, AttributeError):
        return None
    _note_decompressing(folder, files, lazily=True)
    fmt = "ros2-mcap" if storage == "mcap" else "ros2-sqlite3"
    out = [CompressedFileSource(folder, f, fmt, t0, t0 + dur, topics if k == 0 else {}, max_bytes)
           for k, (f, (t0, dur)) in enumerate(zip(files, spans))]  # fmt: skip
    for a, b in zip(out, out[1:]):
        a.next = b
    return out


def _open_ros2(path: Path, max_bytes: int) -> list[Source]:
    from .safe_yaml import MAX_YAML_BYTES, check_regular_file

    info = _bag_info(path) if path.is_dir() else {}  # (read once: the compression of its files or messages)
    if _compression(info)[0] == "file":
        files = _compressed_files(path, info)
        lazy = _file_sources(path, info, files, max_bytes)
        if lazy is not None:
            return lazy
        copy = _decompressed_copy(path, info, files)
        try:
            sources = _open_ros2(copy, max_bytes)
        except BaseException:
            shutil.rmtree(copy, ignore_errors=True)
            raise
        shared = SharedDir(copy, len(sources))
        for src in sources:
            src.temp_dir = shared
        return sources
    mcaps = storage_files(path, ".mcap") if path.is_dir() else []
    if mcaps:  # mcap storage: the mcap package streams it, and reads what a cut-off file still has
        for m in mcaps:
            check_regular_file(m, "log", InputError)
        codec = _message_compression(path, info)
        return [McapSource(m, fmt="ros2-mcap", max_bytes=max_bytes, message_codec=codec) for m in mcaps]
    if path.is_dir():  # rosbags reads metadata.yaml whole: a FIFO or a huge file would hang it
        check_regular_file(path / "metadata.yaml", "ROS 2 bag metadata.yaml", InputError, MAX_YAML_BYTES)
        for db in storage_files(path, ".db3"):
            check_regular_file(db, "log", InputError)
    try:
        return [Ros2BagSource(path)]
    except FileNotFoundError as err:
        raise InputError(f"ROS 2 bag {path}: {err}; the bag folder is incomplete") from None
    except Exception as err:  # noqa: BLE001 - rosbags and sqlite3 raise several kinds
        reason = first_line(err, 200)
        raise LogReadError(f"cannot read ROS 2 bag {path}: {reason}; the bag is corrupt or cut off and "
                           f"nothing in it can be read") from None


__all__ = ["TopicInfo", "RawMessage", "Source", "SkipBefore", "Thunk", "open_source", "normalize_type"]
