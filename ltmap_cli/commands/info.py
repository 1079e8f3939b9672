"""`ltmap info LOG [LOG...]`: what a log holds and what `replay` would use, with warnings.

One streaming pass over every message: counts, first/last log time per topic, the tf tree (tf
messages are decoded into a bounded TfBuffer; each edge shows how many samples the log has), and
the first message of each sensor topic (its frame, for images the encoding, for LaserScans the
check replay makes that the ranges match the angles). Nothing is kept per message, so memory does
not grow with the log.

Exit status 2, after the listing, for a truncated log (unless --allow-truncated) and for a
--fixed-frame that tf does not have, with the line replay would stop with.
"""

from __future__ import annotations

from pathlib import Path

import click


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
) -> dict:
    """Everything `info` shows, as a dict (also used by tests). Raises like the readers."""
    from ..errors import LogReadError, TransformError
    from ..io import decode as dec
    from ..io.logs import IMAGE, TruncatedLogError, open_logs
    from ..io.transforms import TfBuffer

    with open_logs(paths, allow_truncated=True) as logs:
        sel = logs.select(scan_topics, cloud_topics, depth_topics, require_sensor=False)
        buf = TfBuffer(window_ns=10 * 10**9)
        for spec in tf_mounts:
            buf.add_mount(spec)
        counts: dict[str, int] = {}
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        sensor_first: dict[str, object] = {}
        sensor_where: dict[str, str] = {}
        warnings: list[str] = []
        static = set(sel.static_tf)
        sensors = set(sel.sensor_topics) | set(sel.skipped)
        tf_topics = set(sel.tf)
        odom_topics = set(sel.odometry)
        # tf, odometry and the first sensor messages are parsed from their CDR bytes directly
        # when they can be (the generic deserializers cost ~0.15 ms a message plus building the
        # rosbags type store); anything unusual goes through the generic deserializer
        parsers = {name: dec.CDR_PARSERS.get(t.msgtype) for name, t in logs.topics.items()}
        for topic, t, decode, where in logs.raw(logs.topics):
            counts[topic] = counts.get(topic, 0) + 1
            first.setdefault(topic, t)
            last[topic] = t
            if topic in tf_topics or topic in odom_topics or (topic in sensors and topic not in sensor_first):
                try:
                    msg = _decode(decode, parsers.get(topic))
                except Exception as err:  # noqa: BLE001 - report, keep counting
                    warnings.append(f"cannot decode the message {where}: {err}")
                    if topic in sensors:
                        sensor_first[topic] = None
                    continue
                if topic in tf_topics:
                    for s in dec.decode_tf(msg, static=topic in static):
                        buf.add(s)
                elif topic in odom_topics:
                    buf.add(dec.decode_odometry(msg))
                else:
                    sensor_first[topic] = msg
                    sensor_where[topic] = where
        stopped = logs.stats.stopped_at
        topics = logs.topics
        names = [str(p) for p in paths]
        formats = logs.formats

    frames = buf.frames
    error = None
    try:
        fixed = buf.fixed_frame(fixed_frame)
    except TransformError as err:
        fixed = None
        if fixed_frame:  # a frame asked for and not in tf: replay stops on it, so does info
            error = err
        else:  # neither map nor odom: the listing shows the frames to choose from
            warnings.append(str(err))
    used: dict[str, str] = {}
    for kind, group in (("laser", sel.scans), ("cloud", sel.clouds), ("depth", list(sel.depths))):
        for topic in group:
            msg = sensor_first.get(topic)
            if msg is None:
                used[topic] = kind
                if counts.get(topic, 0) == 0:
                    warnings.append(f"{topic}: no messages could be read")
                continue
            frame = dec.frame_name(msg.header.frame_id)
            used[topic] = f"{kind}, frame {frame}"
            if kind == "laser":
                try:  # the check replay makes on every scan
                    dec.decode_scan(msg, topic, sensor_where[topic])
                except LogReadError as err:
                    warnings.append(f"{topic}: replay would stop on its first message: {err}")
            if kind == "depth":
                used[topic] += f" (CameraInfo {sel.depths[topic]})"
                enc = str(getattr(msg, "encoding", ""))
                if enc not in ("16UC1", "32FC1", "mono16"):
                    warnings.append(
                        f"{topic}: encoding {enc!r} is not a depth encoding (16UC1, 32FC1); replay "
                        f"would stop on it: leave it out with --depth-topic naming others"
                    )
            if fixed is not None:
                problem = buf.connection_problem(fixed, frame)
                if problem:
                    warnings.append(f"{topic}: every frame would be skipped: {problem}")
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
    if stopped:
        warnings.append(f"log is truncated or corrupt: {stopped}")
    starts = [v for v in first.values()]
    ends = [v for v in last.values()]
    result = {
        "logs": names,
        "formats": formats,
        "start_ns": min(starts) if starts else None,
        "end_ns": max(ends) if ends else None,
        "topics": {
            n: {
                "type": topics[n].msgtype,
                "count": counts.get(n, 0),
                "first_ns": first.get(n),
                "last_ns": last.get(n),
            }
            for n in sorted(topics)
        },
        "frames": sorted(frames),
        "tree": buf.tree_text(),
        "fixed_frame": fixed,
        "used": used,
        "tf_topics": sel.tf,
        "odometry_topics": sel.odometry,
        "skipped": dict(sel.skipped),
        "warnings": warnings,
        "stopped_at": stopped,
    }
    if error is not None:
        result["error"] = error
    elif stopped and not allow_truncated:
        result["error"] = TruncatedLogError(
            f"log is truncated or corrupt: {stopped}; to use what was read "
            f"before that point, pass --allow-truncated"
        )
    return result


def render(r: dict) -> str:
    lines = []
    for name, fmt in zip(r["logs"], r["formats"]):
        lines.append(f"log:       {name} ({fmt})")
    if len(r["formats"]) > len(r["logs"]):
        lines.append(f"storage:   {', '.join(r['formats'])}")
    if r["start_ns"] is not None:
        dur = (r["end_ns"] - r["start_ns"]) / 1e9
        lines.append(f"duration:  {dur:.2f} s  ({r['start_ns'] / 1e9:.3f} .. {r['end_ns'] / 1e9:.3f})")
    else:
        lines.append("duration:  - (no messages)")
    total = sum(t["count"] for t in r["topics"].values())
    lines.append(f"messages:  {total}")
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
            f"{_rate(t['count'], t['first_ns'], t['last_ns']):>9}  {use}".rstrip()
        )
    lines.append("")
    lines.append("tf tree:" if r["tree"] else "tf tree:   (no transforms)")
    if r["tree"]:
        lines.extend("  " + ln for ln in r["tree"].splitlines())
    lines.append(f"fixed frame: {r['fixed_frame'] or '- (none)'}")
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
    "--depth-topic", "depth_topics", multiple=True, help="Depth Image topic replay would use (repeatable)."
)
@click.option(
    "--tf",
    "tf_mounts",
    multiple=True,
    metavar="PARENT:CHILD=x,y,z,roll,pitch,yaw",
    help="A sensor mount missing from the log (repeatable).",
)
@click.option("--fixed-frame", default="", help="Fixed frame (default: map if tf has it, else odom).")
@click.option("--allow-truncated", is_flag=True, help="Exit 0 on a truncated or corrupt log.")
def info(
    logs: tuple[Path, ...], scan_topics, cloud_topics, depth_topics, tf_mounts, fixed_frame, allow_truncated
) -> None:
    """Show what LOG(s) hold: topics, types, counts, duration, rates, the tf tree, which topics
    `ltmap replay` would use, and warnings for what it would skip and why."""
    r = gather(list(logs), scan_topics, cloud_topics, depth_topics, tf_mounts, fixed_frame, allow_truncated)
    click.echo(render(r))
    if "error" in r:
        raise r["error"]
