"""Read robot logs as one stream of plain frames in log-time order.

Formats: ROS 1 ``.bag`` (v2.0), ROS 2 bag folders (sqlite3 or mcap storage; the folder, its
``metadata.yaml`` or its ``.db3`` may be given), standalone ``.mcap`` (ros2 profile with CDR, or
ros1 messages). Several logs are merged into one stream by log time (a heap merge that opens a
log's stream when the merge reaches its first message: a recording split into many files is read
a file or two at a time); nothing is loaded whole: memory does not grow with log size.

API::

    from ltmap_cli.io.logs import open_logs

    with open_logs(paths, allow_truncated=False) as logs:      # -> LogSet
        logs.topics            # {name: TopicInfo(name, msgtype, count, first_ns, last_ns)}
        logs.start_ns, logs.end_ns
        sel = logs.select(scan_topics=[], cloud_topics=[], depth_topics=[])   # -> TopicSelection
        sel.skipped            # {topic: why it will not be used}
        for topic, log_time_ns, item in logs.messages(sel):
            # item: ScanFrame | CloudFrame | DepthFrame | TfSample | OdometrySample
            ...
        logs.stats             # ReadStats: messages read per topic; stopped_at for a cut-off log
        logs.skipped           # {reason: count} of messages read but not turned into frames

Topic selection (``select_topics``): LaserScan -> scans, PointCloud2 -> clouds, Image and
CompressedImage (image_transport's ``<image>/compressedDepth`` and ``<image>/compressed``:
``compressed_depth``) -> depth; of the same images on several transports, the raw Image is used,
else compressedDepth, else compressed.
With no names, every topic of those types is used, except Image topics whose name does not
contain ``depth`` (a colour camera) and depth topics without a CameraInfo. Naming any topic
(``scan_topics``, ``cloud_topics`` or ``depth_topics``) makes the choice exclusive: only the
named sensor topics are used (``--scan-topic /scan`` alone means laser only). Every TFMessage
topic (``/tf``, ``/tf_static``: static when the name ends in ``tf_static``) and every
nav_msgs/Odometry topic is always read. A depth Image is paired with the CameraInfo topic next
to it (``.../camera_info``), else with the log's only CameraInfo topic; the latest CameraInfo
seen is used; images before any CameraInfo are counted in ``skipped``.

Errors: a missing, empty or unrecognized path raises ``InputError``; an unreadable log raises
``LogReadError``; the same log given twice (as the same file, or a ROS 2 bag as its folder and its
``metadata.yaml``) raises ``InputError``; bad topic names raise ``InputError`` listing what the
log has. A log that is
cut off or corrupt is read up to the damage; at the end of the stream ``messages()`` raises
``TruncatedLogError`` (a ``LogReadError``) saying where reading stopped, unless
``allow_truncated`` is set, in which case ``stats.stopped_at`` records it. A message whose bytes
cannot be deserialized (damaged inside an intact log: a garbage row in a .db3, flipped bytes in a
.bag) is skipped and counted in ``skipped`` as ``cannot decode the message on <topic>``; the first
one per topic is reported as an ``LtmapWarning`` naming its message index (0-based, per topic and
file) and file, and the stream goes on. A message type the log has no definition or decoder for,
or a LaserScan whose increment cannot place its beams, raises ``LogReadError`` naming the topic,
message index and file (a LaserScan's ``angle_max`` is not needed: ``ScanFrame.angle_max_off``
tells when it disagrees). RealSense SDK bags: a depth image on ``.../<Stream>/image/data`` is
paired with ``.../<Stream>/info/camera_info`` and scaled by the sensor's ``Depth Units`` option
(``io.realsense``). Sensor frames carry ``log``: the index in ``paths`` of the log they come from.
"""

from __future__ import annotations

import heapq
import warnings
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from ..errors import InputError, LogReadError, LtmapWarning, bounded, first_line
from . import decode as dec
from . import realsense
from .bounded import DEFAULT_MAX_MESSAGE_MB
from .camera_file import OPTION as CAMERA_OPTION
from .frames import CloudFrame, DepthFrame, OdometrySample, ReadStats, ScanFrame, TfSample
from .skip import SkipBefore
from .sources import Source, TopicInfo, normalize_type, open_source

__all__ = [
    "open_logs", "LogSet", "TopicInfo", "TopicSelection", "select_topics", "TruncatedLogError",
    "normalize_type", "SCAN", "CLOUD", "IMAGE", "COMPRESSED", "CAMERA_INFO", "TF_TYPES", "ODOMETRY",
]

SCAN = "sensor_msgs/msg/LaserScan"
CLOUD = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"  # image_transport's compressedDepth / compressed (io.compressed_depth)
_SENSOR_KIND = {SCAN: SCAN, CLOUD: CLOUD, IMAGE: IMAGE, COMPRESSED: IMAGE}  # a compressed depth image is a depth image
TRANSPORTS = ("compressedDepth", "compressed")  # image_transport's topics for depth, beside the image, preferred first
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
ODOMETRY = "nav_msgs/msg/Odometry"
WINDOW_LEAD_S = 5.0  # messages(start_ns=, end_ns=): tf and odometry are read from this long before to after

Frame = ScanFrame | CloudFrame | DepthFrame | TfSample | OdometrySample


class TruncatedLogError(LogReadError):
    """A log ended early or is corrupt; everything before the damage was yielded."""


class _Undecodable(Exception):
    """One message's bytes could not be deserialized (the message is skipped, not the run)."""


@dataclass
class TopicSelection:
    """Which topics a replay reads, and why the others are not used."""

    scans: list[str] = field(default_factory=list)
    clouds: list[str] = field(default_factory=list)
    depths: dict[str, str] = field(default_factory=dict)  # depth image topic -> its CameraInfo topic
    depth_units: dict[str, str] = field(default_factory=dict)  # depth image topic -> its Depth Units topic
    given_info: dict[str, Any] = field(default_factory=dict)  # a depths value that is a --camera-info file: its CameraInfo
    tf: list[str] = field(default_factory=list)
    static_tf: list[str] = field(default_factory=list)  # subset of tf
    odometry: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)  # topic -> reason

    @property
    def sensor_topics(self) -> list[str]:
        return [*self.scans, *self.clouds, *self.depths]

    @property
    def topics(self) -> set[str]:
        """Every topic to read (sensors, their CameraInfo, tf and odometry)."""
        infos = {i for i in self.depths.values() if i not in self.given_info}
        return {*self.sensor_topics, *infos, *self.depth_units.values(), *self.tf, *self.odometry}


def _listing(topics: Mapping[str, TopicInfo]) -> str:
    return bounded(f"{t.name} ({t.msgtype})" for t in sorted(topics.values(), key=lambda t: t.name))


def image_base(topic: str) -> tuple[str, str | None]:
    """(the image topic, the image_transport transport) of a topic: ``/cam/depth/image_raw/compressedDepth``
    -> (``/cam/depth/image_raw``, ``compressedDepth``); a raw image topic -> (itself, None)."""
    head, _, last = topic.rpartition("/")
    return (head, last) if last in TRANSPORTS and head else (topic, None)


def _camera_info_for(image_topic: str, topics: Mapping[str, TopicInfo]) -> str | None:
    image_topic = image_base(image_topic)[0]
    sibling = image_topic.rsplit("/", 1)[0] + "/camera_info"
    if sibling in topics and topics[sibling].msgtype == CAMERA_INFO:
        return sibling
    rs = realsense.camera_info_topic(image_topic, topics)
    if rs is not None:
        return rs
    infos = [t.name for t in topics.values() if t.msgtype == CAMERA_INFO]
    return infos[0] if len(infos) == 1 else None


def select_topics(topics: Mapping[str, TopicInfo] | Iterable[TopicInfo], scan_topics: Sequence[str] = (),
                  cloud_topics: Sequence[str] = (), depth_topics: Sequence[str] = (), *,
                  require_sensor: bool = True, source: str = "the log",
                  given_info: Mapping[str, Any] | None = None) -> TopicSelection:
    """Choose the topics a replay uses (see the module doc). ``source`` names the log(s) in errors.
    ``given_info`` (``io.camera_file.load_camera_infos``): CameraInfos from files, by depth topic
    (used instead of the log's), "" for every depth topic that has none in the log."""
    given_info = dict(given_info or {})
    if not isinstance(topics, Mapping):
        topics = {t.name: t for t in topics}
    sel = TopicSelection()
    for t in sorted(topics.values(), key=lambda t: t.name):
        if t.msgtype in TF_TYPES:
            sel.tf.append(t.name)
            if t.name.rstrip("/").endswith("tf_static"):
                sel.static_tf.append(t.name)
        elif t.msgtype == ODOMETRY:
            sel.odometry.append(t.name)

    named = {SCAN: list(scan_topics), CLOUD: list(cloud_topics), IMAGE: list(depth_topics)}
    option = {SCAN: "--scan-topic", CLOUD: "--cloud-topic", IMAGE: "--depth-topic"}
    label = {SCAN: "LaserScan", CLOUD: "PointCloud2", IMAGE: "Image"}
    exclusive = any(named.values())
    chosen: dict[str, list[str]] = {SCAN: [], CLOUD: [], IMAGE: []}
    for kind, names in named.items():
        for name in names:
            key = name if name in topics else ("/" + name if "/" + name in topics else None)
            of_type = [t.name for t in topics.values() if _SENSOR_KIND.get(t.msgtype) == kind]
            if key is None:
                raise InputError(
                    f"{option[kind]} {name}: {source} has no topic {name}; its {label[kind]} topics: "
                    f"{bounded(sorted(of_type))}; all topics: {_listing(topics)}")
            if _SENSOR_KIND.get(topics[key].msgtype) != kind:
                raise InputError(
                    f"{option[kind]} {name}: topic {key} in {source} is {topics[key].msgtype}, not "
                    f"{label[kind]}; its {label[kind]} topics: {bounded(sorted(of_type))}")
            if key not in chosen[kind]:
                chosen[kind].append(key)

    # the same depth images on several of image_transport's topics (``rosbag record -a``): the raw
    # Image is used, else compressedDepth, else compressed
    rank = {None: 0, **{tr: i + 1 for i, tr in enumerate(TRANSPORTS)}}
    best: dict[str, TopicInfo] = {}
    for t in topics.values():
        if _SENSOR_KIND.get(t.msgtype) == IMAGE:
            base, transport = image_base(t.name)
            if base not in best or rank[transport] < rank[image_base(best[base].name)[1]]:
                best[base] = t
    for t in sorted(topics.values(), key=lambda t: t.name):
        kind = _SENSOR_KIND.get(t.msgtype)
        if kind is None:
            continue
        picked = t.name in chosen[kind]
        if exclusive and not picked:
            sel.skipped[t.name] = (f"{label[kind]} not chosen (only the topics named with --scan-topic/"
                                   f"--cloud-topic/--depth-topic are used)")
            continue
        if kind == SCAN:
            sel.scans.append(t.name)
        elif kind == CLOUD:
            sel.clouds.append(t.name)
        else:
            what = "Image" if t.msgtype == IMAGE else "CompressedImage"
            if not picked and "depth" not in t.name.lower():
                sel.skipped[t.name] = (f"{what} whose name does not say depth (a colour camera?); "
                                       "if it is 16UC1/mono16/32FC1 depth, choose it with --depth-topic")
                continue
            base, transport = image_base(t.name)
            if not picked and best[base] is not t:
                sel.skipped[t.name] = (f"the same depth images as {best[base].name}"
                                       + (f" (image_transport's {transport} transport)" if transport else "")
                                       + "; to use this topic instead, choose it with --depth-topic")
                continue
            given = given_info.get(t.name, given_info.get(base))
            info = None if given is not None else _camera_info_for(t.name, topics)
            if info is None and given is None:
                given = given_info.get("")
            if given is not None:
                info = f"{given.source} ({CAMERA_OPTION})"
                sel.given_info[info] = given
            if info is None:
                why = (f"depth {what} without CameraInfo: no {base.rsplit('/', 1)[0]}/camera_info (nor a RealSense "
                       f".../info/camera_info) and not exactly one CameraInfo topic in {source}")
                if picked:
                    raise InputError(f"--depth-topic {t.name}: {why}; a depth image cannot be placed "
                                     f"without its camera intrinsics: give them with {CAMERA_OPTION} FILE")
                sel.skipped[t.name] = why + f" (give its intrinsics with {CAMERA_OPTION} FILE)"
                continue
            sel.depths[t.name] = info
            units = realsense.depth_units_topic(t.name, topics)
            if units is not None:
                sel.depth_units[t.name] = units

    images = {n for n, t in topics.items() if _SENSOR_KIND.get(t.msgtype) == IMAGE}
    for name in given_info:
        if name and name not in images and not any(image_base(n)[0] == name for n in images):
            raise InputError(f"{CAMERA_OPTION} {name}=...: {source} has no depth image topic {name}; its image "
                             f"topics: {bounded(sorted(images))}")  # fmt: skip
    if require_sensor and not sel.sensor_topics:
        raise InputError(f"no usable LaserScan, PointCloud2 or depth Image topic in {source}; its topics: "
                         f"{_listing(topics)}" + (f"; skipped: {bounded(f'{k}: {v}' for k, v in sel.skipped.items())}"
                                                  if sel.skipped else ""))
    return sel


_SHARED_TOPICS = {"/tf_static", "/rosout", "/rosout_agg", "/parameter_events", "/robot_description"}


class LogSet:
    """One or several open logs; use as a context manager or call ``close()``."""

    def __init__(self, paths: Sequence[Path], sources: list[Source], allow_truncated: bool,
                 source_log: Sequence[int] | None = None):
        self.paths = list(paths)
        self.sources = sources
        # per source, the index in ``paths`` of the log it belongs to (a ROS 2 bag may be several files)
        self.source_log = list(source_log) if source_log is not None else list(range(len(sources)))
        self.allow_truncated = allow_truncated
        self.stats = ReadStats()
        self.skipped: Counter[str] = Counter()
        self.rate_skipped: Counter[str] = Counter()  # depth images dropped by depth_max_rate, per topic
        self.before_start: Counter[str] = Counter()  # messages before messages()'s start_ns, not decoded
        self._warned: set[str] = set()  # topics whose undecodable messages were reported
        self.topics: dict[str, TopicInfo] = {}
        for src in sources:
            for t in src.topics.values():
                have = self.topics.get(t.name)
                if have is None:
                    self.topics[t.name] = TopicInfo(t.name, t.msgtype, t.count, t.first_ns, t.last_ns)
                else:
                    have.count += t.count
                    if t.first_ns is not None:
                        have.first_ns = t.first_ns if have.first_ns is None else min(have.first_ns, t.first_ns)
                    if t.last_ns is not None:
                        have.last_ns = t.last_ns if have.last_ns is None else max(have.last_ns, t.last_ns)
        starts = [s.start_ns for s in sources if s.start_ns is not None]
        ends = [s.end_ns for s in sources if s.end_ns is not None]
        self.start_ns: int | None = min(starts) if starts else None
        self.end_ns: int | None = max(ends) if ends else None

    @property
    def name(self) -> str:
        return ", ".join(str(p) for p in self.paths)

    @property
    def formats(self) -> list[str]:
        """Per log given, its format; with the number of its files when it has several (a ROS 2
        bag split by rosbag2), e.g. "ros2-sqlite3, 3 files"."""
        out = []
        for k in range(len(self.paths)):
            fmts = [s.fmt for s, log in zip(self.sources, self.source_log) if log == k]
            files = f", {len(fmts)} files" if len(fmts) > 1 else ""
            out.append(", ".join(dict.fromkeys(fmts)) + files)
        return out

    def select(self, scan_topics: Sequence[str] = (), cloud_topics: Sequence[str] = (),
               depth_topics: Sequence[str] = (), *, require_sensor: bool = True,
               given_info: Mapping[str, Any] | None = None) -> TopicSelection:
        stops = [s.stopped_at for s in self.sources if s.stopped_at]
        try:
            sel = select_topics(self.topics, scan_topics, cloud_topics, depth_topics,
                                require_sensor=require_sensor, source=self.name, given_info=given_info)
        except InputError:
            if stops:  # the damage is the real problem
                raise TruncatedLogError(f"log is truncated or corrupt and has no usable sensor topic before "
                                        f"the damage: {'; '.join(stops)}") from None
            raise
        if require_sensor and not any(self.topics[t].count for t in sel.sensor_topics):
            where = f"; {'; '.join(stops)}" if stops else ""
            raise (TruncatedLogError if stops else InputError)(
                f"{self.name} has no message on its sensor topics ({', '.join(sel.sensor_topics[:5])}){where}")
        return sel

    def raw(self, topics: Iterable[str]) -> Iterator[tuple[str, int, Any, str]]:
        """``(topic, log_time_ns, decode, where)`` for ``topics`` in log-time order, undecoded:
        ``decode()`` returns the deserialized message. Cheap: use it to count. Truncation is
        handled as in ``messages``."""
        for topic, t, decode, where, _ in self._raw(topics):
            yield topic, t, decode, where

    def _raw(self, topics: Iterable[str], skip: SkipBefore | None = None) -> Iterator[tuple[str, int, Any, str, int]]:
        """``raw`` with the index (in ``paths``) of the log each message comes from; ``skip``: what
        the sources may leave unread (``sources.SkipBefore``)."""
        wanted = set(topics)
        streams = [self._tagged(src, wanted, k, skip) for k, src in enumerate(self.sources)]
        starts = [src.start_ns for src in self.sources]
        last: dict[str, tuple[int, int]] = {}  # topic -> (log time, source) of its last message
        twice: Counter[tuple[str, int, int]] = Counter()  # (topic, source a, source b) -> messages
        several = len(streams) > 1  # one log cannot repeat another
        n = self.stats.messages_per_topic
        try:
            for t, topic, decode, where, k in _merge(streams, starts):
                n[topic] = n.get(topic, 0) + 1
                if several:
                    prev = last.get(topic)
                    if prev is not None and prev[0] == t and prev[1] != k and topic not in _SHARED_TOPICS:
                        twice[(topic, prev[1], k)] += 1
                    last[topic] = (t, k)
                yield topic, t, decode, where, self.source_log[k]
        except GeneratorExit:  # the reader stopped early (a time window's end): what it read was read twice
            self._warn_twice(twice)
            raise
        finally:
            for st in streams:
                st.close()
        self._warn_twice(twice)
        self.finish()

    def _warn_twice(self, twice: Counter) -> None:
        if twice:
            (topic, a, b), count = twice.most_common(1)[0]
            pa, pb = self.sources[a].path, self.sources[b].path
            warnings.warn(LtmapWarning(
                f"{count} messages on {topic} are in both {pa} and {pb} at the same log times: the same "
                f"recording given twice (e.g. a .bag and its conversion)? Their frames were integrated twice; "
                f"give one of them"), stacklevel=3)  # fmt: skip

    @staticmethod
    def _tagged(src: Source, wanted: set[str], k: int,
                skip: SkipBefore | None = None) -> Iterator[tuple[int, str, Any, str, int]]:
        it = src.iter(wanted, skip)
        try:
            for m in it:
                yield m.log_time_ns, m.topic, m.decode, f"on {m.topic}, message index {m.index} in {src.path}", k
        finally:  # closed early (``messages`` past its end_ns): the source records what it read
            it.close()

    def finish(self) -> None:
        """Record (``stats.stopped_at``) the damage met in what was read, raising
        ``TruncatedLogError`` unless ``allow_truncated``: at the stream's end, or by a reader
        that stops early."""
        stops = [s.stopped_at for s in self.sources if s.stopped_at]
        if not stops:
            return
        self.stats.stopped_at = "; ".join(stops)
        if not self.allow_truncated:
            raise TruncatedLogError(f"log is truncated or corrupt: {self.stats.stopped_at}; to use what could "
                                    f"be read, pass --allow-truncated")

    def window_ns(self, start_s: float = 0.0, end_s: float = 0.0) -> tuple[int | None, int | None]:
        """``messages``' start_ns / end_ns for the window ``start_s`` .. ``end_s`` s after the log's
        first message (``replay.start_s`` / ``end_s``; 0: not bounded on that side)."""
        t0 = self.start_ns or 0
        return (t0 + int(round(start_s * 1e9)) if start_s > 0 else None,
                t0 + int(round(end_s * 1e9)) if end_s > 0 else None)  # fmt: skip

    def messages(self, selection: TopicSelection | None = None, *, fast: bool = False,
                 depth_max_rate: float = 0.0, start_ns: int | None = None,
                 end_ns: int | None = None, log_stamps: bool = False) -> Iterator[tuple[str, int, Frame]]:
        """``(topic, log_time_ns, item)`` in log-time order; item is a ScanFrame, CloudFrame,
        DepthFrame, TfSample (one per transform of a TFMessage) or OdometrySample.

        ``start_ns`` / ``end_ns`` (log times): only the sensor frames logged in [start_ns, end_ns];
        tf and odometry from ``WINDOW_LEAD_S`` before start_ns to as long after end_ns (the first
        and last frames' poses), /tf_static and CameraInfo from the log's start (the latest
        counts). The log is read up to start_ns without decoding its sensor messages, and reading
        stops after that trail (damage met up to there is reported as for the whole log).

        ``fast``: CDR messages of the high-rate types are read directly (``decode.CDR_PARSERS``;
        the same frames, anything unusual falls back to the generic deserializer) and depth images
        come as ``decode.RawDepthFrame`` (raw pixels, no float copy). ``depth_max_rate`` (Hz, 0:
        off): per depth topic, an image whose header stamp is less than 0.9 / rate after the last
        image passed on is dropped before it is decoded (counted in ``rate_skipped``).
        ``log_stamps`` (``replay.sensor_stamps=log``): sensor frames carry their record time as
        their stamp, not their header's (a sensor on its own clock)."""
        sel = selection if selection is not None else self.select()
        kinds: dict[str, str] = {}
        for t in sel.scans:
            kinds[t] = "scan"
        for t in sel.clouds:
            kinds[t] = "cloud"
        for t in sel.odometry:
            kinds[t] = "odom"
        for t in sel.tf:
            kinds[t] = "tf"
        infos_wanted: dict[str, list[str]] = {}
        for image, info in sel.depths.items():
            kinds[image] = "depth"
            infos_wanted.setdefault(info, []).append(image)
        for info in infos_wanted:
            if info not in sel.given_info:  # (a --camera-info file: not read from the log)
                kinds.setdefault(info, "info")
        for units_topic in sel.depth_units.values():
            kinds.setdefault(units_topic, "units")
        units: dict[str, float] = {}  # Depth Units topic -> metres per unit (RealSense SDK bags)
        parsers = {t: dec.CDR_PARSERS.get(self.topics[t].msgtype) if fast and t in self.topics else None
                   for t in kinds}
        min_gap = int(0.9e9 / depth_max_rate) if depth_max_rate > 0 else 0
        last_depth: dict[str, int] = {}
        static = set(sel.static_tf)
        latest_info: dict[str, Any] = {}  # topic -> (decode, where, parser) of its newest message
        good_info: dict[str, Any] = dict(sel.given_info)  # topic -> its newest message that could be decoded
        lead_ns = start_ns - int(WINDOW_LEAD_S * 1e9) if start_ns is not None else None
        skip = None
        if lead_ns is not None:  # what an indexed MCAP need not read: what lies before the lead, but /tf_static,
            # and the CameraInfo and depth units messages last before it
            skip = SkipBefore(lead_ns, frozenset(static & set(kinds)),
                              frozenset(t for t, k in kinds.items() if k in ("info", "units")))  # fmt: skip
        trail_ns = end_ns + int(WINDOW_LEAD_S * 1e9) if end_ns is not None else None
        stream = self._raw(kinds, skip)
        for topic, t, decode, where, log in stream:
            if trail_ns is not None and t > trail_ns:  # past the window and its tf: stop reading
                stream.close()
                self.finish()
                return
            kind = kinds[topic]
            if end_ns is not None and t > end_ns and kind not in ("tf", "odom"):
                continue  # after the window: only the tf that places its last frames
            if start_ns is not None and t < start_ns and (
                    kind in ("depth", "scan", "cloud") or (kind in ("tf", "odom") and t < lead_ns
                                                           and topic not in static)):  # fmt: skip
                self.before_start[topic] += 1  # not decoded
                continue
            parser = parsers[topic] if getattr(decode, "encoding", "") == "cdr" else None
            if kind == "info":
                latest_info[topic] = (decode, where, parser)
                continue
            if kind == "units":
                value = realsense.depth_units(self._decode_or_skip(topic, decode, where, None))
                if value is not None:
                    units[topic] = value
                continue
            if kind == "depth":
                info_topic = sel.depths[topic]
                if info_topic in latest_info:  # decoded only when an image needs it
                    pending = latest_info.pop(info_topic)
                    info = self._decode_or_skip(info_topic, *pending)
                    if info is not None:
                        good_info[info_topic] = info
                if info_topic not in good_info:
                    self.skipped[f"depth image on {topic} before any CameraInfo on {info_topic}"] += 1
                    continue
                if min_gap:
                    stamp = None
                    if parser is not None:
                        try:
                            stamp = dec.cdr_stamp_ns(decode.data)
                        except dec._NotFast:
                            stamp = None
                    msg = None
                    if stamp is None:
                        msg = self._decode_or_skip(topic, decode, where, None)
                        if msg is None:
                            continue
                        stamp = dec.stamp_ns(msg.header.stamp)
                    last = last_depth.get(topic)
                    if last is not None and stamp < last + min_gap:
                        self.rate_skipped[topic] += 1
                        continue
                    last_depth[topic] = stamp
                    if msg is None:
                        msg = self._decode_or_skip(topic, decode, where, parser)
                else:
                    msg = self._decode_or_skip(topic, decode, where, parser)
                if msg is None:
                    continue
                info = good_info[info_topic]
                scale = units.get(sel.depth_units.get(topic, ""))
                if self.topics[topic].msgtype == COMPRESSED:
                    frame = self._compressed_depth(topic, msg, info, where, scale, fast)
                    if frame is not None:
                        yield topic, t, _tag(frame, log, t if log_stamps else None)
                    continue
                if fast:
                    frame = dec.decode_depth_raw(msg, info, topic, where, units=scale)
                else:
                    frame = dec.decode_depth(msg, info, topic, where, units=scale)
                yield topic, t, _tag(frame, log, t if log_stamps else None)
                continue
            msg = self._decode_or_skip(topic, decode, where, parser)
            if msg is None:
                continue
            if kind == "scan":
                frame = dec.decode_scan(msg, topic, where)
                yield topic, t, _tag(frame, log, t if log_stamps else None)
            elif kind == "cloud":
                frame = dec.decode_cloud(msg, topic, where)
                yield topic, t, _tag(frame, log, t if log_stamps else None)
            elif kind == "tf":
                for s in dec.decode_tf(msg, static=topic in static):
                    yield topic, t, s
            else:
                yield topic, t, dec.decode_odometry(msg)

    def _compressed_depth(self, topic: str, msg: Any, info: Any, where: str, units: float | None,
                          fast: bool) -> dec.RawDepthFrame | DepthFrame | None:
        """The frame of a CompressedImage depth message (``io.compressed_depth``), or None when
        its pixels are damaged: counted and reported as an undecodable message."""
        from . import compressed_depth

        try:
            pixels = compressed_depth.decode(msg.data, msg.format, dec.intrinsics_size(info), where)
        except compressed_depth.DamagedPayload as err:
            self._undecodable(topic, f"cannot decode the message {where} ({err}); the message is damaged")
            return None
        return dec.depth_frame(msg.header, pixels, info, topic, where, units, fast)

    def _undecodable(self, topic: str, what: str) -> None:
        self.skipped[f"cannot decode the message on {topic}"] += 1
        if topic not in self._warned:
            self._warned.add(topic)
            warnings.warn(LtmapWarning(f"{what}; skipped it, and any other message on {topic} that cannot "
                                       f"be decoded (counted in report.json messages_not_decoded)"), stacklevel=3)

    def _decode_or_skip(self, topic: str, decode: Any, where: str, parser: Any) -> Any:
        """The message, or None when its bytes are damaged: then it is counted in ``skipped``
        and the first one of its topic is reported as an ``LtmapWarning``."""
        try:
            return self._decode(decode, where, parser)
        except _Undecodable as err:
            self._undecodable(topic, str(err))
            return None

    @staticmethod
    def _decode(decode: Any, where: str, parser: Any) -> Any:
        if parser is not None:
            try:
                return parser(decode.data)
            except dec._NotFast:
                pass
            except Exception:  # noqa: BLE001 - let the generic deserializer report it
                pass
        try:
            return decode()
        except LogReadError as err:
            raise LogReadError(f"cannot decode the message {where}: {err}") from None
        except Exception as err:  # noqa: BLE001 - deserializer errors on damaged data
            reason = first_line(err)
            raise _Undecodable(f"cannot decode the message {where} ({reason}); the message is damaged") from None

    def close(self) -> None:
        for s in self.sources:
            s.close()

    def __enter__(self) -> LogSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _tag(frame: Any, log: int, stamp_ns: int | None) -> Any:
    """A sensor frame with the index of the log it comes from and, given ``stamp_ns`` (its record
    time: ``replay.sensor_stamps=log``), that stamp instead of its header's."""
    changes: dict[str, int] = {}
    if log:
        changes["log"] = log
    if stamp_ns is not None:
        changes["stamp_ns"] = stamp_ns
    return replace(frame, **changes) if changes else frame


def _merge(streams: list[Iterator[tuple]], starts: list[int | None]) -> Iterator[tuple]:
    """The items of ``streams`` (each in order of its item[0], a log time) in order of (log time,
    stream): ``heapq.merge``'s order, but a stream is started (its file read) only when the
    merge reaches ``starts[k]``, its log's first log time (None: at once), and dropped when done.
    A recording split into hundreds of files (rosbag2 ``--max-bag-duration``, ``rosbag record
    --split``) then holds one or two of them open at a time, not a decompressed chunk of each.
    A start later than the stream's first item (a wrong summary) only delays that stream."""
    order = sorted((s, k) for k, s in enumerate(starts) if s is not None)
    heap: list[tuple] = []
    nxt = 0  # order[nxt:]: streams not started yet

    def start(k: int) -> None:
        item = next(streams[k], None)
        if item is not None:
            heapq.heappush(heap, (item[0], k, item))  # (k is unique: items are never compared)

    for k, s in enumerate(starts):
        if s is None:
            start(k)
    while heap or nxt < len(order):
        while nxt < len(order) and (not heap or order[nxt][0] <= heap[0][0]):
            start(order[nxt][1])
            nxt += 1
        if not heap:
            continue
        t, k, item = heap[0]
        yield item
        following = next(streams[k], None)
        if following is None:
            heapq.heappop(heap)
        else:
            heapq.heapreplace(heap, (following[0], k, following))


def open_logs(paths: Path | str | Sequence[Path | str], allow_truncated: bool = False,
              max_message_mb: float = DEFAULT_MAX_MESSAGE_MB) -> LogSet:
    """Open one or several logs as one ``LogSet`` (see the module doc). ``max_message_mb``: the
    largest chunk or message (uncompressed) read; a log declaring more is refused (``TooLargeError``)
    before anything is decompressed."""
    max_bytes = int(max_message_mb * 2**20)
    if isinstance(paths, (str, Path)):
        paths = [paths]
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("no log given; give a ROS 1 .bag, a ROS 2 bag folder or an .mcap file")
    sources: list[Source] = []
    source_log: list[int] = []
    given: dict[Path, Path] = {}  # resolved file of each source -> the path given for it
    try:
        for i, p in enumerate(paths):
            opened = open_source(p, max_bytes)
            sources.extend(opened)
            source_log.extend([i] * len(opened))
            for src in opened:
                real = Path(src.path).resolve()
                if real in given:
                    same = "" if given[real] == p else f" (the same log as {given[real]})"
                    raise InputError(f"log {p} is given twice{same}; its messages would be integrated "
                                     f"twice: give each log once")
                given[real] = p
    except BaseException:
        for s in sources:
            s.close()
        raise
    for src in sources:
        if getattr(src, "note", None):
            warnings.warn(LtmapWarning(src.note), stacklevel=2)
    return LogSet(paths, sources, allow_truncated, source_log)
