"""What a finished replay should tell its user beyond the numbers: warnings and hints read off
the report (report.json's dict), as one-line strings. Pure: no files, no printing; the replay
command prints them as ``ltmap: warning:`` lines.

- LaserScans whose ``angle_max`` disagrees with their ranges (their beams were placed from the
  increment): one line per topic with the count.
- Several logs where one contributed no frame (its frames could not be placed, e.g. they are not
  in the other logs' tf): the log is named.
- A long-term map that is nearly empty because nothing was seen for ``map.layers.st_rise_s``
  (a short log, a robot that moved on): the setting and the log's duration are named.
- A static map that was resampled to the map's resolution.
- A sensor topic none of whose frames was used, whose header stamps are on another clock than
  tf's (``clock_apart``): ``replay.sensor_stamps=log`` named.
- tf or odometry samples ignored as tf2 ignores them (NaN, a quaternion not of unit length).
- Header stamps that jump back (a clock or simulation reset): where, and the windows to map apart.
"""

from __future__ import annotations

from ..errors import bounded

CLOCK_APART_S = 10.0  # a sensor's header stamps this far from tf's (relative to record time): another clock
LT_NEARLY_EMPTY = 0.05  # long-term voxels below this fraction of the voxels seen occupied: "nearly empty"
ST_RISE_HINT_S = 5.0  # the value a hint proposes for map.layers.st_rise_s on a short log


def replay_hints(report: dict, *, st_rise_s: float, resolution: float) -> list[str]:
    """Warnings for a replay's ``report`` (as written to report.json); ``st_rise_s`` and
    ``resolution`` are the run's ``map.layers.st_rise_s`` and ``map.resolution``."""
    out: list[str] = []
    for topic, n in sorted((report.get("scans_angle_max_off") or {}).items()):
        out.append(f"{n} scans on {topic} have an angle_max that disagrees with their ranges; their beams were "
                   f"placed at angle_min + i * angle_increment, as ROS does")
    out.extend(_idle_logs(report))
    out.extend(_clock_hints(report))
    jumps = report.get("stamp_jumps_back") or {}
    if jumps:  # (one line: the earliest jump, and how many topics jump)
        topic, j = min(jumps.items(), key=lambda kv: (kv[1]["at_s"], kv[0]))
        more = f" (and on {len(jumps) - 1} more topics)" if len(jumps) > 1 else ""
        out.append(f"header stamps on {topic[:120]} jump back by {j['by_s']:g} s at {j['at_s']:g} s of log time{more}: "
                   f"a clock or simulation reset? Frames after it are placed with tf of the same clock only; map the "
                   f"parts apart with --end {j['split_s']:g} and --start {j['split_s']:g}")  # fmt: skip
    invalid = report.get("tf_samples_invalid") or {}
    if invalid:  # (one line, however many edges: a hostile log may name thousands)
        edges = bounded(f"{n} of {edge[:120]}" for edge, n in sorted(invalid.items(), key=lambda kv: -kv[1]))
        out.append(f"tf samples ignored, as tf2 ignores them (a NaN or infinite value, or a quaternion that is not "
                   f"of unit length: a message left zeroed?): {edges}; the edges' other samples were used")

    hint = _long_term_hint(report, st_rise_s)
    if hint:
        out.append(hint)
    static = report.get("static") or {}
    src = static.get("source_resolution")
    if src and abs(src - resolution) > 1e-9 * resolution:
        unknown = static.get("unknown_cells")
        out.append(f"the static map {static.get('path')} has {src:g} m cells; it was resampled to the map's "
                   f"{resolution:g} m (a cell is occupied when any source cell in it is, unknown only where no "
                   f"known source cell falls" + (f": {unknown} unknown cells" if unknown is not None else "")
                   + "); give --resolution " + f"{src:g} to keep its cells")
    return out


def clock_apart(topic: str, offsets_s: dict[str, float], tf_topics) -> str | None:
    """A clause for a sensor ``topic`` whose header stamps lie more than CLOCK_APART_S from those
    of every tf / odometry topic in ``tf_topics``, relative to record time (``offsets_s``: record
    time minus header stamp of each topic's first message, s): its frames cannot be placed with
    that tf; the remedy. None when they agree (or nothing is known)."""
    refs = {t: offsets_s[t] for t in tf_topics if t in offsets_s}
    if topic not in offsets_s or not refs:
        return None
    ref, ref_off = min(refs.items(), key=lambda kv: abs(kv[1] - offsets_s[topic]))
    apart = ref_off - offsets_s[topic]  # > 0: the sensor's stamps are later than tf's
    if abs(apart) <= CLOCK_APART_S:
        return None
    s = abs(apart)
    text = f"{s:.0f} s" + (f" ({s / 86400:.1f} days)" if s >= 86400 else "")
    return (f"the header stamps of {topic} are {text} {'after' if apart > 0 else 'before'} those of {ref} (relative "
            f"to record time): a sensor on its own clock? --set replay.sensor_stamps=log places its frames at their "
            f"record time")  # fmt: skip


UPWARD_COS = 0.9  # an optical frame whose z axis is within 26 deg of straight up ...
LEVEL_SIN = 0.45  # ... while its y axis (the image's down) is within 27 deg of level: a body frame?


def body_frame_suspect(topic: str, frame_id: str, R) -> str | None:
    """A warning when depth images on ``topic``, read in an optical frame (z forward, x right, y
    down: REP 103's camera convention), would face straight up while the image's down is level,
    with ``R`` (3 x 3 or 4 x 4) their frame's rotation in a frame whose z is up: the signature of
    the camera's body frame (x forward, z up; a Gazebo camera link) given as the images' frame.
    None otherwise. (Replay and info alike.)"""
    if R[2][2] > UPWARD_COS and abs(R[2][1]) < LEVEL_SIN:
        return (f"depth images on {topic} are in frame {frame_id}, which as an optical frame (z forward, x right, "
                f"y down) faces straight up: is it the camera's body frame (x forward, z up; a Gazebo camera link) "
                f"rather than its optical frame? --set replay.depth_frame_axes=body reads them so; if the camera "
                f"does face up, ignore this")  # fmt: skip
    return None


def _clock_hints(report: dict) -> list[str]:
    """Sensor topics none of whose frames was used, stamped on another clock than tf."""
    offsets = report.get("header_stamp_offset_s") or {}
    used = report.get("frames_used") or {}
    sensors = {t for topics in (report.get("topics_used") or {}).values() for t in topics}
    tf_topics = [t for t in offsets if t not in sensors]
    out = []
    for topic in sorted(report.get("frames_skipped_by_topic") or {}):
        if not used.get(topic):
            clause = clock_apart(topic, offsets, tf_topics)
            if clause:
                out.append(f"no frame of {topic} was used: {clause}")
    return out


def _idle_logs(report: dict) -> list[str]:
    used = report.get("frames_used_by_log") or {}
    if len(used) < 2:
        return []
    skipped = report.get("frames_skipped_by_log") or {}
    reasons = report.get("frames_skipped") or {}
    top = max(reasons.items(), key=lambda kv: kv[1])[0] if reasons else None
    out = []
    for log, n in used.items():
        if n:
            continue
        k = skipped.get(log, 0)
        if k:  # a log without sensor frames (tf only) gives its tf: that is not nothing
            out.append(f"log {log} contributed nothing to the map: all {k} of its sensor frames were skipped"
                       + (f" (the most common reason: {top})" if top else "")
                       + "; are its frames in the tf the logs give? check it with `ltmap info` and give the missing "
                       "transform with --tf")
    return out


def _long_term_hint(report: dict, st_rise_s: float) -> str | None:
    if report.get("static"):
        return None  # with S, walls stay out of LT by design: a small LT says nothing
    vox = report.get("voxels") or {}
    seen = int(vox.get("occupied_O") or 0)
    lt = int(vox.get("long_term_occupied") or 0)
    if seen == 0 or lt >= LT_NEARLY_EMPTY * seen:
        return None
    duration = float(report.get("log_duration_s") or 0.0)
    what = "the window mapped (--start / --end)" if report.get("window") else "the log"
    if duration < st_rise_s:
        why = f"{what} lasts {duration:.1f} s, shorter than that"
    else:
        why = f"{what} lasts {duration:.1f} s, and little stayed in view that long"
    proposal = f"; for a short log lower it, e.g. --set map.layers.st_rise_s={ST_RISE_HINT_S:g}" \
        if st_rise_s > ST_RISE_HINT_S else ""
    return (f"the long-term map is nearly empty ({lt} voxels; {seen} seen occupied): a voxel enters it after "
            f"being seen for map.layers.st_rise_s = {st_rise_s:g} s, and {why}{proposal}")
