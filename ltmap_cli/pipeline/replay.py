"""The replay pipeline: log -> frames -> mapper -> outputs.

Messages are read in log-time order (several logs merged). tf and odometry go into the tf
buffer at once; sensor frames wait ``replay.tf_wait`` seconds of log time (so the tf samples
after their header stamp have arrived), then are placed with the transform at their header stamp
and integrated into O in stamp order. A tick of ``map.layers.tick`` seconds (by header stamp)
applies the ST/LT rules; snapshots are written every ``replay.snapshot_every`` seconds of log
time and at the end. A frame whose pose cannot be had is skipped and counted by reason; when
every frame is skipped the run fails naming the missing transform.

Nothing here prints: progress goes to a callback, results to the output folder and the returned
report.
"""

from __future__ import annotations

import contextlib
import heapq
import json
import os
import queue
import resource
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import Config, dump_config
from ..core.layers import LayeredMap, StaticGrid
from ..core.projection import FootprintTrace, Projection, project
from ..core.sensors import depth_to_points, scan_to_points, transform_points
from ..errors import InputError, OutputError, TransformError, output_error
from ..io.atomic import write_text_atomic
from ..io.decode import RawDepthFrame
from ..io.frames import CloudFrame, DepthFrame, OdometrySample, ScanFrame, TfSample
from ..io.transforms import TfBuffer, norm

NS = 1_000_000_000
MAX_PENDING = 200  # sensor frames held for tf at most (guards logs whose stamps run ahead)
IN_FLIGHT = 8  # frames whose rays and voxels the worker threads may compute ahead of integration
RAY_WORKERS = 2  # worker threads (at most the machine's cores)


@dataclass
class Progress:
    log_done_s: float
    log_total_s: float
    frames: int
    wall_s: float

    @property
    def speed(self) -> float:
        return self.log_done_s / self.wall_s if self.wall_s > 0 else 0.0


@dataclass
class ReplayRequest:
    logs: list[Path]
    out_dir: Path
    static: Path | None = None
    resume: Path | None = None


@dataclass
class _Counts:
    used: Counter = field(default_factory=Counter)  # topic -> frames integrated
    skipped: Counter = field(default_factory=Counter)  # reason -> frames skipped
    skipped_by_topic: Counter = field(default_factory=Counter)
    no_footprint: int = 0
    rays: int = 0
    frame_ms: dict = field(default_factory=dict)  # topic -> [wall ms per frame]
    stamps: dict = field(default_factory=dict)  # topic -> [header stamps ns] (frame periods)
    tick_ms: list = field(default_factory=list)
    stage_s: Counter = field(default_factory=Counter)  # stage -> wall s spent in it (see Replay.stages)
    depth_filtered_frames: int = 0  # depth frames passed through the flying-pixel filter
    depth_filtered_pixels: int = 0  # pixels it dropped


def load_static(path: Path, cfg: Config) -> tuple[StaticGrid, dict, object]:
    """S from a build-static output or a map_server YAML, resampled onto the map lattice."""
    from ..io.static_layer import load_static_input

    layer = load_static_input(path, wall_height=cfg.replay.static_wall_height)
    g = layer.grid
    static = StaticGrid.from_height_map(g.data, layer.height, g.resolution, g.origin, cfg.map.resolution)
    info = {
        "path": str(path),
        "source_resolution": g.resolution,
        "cells": [int(g.data.shape[1]), int(g.data.shape[0])],
        "wall_height": layer.wall_height,
        "static_voxels": int((static.top_k + 1).clip(min=0).sum()),
    }
    return static, info, layer


def _seed_keys(layer, cfg: Config) -> np.ndarray:
    """LT seeds of a build-static layer (furniture drawn as long-term) as voxel keys."""
    h = layer.lt_seed_height
    if h is None or not np.any(h > 0):
        return np.zeros((0, 3), dtype=np.int64)
    occ = np.where(h > 0, 100, -1).astype(np.int8)
    g = layer.grid
    seeds = StaticGrid.from_height_map(occ, h, g.resolution, g.origin, cfg.map.resolution)
    return seeds.voxel_keys()


class Replay:
    """One replay run. ``run()`` returns the report (also written to report.json).

    Speed (SPEC 8), with results identical to the plain serial path:

    - ``fast`` (default on): CDR messages of the high-rate types are parsed directly and depth
      images stay raw pixels (``LogSet.messages(fast=True)``); the rays of a depth image come from
      one fused kernel (``LayeredMap.depth_rays``) instead of points -> transform -> classify ->
      dedupe. Bit for bit the same rays, so the same map.
    - ``threads`` (default on): a reader thread reads and decodes the log ahead of the pipeline,
      and worker threads (``RAY_WORKERS``, at most one per core) compute the rays of the next
      frames and cast them (``LayeredMap.frame_voxels``: the voxels each frame updates, in
      order; numba kernels release the GIL) while the main thread applies the previous frames'
      voxels to O (``LayeredMap.apply_voxels``), strictly in order: frames are integrated, and
      ticks, snapshots and plans happen, in exactly the serial order.

    The report's ``stage_s`` gives the wall time per stage: ``read`` (reading and decoding the
    log; with the reader thread, the time the pipeline waited for it, and ``read_thread`` its own
    busy time), ``tf`` (tf buffer and lookups), ``rays`` (points and rays) and ``cast`` (ray
    casting: the voxels each frame updates), with the workers their busy time summed over the
    workers, and ``rays_wait`` the time integration waited for them; ``integrate`` (the voxels'
    updates in O), ``ticks`` (tick rules), ``projection`` (P and the virtual scan) and ``output``
    (snapshots, maps, measurements, replay.mcap); ``warmup`` is the kernels' first calls on a
    throw-away map before the log (numba compiles them after an install, then loads them from its
    disk cache), so that no frame or tick measures it.
    """

    fast: bool = True
    threads: bool = True

    def __init__(self, cfg: Config, request: ReplayRequest, progress: Callable[[Progress], None] | None = None):
        cfg.validate()
        self.cfg = cfg
        self.req = request
        self.progress = progress
        self.counts = _Counts()
        self.lmap: LayeredMap | None = None
        self.fixed_frame: str | None = None
        self.base_frame: str | None = None
        self.snapshots: list[dict] = []
        self.robot_xy: tuple[float, float] | None = None
        self.trajectory: list[tuple[float, float, float]] = []  # (t_s, x, y) of the robot per frame
        self.tracker = None
        if cfg.replay.plan_goal:
            from ..analysis.plan_tracker import PlanTracker

            self.tracker = PlanTracker(tuple(cfg.replay.plan_goal), cfg.replay.robot_radius)
        self._next_plan_s = 0.0
        self.mcap = None
        self._next_map_ns = None
        self._map_dirty = True
        self._p_latest: Projection | None = None
        self._p_now_key: tuple | None = None  # (frame_id, tick_index) of _p_now_value
        self._p_now_value: Projection | None = None
        self._footprint: FootprintTrace | None = None  # the cells of self.trajectory's footprint
        self._members: dict[int, np.ndarray] = {}  # event id -> its D voxel ids (find_events)
        self._p_published = None  # ((shape, origin), data) of the last /map written
        self._frame_log: deque = deque()  # (stamp ns, lmap.frame_id) of the frames of the last seconds
        self._jobs: deque = deque()
        self._pool = None

    # ------------------------------------------------------------------------------------
    def run(self) -> dict:
        req = self.req
        t_wall0 = time.perf_counter()
        self._created_out = not req.out_dir.exists()
        try:  # first: a bad -o must not cost a whole replay
            req.out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise output_error(err, f"the output folder {req.out_dir}") from None
        if not os.access(req.out_dir, os.W_OK):
            raise OutputError(f"cannot write the output folder {req.out_dir}: permission denied; choose another -o")
        from ..outputs.names import check_replay_outputs

        check_replay_outputs(req.out_dir, self.cfg, static=req.static is not None)
        try:
            return self._setup_and_run(t_wall0)
        except BaseException:
            import shutil

            if self.mcap is not None:
                self.mcap.abort()
            shutil.rmtree(self._staging(), ignore_errors=True)
            if self._created_out and req.out_dir.is_dir() and not any(req.out_dir.iterdir()):
                req.out_dir.rmdir()  # a failed run into a new folder leaves nothing behind
            raise

    def _setup_and_run(self, t_wall0: float) -> dict:
        cfg, req = self.cfg, self.req
        static, static_info, static_layer = (None, None, None)
        if req.static is not None:
            static, static_info, static_layer = load_static(req.static, cfg)
        self.lmap = lmap = LayeredMap(cfg.map, static=static)
        self._warm_up()
        resume_info = None
        if static_layer is not None and req.resume is not None:
            # the resumed long-term map already holds the seeds, as day 1 left them (seen gone or
            # not): seeding again would bring back furniture seen gone
            if len(_seed_keys(static_layer, cfg)):
                static_info["long_term_seed_voxels"] = 0
                static_info["long_term_seed_note"] = "not seeded: --resume carries the long-term map"
        elif static_layer is not None:
            seeds = _seed_keys(static_layer, cfg)
            if len(seeds):
                lmap.seed_long_term(seeds, 1.0)
                static_info["long_term_seed_voxels"] = len(seeds)
        if req.resume is not None:
            from ..outputs.snapshots import load_resume

            resume_info = load_resume(lmap, req.resume)

        tf = TfBuffer(tolerance_ns=int(cfg.replay.tf_tolerance * NS))
        mounts = [tf.add_mount(spec) for spec in cfg.replay.tf]
        self.tf = tf
        out = req.out_dir
        if cfg.replay.mcap_out:
            from ..io.mcap_out import ReplayMcapWriter

            self.mcap = ReplayMcapWriter(out / "replay.mcap")
        self._mounts = mounts  # written to replay.mcap's /tf_static once the log's start is known
        return self._run(logs_paths=req.logs, out=out, static_info=static_info, resume_info=resume_info,
                         t_wall0=t_wall0)  # fmt: skip

    def _run(self, logs_paths, out, static_info, resume_info, t_wall0) -> dict:
        from ..io.logs import open_logs

        cfg, req, lmap, tf = self.cfg, self.req, self.lmap, self.tf
        stopped_at = None
        with open_logs(logs_paths, allow_truncated=cfg.replay.allow_truncated) as logs:
            sel = logs.select(
                scan_topics=cfg.replay.scan_topics,
                cloud_topics=cfg.replay.cloud_topics,
                depth_topics=cfg.replay.depth_topics,
            )
            self.log_start = logs.start_ns
            if self.mcap is not None:
                # the mounts given with --tf go to /tf_static, so that a viewer places the sensors
                # where the replay did (stamped at the log's start, like the log's own)
                for m in self._mounts:
                    self.mcap.write_tf(self.log_start, [(m.parent, m.child, m.translation, m.rotation_xyzw)],
                                       static=True)  # fmt: skip
            self.log_total_s = max((logs.end_ns - logs.start_ns) / NS, 1e-9)
            tick_ns = int(round(cfg.map.layers.tick * NS))
            wait_ns = int(cfg.replay.tf_wait * NS)
            snap_ns = int(round(cfg.replay.snapshot_every * NS))
            self._pending: list = []
            self._seq = 0
            self._tick_end: int | None = None
            self._tick_ns = tick_ns
            self._next_snapshot = snap_ns
            self._snap_ns = snap_ns
            self._t0: int | None = None
            self._last_progress = 0.0
            self._t_wall0 = t_wall0
            stage = self.counts.stage_s
            stream = logs.messages(sel, fast=self.fast, depth_max_rate=cfg.map.sensor.depth_max_rate)
            reader = _ReaderThread(stream, stage) if self.threads else _TimedIter(stream, stage)
            if self.threads:
                from concurrent.futures import ThreadPoolExecutor

                workers = max(1, min(RAY_WORKERS, os.cpu_count() or 1))
                self._pool = ThreadPoolExecutor(workers, thread_name_prefix="ltmap-rays")
            try:
                for topic, log_ns, item in reader:
                    if isinstance(item, (TfSample, OdometrySample)):
                        t0 = time.perf_counter()
                        tf.add(item)
                        stage["tf"] += time.perf_counter() - t0
                        if self.mcap is not None:
                            self._copy_tf(item, logs.start_ns)
                    else:
                        heapq.heappush(self._pending, (item.stamp_ns, self._seq, topic, item))
                        self._seq += 1
                    while self._pending and (
                        self._pending[0][0] <= log_ns - wait_ns or len(self._pending) > MAX_PENDING
                    ):
                        self._process(*heapq.heappop(self._pending)[2:])
                    self._report_progress(log_ns)
                while self._pending:
                    self._process(*heapq.heappop(self._pending)[2:])
                self._drain(0)
                if logs.stats.stopped_at is None:  # the whole log was read: the bar ends at 100 %
                    self._report_progress(self.log_start + int(round(self.log_total_s * NS)), force=True)
            finally:
                reader.close()
                if self._pool is not None:
                    self._pool.shutdown(wait=True, cancel_futures=True)
                    self._pool = None
                stats = logs.stats
            stopped_at = stats.stopped_at
            messages = dict(stats.messages_per_topic)
            not_decoded = dict(getattr(logs, "skipped", {}) or {})
            rate_skipped = dict(logs.rate_skipped)
            topics_not_used = dict(sel.skipped)
            selected = {"scans": sel.scans, "clouds": sel.clouds, "depth": sel.depths}

        total_used = sum(self.counts.used.values())
        if total_used == 0:
            if self.counts.skipped:
                reason, n = self.counts.skipped.most_common(1)[0]
                raise TransformError(f"every sensor frame was skipped ({n} x): {reason}")
            damaged = {k: v for k, v in not_decoded.items() if any(k.endswith(" " + t) for t in sel.sensor_topics)}
            if damaged:
                reason, n = max(damaged.items(), key=lambda kv: kv[1])
                raise InputError(f"no usable sensor frame in {', '.join(str(p) for p in req.logs)}: {reason} "
                                 f"({n} x, every one); the log is damaged there, or its message definitions "
                                 f"are wrong: check it with `ltmap info`")  # fmt: skip
            raise InputError(
                f"no sensor frames in {', '.join(str(p) for p in req.logs)} on topics "
                f"{', '.join(sel.sensor_topics) or '(none)'}; check the topics with `ltmap info`"
            )
        stage = self.counts.stage_s
        t0 = time.perf_counter()
        lmap.end_tick()  # the last, partial tick
        t1 = time.perf_counter()
        stage["ticks"] += t1 - t0
        if self.mcap is not None:
            self._publish_maps(self._last_stamp, force=True)
            self.mcap.close()
        self._snapshot(None)
        self._commit_snapshots()
        wall = time.perf_counter() - t_wall0
        t2 = time.perf_counter()
        stage["output"] += t2 - t1
        outputs = self._write_maps(out)
        t3 = time.perf_counter()
        events, processing = self._measurements(out)
        outputs["events"] = str(out / "events.csv")
        if cfg.replay.plots:
            outputs["plots"] = self._plots(out / "plots")
        stage["output"] += time.perf_counter() - t3
        stage["projection"] += t3 - t2  # _write_maps: three projections and their files
        if self.mcap is not None:
            outputs["mcap"] = str(out / "replay.mcap")
            outputs["mcap_messages"] = dict(self.mcap.counts)
        report = {
            "logs": [str(p) for p in req.logs],
            "fixed_frame": self.fixed_frame,
            "base_frame": self.base_frame,
            "topics_used": selected,
            "topics_not_used": topics_not_used,
            "messages_per_topic": messages,
            "messages_not_decoded": not_decoded,
            "frames_used": dict(self.counts.used),
            "frames_skipped": dict(self.counts.skipped),
            "frames_skipped_by_topic": dict(self.counts.skipped_by_topic),
            "frames_over_depth_max_rate": rate_skipped,
            "frames_without_footprint": self.counts.no_footprint,
            "depth_outlier_filter": {
                "enabled": cfg.replay.depth_outlier_filter,
                "frames": self.counts.depth_filtered_frames,
                "pixels_dropped": self.counts.depth_filtered_pixels,
            },
            "rays": self.counts.rays,
            "log_start_ns": int(self.log_start),
            "log_duration_s": round(self.log_total_s, 3),
            "wall_time_s": round(wall, 3),
            "speed_vs_real_time": round(self.log_total_s / wall, 2) if wall > 0 else None,
            "stage_s": {k: round(v, 3) for k, v in sorted(self.counts.stage_s.items())},
            "ticks": lmap.tick_index,
            "stopped_at": stopped_at,
            "peak_memory_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
            "map_memory_mb": round(lmap.nbytes() / 2**20, 1),
            "voxels": {
                "observed_blocks": lmap.O.n_blocks,
                "occupied_O": int((lmap.O.channel("logodds") > 0).sum()),
                "long_term_occupied": int(
                    (lmap.D.channel("lt") >= cfg.map.projection.occupied_thresh).sum()
                ),
            },
            "static": static_info,
            "resume": resume_info,
            "snapshots": self.snapshots,
            "events": events,
            "processing_latency_ms": processing,
            "outputs": outputs,
        }
        write_text_atomic(out / "config.yaml", self._inputs_comment() + dump_config(cfg))
        write_text_atomic(out / "report.json", json.dumps(report, indent=2, default=_json_default) + "\n")
        return report

    # ------------------------------------------------------------------------------------
    def _report_progress(self, log_ns: int, force: bool = False) -> None:
        if self.progress is None:
            return
        now = time.perf_counter()
        if not force and now - self._last_progress < 0.2:
            return
        self._last_progress = now
        done = min(max((log_ns - self.log_start) / NS, 0.0), self.log_total_s)
        self.progress(Progress(done, self.log_total_s, sum(self.counts.used.values()), now - self._t_wall0))

    def _skip(self, topic: str, reason: str) -> None:
        self.counts.skipped[reason] += 1
        self.counts.skipped_by_topic[topic] += 1

    def _choose_frames(self) -> None:
        frames = self.tf.frames
        self.fixed_frame = self.tf.fixed_frame(self.cfg.replay.fixed_frame)
        base = self.cfg.map.robot.base_frame
        if base not in frames:
            base = next((f for f in ("base_link", "base_footprint") if f in frames), base)
        self.base_frame = base

    def _inputs_comment(self) -> str:
        """config.yaml's header: the inputs of this run, which are not parameters, so that the run
        can be repeated with ``ltmap replay LOGS --config config.yaml`` and these options."""
        import shlex

        req = self.req
        args = ["ltmap", "replay", *(str(p) for p in req.logs)]
        if req.static is not None:
            args += ["--static", str(req.static)]
        if req.resume is not None:
            args += ["--resume", str(req.resume)]
        args += ["-o", str(req.out_dir), "--config", str(req.out_dir / "config.yaml")]
        return ("# every parameter of this run; its inputs were:\n"
                f"# {shlex.join(args)}\n")  # fmt: skip

    def _copy_tf(self, item, start_ns: int) -> None:
        """replay.mcap's /tf and /tf_static: the transforms the replay used, as it used them. A
        sample the tf buffer ignored (an edge a --tf mount or /tf owns) is not copied; a pose taken
        from nav_msgs/Odometry (no /tf for that edge) is written to /tf."""
        static = isinstance(item, TfSample) and item.static
        source = "odom" if isinstance(item, OdometrySample) else ("static" if static else "tf")
        edge = self.tf.edges.get(norm(item.child))
        if edge is None or edge.source != source or edge.parent != norm(item.parent):
            return
        self.mcap.write_tf(start_ns if static else item.stamp_ns,
                           [(norm(item.parent), norm(item.child), item.translation, item.rotation_xyzw)],
                           static=static)  # fmt: skip

    def _warm_up(self) -> None:
        from .warmup import warm_up

        t0 = time.perf_counter()
        warm_up(self.cfg.map)
        if self.tracker is not None:
            from ..analysis.planner import plan_path

            plan_path(np.zeros((4, 4), dtype=bool), (0, 0), (3, 3))
        self.counts.stage_s["warmup"] += time.perf_counter() - t0

    def _advance_ticks(self, stamp: int) -> None:
        lmap = self.lmap
        if self._tick_end is None:
            self._t0 = stamp
            self._tick_end = stamp + self._tick_ns
            return
        while stamp >= self._tick_end:
            stage = self.counts.stage_s
            t_tick = time.perf_counter()
            tr = lmap.end_tick()
            if tr.lt_entered or tr.lt_left:
                self._map_dirty = True
            t1 = time.perf_counter()
            stage["ticks"] += t1 - t_tick
            if self.tracker is not None:
                self._plan((self._tick_end - self.log_start) / NS)
                t2 = time.perf_counter()
                stage["projection"] += t2 - t1
                t1 = t2
            if self.mcap is not None:
                self._publish_maps(self._tick_end)
            if self._tick_end - self._t0 >= self._next_snapshot:
                self._snapshot((self._tick_end - self._t0) / NS)
                self._next_snapshot += self._snap_ns
            t2 = time.perf_counter()
            stage["output"] += t2 - t1
            # the whole tick: tick rules, planning, map messages and snapshots at this tick
            self.counts.tick_ms.append((t2 - t_tick) * 1e3)
            self._tick_end += self._tick_ns

    def _p_now(self) -> Projection:
        """P of the map as it is now, projected once per map state (frames and ticks change it):
        the planner, /map and the outputs at one state share one projection."""
        key = (self.lmap.frame_id, self.lmap.tick_index)
        if self._p_now_key != key:  # the cells the robot's footprint covered are free (SPEC 2.3)
            if self._footprint is None:
                self._footprint = FootprintTrace(self.cfg.map.projection.footprint_radius, self.lmap.resolution)
            cells = self._footprint.update(self.trajectory)
            self._p_now_key, self._p_now_value = key, project(self.lmap, footprint=cells)
        return self._p_now_value

    def _plan(self, t_s: float) -> None:
        """Plan from the robot's current position on the current P (for the planner latency)."""
        from ..io.mapfile import GridMap

        if self.robot_xy is None or t_s < self._next_plan_s:
            return
        self._next_plan_s = t_s + self.cfg.replay.plan_period
        p = self._p_now()
        self.tracker.update(t_s, GridMap(p.data, p.resolution, p.origin), self.robot_xy)

    def _publish_maps(self, stamp_ns: int, force: bool = False) -> None:
        """/map, /long_term_map and /ltmap/occupied_voxels in replay.mcap: at a tick where P
        changed (an obstacle entered or left LT, or free space grew), at most every map_period;
        the static voxels once."""
        if self._next_map_ns is None:
            self._next_map_ns = stamp_ns
            if self.lmap.static is not None:
                from ..core.grid import coord_to_pos

                keys = self.lmap.static.voxel_keys()
                self.mcap.write_cloud("/ltmap/static_voxels", stamp_ns, coord_to_pos(keys, self.lmap.resolution),
                                      self.fixed_frame)  # fmt: skip
        if not force and stamp_ns < self._next_map_ns:
            return
        from ..core.grid import coord_to_pos

        lmap, frame = self.lmap, self.fixed_frame
        p = self._p_now()
        sig = (p.data.shape, tuple(p.origin))
        last = self._p_published
        self._next_map_ns = stamp_ns + int(self.cfg.replay.map_period * NS)  # checked at most once a period
        if not force and not self._map_dirty and last is not None and last[0] == sig and np.array_equal(last[1], p.data):
            return
        self._p_published = (sig, p.data)
        self._p_latest = p
        self.mcap.write_grid("/map", stamp_ns, p.data, p.resolution, p.origin, frame)
        lt = project(lmap, use_static=False)
        self.mcap.write_grid("/long_term_map", stamp_ns, lt.data, lt.resolution, lt.origin, frame)
        keys = lmap.occupied_keys("LT")
        self.mcap.write_cloud("/ltmap/occupied_voxels", stamp_ns, coord_to_pos(keys, lmap.resolution), frame,
                              values=lmap.values("LT", keys), value_name="long_term")  # fmt: skip
        self._map_dirty = False

    def _publish_fused_scan(self, item: ScanFrame, T: np.ndarray) -> None:
        """/scan_fused: the virtual scan of SPEC 2.3 in the laser's frame and angles."""
        from ..core.projection import virtual_scan

        if self._p_latest is None:
            self._p_latest = self._p_now()
        yaw = float(np.arctan2(T[1, 0], T[0, 0]))
        sign = 1.0 if T[2, 2] >= 0 else -1.0  # an upside-down laser turns the other way
        angles = sign * item.angles
        # current obstacles in O: updated by a frame stamped within the window before this scan
        # (_consume keeps the last few seconds of frames in _frame_log)
        t_from = item.stamp_ns - int(self.cfg.replay.scan_fused_window_s * NS)
        since = next((fid for stamp, fid in self._frame_log if stamp >= t_from), self.lmap.frame_id + 1)
        ranges = virtual_scan(self.lmap, self._p_latest, (T[0, 3], T[1, 3], yaw), angles, item.range_min,
                              item.range_max, o_since_frame=since)  # fmt: skip
        self.mcap.write_scan("/scan_fused", item.stamp_ns, item.frame_id, item.angle_min, item.angle_increment,
                             item.range_min, item.range_max, ranges)  # fmt: skip

    def _snapshot(self, t_s: float | None) -> None:
        from ..outputs.snapshots import write_snapshot

        # staged beside the output: a run that fails leaves the folder's snapshots/ as it was
        paths = write_snapshot(self.lmap, self._staging(), t_s, {"fixed_frame": self.fixed_frame})
        final = self.req.out_dir / "snapshots"
        self.snapshots.append({"log_time_s": t_s, **{k: str(final / Path(v).name) for k, v in paths.items()}})

    def _staging(self) -> Path:
        return self.req.out_dir / f".snapshots.partial-{os.getpid()}"

    def _commit_snapshots(self) -> None:
        """This run's snapshots become OUT/snapshots (the previous run's, if any, go)."""
        import shutil

        staging, final = self._staging(), self.req.out_dir / "snapshots"
        if not staging.is_dir():
            return
        old = final.with_name(f".snapshots.old-{os.getpid()}")
        if final.exists():
            os.replace(final, old)
        os.replace(staging, final)
        shutil.rmtree(old, ignore_errors=True)

    def _process(self, topic: str, item) -> None:
        """Place a sensor frame (tf lookups, main thread), have its rays computed (worker thread
        or here) and integrate frames in order."""
        t_start = time.perf_counter()
        if self.fixed_frame is None:
            self._choose_frames()
        if not item.frame_id:
            self._skip(topic, f"{topic}: message has an empty header.frame_id")
            return
        T, reason = self.tf.try_lookup(self.fixed_frame, item.frame_id, item.stamp_ns)
        if T is None:
            self._skip(topic, reason)
            return
        robot, _ = self.tf.try_lookup(self.fixed_frame, self.base_frame, item.stamp_ns)
        lookup_s = time.perf_counter() - t_start
        self.counts.stage_s["tf"] += lookup_s
        if self._pool is None:
            self._jobs.append((topic, item, T, robot, self._rays(item, T, robot), lookup_s))
            self._drain(0)
            return
        self._jobs.append((topic, item, T, robot, self._pool.submit(self._rays, item, T, robot), lookup_s))
        self._drain(IN_FLIGHT)

    def _rays(self, item, T: np.ndarray, robot: np.ndarray | None) -> tuple:
        """What ``LayeredMap.integrate`` would do before touching the map, for one frame: its
        rays, then its voxels (``frame_voxels``). Returns (hits, misses, rays cast, rays seconds,
        cast seconds, flying pixels dropped or -1 without the filter). Reads no map state (runs
        in a worker thread)."""
        t0 = time.perf_counter()
        sc = self.cfg.map.sensor
        lmap = self.lmap
        rc = self.cfg.replay
        dropped = -1
        if rc.depth_outlier_filter and isinstance(item, (DepthFrame, RawDepthFrame)):
            item, dropped = self._filter_depth(item)
        if isinstance(item, RawDepthFrame) and self.fast:
            k = item.intrinsics
            ends, kind = lmap.depth_rays(item.raw, k.fx, k.fy, k.cx, k.cy, T, sc.depth_max_range, robot,
                                         dedupe=sc.dedupe_dense)  # fmt: skip
        else:
            dedupe = False
            if isinstance(item, ScanFrame):
                pts, rets = scan_to_points(
                    item.ranges, item.angle_min, item.angle_increment, item.range_min, item.range_max,
                    clear_no_return=sc.clear_no_return,
                )  # fmt: skip
                max_range = float(item.range_max)
            elif isinstance(item, (DepthFrame, RawDepthFrame)):
                k = item.intrinsics
                pts = depth_to_points(item.depth_m, k.fx, k.fy, k.cx, k.cy)
                rets = None
                max_range = sc.depth_max_range
                dedupe = sc.dedupe_dense
            elif isinstance(item, CloudFrame):
                pts = np.asarray(item.points, dtype=np.float64)
                rets = None
                max_range = sc.depth_max_range
                dedupe = sc.dedupe_dense
            else:  # pragma: no cover - the reader yields only these
                raise TypeError(type(item).__name__)
            world = transform_points(T, pts)
            ends, kind = lmap.rays(T[:3, 3], world, rets, max_range=max_range, robot_pose=robot, dedupe=dedupe)
        t1 = time.perf_counter()
        hits, misses = lmap.frame_voxels(T[:3, 3], ends, kind)
        return hits, misses, int((kind > 0).sum()), t1 - t0, time.perf_counter() - t1, dropped

    def _filter_depth(self, item) -> tuple[DepthFrame, int]:
        """The frame with its flying pixels set invalid (NaN), and how many (counted in the
        report by the main thread: this runs in a worker)."""
        from .filters import flying_pixel_mask

        rc = self.cfg.replay
        k = item.intrinsics
        depth = np.array(item.depth_m, dtype=np.float32)  # a copy: the message buffer stays as read
        drop = flying_pixel_mask(depth, k.fx, k.fy, k.cx, k.cy, radius=rc.depth_outlier_radius,
                                 min_neighbors=rc.depth_outlier_min_neighbors)  # fmt: skip
        depth[drop] = np.nan
        return DepthFrame(item.stamp_ns, item.frame_id, depth, k, item.topic), int(drop.sum())

    def _drain(self, keep: int) -> None:
        """Integrate queued frames in order until at most ``keep`` are left (and none whose rays
        are ready at the head, when the worker runs ahead)."""
        jobs = self._jobs
        while jobs and (len(jobs) > keep or (keep and not isinstance(jobs[0][4], tuple) and jobs[0][4].done())):
            self._consume(*jobs.popleft())

    def _consume(self, topic: str, item, T: np.ndarray, robot: np.ndarray | None, rays, lookup_s: float) -> None:
        stage = self.counts.stage_s
        if robot is None:
            self.counts.no_footprint += 1
        else:
            self.robot_xy = (float(robot[0, 3]), float(robot[1, 3]))
            self.trajectory.append(((item.stamp_ns - self.log_start) / NS, *self.robot_xy))
        self._advance_ticks(item.stamp_ns)
        if not isinstance(rays, tuple):
            t0 = time.perf_counter()
            rays = rays.result()
            stage["rays_wait"] += time.perf_counter() - t0
        hits, misses, n_rays, rays_s, cast_s, dropped = rays
        stage["rays"] += rays_s
        stage["cast"] += cast_s
        t0 = time.perf_counter()
        r = self.lmap.apply_voxels(hits, misses, n_rays)
        integrate_s = time.perf_counter() - t0
        stage["integrate"] += integrate_s
        c = self.counts
        if dropped >= 0:
            c.depth_filtered_frames += 1
            c.depth_filtered_pixels += dropped
        c.used[topic] += 1
        c.rays += r.rays
        self._last_stamp = max(getattr(self, "_last_stamp", 0), item.stamp_ns)
        fused_s = 0.0
        if self.mcap is not None:
            self._frame_log.append((item.stamp_ns, self.lmap.frame_id))
            keep_ns = item.stamp_ns - 2 * int(self.cfg.replay.scan_fused_window_s * NS) - NS
            while len(self._frame_log) > 1 and self._frame_log[0][0] < keep_ns:
                self._frame_log.popleft()
        if self.mcap is not None and isinstance(item, ScanFrame):
            t0 = time.perf_counter()
            self._publish_fused_scan(item, T)
            fused_s = time.perf_counter() - t0
            stage["projection"] += fused_s
        c.frame_ms.setdefault(topic, []).append((lookup_s + rays_s + cast_s + integrate_s + fused_s) * 1e3)
        c.stamps.setdefault(topic, []).append(item.stamp_ns)

    # ------------------------------------------------------------------------------------
    def _clock(self):
        from ..analysis.events import TickClock

        t0 = (self._t0 - self.log_start) / NS if self._t0 is not None else 0.0
        return TickClock(t0, self.cfg.map.layers.tick)

    def _measurements(self, out: Path) -> tuple[dict, dict]:
        """events.csv and the summaries of report.json: change events with their latencies, and
        wall-clock processing time per frame (by topic) and per tick against the frame period."""
        from ..analysis.events import event_history, events_csv, find_events, percentiles
        from ..core.grid import band_k_range
        from ..core.projection import static_fills

        lmap, clock = self.lmap, self._clock()
        pc = self.cfg.map.projection
        k_lo, k_hi = band_k_range(pc.z_min, pc.z_max, lmap.resolution)
        lt_keys = lmap.occupied_keys("LT")
        final_cols = lt_keys[(lt_keys[:, 2] >= k_lo) & (lt_keys[:, 2] <= k_hi), :2]
        rc = self.cfg.replay
        filtered: dict = {}
        events, members = find_events(
            lmap.events.transitions, lmap.D.block_coords[: lmap.D.n_blocks], lmap.resolution, clock,
            window_s=rc.event_window_s, link_m=rc.event_link_m, min_voxels=rc.event_min_voxels,
            min_p_cells=rc.event_min_p_cells, filtered=filtered, drop_surface=rc.event_drop_surface,
            final_cols=final_cols, static_cols=lambda cols: static_fills(lmap, cols),
        )  # fmt: skip
        if self.tracker is not None:
            self.tracker.attribute(events, lmap.resolution)
        write_text_atomic(out / "events.csv", events_csv(events))
        self.events = events
        self._members = members
        hist_i, hist_v = lmap.events.history
        self.histories = {
            e["id"]: event_history(hist_i, hist_v, members[e["id"]], clock,
                                   t_from_s=(e["t_start_s"] if e["t_start_s"] is not None else e["t_lt_s"]) - 5.0)  # fmt: skip
            for e in events
        }
        lat = {"add": [e["latency_s"] for e in events if e["kind"] == "appear" and e["latency_s"] is not None],
               "remove": [e["latency_s"] for e in events if e["kind"] == "disappear" and e["latency_s"] is not None],
               "planner": [e["planner_latency_s"] for e in events if e.get("planner_latency_s") is not None]}  # fmt: skip
        self.latencies = lat
        summary = {
            "count": len(events),
            "appear": sum(e["kind"] == "appear" for e in events),
            "disappear": sum(e["kind"] == "disappear" for e in events),
            # groups below event_min_voxels that changed fewer than event_min_p_cells cells of P
            "filtered": {**filtered, "min_voxels": rc.event_min_voxels, "min_p_cells": rc.event_min_p_cells,
                         "drop_surface": rc.event_drop_surface},
            "add_latency_s": percentiles(lat["add"]),
            "remove_latency_s": percentiles(lat["remove"]),
            "planner_latency_s": percentiles(lat["planner"]) if self.tracker is not None else None,
            "list": events,
        }
        if self.tracker is not None:
            summary["plan"] = self.tracker.summary()
        processing = {}
        self.periods_ms = {}
        for topic, ms in self.counts.frame_ms.items():
            stamps = np.sort(np.asarray(self.counts.stamps[topic], dtype=np.int64))
            period = float(np.median(np.diff(stamps)) / 1e6) if len(stamps) > 1 else None
            self.periods_ms[topic] = period
            processing[topic] = {**percentiles(ms), "frame_period_ms": period,
                                 "keeps_up": (bool(np.percentile(ms, 95) < period) if period else None)}  # fmt: skip
        tick_period = self.cfg.map.layers.tick * 1e3
        processing["tick"] = {**percentiles(self.counts.tick_ms), "frame_period_ms": tick_period}
        self.periods_ms["tick"] = tick_period
        return summary, processing

    def _plots(self, folder: Path) -> dict[str, str]:
        """plots/: ST and LT of each event over time (Fig. 4), latency box plots (Fig. 5), the
        processing-time histogram, the final map with events (and path), and map_3d.png."""
        from ..core.grid import coord_to_pos
        from ..io.mapfile import GridMap
        from ..viz.plots import write_summary_plots

        lmap, cfg = self.lmap, self.cfg
        p = self._p_now()
        for e in self.events:
            h = self.histories.get(e["id"])
            if h is None:
                continue
            first = "first seen" if e["kind"] == "appear" else "first seen free"
            shown = "in P" if e["kind"] == "appear" else "out of P"
            h["marks"] = {k: v for k, v in ((first, e["t_start_s"]), (shown, e["t_in_map_s"]),
                                            ("path changed", e.get("t_plan_change_s"))) if v is not None}  # fmt: skip
        keys = lmap.occupied_keys("LT")
        static_keys = lmap.static.voxel_keys() if lmap.static is not None else None
        traj = np.array([(x, y) for _, x, y in self.trajectory]) if self.trajectory else None
        lay = cfg.map.layers
        return write_summary_plots(
            folder, grid=GridMap(p.data, p.resolution, p.origin), events=self.events, histories=self.histories,
            latencies=self.latencies if self.tracker is not None else {k: v for k, v in self.latencies.items()
                                                                       if k != "planner"},
            processing_ms={k: np.asarray(v) for k, v in self.counts.frame_ms.items()} | {"tick": np.asarray(
                self.counts.tick_ms)},
            periods_ms=self.periods_ms,
            path_xy=self.tracker.final_path_xy if self.tracker is not None else None, robot_xy=traj,
            occupied_thresh=cfg.map.projection.occupied_thresh,
            targets={"add": lay.st_rise_s, "remove": lay.lt_fall_s}, event_cells=self._event_cells(),
            map3d={"centers": coord_to_pos(keys, lmap.resolution), "values": lmap.values("LT", keys),
                   "resolution": lmap.resolution,
                   "static_centers": coord_to_pos(static_keys, lmap.resolution) if static_keys is not None else None,
                   "title": None},
        )  # fmt: skip

    def _event_cells(self) -> dict[int, np.ndarray]:
        """{event id: (N, 2) lower-left corners (m) of the xy cells its voxels cover}, for the map plot."""
        from ..analysis.events import _voxel_keys

        lmap = self.lmap
        coords = lmap.D.block_coords[: lmap.D.n_blocks]
        return {eid: np.unique(_voxel_keys(vids // 512, vids % 512, coords)[:, :2], axis=0) * lmap.resolution
                for eid, vids in self._members.items()}  # fmt: skip

    def _write_maps(self, out: Path) -> dict[str, str]:
        from ..io.mapfile import GridMap, write_map

        cfg, lmap = self.cfg, self.lmap
        pc = cfg.map.projection
        written = {}

        def save(name: str, p: Projection, mode: str) -> None:
            data = p.scale_data() if mode in ("scale", "raw") else p.data
            write_map(
                out / f"{name}.yaml", GridMap(data, p.resolution, p.origin), mode=mode,
                occupied_thresh=pc.occupied_thresh, free_thresh=pc.free_thresh, negate=cfg.replay.negate,
            )  # fmt: skip
            written[name] = str(out / f"{name}.yaml")

        save("map", self._p_now(), cfg.replay.mode)
        save("long_term", project(lmap, use_static=False), cfg.replay.mode)
        if lmap.static is not None:
            save("static", project(lmap, use_lt=False, use_o_free=False), "trinary")
        return written


class _TimedIter:
    """Iterate a frame stream in this thread, adding the time spent in it to ``stage["read"]``."""

    def __init__(self, stream, stage: Counter):
        self.stream = stream
        self.stage = stage

    def __iter__(self):
        it = iter(self.stream)
        while True:
            t0 = time.perf_counter()
            try:
                x = next(it)
            except StopIteration:
                self.stage["read"] += time.perf_counter() - t0
                return
            self.stage["read"] += time.perf_counter() - t0
            yield x

    def close(self) -> None:
        close = getattr(self.stream, "close", None)
        if close is not None:
            close()


class _ReaderThread:
    """Read and decode a frame stream in a background thread, handing batches to the consumer
    through a bounded queue (log order kept; an exception of the stream is re-raised where the
    consumer reaches it). ``stage["read"]``: time the consumer waited; ``stage["read_thread"]``:
    the reader's busy time."""

    BATCH = 32
    DEPTH = 8  # batches queued at most

    def __init__(self, stream, stage: Counter):
        self.stream = stream
        self.stage = stage
        self.q: queue.Queue = queue.Queue(maxsize=self.DEPTH)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="ltmap-reader", daemon=True)
        self.thread.start()

    def _put(self, item) -> bool:
        while not self.stop.is_set():
            try:
                self.q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        busy = 0.0
        batch: list = []
        try:
            it = iter(self.stream)
            while not self.stop.is_set():
                t0 = time.perf_counter()
                try:
                    x = next(it)
                except StopIteration:
                    busy += time.perf_counter() - t0
                    break
                busy += time.perf_counter() - t0
                batch.append(x)
                if len(batch) >= self.BATCH:
                    if not self._put(("items", batch)):
                        return
                    batch = []
            if batch:
                self._put(("items", batch))
            self._put(("end", None))
        except BaseException as err:  # noqa: BLE001 - handed to the consumer
            if batch:
                self._put(("items", batch))
            self._put(("error", err))
        finally:
            self.stage["read_thread"] += busy
            close = getattr(self.stream, "close", None)
            if close is not None and self.stop.is_set():
                close()

    def __iter__(self):
        while True:
            t0 = time.perf_counter()
            kind, payload = self.q.get()
            self.stage["read"] += time.perf_counter() - t0
            if kind == "items":
                yield from payload
            elif kind == "end":
                return
            else:
                raise payload

    def close(self) -> None:
        self.stop.set()
        while self.thread.is_alive():
            with contextlib.suppress(queue.Empty):
                self.q.get(timeout=0.05)
        self.thread.join()


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, Path):
        return str(o)
    return str(o)

