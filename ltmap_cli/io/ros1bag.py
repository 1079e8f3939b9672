"""ROS 1 bag (format 2.0) records, read by ltmap itself: bounded, and robust to damage.

Two ways in, as ``rosbag`` has them:

- **indexed**: the bag header points to the index at the end (connection records and one chunk
  info per chunk, each with its message count per connection and time range), and every chunk
  is followed by its index data records (per connection: time and offset of each message). All
  of it is checked (sizes, counts, versions, offsets inside the file); the chunks are then read
  in time order, only those holding a wanted connection.
- **scan** (``rosbag reindex``'s way), when the index is missing (a bag still being recorded, or
  killed), cut off, or inconsistent in any way (an old bag with odd index records, flipped
  bytes): every record is read from the start; chunks are opened to count their messages and
  find their connections. A chunk that cannot be read (bad compression, bad records inside,
  cut off) is skipped and named; a record whose framing is broken is skipped by searching for the
  next chunk record.

Every size a record declares is checked against the file and the limit before it is read or
decompressed (``bounded``): a 7 kB bag cannot make ltmap allocate gigabytes.
"""

from __future__ import annotations

import heapq
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from .bounded import DecompressError, TooLargeError, decompress, too_large
from .skip import SkipBefore, unread_chunks

MAGIC = b"#ROSBAG V2.0\n"
MAX_HEADER = 1 << 20  # a record header is tens of bytes; a connection's definitions a few kB
OP_MSG, OP_BAGHEADER, OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7


class RecordError(ValueError):
    """A record that cannot be parsed where it should be."""


class CutOff(RecordError):
    """The file ends inside a record."""


def parse_header(buf: bytes) -> dict[str, bytes]:
    """The ``name=value`` fields of a record header (each with its 4-byte length)."""
    fields: dict[str, bytes] = {}
    pos, n = 0, len(buf)
    while pos < n:
        if pos + 4 > n:
            raise RecordError("header field length cut off")
        (size,) = struct.unpack_from("<I", buf, pos)
        pos += 4
        if size > n - pos:
            raise RecordError("header field runs past its header")
        item = buf[pos : pos + size]
        pos += size
        eq = item.find(b"=")
        if eq <= 0:
            raise RecordError("header field without a name")
        try:
            name = item[:eq].decode("ascii")
        except UnicodeDecodeError:
            raise RecordError("header field name is not text") from None
        fields[name] = bytes(item[eq + 1 :])
    return fields


def _u(fields: dict[str, bytes], name: str, fmt: str) -> int:
    try:
        return struct.unpack(fmt, fields[name])[0]
    except KeyError:
        raise RecordError(f"record without its {name} field") from None
    except struct.error:
        raise RecordError(f"record field {name} has the wrong size") from None


def op_of(fields: dict[str, bytes]) -> int:
    return _u(fields, "op", "<B")


def time_of(fields: dict[str, bytes], name: str = "time") -> int:
    sec, nsec = struct.unpack("<II", fields[name]) if len(fields.get(name, b"")) == 8 else (None, None)
    if sec is None:
        raise RecordError(f"record without a valid {name} field")
    return sec * 1_000_000_000 + nsec


def text_of(fields: dict[str, bytes], name: str) -> str:
    try:
        return fields[name].decode("utf-8")
    except KeyError:
        raise RecordError(f"record without its {name} field") from None
    except UnicodeDecodeError:
        raise RecordError(f"record field {name} is not UTF-8 text") from None


@dataclass
class Record:
    pos: int  # where the record starts
    fields: dict[str, bytes]
    data_pos: int
    data_len: int

    @property
    def end(self) -> int:
        return self.data_pos + self.data_len


def read_record(f: BinaryIO, pos: int, file_size: int, limit: int, read_data: bool = True
                ) -> tuple[Record, bytes | None]:
    """The record at ``pos`` and (``read_data``) its data; sizes checked before reading."""
    if pos + 4 > file_size:
        raise CutOff("record cut off")
    f.seek(pos)
    (hlen,) = struct.unpack("<I", f.read(4))
    if hlen > MAX_HEADER:
        raise RecordError(f"record header declares {hlen} bytes")
    if pos + 4 + hlen + 4 > file_size:
        raise CutOff("record cut off")
    fields = parse_header(f.read(hlen))
    (dlen,) = struct.unpack("<I", f.read(4))
    data_pos = pos + 8 + hlen
    rec = Record(pos, fields, data_pos, dlen)
    if data_pos + dlen > file_size:  # first: a length past the end is a cut (or a damaged length)
        raise CutOff("record cut off")
    if dlen > limit:
        raise too_large(f"the record at byte {pos}", dlen, limit)
    data = f.read(dlen) if read_data else None
    return rec, data


def records_in(buf: bytes) -> Iterator[tuple[dict[str, bytes], memoryview]]:
    """(header fields, data) of every record in a chunk's uncompressed bytes."""
    view = memoryview(buf)
    pos, n = 0, len(buf)
    while pos < n:
        if pos + 4 > n:
            raise RecordError("a record inside the chunk is cut off")
        (hlen,) = struct.unpack_from("<I", buf, pos)
        if hlen > n - pos - 8:
            raise RecordError("a record header inside the chunk runs past it")
        fields = parse_header(buf[pos + 4 : pos + 4 + hlen])
        (dlen,) = struct.unpack_from("<I", buf, pos + 4 + hlen)
        start = pos + 8 + hlen
        if dlen > n - start:
            raise RecordError("a record inside the chunk runs past it")
        yield fields, view[start : start + dlen]
        pos = start + dlen


@dataclass
class Connection:
    id: int
    topic: str
    msgtype: str  # as in the bag: sensor_msgs/LaserScan
    msgdef: str


def connection_of(fields: dict[str, bytes], data: bytes | memoryview) -> Connection:
    cid = _u(fields, "conn", "<I")
    topic = text_of(fields, "topic")
    inner = parse_header(bytes(data))
    msgtype = text_of(inner, "type")
    if not topic or not msgtype or "/" not in msgtype or len(topic) > 1024 or len(msgtype) > 256:
        raise RecordError("connection record with a bad topic or type")
    msgdef = inner.get("message_definition", b"").decode("utf-8", "replace")
    return Connection(cid, topic if topic.startswith("/") else "/" + topic, msgtype, msgdef)


@dataclass
class Chunk:
    """A chunk record (or one message record outside any chunk) and what is known of it."""

    pos: int
    start_ns: int
    end_ns: int
    counts: dict[int, int] = field(default_factory=dict)  # connection id -> messages


class BadIndex(Exception):
    """The bag's index is missing or cannot be trusted: read it by scanning."""


@dataclass
class BagLayout:
    connections: dict[int, Connection]
    chunks: list[Chunk]
    first: dict[int, int]  # connection -> first / last message time
    last: dict[int, int]
    indexed: bool
    problems: list[str] = field(default_factory=list)  # damaged chunks and records seen while scanning
    index_problem: str | None = None  # why the index was not used
    stop: tuple[int, str] | None = None  # (byte, reason) where the file ends inside a record


class Ros1Bag:
    """A ROS 1 bag: ``layout`` (indexed or scanned) and ``messages()`` in time order."""

    def __init__(self, path: Path, limit: int):
        self.path = path
        self.limit = limit
        self.f = path.open("rb")
        self.size = os.fstat(self.f.fileno()).st_size
        self.index_pos = 0  # where the bag header says the index starts (0: unknown)
        try:
            if self.f.readline(64) != MAGIC:
                raise RecordError("not a ROS 1 bag v2.0")
            self.header_end = self.f.tell()
            try:
                self.layout = self._indexed()
            except BadIndex as err:
                self.layout = self._scan()
                self.layout.index_problem = str(err)
        except BaseException:
            self.f.close()
            raise

    def close(self) -> None:
        self.f.close()

    # ------------------------------------------------------------------ the index

    def _indexed(self) -> BagLayout:
        try:
            rec, _ = read_record(self.f, self.header_end, self.size, self.limit)
            if op_of(rec.fields) != OP_BAGHEADER:
                raise BadIndex("the bag header record is missing")
            index_pos = _u(rec.fields, "index_pos", "<Q")
            n_conn = _u(rec.fields, "conn_count", "<I")
            n_chunk = _u(rec.fields, "chunk_count", "<I")
            self.index_pos = index_pos
            if "encryptor" in rec.fields and rec.fields["encryptor"]:
                raise BadIndex("the bag is encrypted")
        except (RecordError, TooLargeError) as err:
            raise BadIndex(f"bag header unreadable ({err})") from None
        if index_pos == 0:
            raise BadIndex("the bag has no index (it was not closed: still recording, or killed)")
        if not rec.end <= index_pos < self.size:
            raise BadIndex(f"the bag header points to byte {index_pos}, outside the file")
        if n_chunk > self.size // 16 or n_conn > self.size // 16:
            raise BadIndex("the bag header declares more chunks or connections than the file can hold")
        conns: dict[int, Connection] = {}
        chunks: list[Chunk] = []
        pos = index_pos
        try:
            for _ in range(n_conn):
                rec, data = read_record(self.f, pos, self.size, self.limit)
                if op_of(rec.fields) != OP_CONNECTION:
                    raise BadIndex(f"expected a connection record at byte {pos}")
                c = connection_of(rec.fields, data)
                conns[c.id] = c
                pos = rec.end
            for _ in range(n_chunk):
                rec, data = read_record(self.f, pos, self.size, self.limit)
                if op_of(rec.fields) != OP_CHUNK_INFO or _u(rec.fields, "ver", "<I") != 1:
                    raise BadIndex(f"expected a chunk info record (version 1) at byte {pos}")
                count = _u(rec.fields, "count", "<I")
                if len(data) != count * 8:
                    raise BadIndex(f"the chunk info at byte {pos} holds {len(data)} bytes for {count} connections")
                counts = dict(struct.iter_unpack("<II", data))
                cpos = _u(rec.fields, "chunk_pos", "<Q")
                if not self.header_end <= cpos < index_pos or any(k not in conns for k in counts):
                    raise BadIndex(f"the chunk info at byte {pos} names a chunk or connection that does not exist")
                chunks.append(Chunk(cpos, time_of(rec.fields, "start_time"), time_of(rec.fields, "end_time"),
                                    counts))
                pos = rec.end
        except (RecordError, TooLargeError) as err:
            raise BadIndex(f"its index records are damaged ({err})") from None
        first: dict[int, int] = {}
        last: dict[int, int] = {}
        for ch in chunks:
            self._check_chunk_index(ch, index_pos, first, last)
        return BagLayout(conns, chunks, first, last, indexed=True)

    def _check_chunk_index(self, ch: Chunk, index_pos: int, first: dict[int, int], last: dict[int, int]) -> None:
        """The chunk's record and its index data records agree with the chunk info (exact first
        and last times per connection come from them)."""
        try:
            rec, _ = read_record(self.f, ch.pos, self.size, self.limit, read_data=False)
            if op_of(rec.fields) != OP_CHUNK:
                raise BadIndex(f"no chunk at byte {ch.pos}, where the index says")
            declared = _u(rec.fields, "size", "<I")
            if declared > self.limit:
                raise too_large(f"{self.path}: the chunk at byte {ch.pos}", declared, self.limit)
            pos = rec.end
            for _ in range(len(ch.counts)):
                irec, data = read_record(self.f, pos, self.size, self.limit)
                if op_of(irec.fields) != OP_INDEX or _u(irec.fields, "ver", "<I") != 1:
                    raise BadIndex(f"expected an index data record (version 1) at byte {pos}")
                conn = _u(irec.fields, "conn", "<I")
                count = _u(irec.fields, "count", "<I")
                if len(data) != count * 12 or ch.counts.get(conn) != count:
                    raise BadIndex(f"the index data at byte {pos} disagrees with its chunk info")
                times = [s * 1_000_000_000 + ns for s, ns, _off in struct.iter_unpack("<III", data)]
                if times:
                    lo, hi = min(times), max(times)
                    if lo < ch.start_ns or hi > ch.end_ns:
                        raise BadIndex(f"the index data at byte {pos} has times outside its chunk's")
                    first[conn] = min(first.get(conn, lo), lo)
                    last[conn] = max(last.get(conn, hi), hi)
                pos = irec.end
        except TooLargeError:
            raise
        except RecordError as err:
            raise BadIndex(f"its index data records are damaged ({err})") from None

    # ------------------------------------------------------------------ scanning

    def _scan(self) -> BagLayout:
        """Every record from the start (as ``rosbag reindex``): chunks opened to count."""
        layout = BagLayout({}, [], {}, {}, indexed=False)
        pending: list[tuple[Chunk, list[tuple[int, int]]]] = []  # chunk, [(conn, time)]
        pos = self.header_end
        while pos < self.size:
            try:
                rec, data = self._record_for_scan(pos)
            except CutOffChunk as cut:  # an uncompressed chunk cut off: its whole messages count
                msgs = _salvage(cut.data, layout.connections)
                if msgs:
                    pending.append((Chunk(pos, min(t for _, t, _ in msgs), max(t for _, t, _ in msgs)),
                                    [(c, t) for c, t, _ in msgs]))
                layout.stop = (pos, str(cut))
                break
            except CutOff as err:
                nxt = self._resync(pos + 1)
                if nxt is None:  # the end of the file: a bag cut off
                    layout.stop = (pos, str(err))
                    break
                layout.problems.append(f"a record at byte {pos} runs past the end of the file (its length is "
                                       f"damaged); resumed at byte {nxt}")
                pos = nxt
                continue
            except RecordError as err:
                nxt = self._resync(pos + 1)
                if nxt is None and 0 < self.index_pos <= pos:
                    break  # the bag's own index, damaged: the note says so; no message is lost
                layout.problems.append(f"unreadable records at bytes {pos} to {nxt if nxt is not None else 'the end'} "
                                       f"({err})")
                if nxt is None:
                    break
                pos = nxt
                continue
            op = op_of(rec.fields) if "op" in rec.fields and len(rec.fields["op"]) == 1 else None
            if op == OP_CONNECTION:
                try:
                    c = connection_of(rec.fields, data)
                    layout.connections.setdefault(c.id, c)
                except RecordError as err:
                    layout.problems.append(f"the connection record at byte {pos} ({err})")
            elif op == OP_CHUNK:
                try:
                    msgs = list(self._chunk_messages(rec, data, layout.connections))
                    if msgs:
                        ch = Chunk(pos, min(t for _, t, _ in msgs), max(t for _, t, _ in msgs))
                        pending.append((ch, [(c, t) for c, t, _ in msgs]))
                except TooLargeError:
                    raise
                except (RecordError, DecompressError) as err:
                    layout.problems.append(f"the chunk at byte {pos} ({err})")
            elif op == OP_MSG:
                try:
                    conn, t = _u(rec.fields, "conn", "<I"), time_of(rec.fields)
                    pending.append((Chunk(pos, t, t), [(conn, t)]))
                except RecordError as err:
                    layout.problems.append(f"the message record at byte {pos} ({err})")
            pos = rec.end
        lost: dict[int, int] = {}
        for ch, msgs in pending:
            for conn, t in msgs:
                if conn not in layout.connections:
                    lost[conn] = lost.get(conn, 0) + 1
                    continue
                ch.counts[conn] = ch.counts.get(conn, 0) + 1
                layout.first[conn] = min(layout.first.get(conn, t), t)
                layout.last[conn] = max(layout.last.get(conn, t), t)
            if ch.counts:
                layout.chunks.append(ch)
        if lost:
            layout.problems.append(f"{sum(lost.values())} messages of connections without a connection record")
        return layout

    def _record_for_scan(self, pos: int) -> tuple[Record, bytes | None]:
        """The record at ``pos``; the data of a chunk cut off by the end of the file is read as
        far as it goes (an uncompressed chunk still gives its whole messages)."""
        try:
            return read_record(self.f, pos, self.size, self.limit)
        except CutOff:
            if pos + 4 > self.size:
                raise
            self.f.seek(pos)
            (hlen,) = struct.unpack("<I", self.f.read(4))
            if hlen > MAX_HEADER or pos + 8 + hlen > self.size:
                raise
            fields = parse_header(self.f.read(hlen))
            self.f.read(4)
            data = self.f.read(max(0, self.size - (pos + 12 + hlen)))
            if fields.get("op") == bytes([OP_CHUNK]) and fields.get("compression") == b"none":
                raise CutOffChunk(Record(pos, fields, pos + 8 + hlen, len(data)), data) from None
            raise

    def _resync(self, start: int) -> int | None:
        """The position of the next readable chunk record at or after ``start`` (None: none)."""
        needle = b"\x04\x00\x00\x00op=\x05"
        pos = start
        step = 1 << 20
        while pos < self.size:
            self.f.seek(pos)
            window = self.f.read(step + 64)
            j = window.find(needle)
            while j >= 0:
                at = pos + j
                # the op field first, or after compression=bz2|lz4 / compression=none (rosbag's order)
                for cand in (at - 4, at - 4 - 19, at - 4 - 20):
                    if cand >= start:
                        try:
                            rec, _ = read_record(self.f, cand, self.size, self.limit, read_data=False)
                            if op_of(rec.fields) == OP_CHUNK:
                                return cand
                        except (RecordError, TooLargeError):
                            pass
                j = window.find(needle, j + 1)
            pos += step
        return None

    def _chunk_messages(self, rec: Record, data: bytes | None, conns: dict[int, Connection]
                        ) -> Iterator[tuple[int, int, memoryview]]:
        """(connection, time, data) of the messages in a chunk record; connection records in
        it are added to ``conns``."""
        compression = text_of(rec.fields, "compression")
        declared = _u(rec.fields, "size", "<I")
        raw = decompress(compression, data or b"", declared, self.limit,
                         f"{self.path}: the chunk at byte {rec.pos}")
        for fields, body in records_in(raw):
            op = op_of(fields)
            if op == OP_CONNECTION:
                c = connection_of(fields, body)
                conns.setdefault(c.id, c)
            elif op == OP_MSG:
                yield _u(fields, "conn", "<I"), time_of(fields), body

    # ------------------------------------------------------------------ reading

    def messages(self, wanted: set[int], damaged: list[str], skip: SkipBefore | None = None
                 ) -> Iterator[tuple[int, int, Any]]:  # fmt: skip
        """(time, connection, data) of the wanted connections' messages in time order (file
        order among equal times). A chunk that cannot be read is skipped and described in
        ``damaged``. ``skip`` (its keep sets by connection id): the chunks whose messages all lie
        before ``skip.ns`` that ``io.skip.unread_chunks`` lets go are not read; each gives (its
        start, -1, {connection: messages}) in its place instead."""
        chunks = sorted((c for c in self.layout.chunks if wanted.intersection(c.counts)),
                        key=lambda c: (c.start_ns, c.pos))
        unread: set[int] = set()
        if skip is not None:
            early = [c for c in chunks if c.end_ns < skip.ns]
            unread = {early[k].pos for k in unread_chunks(early, lambda c: c.counts, lambda c: (c.end_ns, c.pos),
                                                          skip.keep_all, skip.keep_last)}  # fmt: skip
        heap: list[tuple[int, int, int, Any]] = []
        seq = 0
        k = 0
        while k < len(chunks) or heap:
            while k < len(chunks) and (not heap or chunks[k].start_ns <= heap[0][0]):
                ch = chunks[k]
                k += 1
                if ch.pos in unread:  # its place in time: the per-connection message counts go on
                    heapq.heappush(heap, (ch.start_ns, seq, -1, {c: n for c, n in ch.counts.items() if c in wanted}))
                    seq += 1
                    continue
                try:
                    for conn, t, body in self._read_chunk(ch):
                        if conn in wanted:
                            heapq.heappush(heap, (t, seq, conn, body))
                            seq += 1
                except TooLargeError:
                    raise
                except (RecordError, DecompressError, OSError, struct.error) as err:
                    damaged.append(f"the chunk at byte {ch.pos} ({err})")
            if heap:
                t, _, conn, body = heapq.heappop(heap)
                yield t, conn, body

    def _read_chunk(self, ch: Chunk) -> list[tuple[int, int, memoryview]]:
        try:
            rec, data = read_record(self.f, ch.pos, self.size, self.limit)
        except CutOff:
            try:
                self._record_for_scan(ch.pos)
            except CutOffChunk as cut:
                return [m for m in _salvage(cut.data, {}) if m[0] in self.layout.connections]
            raise
        op = op_of(rec.fields)
        if op == OP_MSG:
            return [(_u(rec.fields, "conn", "<I"), time_of(rec.fields), memoryview(data))]
        if op != OP_CHUNK:
            raise RecordError("not a chunk record")
        conns = self.layout.connections
        return [m for m in self._chunk_messages(rec, data, conns) if m[0] in conns]


class CutOffChunk(CutOff):
    """An uncompressed chunk cut off by the end of the file: its whole messages can be read."""

    def __init__(self, rec: Record, data: bytes):
        super().__init__("chunk cut off")
        self.rec = rec
        self.data = data


def _salvage(buf: bytes, conns: dict[int, Connection]) -> list[tuple[int, int, memoryview]]:
    """The whole messages (and connections, into ``conns``) of an uncompressed chunk cut off."""
    out = []
    try:
        for fields, body in records_in(buf):
            op = op_of(fields)
            if op == OP_MSG:
                out.append((_u(fields, "conn", "<I"), time_of(fields), body))
            elif op == OP_CONNECTION:
                c = connection_of(fields, body)
                conns.setdefault(c.id, c)
    except RecordError:
        pass  # the cut
    return out


__all__ = ["Ros1Bag", "BagLayout", "Connection", "Chunk", "RecordError", "CutOff", "MAGIC"]
