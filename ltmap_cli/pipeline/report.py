"""report.json as a typed object: the run's inputs and counts, and what the sinks returned."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field


@dataclass
class Report:
    logs: list[str]
    fixed_frame: str | None
    base_frame: str | None
    topics_used: dict  # {"scans": [...], "clouds": [...], "depth": [...]}
    topics_not_used: dict  # topic -> why
    messages_per_topic: dict
    messages_not_decoded: dict  # reason -> count
    frames_used: dict  # topic -> frames integrated
    frames_skipped: dict  # reason -> frames
    frames_skipped_by_topic: dict
    frames_used_by_log: dict  # log path -> frames integrated
    frames_skipped_by_log: dict
    scans_angle_max_off: dict  # topic -> scans whose angle_max disagrees with their ranges
    frames_over_depth_max_rate: dict
    frames_without_footprint: int
    depth_outlier_filter: dict
    rays: int
    log_start_ns: int
    log_duration_s: float
    wall_time_s: float  # the whole run, outputs and plots included
    speed_vs_real_time: float | None  # log time / wall_time_s
    mapping_wall_time_s: float  # up to the map's last snapshot (before map files, events, plots)
    mapping_speed_vs_real_time: float | None
    kernels_compiled_s: float  # of the wall time, waiting for the kernels' compiling (a first run); 0 when cached
    stage_s: dict  # stage -> wall seconds (pipeline/timing.py)
    ray_workers: int  # threads that computed the frames' rays (replay.workers; 0: the serial path)
    # CPU seconds by thread up to the report: the map thread ("main": integration, ticks, outputs,
    # and the rays too on the serial path), the log reader, the ray workers summed, the whole process
    # (numba and numpy threads of their own included). With more cores the wall time tends to the
    # largest of main, reader and ray_workers / workers.
    thread_cpu_s: dict
    ticks: int
    stopped_at: str | None  # where a damaged or cut-off log stopped being read
    window: dict | None  # --start / --end: the log times mapped (s from the log's first message), else None
    header_stamp_offset_s: dict  # sensor, tf and odometry topic -> record time - stamp of its first message (s)
    tf_samples_invalid: dict  # "parent -> child" -> tf / odometry samples refused (NaN, a quaternion not unit), as tf2 does
    stamp_jumps_back: dict  # sensor topic -> {"at_s", "by_s", "split_s" (s)} of its first header stamp jump back
    interrupted_at_s: float | None  # Ctrl-C (Replay.interrupt): the log time mapped up to (s from its first message)
    peak_memory_mb: float
    map_memory_mb: float
    voxels: dict
    static: dict | None
    resume: dict | None
    snapshots: list = field(default_factory=list)  # SnapshotSink
    snapshots_skipped_low_disk: int = 0  # periodic snapshots left out: the output's disk was nearly full
    events: dict | None = None  # EventsSink
    processing_latency_ms: dict | None = None  # MetricsSink
    localization: dict | None = None  # LocalizationSink (--localize)
    outputs: dict = field(default_factory=dict)  # every sink: name -> path

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
