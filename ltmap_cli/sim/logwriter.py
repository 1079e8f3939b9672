"""Write ROS messages as MCAP (ros2 profile, CDR), a ROS 1 bag or a ROS 2 bag folder.

Messages are plain nested dicts with ROS 2 field names (``k``, ``d``; matched case-insensitively,
so a ROS 1 bag gets ``K``/``D``); missing fields get zeros. Header stamps and builtin times are
integer nanoseconds. Serialization is rosbags' typestore (CDR or ROS 1), so every format holds the
same bytes a ROS node would send. Nothing in the output depends on the wall clock: the same
messages give byte-identical files.

A file (MCAP, ROS 1 bag) is written beside its target under a temporary name and renamed. A ROS 2
bag folder is written at the path given, which must not exist: ``sim.simulate`` gives a path in an
``OutputFolder``'s staging folder, swapped in as a whole.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..io.atomic import current_umask

FORMATS = ("mcap", "ros1", "ros2")
LIBRARY = "ltmap simulate"

_TIME = ("builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration")
_NUMPY = {
    "bool": np.bool_,
    "int8": np.int8,
    "uint8": np.uint8,
    "byte": np.uint8,
    "char": np.uint8,
    "int16": np.int16,
    "uint16": np.uint16,
    "int32": np.int32,
    "uint32": np.uint32,
    "int64": np.int64,
    "uint64": np.uint64,
    "float32": np.float32,
    "float64": np.float64,
}


def typestore(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in ts.fielddefs:  # the ROS 1 store lacks it
        ts.register(
            get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
        )
    return ts


def build(ts: Any, msgtype: str, value: dict | None) -> Any:
    """A typestore message object of ``msgtype`` from a plain dict (missing fields: zero)."""
    from rosbags.typesys.base import Nodetype

    value = {k.lower(): v for k, v in (value or {}).items()}
    kwargs = {}
    for name, (node, desc) in ts.fielddefs[msgtype][1]:
        v = value.get(name.lower())
        if node == Nodetype.NAME:
            if desc in _TIME:
                ns = int(v or 0)
                v = ts.types[desc](sec=ns // 10**9, nanosec=ns % 10**9)
            else:
                v = build(ts, desc, v)
        elif node == Nodetype.BASE:
            v = ("" if desc[0] == "string" else 0) if v is None else v
        else:
            (enode, edesc), length = desc
            if enode == Nodetype.BASE:
                if edesc[0] == "string":
                    v = list(v or [""] * length)
                else:
                    v = np.asarray(v if v is not None else np.zeros(length), dtype=_NUMPY[edesc[0]])
            else:
                v = [build(ts, edesc, x) for x in (v or [])]
        kwargs[name] = v
    return ts.types[msgtype](**kwargs)


class LogWriter:
    """``with LogWriter(path, fmt) as w: w.write(topic, msgtype, log_time_ns, fields)``."""

    def __init__(self, path: str | Path, fmt: str = "mcap", chunk_size: int = 4 * 1024 * 1024):
        if fmt not in FORMATS:
            raise InputError(f"--format {fmt}: unknown log format; use one of {', '.join(FORMATS)}")
        self.path = Path(path)
        self.fmt = fmt
        self.chunk_size = chunk_size
        self.ts = typestore(fmt == "ros1")
        self._conns: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    # -- lifecycle ------------------------------------------------------------------------
    def __enter__(self) -> LogWriter:
        target = self.path
        if self.fmt == "ros2":
            if target.exists():
                raise InputError(f"-o {target}: exists; a ROS 2 bag folder is written into a new folder")
            target.parent.mkdir(parents=True, exist_ok=True)
            self._tmpdir = self._tmp = target
        else:
            if target.is_dir():
                raise InputError(
                    f"-o {target}: is a folder; give a file name ending in "
                    f"{'.bag' if self.fmt == 'ros1' else '.mcap'}"
                )
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(
                prefix=f".{target.stem}.", suffix=f".tmp{target.suffix}", dir=target.parent
            )
            os.close(fd)
            self._tmp = Path(tmp)
            self._tmpdir = None
        try:
            self._open()
        except BaseException:
            self._cleanup()
            raise
        return self

    def _open(self) -> None:
        if self.fmt == "mcap":
            from mcap.writer import CompressionType, Writer

            self._file = self._tmp.open("wb")
            self._w = Writer(self._file, chunk_size=self.chunk_size, compression=CompressionType.ZSTD)
            self._w.start(profile="ros2", library=LIBRARY)
            self._schemas: dict[str, int] = {}
        elif self.fmt == "ros1":
            from rosbags.rosbag1 import Writer as Writer1

            self._tmp.unlink()  # the bag writer refuses an existing file
            self._w = Writer1(self._tmp)
            self._w.set_compression(Writer1.CompressionFormat.LZ4)
            self._w.open()
        else:
            from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
            from rosbags.rosbag2 import Writer as Writer2

            self._w = Writer2(self._tmp, version=9, storage_plugin=StoragePlugin.MCAP)
            self._w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            self._w.open()

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            with contextlib.suppress(Exception):
                self._close_writer()
            self._cleanup()
            return
        try:
            self._close_writer()
            if self.fmt != "ros2":
                os.chmod(self._tmp, 0o666 & ~current_umask())
                os.replace(self._tmp, self.path)
        except BaseException:
            self._cleanup()
            raise

    def _close_writer(self) -> None:
        if self.fmt == "mcap":
            self._w.finish()
            self._file.close()
        else:
            self._w.close()

    def _cleanup(self) -> None:
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
        elif self._tmp.exists():
            self._tmp.unlink()

    # -- writing --------------------------------------------------------------------------
    def write(
        self, topic: str, msgtype: str, log_time_ns: int, fields: dict, *, latching: bool = False
    ) -> None:
        ts = self.ts
        obj = build(ts, msgtype, fields)
        if topic not in self._conns:
            self._conns[topic] = self._connection(topic, msgtype, latching)
            self.counts[topic] = 0
        conn = self._conns[topic]
        if self.fmt == "mcap":
            data = ts.serialize_cdr(obj, msgtype)
            self._w.add_message(
                conn,
                log_time=log_time_ns,
                data=bytes(data),
                publish_time=log_time_ns,
                sequence=self.counts[topic],
            )
        elif self.fmt == "ros1":
            self._w.write(conn, log_time_ns, ts.serialize_ros1(obj, msgtype))
        else:
            self._w.write(conn, log_time_ns, ts.serialize_cdr(obj, msgtype))
        self.counts[topic] += 1

    def _connection(self, topic: str, msgtype: str, latching: bool) -> Any:
        ts = self.ts
        if self.fmt == "mcap":
            if msgtype not in self._schemas:
                text = ts.generate_msgdef(msgtype, ros_version=2)[0]
                self._schemas[msgtype] = self._w.register_schema(msgtype, "ros2msg", text.encode())
            return self._w.register_channel(topic, "cdr", self._schemas[msgtype])
        if self.fmt == "ros1":
            return self._w.add_connection(topic, msgtype, typestore=ts, latching=1 if latching else None)
        return self._w.add_connection(topic, msgtype, typestore=ts)
