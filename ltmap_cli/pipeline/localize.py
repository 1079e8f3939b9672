"""``ltmap replay --localize``: a pre-pass over the logs that estimates ``map -> odom``.

It reads only the scans, tf and odometry (``io.logs``), places each scan in the *child* frame
(the top of the laser's tf tree below ``map``: ``odom`` when the log has odometry, else the robot's
or the laser's own frame) with ``io.transforms.TfBuffer`` at the scan's stamp (after waiting
``replay.tf_wait`` s of log time for tf, as the replay does), and runs
``analysis.localization``: with a static map, the start alignment then tracking against it and
the map built so far; without, scan-matching odometry. The result is a list of ``map -> child``
``TfSample``s at the scans' stamps (each with the log time of its scan's message: the replay adds
it to its tf buffer when the log reaches that time, as if recorded with the scan, so that frames
between two scans find the correction after them too) and one row per scan for
``localization.csv``. A recorded ``map -> ...`` edge is not read: the estimate replaces it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..analysis import occupied_centres
from ..analysis.localization import Alignment, SurfaceField, Tracker, apply, downsample, global_align
from ..core.sensors import scan_to_points
from ..io.frames import OdometrySample, ScanFrame, TfSample
from ..io.logs import open_logs
from ..io.mapfile import GridMap
from ..io.transforms import TfBuffer, norm, parse_mount
from .scheduler import FrameHold

NS = 1_000_000_000

HOLD_S = 1.0  # s: the first and last corrections also hold this long before and after the scans
CSV_HEADER = "stamp_ns,log_time_s,x,y,yaw,robot_x,robot_y,score,accepted"


@dataclass
class LocalizationResult:
    frame: str  # the fixed frame of the estimate ("map")
    child: str | None  # the corrected frame (odom, or the robot's or laser's frame); None: no estimate
    samples: list[TfSample] = field(default_factory=list)  # frame -> child, stamp order
    log_times: list[int] = field(default_factory=list)  # per sample: the log time it is "recorded" at
    rows: list[tuple] = field(default_factory=list)  # localization.csv rows (CSV_HEADER)
    alignment: Alignment | None = None
    summary: dict = field(default_factory=dict)  # report.json's "localization" section
    message: str = ""  # one line for the user (the alignment found, or why there is none)

    def csv_text(self) -> str:
        lines = [CSV_HEADER]
        for stamp, t_s, x, y, yaw, rx, ry, score, ok in self.rows:
            sc = "" if not math.isfinite(score) else f"{score:.3f}"
            lines.append(f"{stamp},{t_s:.3f},{x:.4f},{y:.4f},{yaw:.5f},{rx:.3f},{ry:.3f},{sc},{int(ok)}")
        return "\n".join(lines) + "\n"


def _scan_points(item: ScanFrame, T: np.ndarray, lc) -> np.ndarray:
    """The scan's returns in the child frame (xy), within the matching ranges, one per cell."""
    lo = max(float(item.range_min), lc.min_range)
    hi = min(float(item.range_max), lc.max_range)
    pts, _ = scan_to_points(item.ranges, item.angle_min, item.angle_increment, lo, hi, clear_no_return=False)
    world = pts @ T[:3, :3].T + T[:3, 3]
    return downsample(world[:, :2], lc.resolution)


def localize_logs(logs, cfg, static_grid: GridMap | None, tf_mounts=(), stop=None) -> LocalizationResult:
    """Run the pre-pass over ``logs`` (paths: read on their own, so the replay's counts stay its
    own). ``cfg``: the run's Config
    (``replay.localization``, topics, ``tf_wait``); ``static_grid``: the static
    map S (any occupancy ``GridMap``) or None; ``tf_mounts``: the ``--tf`` specs; ``stop``: a
    callable, true once the run is interrupted (Ctrl-C): the pass ends there."""
    with open_logs(logs, allow_truncated=cfg.replay.allow_truncated, max_message_mb=cfg.replay.max_message_mb) as opened:
        return _run(opened, cfg, static_grid, tf_mounts, stop or (lambda: False))


def _run(logs, cfg, static_grid, tf_mounts, stop) -> LocalizationResult:
    t_wall = time.perf_counter()
    lc = cfg.replay.localization
    frame = "map"
    # the laser scans (those named with --scan-topic, else all), also when the map is made from
    # depth or clouds only (--depth-topic / --cloud-topic): they are placed with the estimate
    sel = logs.select(scan_topics=cfg.replay.scan_topics, require_sensor=False)
    sel.clouds, sel.depths = [], {}
    tf = TfBuffer(tolerance_ns=int(cfg.replay.tf_tolerance * NS))
    for spec in tf_mounts:
        if parse_mount(spec).parent != frame:  # a --tf map:odom is what we estimate
            tf.add_mount(spec)
    wait_ns = int(cfg.replay.tf_wait * NS)
    start_ns = logs.start_ns or 0

    walls = occupied_centres(static_grid) if static_grid is not None else None
    static_field = None
    if walls is not None and len(walls):
        static_field = SurfaceField.from_points(walls, lc.resolution, lc.surface_distance, min_hits=lc.map_min_hits)

    res = LocalizationResult(frame, None)
    state: dict = {"child": None, "laser": None, "odometry": None, "tracker": None, "window": [], "t_first": None,
                   "failed": False, "skipped": 0, "match_s": 0.0}  # fmt: skip
    hold = FrameHold(wait_ns)  # the replay scheduler's rule: scans released once their tf can have come

    def place(log_ns: int, item: ScanFrame) -> None:
        laser = norm(item.frame_id)
        if state["child"] is None:
            chain = tf.chain(laser)
            state["child"], state["laser"] = chain[-1], laser
            state["odometry"] = any(not tf.edges[c].timeless for c in chain[:-1])
        T, _ = tf.try_lookup(state["child"], laser, item.stamp_ns)
        if T is None:
            state["skipped"] += 1
            return
        pts = _scan_points(item, T, lc)
        if len(pts) < 10:
            state["skipped"] += 1
            return
        scan = (item.stamp_ns, log_ns, pts, T[:2, 3].copy())
        if state["tracker"] is None:
            if state["t_first"] is None:
                state["t_first"] = item.stamp_ns
            state["window"].append(scan)
            # with odometry, the first align_window_s of scans together; without, the first scan
            if (static_field is not None and state["odometry"]
                    and item.stamp_ns - state["t_first"] < lc.align_window_s * NS):
                return
            start()
        else:
            track(scan)

    def start() -> None:
        init = tuple(float(v) for v in lc.initial_pose) if lc.initial_pose else (0.0, 0.0, 0.0)
        if static_field is not None:
            pts = np.concatenate([s[2] for s in state["window"]])
            res.alignment = al = global_align(pts, walls, lc, static_field)
            if not al.found:
                state["failed"] = True
                state["window"] = []
                return
            init = al.pose
        state["tracker"] = Tracker(lc, odometry=bool(state["odometry"]), field=static_field, correction=init)
        for scan in state["window"]:
            track(scan)
        state["window"] = []

    def track(scan) -> None:
        stamp, log_ns, pts, sensor = scan
        t0 = time.perf_counter()
        st = state["tracker"].step(stamp, pts, sensor)
        state["match_s"] += time.perf_counter() - t0
        x, y, yaw = st.correction
        robot = apply(st.correction, sensor.reshape(1, 2))[0]
        res.rows.append((stamp, (stamp - start_ns) / NS, x, y, yaw, float(robot[0]), float(robot[1]), st.score,
                         st.accepted))  # fmt: skip
        z = lc.sensor_height if state["child"] == state["laser"] else 0.0  # no tf places the laser
        q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
        res.samples.append(TfSample(stamp, frame, state["child"], (x, y, z), q))
        res.log_times.append(log_ns)

    window = logs.window_ns(cfg.replay.start_s, cfg.replay.end_s)  # the replay's --start / --end
    stream = logs.messages(sel, fast=True, start_ns=window[0], end_ns=window[1])
    for _topic, log_ns, item in stream:
        if state["failed"] or stop():
            stream.close()
            break
        if isinstance(item, (TfSample, OdometrySample)):
            if norm(item.parent) != frame:  # a recorded map -> odom is what we estimate
                for ln, it in hold.outdated_by(tf, item):
                    place(ln, it)
                tf.add(item)
                hold.took_tf(item)
        elif isinstance(item, ScanFrame):
            hold.push(item.stamp_ns, log_ns, (log_ns, item))
        for ln, it in hold.release(log_ns):
            place(ln, it)
    for ln, it in hold.flush():
        if state["failed"]:
            break
        place(ln, it)
    if state["tracker"] is None and not state["failed"] and state["window"]:
        start()  # a log shorter than the alignment window

    tracker = state["tracker"]
    res.child = state["child"] if tracker is not None else None
    if res.samples:  # hold the first and last corrections a little before and after the scans
        first, last = res.samples[0], res.samples[-1]
        hold = int(HOLD_S * NS)
        res.samples.insert(0, TfSample(first.stamp_ns - hold, first.parent, first.child, first.translation,
                                       first.rotation_xyzw))  # fmt: skip
        res.log_times.insert(0, res.log_times[0])
        res.samples.append(TfSample(last.stamp_ns + hold, last.parent, last.child, last.translation,
                                    last.rotation_xyzw))  # fmt: skip
        res.log_times.append(res.log_times[-1])
    scores = np.array([r[7] for r in res.rows if r[8] and math.isfinite(r[7])])
    al = res.alignment
    res.summary = {
        "mode": ("static map" if static_field is not None else "scan matching") + (
            ", odometry" if state["odometry"] else ", no odometry"),
        "frame": frame,
        "child_frame": res.child,
        "alignment": None if al is None else {
            "found": al.found, "x": round(al.pose[0], 4) if al.pose else None,
            "y": round(al.pose[1], 4) if al.pose else None,
            "yaw_deg": round(math.degrees(al.pose[2]), 3) if al.pose else None,
            "score": round(al.score, 3), "runner_up_score": round(al.runner_up, 3), "points": al.points,
            "seconds": round(al.seconds, 3)},
        "scans": len(res.rows),
        "scans_not_placed": state["skipped"],
        "accepted": tracker.accepted if tracker else 0,
        "rejected": tracker.rejected if tracker else 0,
        "score_median": round(float(np.median(scores)), 3) if len(scores) else None,
        "score_p10": round(float(np.percentile(scores, 10)), 3) if len(scores) else None,
        "match_s": round(state["match_s"], 3),
        "wall_s": round(time.perf_counter() - t_wall, 3),
    }
    if al is not None and not al.found:
        res.message = al.message
    elif not sel.scans:
        res.message = ("cannot localize: the log has no LaserScan topic (--localize matches laser scans); "
                       "using the recorded poses")
    elif tracker is None:
        res.message = (f"cannot localize: none of the {state['skipped']} scans could be placed in tf, or each had "
                       f"fewer than 10 returns; using the recorded poses")
    else:
        head = al.message if al is not None else (
            f"scan matching without a static map: poses of {res.child} in {frame}")
        res.message = (f"{head}; {tracker.accepted} of {len(res.rows)} scans matched (median score "
                       f"{res.summary['score_median']}), {tracker.rejected} rejected")
    res.summary["message"] = res.message
    return res
