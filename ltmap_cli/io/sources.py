"""One log file or bag folder as a stream of raw messages (internal to ``ltmap_cli.io.logs``).

Each source knows its topics (name, type, count) and yields ``RawMessage`` items in log-time
order (file order for damaged files that have lost their index), each with a thunk that
deserializes the message only when called. A source whose file ends early or is corrupt stops
yielding and sets ``stopped_at`` to where reading stopped; it never raises mid-stream for that.

- ROS 1 bag: rosbags' rosbag1 Reader (indexed bags); a streaming record parser of our own for
  bags without a usable index (still recording, truncated). Types are registered from the
  connections' message definitions, so custom types that exist only in the bag decode, and the
  old ``roslib/Header`` is read as ``std_msgs/Header``.
- ROS 2 bag folder (sqlite3 or mcap storage): rosbags' rosbag2 Reader; definitions from the bag
  when it has them, else the ROS 2 Humble type store.
- standalone MCAP: the ``mcap`` package, indexed reading in log-time order when the summary is
  intact, else a streaming pass; decoding by mcap_ros2 (ros2 profile, CDR) or mcap_ros1 (ros1).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from ..errors import InputError, LogReadError

ROS1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"


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
    if isinstance(err, (struct.error, EOFError)) or type(err).__name__ == "EndOfFile":
        reason = "the file ends in the middle of a record"
    else:
        reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
    return f"{path}: reading stopped after {count} messages{where} ({reason})"


class Source:
    path: Path
    fmt: str
    topics: dict[str, TopicInfo]
    start_ns: int | None
    end_ns: int | None
    stopped_at: str | None = None

    def iter(self, topics: set[str]) -> Iterator[RawMessage]:  # pragma: no cover - interface
        raise NotImplementedError

    def close(self) -> None:
        pass


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


class Ros1BagSource(Source):
    fmt = "ros1"

    def __init__(self, path: Path):
        from rosbags.rosbag1 import Reader, ReaderError

        self.path = path
        self.reader = Reader(path)
        try:
            self.reader.open()
        except ReaderError as err:
            raise _NeedsStreaming(str(err)) from None
        defs: dict[str, tuple[str, str]] = {}
        self.topics = {}
        for c in self.reader.connections:
            defs.setdefault(c.msgtype, ("msg", c.msgdef.data))
            idx = self.reader.indexes.get(c.id, [])
            first = idx[0].time if idx else None
            last = idx[-1].time if idx else None
            _merge_topic(self.topics, TopicInfo(c.topic, c.msgtype, len(idx), first, last))
        self.types = _TypeRegistry(defs, None)
        self.start_ns = self.reader.start_time if self.reader.message_count else None
        self.end_ns = self.reader.end_time - 1 if self.reader.message_count else None

    def iter(self, topics: set[str]) -> Iterator[RawMessage]:
        conns = [c for c in self.reader.connections if c.topic in topics]
        if not conns:
            return
        counts: dict[str, int] = {}
        n = 0
        store = self.types
        try:
            for conn, t, raw in self.reader.messages(connections=conns):
                i = counts.get(conn.topic, 0)
                counts[conn.topic] = i + 1
                n += 1
                yield RawMessage(t, conn.topic, i, _deser(store, raw, conn.msgtype, ros1=True))
        except Exception as err:  # noqa: BLE001 - corrupt chunk: stop here, report where
            self.stopped_at = _stop_text(self.path, n, _tell(self.file), err)

    def close(self) -> None:
        self.reader.close()


class _NeedsStreaming(Exception):
    pass


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


class Ros1StreamSource(Source):
    """A ROS 1 bag read record by record, for bags whose index is missing or cut off."""

    fmt = "ros1"

    def __init__(self, path: Path):
        self.path = path
        self.topics = {}
        self.conns: dict[int, tuple[str, str]] = {}
        defs: dict[str, tuple[str, str]] = {}
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        counts: dict[str, int] = {}
        for item in self._records(set(), defs):
            counts[item.topic] = counts.get(item.topic, 0) + 1
            first.setdefault(item.topic, item.log_time_ns)
            last[item.topic] = item.log_time_ns
        self.stopped_at = self._stop
        types: dict[str, str] = {}
        for topic, msgtype in self.conns.values():
            types.setdefault(topic, msgtype)
        for topic, msgtype in types.items():
            _merge_topic(self.topics, TopicInfo(topic, msgtype, counts.get(topic, 0), first.get(topic),
                                                last.get(topic)))
        self.types = _TypeRegistry(defs, None)
        self.start_ns = min(first.values()) if first else None
        self.end_ns = max(last.values()) if last else None

    def _records(self, wanted: set[str] | None, defs: dict[str, tuple[str, str]]) -> Iterator[RawMessage]:
        """All messages (wanted None: count every topic; ``set()`` also means every topic)."""
        from rosbags.rosbag1.reader import Header, decompressors

        self._stop = None
        n = 0
        counts: dict[str, int] = {}
        with self.path.open("rb") as f:
            f.readline()  # magic, checked by the caller
            while True:
                pos = f.tell()
                head = f.read(4)
                if not head:
                    return
                try:
                    if len(head) < 4:
                        raise LogReadError("record cut off")
                    f.seek(pos)
                    header = Header.read(f)
                    size_b = f.read(4)
                    if len(size_b) < 4:
                        raise LogReadError("record cut off")
                    size = int.from_bytes(size_b, "little")
                    data = f.read(size)
                    op = header.get_uint8("op")
                    cut = len(data) < size
                    if cut and not (op == 5 and header.get_string("compression") == "none"):
                        raise LogReadError("record cut off")
                    if op == 7:
                        self._connection(header, data, defs)
                    elif op == 2:
                        item = self._message(header, data, counts, wanted)
                        if item is not None:
                            n += 1
                            yield item
                    elif op == 5:
                        comp = header.get_string("compression")
                        if comp not in decompressors:
                            raise LogReadError(f"chunk compression {comp!r} is not supported")
                        inner = decompressors[comp](data)
                        for item in self._chunk(inner, counts, wanted, defs):
                            n += 1
                            yield item
                        if cut:
                            raise LogReadError("chunk cut off")
                except Exception as err:  # noqa: BLE001 - damaged or cut-off record
                    self._stop = _stop_text(self.path, n, pos, err)
                    return

    def _connection(self, header: Any, data: bytes, defs: dict[str, tuple[str, str]]) -> None:
        import io

        from rosbags.rosbag1.reader import Header

        conn = header.get_uint32("conn")
        topic = header.get_string("topic")
        topic = topic if topic.startswith("/") else "/" + topic
        inner = Header.read(io.BytesIO(int.to_bytes(len(data), 4, "little") + data))
        msgtype = normalize_type(inner.get_string("type"))
        self.conns[conn] = (topic, msgtype)
        defs.setdefault(msgtype, ("msg", inner.get_string("message_definition")))

    def _message(self, header: Any, data: bytes, counts: dict[str, int], wanted: set[str] | None):
        conn = self.conns.get(header.get_uint32("conn"))
        if conn is None:
            raise LogReadError("message before its connection record")
        topic, msgtype = conn
        if wanted and topic not in wanted:
            return None
        i = counts.get(topic, 0)
        counts[topic] = i + 1
        t = header.get_time("time")
        return RawMessage(t, topic, i, _deser(self.types, data, msgtype, ros1=True)
                          if hasattr(self, "types") else _never)

    def _chunk(self, inner: bytes, counts, wanted, defs) -> Iterator[RawMessage]:
        import io

        from rosbags.rosbag1.reader import Header

        bio = io.BytesIO(inner)
        end = len(inner)
        while bio.tell() < end:
            start = bio.tell()
            try:
                header = Header.read(bio)
                size = int.from_bytes(bio.read(4), "little")
                data = bio.read(size)
            except Exception:  # noqa: BLE001 - cut inside an uncompressed chunk
                bio.seek(start)
                raise LogReadError("chunk cut off") from None
            if len(data) < size:
                raise LogReadError("chunk cut off")
            op = header.get_uint8("op")
            if op == 7:
                self._connection(header, data, defs)
            elif op == 2:
                item = self._message(header, data, counts, wanted)
                if item is not None:
                    yield item

    def iter(self, topics: set[str]) -> Iterator[RawMessage]:
        if topics:
            yield from self._records(topics, {})
        self.stopped_at = self._stop or self.stopped_at


def _never() -> Any:  # pragma: no cover - counting pass never decodes
    raise RuntimeError("not decodable in the counting pass")


# ----------------------------------------------------------------------------- ROS 2 bags


class _CSafeYAML:
    """Stand-in for ``ruamel.yaml.YAML(typ="safe")`` in rosbags' rosbag2 reader: PyYAML's libyaml
    loader (CSafeLoader) reads metadata.yaml and its QoS strings ~20x faster than ruamel's pure
    Python one (0.1 s of `ltmap info` on a small bag). Parse errors are re-raised as ruamel's
    YAMLError, which the reader reports."""

    def __init__(self, typ: str = "safe", **_kw: Any):
        self.typ = typ

    def load(self, text: str) -> Any:
        import yaml
        from ruamel.yaml.error import YAMLError

        try:
            return yaml.load(text, Loader=yaml.CSafeLoader)  # noqa: S506 - the C *safe* loader
        except yaml.YAMLError as err:
            raise YAMLError(str(err)) from None


def _use_c_yaml() -> None:
    try:
        import yaml
        from rosbags.rosbag2 import reader
    except ImportError:  # pragma: no cover - rosbags is a dependency
        return
    if getattr(yaml, "CSafeLoader", None) is not None and getattr(reader, "YAML", None) is not _CSafeYAML:
        reader.YAML = _CSafeYAML


class Ros2BagSource(Source):
    def __init__(self, path: Path):
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.rosbag2 import Reader

        _use_c_yaml()
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

    def iter(self, topics: set[str]) -> Iterator[RawMessage]:
        conns = [c for c in self.reader.connections if c.topic in topics]
        if not conns:
            return
        counts: dict[str, int] = {}
        n = 0
        try:
            for conn, t, raw in self.reader.messages(connections=conns):
                i = counts.get(conn.topic, 0)
                counts[conn.topic] = i + 1
                n += 1
                yield RawMessage(t, conn.topic, i, _deser(self.types, raw, conn.msgtype, ros1=False))
        except Exception as err:  # noqa: BLE001 - damaged storage: stop here, report where
            self.stopped_at = _stop_text(self.path, n, None, err)

    def close(self) -> None:
        self.reader.close()


# ----------------------------------------------------------------------------- MCAP


class McapSource(Source):
    def __init__(self, path: Path, fmt: str | None = None):
        from mcap.reader import SeekingReader

        self.path = path
        self.file = path.open("rb")
        self._decoders: dict[int, Callable[[bytes], Any] | None] = {}
        self._factories = _mcap_factories()
        summary = None
        try:
            self.reader = SeekingReader(self.file, validate_crcs=True, decoder_factories=self._factories)
            summary = self.reader.get_summary()
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
            for item in self._stream(None):
                counts[item.topic] = counts.get(item.topic, 0) + 1
                first.setdefault(item.topic, item.log_time_ns)
                last[item.topic] = item.log_time_ns
            self.stopped_at = self._stop
            for ch in self.channels.values():
                _merge_topic(self.topics, TopicInfo(ch.topic, self._type(ch), counts.get(ch.topic, 0),
                                                    first.get(ch.topic), last.get(ch.topic)))
            self.start_ns = min(first.values()) if first else None
            self.end_ns = max(last.values()) if last else None
        profiles = {"ros1" if ch.message_encoding == "ros1" else "ros2" for ch in self.channels.values()}
        self.fmt = fmt or ("mcap-ros1" if profiles == {"ros1"} else "mcap-ros2")

    def _type(self, ch: Any) -> str:
        schema = self.schemas.get(ch.schema_id)
        return normalize_type(schema.name) if schema is not None else "(no schema)"

    def _decoder(self, ch: Any) -> Callable[[bytes], Any] | None:
        if ch.id not in self._decoders:
            schema = self.schemas.get(ch.schema_id)
            dec = None
            for factory in self._factories:
                dec = factory.decoder_for(ch.message_encoding, schema)
                if dec is not None:
                    break
            self._decoders[ch.id] = dec
        return self._decoders[ch.id]

    def _thunk(self, ch: Any, data: bytes) -> Callable[[], Any]:
        def decode(data: bytes) -> Any:
            dec = self._decoder(ch)
            if dec is None:
                raise LogReadError(f"no decoder for message encoding {ch.message_encoding!r} "
                                   f"(ltmap reads ros1 and cdr)")
            return dec(data)

        return Thunk(decode, data, ch.message_encoding)

    def _stream(self, wanted: set[str] | None) -> Iterator[RawMessage]:
        from mcap.records import Channel, Message, Schema
        from mcap.stream_reader import StreamReader

        self._stop = None
        n = 0
        counts: dict[str, int] = {}
        with self.path.open("rb") as f:
            try:
                for record in StreamReader(f, skip_magic=False, validate_crcs=True).records:
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
            except Exception as err:  # noqa: BLE001 - truncated or corrupt: stop here
                self._stop = _stop_text(self.path, n, _tell(f), err)

    def iter(self, topics: set[str]) -> Iterator[RawMessage]:
        if not topics:
            return
        if not self.indexed:
            yield from self._stream(topics)
            self.stopped_at = self._stop
            return
        counts: dict[str, int] = {}
        n = 0
        damaged: list[str] = []
        for ch, msg in self._indexed_messages(topics, damaged):
            i = counts.get(ch.topic, 0)
            counts[ch.topic] = i + 1
            n += 1
            yield RawMessage(msg.log_time, ch.topic, i, self._thunk(ch, msg.data))
        if damaged:
            self.stopped_at = (f"{self.path}: skipped {len(damaged)} damaged chunk{'s' if len(damaged) > 1 else ''} "
                               f"and read the rest ({n} messages): {'; '.join(damaged[:3])}"
                               + (f"; and {len(damaged) - 3} more" if len(damaged) > 3 else ""))  # fmt: skip

    def _indexed_messages(self, topics: set[str], damaged: list[str]) -> Iterator[tuple[Any, Any]]:
        """(channel, message) of ``topics`` in log-time order, chunk by chunk through the summary's
        chunk indexes (as mcap's SeekingReader does). A chunk that cannot be read (CRC mismatch,
        bad compression, cut short) is skipped and described in ``damaged``: the chunks after it
        are still read, so one bad block of the disk loses its own seconds of log only."""
        import heapq
        import io

        from mcap.data_stream import ReadDataStream
        from mcap.records import Chunk, Message
        from mcap.stream_reader import breakup_chunk

        summary = self.reader.get_summary()
        ids = {cid for cid, ch in summary.channels.items() if ch.topic in topics}
        heap: list[tuple] = []
        for ci in summary.chunk_indexes:
            if ci.message_index_offsets and not ids.intersection(ci.message_index_offsets):
                continue  # no message of these topics in it
            heap.append((ci.message_start_time, 0, ci.chunk_start_offset, 0, ci))
        heapq.heapify(heap)
        t0 = self.start_ns or 0
        while heap:
            item = heapq.heappop(heap)
            if item[1] == 1:
                yield item[4]
                continue
            ci = item[4]
            try:
                self.file.seek(ci.chunk_start_offset + 1 + 8, io.SEEK_SET)
                chunk = Chunk.read(ReadDataStream(self.file))
                records = list(breakup_chunk(chunk, validate_crc=True))
            except Exception as err:  # noqa: BLE001 - a damaged chunk: skip it, say which
                reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
                damaged.append(f"the chunk at byte {ci.chunk_start_offset} (log time "
                               f"{(ci.message_start_time - t0) / 1e9:.1f} to {(ci.message_end_time - t0) / 1e9:.1f} s: "
                               f"its messages are lost; {reason})")  # fmt: skip
                continue
            for index, record in enumerate(records):
                if isinstance(record, Message) and record.channel_id in ids:
                    heapq.heappush(heap, (record.log_time, 1, ci.chunk_start_offset, index,
                                          (summary.channels[record.channel_id], record)))  # fmt: skip

    def close(self) -> None:
        self.file.close()


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


def open_source(path: Path) -> list[Source]:
    """Open one log (a ROS 2 bag folder may give several sources); ``InputError`` / ``LogReadError`` name the file and what to do."""
    if not path.exists():
        raise InputError(f"log not found: {path}; {_KINDS}")
    if path.is_file() and (path.name == "metadata.yaml" or path.suffix == ".db3") \
            and (path.parent / "metadata.yaml").is_file():
        path = path.parent
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise InputError(f"{path} is a folder without metadata.yaml, not a ROS 2 bag; {_KINDS}")
        return _open_ros2(path)
    if path.stat().st_size == 0:
        raise InputError(f"log {path} is empty (0 bytes); the recording did not write anything")
    with path.open("rb") as f:
        head = f.read(16)
    if head.startswith(ROS1_MAGIC[:9]):
        if not head.startswith(ROS1_MAGIC[:12]):
            raise InputError(f"{path} is a ROS 1 bag of an unsupported version ({head[:12]!r}); "
                             f"only bag format 2.0 is read: migrate it with `rosbag fix`")
        try:
            return [Ros1BagSource(path)]
        except _NeedsStreaming:
            return [Ros1StreamSource(path)]
    if head.startswith(MCAP_MAGIC[:6]):
        return [McapSource(path)]
    if head.startswith(SQLITE_MAGIC):
        return _open_ros2(path)
    raise InputError(f"{path} is not a robot log (it starts with {head[:8]!r}); {_KINDS}")


def _open_ros2(path: Path) -> list[Source]:
    mcaps = sorted(path.glob("*.mcap")) if path.is_dir() else []
    if mcaps:  # mcap storage: the mcap package streams it, and reads what a cut-off file still has
        return [McapSource(m, fmt="ros2-mcap") for m in mcaps]
    try:
        return [Ros2BagSource(path)]
    except FileNotFoundError as err:
        raise InputError(f"ROS 2 bag {path}: {err}; the bag folder is incomplete") from None
    except Exception as err:  # noqa: BLE001 - rosbags and sqlite3 raise several kinds
        reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise LogReadError(f"cannot read ROS 2 bag {path}: {reason}; the bag is corrupt or cut off and "
                           f"nothing in it can be read") from None


__all__ = ["TopicInfo", "RawMessage", "Source", "Thunk", "open_source", "normalize_type"]
