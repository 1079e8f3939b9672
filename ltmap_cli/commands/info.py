"""`ltmap info LOG [LOG...]`: what a log holds and what `replay` would use, with warnings.

One streaming pass over every message: counts, first/last log time per topic, the tf tree (tf
messages are decoded into a bounded TfBuffer; each edge shows how many samples the log has), and
the first message of each sensor topic (its frame, for images the encoding, for LaserScans the
check replay makes that the ranges match the angles). Nothing is kept per message, so memory does
not grow with the log. Logs of more than ``INFO_FULL_BYTES`` (hours of depth images: the whole
pass would take minutes) are read for their first ``INFO_HEAD_S`` of log time, where replay
makes its choices, with counts and times from their index; ``--full`` reads them whole.

Exit status 2, after the listing, for a truncated log (unless --allow-truncated) and for a
--fixed-frame that tf does not have, with the line replay would stop with.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import click

from ..analysis.hints import body_frame_suspect, clock_apart
from ..config import ReplayConfig, load_config, parse_set, set_dotted
from ..core.config import MapConfig
from ..errors import LogReadError, TransformError
from ..io import decode as dec
from ..io import rectify
from ..io.camera_file import load_camera_infos
from ..io.logs import IMAGE, TruncatedLogError, open_logs
from ..io.transforms import TfBuffer, choose_base_frame
from . import allow_open_files, clock, sensor_options

NS = 1_000_000_000
INFO_FULL_BYTES = 1 << 30  # logs up to this size in all are read whole (a few seconds) ...
INFO_HEAD_S = 30.0  # ... bigger ones for their first this many s of log time (where replay makes its choices)
OFFSET_SHOWN_S = 1.0  # header stamps this far from record time (either way) are shown


def _offset_text(ns: int | float) -> str:
    """A time difference (ns) as ``33194330 s (384.2 days)`` / ``2.50 s``, without sign."""
    s_ = abs(ns) / NS
    text = f"{s_:.0f} s" if s_ >= 100 else f"{s_:.2f} s"
    return text + (f" ({s_ / 86400:.1f} days)" if s_ >= 86400 else "")


def stamp_offset_lines(offsets_s: dict[str, float]) -> list[str]:
    """``header stamps are X s before record time`` per topic whose first header stamp is at
    least OFFSET_SHOWN_S from its record time (a bag re-recorded from playback, sim time, an
    unsynced clock)."""
    out = []
    for topic, off in sorted(offsets_s.items()):
        if abs(off) >= OFFSET_SHOWN_S:
            side = "before" if off > 0 else "after"
            out.append(f"{topic}: header stamps are {_offset_text(off * NS)} {side} record time")
    return out


def _size(path: Path) -> int:
    """Bytes of a log file, or of the files in a ROS 2 bag folder."""
    p = Path(path)
    if p.is_dir():
        return sum(f.stat().st_size for f in p.iterdir() if f.is_file())
    return p.stat().st_size if p.exists() else 0


def _rate(count: int, first: int | None, last: int | None) -> str:
    if count < 2 or first is None or last is None or last <= first:
        return "-"
    return f"{(count - 1) / ((last - first) / 1e9):.1f} Hz"


def _decode(decode, parser):
    """The message of a reader thunk: parsed from CDR directly when ``parser`` can, else the
    generic deserializer."""

    if parser is not None and getattr(decode, "encoding", "") == "cdr":
        try:
            return parser(decode.data)
        except Exception:  # noqa: BLE001 - unusual layout: the generic deserializer decides
            pass
    return decode()


def gather(
    paths: list[Path],
    scan_topics=(),
    cloud_topics=(),
    depth_topics=(),
    tf_mounts=(),
    fixed_frame: str = "",
    allow_truncated: bool = False,
    base_frame: str | None = None,
    full: bool = False,
    camera_infos=(),
) -> dict:
    """Everything `info` shows, as a dict (also used by tests and ``--json``). Raises like the
    readers. ``base_frame``: ``map.robot.base_frame`` (default: its default). Logs of more than
    ``INFO_FULL_BYTES`` in all are read for their first ``INFO_HEAD_S`` of log time only (what
    replay decides its frames from), with counts and times from their index, unless ``full``."""

    size = sum(_size(p) for p in paths)
    head = not full and size > INFO_FULL_BYTES
    with open_logs(paths, allow_truncated=True) as logs:
        head_ns = None if not head or logs.start_ns is None else logs.start_ns + int(INFO_HEAD_S * NS)
        read_to: int | None = None  # head_ns, when reading stopped there
        sel = logs.select(scan_topics, cloud_topics, depth_topics, require_sensor=False,
                          given_info=load_camera_infos(camera_infos))  # fmt: skip
        buf = TfBuffer(window_ns=10 * 10**9)
        for spec in tf_mounts:
            buf.add_mount(spec)
        counts: dict[str, int] = {}
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        sensor_first: dict[str, object] = {}
        sensor_where: dict[str, str] = {}
        offset: dict[str, int] = {}  # topic -> record time - header stamp of its first stamped message (ns)
        warnings: list[str] = []
        static = set(sel.static_tf)
        sensors = set(sel.sensor_topics) | set(sel.skipped)
        tf_topics = set(sel.tf)
        odom_topics = set(sel.odometry)
        # tf, odometry and the first sensor messages are parsed from their CDR bytes directly
        # when they can be (the generic deserializers cost ~0.15 ms a message plus building the
        # rosbags type store); anything unusual goes through the generic deserializer
        parsers = {name: dec.CDR_PARSERS.get(t.msgtype) for name, t in logs.topics.items()}
        # replay chooses the fixed frame when its first sensor frame is released (tf_wait after
        # it, in log time), from the tf it has by then: the frames at that point, as replay sees them
        used_sensors = set(sel.sensor_topics)
        infos = set(sel.depths.values())  # CameraInfo topics: their first message tells the lens
        info_first: dict[str, object] = dict(sel.given_info)
        wait_ns = int(ReplayConfig().tf_wait * NS)
        release_ns: int | None = None
        early: set[str] | None = None
        stream = logs.raw(logs.topics)
        for topic, t, decode, where in stream:
            if head_ns is not None and t > head_ns:
                read_to = head_ns
                stream.close()
                logs.finish()  # the damage met in the part read, if any
                break
            if release_ns is None and topic in used_sensors:
                release_ns = t + wait_ns
            if early is None and release_ns is not None and t > release_ns:
                early = buf.frames
            counts[topic] = counts.get(topic, 0) + 1
            first.setdefault(topic, t)
            last[topic] = t
            if topic in infos and topic not in info_first:
                with contextlib.suppress(Exception):  # a damaged CameraInfo: replay takes the next one
                    info_first[topic] = _decode(decode, parsers.get(topic))
            if topic in tf_topics or topic in odom_topics or (topic in sensors and topic not in sensor_first):
                try:
                    msg = _decode(decode, parsers.get(topic))
                except Exception as err:  # noqa: BLE001 - report, keep counting
                    warnings.append(f"cannot decode the message {where}: {err}")
                    if topic in sensors:
                        sensor_first[topic] = None
                    continue
                if topic in tf_topics:
                    samples = dec.decode_tf(msg, static=topic in static)
                    for s in samples:
                        buf.add(s)
                    if samples and topic not in static and topic not in offset:
                        offset[topic] = t - samples[0].stamp_ns
                elif topic in odom_topics:
                    o = dec.decode_odometry(msg)
                    buf.add(o)
                    offset.setdefault(topic, t - o.stamp_ns)
                else:
                    sensor_first[topic] = msg
                    sensor_where[topic] = where
                    offset.setdefault(topic, t - dec.stamp_ns(msg.header.stamp))
        stopped = logs.stats.stopped_at
        if read_to is not None and not stopped:  # the part read is whole; the file's end may be known to be cut
            stopped = "; ".join(s.end_stop for s in logs.sources if s.end_stop) or None
        topics = logs.topics
        log_start, log_end = logs.start_ns, logs.end_ns
        names = [str(p) for p in paths]
        formats = logs.formats

    frames = buf.frames
    if early is None:
        early = frames
    error = None
    sensor_frames = {dec.frame_name(m.header.frame_id) for t, m in sensor_first.items()
                     if m is not None and t in sel.sensor_topics} - {""}  # fmt: skip
    try:
        # replay's own choice is made from the frames tf has at its first sensor frame
        fixed = buf.fixed_frame(fixed_frame, sensor_frames, frames=None if fixed_frame else early)
        if not fixed_frame and "map" in frames and fixed != "map":
            warnings.append("tf has map only after the first sensor frames (a localizer that starts later?): "
                            f"replay maps in {fixed}; with --fixed-frame map it maps in map, skipping the "
                            "frames before map -> odom exists")
    except TransformError as err:
        fixed = None
        if fixed_frame:  # a frame asked for and not in tf: replay stops on it, so does info
            error = err
        else:  # neither map nor odom: the listing shows the frames to choose from
            warnings.append(str(err))
    used: dict[str, str] = {}
    base = choose_base_frame(frames, base_frame or MapConfig().robot.base_frame)
    for kind, group in (("laser", sel.scans), ("cloud", sel.clouds), ("depth", list(sel.depths))):
        for topic in group:
            msg = sensor_first.get(topic)
            if msg is None:
                used[topic] = kind
                if counts.get(topic, 0) == 0:
                    warnings.append(f"{topic}: no messages could be read")
                continue
            frame = dec.frame_name(msg.header.frame_id)
            used[topic] = f"{kind}, frame {frame or '(empty header.frame_id)'}"
            if not frame:
                warnings.append(f"{topic}: its first message has an empty header.frame_id: replay skips such "
                                f"messages (nothing tells where the sensor was)")
            if kind == "laser":
                try:  # the check replay makes on every scan
                    sf = dec.decode_scan(msg, topic, sensor_where[topic])
                except LogReadError as err:
                    warnings.append(f"{topic}: replay would stop on its first message: {err}")
                else:
                    if sf.angle_max_off:
                        n = len(sf.ranges)
                        warnings.append(
                            f"{topic}: angle_max {float(msg.angle_max):.6g} disagrees with its {n} ranges from "
                            f"angle_min {sf.angle_min:.6g} by angle_increment {sf.angle_increment:.6g} (last beam "
                            f"at {sf.angle_min + (n - 1) * sf.angle_increment:.6g}); replay places beam i at "
                            f"angle_min + i * angle_increment, as ROS does, and counts such scans")
            if kind == "depth":
                used[topic] += f" (CameraInfo {sel.depths[topic]})"
                cam = info_first.get(sel.depths[topic])
                with contextlib.suppress(Exception):  # (a damaged CameraInfo: replay's own checks say it)
                    c = dec.intrinsics(cam) if cam is not None else None
                    if c is not None and c.width and c.height:  # the images it describes: binning and ROI applied
                        full = dec.full_camera(cam)
                        used[topic] += (f", {c.width}x{c.height} fx {c.fx:.6g} fy {c.fy:.6g} cx {c.cx:.6g} cy {c.cy:.6g}"
                                        + (f" of {full}" if full else ""))  # fmt: skip
                lens = rectify.distortion(cam) if cam is not None else None
                if lens is not None:
                    try:  # replay's own check (io.rectify), on one point
                        rectify.distort(0.0, 0.0, lens, sensor_where[topic])
                    except LogReadError as err:
                        warnings.append(f"{topic}: replay would stop on its first image: {err}")
                    else:
                        used[topic] += f", lens {lens.model} rectified to pinhole"
                enc = str(getattr(msg, "encoding", ""))
                if hasattr(msg, "format"):  # a CompressedImage: the check replay makes on every image
                    from ..io import compressed_depth

                    try:
                        compressed_depth.decode(msg.data, msg.format, None, sensor_where[topic])
                    except LogReadError as err:
                        warnings.append(f"{topic}: replay would stop on its first message: {err}")
                    except compressed_depth.DamagedPayload as err:
                        warnings.append(f"{topic}: its first message cannot be decoded ({err}): replay skips "
                                        f"such messages and counts them")  # fmt: skip
                    else:
                        used[topic] += f", {str(msg.format).strip()}"
                elif enc not in ("16UC1", "32FC1", "mono16"):
                    warnings.append(
                        f"{topic}: encoding {enc!r} is not a depth encoding (16UC1, 32FC1); replay "
                        f"would stop on it: leave it out with --depth-topic naming others"
                    )
            if fixed is not None and frame:
                problem = buf.connection_problem(fixed, frame)
                if problem:
                    warnings.append(f"{topic}: every frame would be skipped: {problem}")
                elif kind == "depth" and frame != fixed:  # replay's check of the camera's axes, against
                    # the robot's (level) base through the camera's static mount, else the fixed frame
                    up = base if base in buf.frames and base != frame else fixed
                    R, _ = buf.try_lookup(up, frame, dec.stamp_ns(msg.header.stamp))
                    text = body_frame_suspect(topic, frame, R) if R is not None else None
                    if text:
                        warnings.append(text)
    for topic, why in sel.skipped.items():
        if topic in sensor_first and sensor_first[topic] is not None and topics[topic].msgtype == IMAGE:
            why += f" (encoding {sensor_first[topic].encoding})"
        warnings.append(f"{topic} would be skipped: {why}")
    if not sel.sensor_topics:
        warnings.append(
            "no usable LaserScan, PointCloud2 or depth Image topic: replay would have nothing to map"
        )
    for edge, n in buf.ignored.items():
        if edge.endswith(" from odom"):
            continue  # odometry duplicating /tf is normal: tf is used
        warnings.append(
            f"{n} samples of {edge} ignored: the edge also comes from a stronger source "
            f"(--tf mount, then /tf and /tf_static, then odometry)"
        )
    for edge, n in sorted(buf.invalid.items()):
        warnings.append(f"{n} samples of {edge} not used: a NaN or infinite value, or a quaternion that is not of "
                        f"unit length (tf2 ignores them too)")
    for what, n in buf.unnamed.items():
        if what.startswith("nav_msgs/Odometry") and what.endswith("(empty child_frame_id)"):
            todo = ("it does not say which frame it moves, so ltmap cannot use it: publish the robot's "
                    "pose in /tf, or map in a sensor's own frame with --fixed-frame "
                    f"{min(sensor_frames) if sensor_frames else '<frame>'}")
        else:
            todo = "tf refuses an empty frame name: fix the recording, or give the transform with --tf"
        warnings.append(f"{n} samples {what} not used: {todo}")
    offsets_s = {k: v / NS for k, v in offset.items()}
    for topic in sel.sensor_topics:  # replay's own check when every frame is skipped (analysis.hints)
        clause = clock_apart(topic, offsets_s, [k for k in offset if k in tf_topics or k in odom_topics])
        if clause:
            warnings.append(f"{topic}: its frames cannot be placed with that tf: {clause}")
    if stopped:
        warnings.append(f"log is truncated or corrupt: {stopped}")
    starts = [v for v in first.values()] if read_to is None else [log_start] if log_start is not None else []
    ends = [v for v in last.values()] if read_to is None else [log_end] if log_end is not None else []
    result = {
        "logs": names,
        "formats": formats,
        "start_ns": min(starts) if starts else None,
        "end_ns": max(ends) if ends else None,
        "topics": {
            n: {
                "type": topics[n].msgtype,
                "count": counts.get(n, 0) if read_to is None else topics[n].count,
                "first_ns": first.get(n) if read_to is None else (topics[n].first_ns or first.get(n)),
                "last_ns": last.get(n) if read_to is None else topics[n].last_ns,
            }
            for n in sorted(topics)
        },
        "frames": sorted(frames),
        "tree": buf.tree_text(),
        "fixed_frame": fixed,
        "base_frame": base,
        "sensor_frames": sorted(sensor_frames),
        "stamp_offset_s": {k: v / NS for k, v in sorted(offset.items())},
        "used": used,
        "tf_topics": sel.tf,
        "odometry_topics": sel.odometry,
        "skipped": dict(sel.skipped),
        "warnings": warnings,
        "stopped_at": stopped,
        "read_s": None if read_to is None else INFO_HEAD_S,  # None: the whole log was read
    }
    if error is not None:
        result["error"] = error
    elif stopped and not allow_truncated:
        result["error"] = TruncatedLogError(
            f"log is truncated or corrupt: {stopped}; to use what was read "
            f"before that point, pass --allow-truncated"
        )
    return result


EPOCH_2001_NS = 978_307_200 * 10**9  # record times after this are wall-clock times (sim time starts near 0)


def _utc(start_ns: int, end_ns: int) -> str:
    """The log's span as UTC dates, when its record times are wall-clock times."""
    if start_ns < EPOCH_2001_NS:
        return ""
    import datetime

    a, b = (datetime.datetime.fromtimestamp(ns / 1e9, datetime.timezone.utc) for ns in (start_ns, end_ns))
    return f"; {a:%Y-%m-%d %H:%M:%S} .. {b:%H:%M:%S} UTC" if a.date() == b.date() else \
        f"; {a:%Y-%m-%d %H:%M:%S} .. {b:%Y-%m-%d %H:%M:%S} UTC"  # fmt: skip


def render(r: dict) -> str:
    lines = []
    for name, fmt in zip(r["logs"], r["formats"]):
        lines.append(f"log:       {name} ({fmt})")
    if r["start_ns"] is not None:
        dur = (r["end_ns"] - r["start_ns"]) / 1e9
        lines.append(f"duration:  {dur:.2f} s{f' ({clock(dur)})' if dur >= 60 else ''}  "
                     f"({r['start_ns'] / 1e9:.3f} .. {r['end_ns'] / 1e9:.3f}{_utc(r['start_ns'], r['end_ns'])})")
    else:
        lines.append("duration:  - (no messages)")
    total = sum(t["count"] for t in r["topics"].values())
    lines.append(f"messages:  {total}")
    if r.get("read_s") is not None:
        lines.append(f"read:      the first {r['read_s']:g} s of log time (counts and times from the index; the tf "
                     f"tree, frames and warnings from that part): --full reads it all")  # fmt: skip
    lines.append("")
    width = max([len(n) for n in r["topics"]] + [5])
    twidth = max([len(t["type"]) for t in r["topics"].values()] + [4])
    lines.append(f"{'topic':<{width}}  {'type':<{twidth}}  {'count':>7}  {'rate':>9}  replay")
    for name, t in r["topics"].items():
        if name in r["used"]:
            use = "uses: " + r["used"][name]
        elif name in r["tf_topics"]:
            use = "uses: tf"
        elif name in r["odometry_topics"]:
            use = "uses: odometry"
        elif name in r["skipped"]:
            use = "skips"
        else:
            use = ""
        lines.append(
            f"{name:<{width}}  {t['type']:<{twidth}}  {t['count']:>7}  "
            f"{_rate(t['count'], t['first_ns'] or r['start_ns'], t['last_ns'] or r['end_ns']):>9}  {use}".rstrip()
        )
    lines.append("")
    lines.append("tf tree:" if r["tree"] else "tf tree:   (no transforms)")
    if r["tree"]:
        lines.extend("  " + ln for ln in r["tree"].splitlines())
    lines.append(f"fixed frame: {r['fixed_frame'] or '- (none)'}")
    lines.append(f"base frame:  {r['base_frame']}" + ("" if r["base_frame"] in r["frames"] else
                                                      " (not in tf: the robot's footprint is not placed)"))
    shifted = stamp_offset_lines(r.get("stamp_offset_s") or {})
    if shifted:
        lines.append("")
        lines.append("header stamps against record time:")
        lines.extend("  " + ln for ln in shifted)
    lines.append("")
    if r["warnings"]:
        lines.append("warnings:")
        lines.extend(f"  - {w}" for w in r["warnings"])
    else:
        lines.append("warnings: none")
    return "\n".join(lines)


@click.command("info")
@click.argument("logs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option(
    "--scan-topic", "scan_topics", multiple=True, help="LaserScan topic replay would use (repeatable)."
)
@click.option(
    "--cloud-topic", "cloud_topics", multiple=True, help="PointCloud2 topic replay would use (repeatable)."
)
@click.option(
    "--depth-topic", "depth_topics", multiple=True,
    help="Depth image topic replay would use (an Image or a .../compressedDepth; repeatable)."
)
@click.option(
    "--tf",
    "tf_mounts",
    multiple=True,
    metavar="PARENT:CHILD=x,y,z,roll,pitch,yaw",
    help="A sensor mount missing from the log (repeatable).",
)
@click.option("--camera-info", "camera_infos", multiple=True, metavar="[TOPIC=]FILE",
              help="A depth camera's calibration YAML, as replay's --camera-info (repeatable).")
@click.option("--fixed-frame", default="", help="Fixed frame (default: map if tf has it, else odom).")
@click.option("--config", "config_file", type=click.Path(path_type=Path),
              help="The parameters replay would be given (a YAML file, as replay's --config): its topics, mounts, "
              "fixed and base frames.")  # fmt: skip
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="A parameter as replay's --set, e.g. --set map.robot.base_frame=base_footprint.")
@click.option("--allow-truncated", is_flag=True, help="Exit 0 on a truncated or corrupt log.")
@click.option("--json", "as_json", is_flag=True, help="Print what info found as JSON (the same claims).")
@click.option("--full", is_flag=True, help=f"Read every message of logs over {INFO_FULL_BYTES >> 30} GiB too (by "
              f"default their first {INFO_HEAD_S:g} s of log time, counts from the index).")
def info(
    logs: tuple[Path, ...], scan_topics, cloud_topics, depth_topics, tf_mounts, camera_infos, fixed_frame, config_file,
    overrides, allow_truncated, as_json, full,
) -> None:
    """Show what LOG(s) hold: topics, types, counts, duration, rates, the tf tree, which topics
    `ltmap replay` would use, the fixed and base frames it would use, and warnings for what it
    would skip and why. With replay's --config / --set, what replay would use with them."""
    cfg = load_config(config_file)  # in replay's order: the file, the options, then --set
    sensor_options(cfg, fixed_frame or None, tf_mounts, scan_topics, cloud_topics, depth_topics, camera_infos)
    for key, value in parse_set(overrides):
        set_dotted(cfg, key, value)
    cfg.validate()
    rc = cfg.replay
    allow_open_files(logs)
    r = gather(list(logs), rc.scan_topics, rc.cloud_topics, rc.depth_topics, rc.tf, rc.fixed_frame, allow_truncated,
               base_frame=cfg.map.robot.base_frame, full=full, camera_infos=rc.camera_info)  # fmt: skip
    if as_json:

        click.echo(json.dumps({k: (str(v) if k == "error" else v) for k, v in r.items()}, indent=2))
    else:
        click.echo(render(r))
    if "error" in r:
        raise r["error"]
