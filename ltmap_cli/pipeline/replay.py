"""The replay: log -> frames -> mapper -> sinks -> output folder.

``Replay.run`` wires the stages and runs them: the reader (``reader``: the logs merged in log
order, decoded ahead in a thread), the scheduler (``scheduler``: tf in, frames held for tf and
placed at their header stamp, or skipped with a reason), the rays of each sensor type computed in
worker threads (``rays``, ``executor``: applied to O strictly in order, so the map is that of the
serial path), the tick clock (``clock``: ST/LT rules every ``map.layers.tick`` s of header time)
and the sinks (``sinks``: planner, replay.mcap, snapshots, map files, events, plots, metrics),
whose parts make the report (``report``). Nothing here prints: progress goes to a callback,
results to the output folder and the returned report.
"""

from __future__ import annotations

import json
import resource
import threading
import time
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..analysis.hints import body_frame_suspect, clock_apart
from ..config import Config, dump_config
from ..core.layers import LayeredMap, StaticGrid
from ..errors import InputError, LtmapWarning, MapFileError, RunInterrupted, TransformError, human
from ..io.atomic import write_text_atomic
from ..io.camera_file import load_camera_infos
from ..io.decode import RawDepthFrame
from ..io.frames import DepthFrame, OdometrySample, ScanFrame, TfSample, frame_nbytes
from ..io.logs import open_logs
from ..io.static_layer import load_static_input
from ..io.transforms import TfBuffer
from ..outputs.snapshots import load_resume
from ..static.memory import lattice_bytes
from ..viz.plots import MAX_HISTORY_EVENTS
from .clock import Ticker
from .executor import OrderedExecutor
from .localize import localize_logs
from .rays import CastFrame, FrameCaster
from .reader import open_reader
from .report import Report
from .scheduler import Placed, Scheduler, Skipped, TfSeen
from .sinks import (
    EventsSink,
    FrameDone,
    LocalizationSink,
    MapsSink,
    McapSink,
    MetricsSink,
    PlannerSink,
    PlotsSink,
    RunState,
    Sink,
    SnapshotSink,
    TickDone,
    inputs_comment,
)
from .timing import StageTimer
from .warmup import (
    BackgroundCompile,
    BackgroundWarmUp,
    box_blocks,
    depth_bits,
    depth_groups,
    depth_key,
    groups_cached,
    kernels_cached,
    lists_needed,
    replay_groups,
    scan_box_blocks,
    warm_depth,
    warm_depth_points,
    warm_up,
)

NS = 1_000_000_000
COMPILING = "compiling kernels (first run only)"  # the progress's phase while a first run waits for them


@dataclass
class Progress:
    log_done_s: float
    log_total_s: float
    frames: int
    wall_s: float  # since the run began, the kernels' warm-up left out (a first run's compiling: not mapping)
    phase: str | None = None  # a step that is not mapping the log (compiling kernels, writing plots)

    @property
    def speed(self) -> float:
        return self.log_done_s / self.wall_s if self.wall_s > 0 else 0.0


@dataclass
class ReplayRequest:
    logs: list[Path]
    out_dir: Path  # where the files are written
    static: Path | None = None
    resume: Path | None = None
    final_dir: Path | None = None  # the folder the user named, when out_dir is its staging folder

    @property
    def shown_dir(self) -> Path:
        return self.final_dir if self.final_dir is not None else self.out_dir


@dataclass
class FrameCounts:
    used: Counter = field(default_factory=Counter)  # topic -> frames integrated
    skipped: Counter = field(default_factory=Counter)  # reason -> frames skipped
    skipped_by_topic: Counter = field(default_factory=Counter)
    used_by_log: Counter = field(default_factory=Counter)  # index in request.logs -> frames integrated
    skipped_by_log: Counter = field(default_factory=Counter)
    angle_max_off: Counter = field(default_factory=Counter)  # topic -> scans whose angle_max disagrees
    no_footprint: int = 0
    rays: int = 0
    depth_filtered_frames: int = 0  # depth frames passed through the flying-pixel filter
    depth_filtered_pixels: int = 0  # pixels it dropped


def load_static(path: Path, cfg: Config) -> tuple[StaticGrid, dict, object]:
    """S from a build-static output or a map_server YAML, resampled onto the map lattice."""
    layer = load_static_input(path, wall_height=cfg.replay.static_wall_height)
    g = layer.grid
    check_static_memory(path, g.data.shape, g.resolution, cfg)  # before the lattice is allocated
    static = StaticGrid.from_height_map(g.data, layer.height, g.resolution, g.origin, cfg.map.resolution)
    info = {
        "path": str(path),
        "source_resolution": g.resolution,
        "cells": [int(g.data.shape[1]), int(g.data.shape[0])],
        "wall_height": layer.wall_height,
        "static_voxels": int((static.top_k + 1).clip(min=0).sum()),
        "unknown_cells": int((static.occ < 0).sum()),  # on the map lattice: kept unknown in S and P
    }
    return static, info, layer


def check_static_memory(path: Path, shape: tuple[int, ...], resolution: float, cfg: Config) -> None:
    """Refuse, in one line, a static map whose voxel lattice would need more than
    ``replay.max_static_mb`` (a 700 m map at 0.05 m, or a fine map under a very fine --resolution)."""
    h, w = int(shape[0]), int(shape[1])
    cells, need = lattice_bytes(w, h, float(resolution), cfg.map.resolution)
    limit = cfg.replay.max_static_mb * 2**20
    if need > limit:
        raise MapFileError(
            f"--static {path}: the static map is {w} x {h} cells ({w * resolution:.6g} x {h * resolution:.6g} m); "
            f"on the {cfg.map.resolution:g} m voxel lattice that is about {cells:.3g} cells, needing about "
            f"{human(need)}, over replay.max_static_mb ({cfg.replay.max_static_mb:g} MB); crop the map, use a coarser "
            f"--resolution, or raise the limit with --set replay.max_static_mb=N")


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

    ``fast`` (default on): CDR messages of the high-rate types are parsed directly and depth
    images stay raw pixels, whose rays come from one fused kernel; ``threads`` (default on): the
    reader thread and the ray workers. Both give bit for bit the map of the plain serial path.
    """

    fast: bool = True
    threads: bool = True

    def __init__(self, cfg: Config, request: ReplayRequest, progress: Callable[[Progress], None] | None = None):
        cfg.validate()
        self.cfg = cfg
        self.req = request
        self.progress = progress
        self.counts = FrameCounts()
        self.timer = StageTimer()
        self.lmap: LayeredMap | None = None
        self.sinks: list[Sink] = []
        self._last_progress = 0.0
        self._compile: BackgroundCompile | None = None
        self._compile_groups: list[str] | None = None  # what a warm run's children compile (a group it lacks)
        self._lists = False  # whether the run calls the lists group (lists_needed; a long-range scan turns it on)
        self._depth_cached: dict[tuple, bool] = {}  # depth_key -> its kernels in the cache (a warm run's groups_cached)
        self._loading: BackgroundWarmUp | None = None  # a warm run's kernels, loaded from the run's start
        self._compile_pending = False  # a first run whose compiling children are not started yet
        self._cold_depth = False  # ... and which will want the depth kernels
        self._compiled_depth: tuple | None = None  # the (dtype, contiguous) key of the depth kernels they compile
        self.localization = None  # the --localize pre-pass's result
        self._next_loc = 0
        self._warm_depth: set = set()  # (dtype, contiguous) of the raw depth images warmed up; "points": the plain path's
        self._done_s = 0.0  # log time done, for the progress of the phases after the log
        self.log_total_s = 0.0
        self._window_start_ns = 0  # the first log time mapped (the log's first message, or replay.start_s after it)
        self._warm = False
        self._compile_wait_s = 0.0  # the wait for a first run's compiling children (report.json kernels_compiled_s)
        self._stop = threading.Event()
        self.whole_log_read = False  # the log's last frame was read (an interrupt then changes nothing)
        self._workers_cpu_s = 0.0  # CPU seconds of the ray workers (report.json thread_cpu_s)
        self._reader_cpu_s = 0.0
        self._axes_checked: set[str] = set()  # depth topics whose frame's axes were looked at (_depth_axes)

    def interrupt(self) -> None:
        """Stop reading the log (from any thread; a signal handler's call): the frames read so
        far are mapped, the last tick ends, and the outputs are written as for a log that ended
        there; report.json's ``interrupted_at_s`` says where."""
        self._stop.set()

    def run(self) -> dict:
        self._t_wall0 = time.perf_counter()
        self._cpu0 = (time.thread_time(), time.process_time())
        try:
            return self._run()
        except BaseException:
            for s in self.sinks:
                s.abort()
            raise
        finally:
            if self._compile is not None:
                self._compile.stop()
            if self._loading is not None:
                self._loading.close()

    # ------------------------------------------------------------------------------------
    def _setup(self) -> tuple[RunState, TfBuffer, list, dict | None, dict | None]:
        """The map with S, the seeds or the resumed LT, the tf buffer with the --tf mounts."""
        cfg, req = self.cfg, self.req
        static, static_info, static_layer = (None, None, None)
        if req.static is not None:
            static, static_info, static_layer = load_static(req.static, cfg)
        self.lmap = lmap = LayeredMap(cfg.map, static=static)
        if static_layer is not None and len(seeds := _seed_keys(static_layer, cfg)):
            if req.resume is not None:
                # the resumed long-term map already holds the seeds, as day 1 left them (seen gone
                # or not): seeding again would bring back furniture seen gone
                static_info["long_term_seed_voxels"] = 0
                static_info["long_term_seed_note"] = "not seeded: --resume carries the long-term map"
            else:
                lmap.seed_long_term(seeds, 1.0)
                static_info["long_term_seed_voxels"] = len(seeds)
        resume_info = None
        if req.resume is not None:
            resume_info = load_resume(lmap, req.resume)
        tf = TfBuffer(tolerance_ns=int(cfg.replay.tf_tolerance * NS))
        mounts = [tf.add_mount(spec) for spec in cfg.replay.tf]
        if cfg.replay.localize:  # a pre-pass: map -> odom estimated from the scans (pipeline/localize.py)
            with self.timer("localize"):
                self.localization = localize_logs(req.logs, cfg, static_layer.grid if static_layer else None,
                                                  cfg.replay.tf, stop=self._stop.is_set)  # fmt: skip
            if self.localization.child is None and not self._stop.is_set():  # cannot align: one warning, the recorded poses
                warnings.warn(LtmapWarning(self.localization.message), stacklevel=2)
        req.out_dir.mkdir(parents=True, exist_ok=True)  # the CLI gives a fresh staging folder (OutputFolder)
        run = RunState(cfg, lmap, req.out_dir, req.shown_dir)
        return run, tf, mounts, static_info, resume_info

    def _make_sinks(self, run: RunState, mounts) -> list[Sink]:
        """The sinks this run has, in the order they are called (metrics last: a frame's and a
        tick's cost include the others')."""
        cfg = self.cfg
        planner = PlannerSink(cfg) if cfg.replay.plan_goal else None
        self.metrics = MetricsSink(cfg.map.layers.tick)
        # the ST / LT histories only feed the layer-history plot, which shows the first events
        self.events = EventsSink(self.ticker, planner, history_events=MAX_HISTORY_EVENTS if cfg.replay.plots else 0)
        sinks: list[Sink] = [planner] if planner is not None else []
        if cfg.replay.mcap_out:
            sinks.append(McapSink(run, mounts))
        if self.localization is not None:
            sinks.append(LocalizationSink(self.localization))
        sinks += [SnapshotSink(cfg), MapsSink(), self.events]
        if cfg.replay.plots:
            sinks.append(PlotsSink(self.events, self.metrics, planner))
        return sinks + [self.metrics]

    def _run(self) -> dict:
        cfg, req, timer = self.cfg, self.req, self.timer
        cached = kernels_cached()
        if cached and self.threads:
            self._loading = BackgroundWarmUp(cfg.map, replay_groups(cfg.replay))
        run, tf, mounts, static_info, resume_info = self._setup()
        self.state, self.lmap = run, run.lmap
        self.ticker = Ticker(cfg.map.layers.tick)
        self.sinks = self._make_sinks(run, mounts)
        self._frame_sinks = [s for s in self.sinks if type(s).on_frame is not Sink.on_frame]
        self._tick_sinks = [s for s in self.sinks if type(s).on_tick is not Sink.on_tick]
        self._tf_sinks = [s for s in self.sinks if type(s).on_tf is not Sink.on_tf]
        with open_logs(req.logs, allow_truncated=cfg.replay.allow_truncated,
                       max_message_mb=cfg.replay.max_message_mb) as logs:
            sel = logs.select(scan_topics=cfg.replay.scan_topics, cloud_topics=cfg.replay.cloud_topics,
                              depth_topics=cfg.replay.depth_topics,
                              given_info=load_camera_infos(cfg.replay.camera_info))  # fmt: skip
            run.log_start_ns = logs.start_ns
            start_ns, end_ns = self._window(logs)
            self.log_total_s = max((end_ns - start_ns) / NS, 1e-9)
            # the voxels listed, not masked: depth images and clouds whose box may be too big (a
            # long depth_max_range, a fine resolution); scans say frame by frame (_dispatch)
            self._lists = bool(sel.depths or sel.clouds) and lists_needed(box_blocks(
                cfg.map.sensor.depth_max_range, cfg.map.resolution))  # fmt: skip
            if not cached:  # the first run: compile while the log is read and checked, from
                self._cold_depth = bool(sel.depths) and self.fast  # its first depth image or frame (_start_compile)
                self._compile_pending = True
            elif groups_cached(["lists"]):  # loaded whether needed or not (milliseconds): a frame the
                self._lists = True  # checks above do not foresee (a step out of its box) lists its voxels
                if self._loading is not None:
                    self._loading.add(["lists"])
            elif self._lists:  # needed, and compiled by no run before (they did without)
                self._compile_groups, self._compile_pending = ["lists"], True
            for s in self.sinks:
                s.start(run, tf)
            self.scheduler = Scheduler(tf, wait_ns=int(cfg.replay.tf_wait * NS), timer=timer,
                                       fixed_frame_request=cfg.replay.fixed_frame,
                                       base_frame=cfg.map.robot.base_frame)  # fmt: skip
            self.caster = FrameCaster(run.lmap, cfg, fast=self.fast)
            self.executor = OrderedExecutor(self.threads, cfg.replay.workers)
            win_start, win_end = logs.window_ns(cfg.replay.start_s, cfg.replay.end_s)  # None: not bounded
            stream = logs.messages(sel, fast=self.fast, depth_max_rate=cfg.map.sensor.depth_max_rate,
                                   start_ns=win_start, end_ns=win_end,
                                   log_stamps=cfg.replay.sensor_stamps == "log")  # fmt: skip
            reader = open_reader(stream, timer.seconds, self.threads)
            stopped_ns = None  # interrupt(): the log time of the last sensor frame taken
            offsets: dict[str, float] = {}  # topic -> record time - header stamp of its first message (s)
            last_stamp: dict[str, int] = {}  # topic -> the header stamp of its last message ...
            last_log: dict[str, int] = {}  # ... and its log time
            jumps: dict[str, dict] = {}  # sensor topic -> its first jump back in header stamps (a clock reset)
            last_ns = start_ns
            failed = True
            try:
                self._feed_localization(None)
                for topic, log_ns, item in reader:
                    if self._stop.is_set():  # interrupted: only the poses of the frames taken, for tf_wait
                        stopped_ns = last_ns if stopped_ns is None else stopped_ns
                        if log_ns > stopped_ns + self.scheduler.hold.wait_ns:
                            break
                        if not isinstance(item, (TfSample, OdometrySample)):
                            continue
                    last_ns = log_ns
                    if not getattr(item, "static", False):
                        if topic not in offsets:
                            offsets[topic] = (log_ns - item.stamp_ns) / NS
                        prev = last_stamp.get(topic)  # (sensor frames: their stamps drive the ticks)
                        if prev is not None and item.stamp_ns < prev - STAMP_JUMP_NS and topic not in jumps \
                                and not isinstance(item, (TfSample, OdometrySample)):  # fmt: skip
                            jumps[topic] = {"at_s": round((log_ns - logs.start_ns) / NS, 3),
                                            "by_s": round((prev - item.stamp_ns) / NS, 3),
                                            "split_s": round((last_log[topic] + log_ns) / 2e9 - logs.start_ns / NS, 3)}  # fmt: skip
                        last_stamp[topic], last_log[topic] = item.stamp_ns, log_ns
                    if self._compile_pending and (not self._cold_depth or isinstance(item, RawDepthFrame)):
                        self._start_compile(item)
                    if self._loading is not None and self.fast and isinstance(item, RawDepthFrame) \
                            and self._depth_is_cached(key := depth_key(item.raw)):  # fmt: skip
                        self._loading.depth(key)  # (its kernels loaded before its turn)
                    self._feed_localization(log_ns)
                    for event in self.scheduler.feed(topic, log_ns, item):
                        self._dispatch(event)
                    self._report_progress(log_ns)
                self.whole_log_read = stopped_ns is None and not self._stop.is_set()
                self._feed_localization(2**63 - 1)
                for event in self.scheduler.flush():
                    self._dispatch(event)
                for job in self.executor.drain():
                    self._integrate(*job)
                if stopped_ns is not None:  # the log "ends" where it was interrupted
                    end_ns = max(min(stopped_ns, end_ns), start_ns)
                    self.log_total_s = max((end_ns - start_ns) / NS, 1e-9)
                elif logs.stats.stopped_at is None:  # the whole log was read: the bar ends at 100 %
                    self._report_progress(end_ns, force=True)
                failed = False
            finally:
                reader.close()
                self._reader_cpu_s = reader.cpu_s
                self.executor.close(wait=not failed)
            stats = logs.stats
            inputs = {
                "topics_used": {"scans": sel.scans, "clouds": sel.clouds, "depth": sel.depths},
                "topics_not_used": dict(sel.skipped),
                "messages_per_topic": dict(stats.messages_per_topic),
                "messages_not_decoded": dict(getattr(logs, "skipped", {}) or {}),
                "frames_over_depth_max_rate": dict(logs.rate_skipped),
                "stopped_at": stats.stopped_at,
                "window": None if not (cfg.replay.start_s or cfg.replay.end_s) else {
                    "start_s": round((start_ns - logs.start_ns) / NS, 3), "end_s": round((end_ns - logs.start_ns) / NS, 3)},
                "interrupted_at_s": None if stopped_ns is None else round((end_ns - logs.start_ns) / NS, 3),
                "header_stamp_offset_s": {t: round(v, 6) for t, v in sorted(offsets.items())},
                "tf_samples_invalid": dict(self.scheduler.tf.invalid),
                "stamp_jumps_back": jumps,
            }
        self._check_used(sel, inputs["messages_not_decoded"], offsets)
        return self._finish(run, inputs, static_info, resume_info)

    def _window(self, logs) -> tuple[int, int]:
        """The log times mapped: ``replay.start_s`` / ``end_s`` after the log's first message (the
        whole log by default); a start past the log's end is refused."""
        rc = self.cfg.replay
        start_ns, end_ns = logs.window_ns(rc.start_s, rc.end_s)
        start_ns = logs.start_ns if start_ns is None else start_ns
        end_ns = logs.end_ns if end_ns is None else min(end_ns, logs.end_ns)
        if start_ns > logs.end_ns:
            raise InputError(f"--start {rc.start_s:g} s is past the end of {', '.join(str(p) for p in self.req.logs)} "
                             f"(it lasts {(logs.end_ns - logs.start_ns) / NS:.1f} s from its first message); give a "
                             f"start within it")  # fmt: skip
        self._window_start_ns = start_ns
        return start_ns, end_ns

    def _check_used(self, sel, not_decoded: dict, offsets: dict[str, float]) -> None:
        """A run in which no frame was integrated fails, naming why (SPEC 4)."""
        if sum(self.counts.used.values()):
            return
        if self._stop.is_set():
            raise RunInterrupted(f"interrupted before any sensor frame of {', '.join(str(p) for p in self.req.logs)} "
                                 f"was mapped; nothing was written")  # fmt: skip
        if self.scheduler.fixed_later is not None:  # --fixed-frame named a frame the whole log lacks
            self.scheduler.tf.fixed_frame(*self.scheduler.fixed_later)  # raises info's line for it
        logs = ", ".join(str(p) for p in self.req.logs)
        if self.counts.skipped:
            reason, n = self.counts.skipped.most_common(1)[0]
            tf_topics = [t for t in offsets if t not in sel.sensor_topics]
            clocks = [c for c in (clock_apart(t, offsets, tf_topics) for t in sel.sensor_topics) if c]
            raise TransformError(f"every sensor frame was skipped ({n} x): {reason}"
                                 + (f"; {clocks[0]}" if clocks and self.cfg.replay.sensor_stamps == "header" else ""))
        damaged = {k: v for k, v in not_decoded.items() if any(k.endswith(" " + t) for t in sel.sensor_topics)}
        if damaged:
            reason, n = max(damaged.items(), key=lambda kv: kv[1])
            raise InputError(f"no usable sensor frame in {logs}: {reason} ({n} x, every one); the log is damaged "
                             "there, or its message definitions are wrong: check it with `ltmap info`")  # fmt: skip
        rc = self.cfg.replay
        if rc.start_s or rc.end_s:
            end = f"{rc.end_s:g} s" if rc.end_s else "the log's end"
            raise InputError(f"no sensor frames in {logs} between --start {rc.start_s:g} s and {end} (log time from its "
                             f"first message) on topics {', '.join(sel.sensor_topics) or '(none)'}; widen the window, "
                             f"or check when the sensors publish with `ltmap info`")  # fmt: skip
        raise InputError(f"no sensor frames in {logs} on topics {', '.join(sel.sensor_topics) or '(none)'}; "
                         "check the topics with `ltmap info`")  # fmt: skip

    def _finish(self, run: RunState, inputs: dict, static_info, resume_info) -> dict:
        cfg, lmap, timer = self.cfg, run.lmap, self.timer
        with timer("ticks"):
            lmap.end_tick()  # the last, partial tick
        parts: dict = {"outputs": {}}
        mapping_wall = None
        for s in self.sinks:
            if s.phase is not None:
                self._report_progress(None, force=True, phase=s.phase)
            with timer(s.finish_stage):
                part = s.finish(run)
            parts["outputs"].update(part.pop("outputs", {}))
            parts.update(part)
            if s.ends_mapping:  # the map is done: mapping speed up to here
                mapping_wall = time.perf_counter() - self._t_wall0
        wall = time.perf_counter() - self._t_wall0
        c, total = self.counts, self.log_total_s
        report = Report(
            logs=[str(p) for p in self.req.logs],
            fixed_frame=run.fixed_frame,
            base_frame=self.scheduler.base_frame,
            **inputs,
            frames_used=dict(c.used),
            frames_skipped=dict(c.skipped),
            frames_skipped_by_topic=dict(c.skipped_by_topic),
            frames_used_by_log={str(p): c.used_by_log[i] for i, p in enumerate(self.req.logs)},
            frames_skipped_by_log={str(p): c.skipped_by_log[i] for i, p in enumerate(self.req.logs)},
            scans_angle_max_off=dict(c.angle_max_off),
            frames_without_footprint=c.no_footprint,
            depth_outlier_filter={"enabled": cfg.replay.depth_outlier_filter, "frames": c.depth_filtered_frames,
                                  "pixels_dropped": c.depth_filtered_pixels},  # fmt: skip
            rays=c.rays,
            log_start_ns=int(run.log_start_ns),
            log_duration_s=round(total, 3),
            wall_time_s=round(wall, 3),
            speed_vs_real_time=round(total / wall, 2) if wall > 0 else None,
            mapping_wall_time_s=round(mapping_wall, 3),
            mapping_speed_vs_real_time=round(total / mapping_wall, 2) if mapping_wall > 0 else None,
            kernels_compiled_s=round(self._compile_wait_s, 3),
            stage_s=timer.rounded(),
            ray_workers=self.executor.workers,
            thread_cpu_s={"main": round(time.thread_time() - self._cpu0[0], 3),
                          "reader": round(self._reader_cpu_s, 3), "ray_workers": round(self._workers_cpu_s, 3),
                          "process": round(time.process_time() - self._cpu0[1], 3)},  # fmt: skip
            ticks=lmap.tick_index,
            peak_memory_mb=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
            map_memory_mb=round(lmap.nbytes() / 2**20, 1),
            voxels={
                "observed_blocks": lmap.O.n_blocks,
                "occupied_O": int((lmap.O.channel("logodds") > 0).sum()),
                "long_term_occupied": int((lmap.D.channel("lt") >= cfg.map.projection.occupied_thresh).sum()),
            },
            static=static_info,
            resume=resume_info,
            **parts,
        )
        out = self.req.out_dir
        write_text_atomic(out / "config.yaml", inputs_comment(self.req.logs, self.req.static, self.req.resume,
                                                              self.req.shown_dir) + dump_config(cfg))  # fmt: skip
        data = report.to_dict()
        write_text_atomic(out / "report.json", json.dumps(data, indent=2, default=_json_default) + "\n")
        return data

    def clock(self):
        """Tick index -> seconds since the log's start, for this run (events, plots, tests)."""
        return self.ticker.analysis_clock(self.state.log_start_ns)

    # ------------------------------------------------------------------------------------
    def _feed_localization(self, log_ns: int | None) -> None:
        """The pre-pass's map -> odom estimates enter tf as if recorded: each when the log reaches
        the scan it was estimated from (``None``: the first ones, before the log)."""
        loc = self.localization
        if loc is None or not loc.samples:
            return
        i = self._next_loc
        while i < len(loc.samples) and (i < 2 if log_ns is None else loc.log_times[i] <= log_ns):
            self._dispatch(self.scheduler.add_localized(loc.samples[i]))
            i += 1
        self._next_loc = i

    def _dispatch(self, event) -> None:
        if isinstance(event, TfSeen):
            for s in self._tf_sinks:
                s.on_tf(self.state, event.sample, event.source)
        elif isinstance(event, Skipped):
            c = self.counts
            c.skipped[event.reason] += 1
            c.skipped_by_topic[event.topic] += 1
            c.skipped_by_log[event.frame.log] += 1
            if getattr(event.frame, "angle_max_off", False):
                c.angle_max_off[event.topic] += 1
        else:
            if getattr(event.frame, "angle_max_off", False):
                self.counts.angle_max_off[event.topic] += 1
            if not self._warm:
                self._warm_up()
            if not self._lists and isinstance(event.frame, ScanFrame) and lists_needed(
                    scan_box_blocks(event.frame, event.T, self.cfg.map.resolution)):  # fmt: skip
                self._warm_lists()
            raw = event.frame.raw if isinstance(event.frame, RawDepthFrame) and self.fast else None
            if raw is not None and (key := depth_key(raw)) not in self._warm_depth:
                self._warm_depth.add(key)
                self._depth_kernels(key)
            elif raw is None and isinstance(event.frame, (DepthFrame, RawDepthFrame)) and "points" not in self._warm_depth:
                self._warm_depth.add("points")  # (the plain path: float32 metres as points)
                with self.timer("warmup"):
                    warm_depth_points(self.cfg.map)
            if self.state.fixed_frame is None:
                self.state.fixed_frame = self.scheduler.fixed_frame
            T = event.T
            if isinstance(event.frame, (DepthFrame, RawDepthFrame)):
                T = self._depth_axes(event.topic, event.frame.frame_id, T)
            self.executor.submit(event, self.caster.cast, event.frame, T, event.robot,
                                 nbytes=frame_nbytes(event.frame))  # fmt: skip
            for job in self.executor.ready():
                self._integrate(*job)

    def _depth_axes(self, topic: str, frame_id: str, T: np.ndarray) -> np.ndarray:
        """A depth image's pose: ``T`` (its frame in the fixed frame) for an optical frame (z
        forward, x right, y down: REP 103's camera convention, what the images are read in), or
        with ``replay.depth_frame_axes: body`` its frame taken as the camera's body frame (x
        forward, y left, z up: a Gazebo camera link). Warns once per topic when an optical frame
        faces straight up while its image's down is level: the signature of a body frame given
        as the image's frame."""
        if self.cfg.replay.depth_frame_axes == "body":
            return T @ BODY_FROM_OPTICAL
        # (the fixed frame's z is up: not so when the map is made in the camera's own frame)
        if topic not in self._axes_checked and frame_id != self.state.fixed_frame:
            self._axes_checked.add(topic)
            text = body_frame_suspect(topic, frame_id, T)
            if text:
                warnings.warn(LtmapWarning(text), stacklevel=2)
        return T

    def _start_compile(self, item) -> None:
        """A first run: start the children that compile the kernel groups it calls
        (``warmup.replay_groups``), at its first message, or with raw depth images at the first of
        them (a few messages later), whose pixels say which depth kernels: 16UC1 or 32FC1. (Started
        at once with the 16-bit ones, a 32FC1 log compiled those for nothing, then its own for 7 s
        in the middle of mapping.) With no depth image before the first frame is placed
        (``_warm_up``), the 16-bit ones, the encoding of most cameras."""
        self._compile_pending = False
        cfg = self.cfg
        bits = depth_bits(item.raw.dtype) if isinstance(item, RawDepthFrame) else "16"
        if self._cold_depth:  # (what the children compile: C-contiguous images of that encoding)
            self._compiled_depth = (np.dtype(np.float32 if bits == "32" else np.uint16), True)
        self._compile = BackgroundCompile(self._compile_groups or replay_groups(
            cfg.replay, self._cold_depth, self._projective(), bits, lists=self._lists))

    def _depth_is_cached(self, key: tuple) -> bool:
        if key not in self._depth_cached:
            self._depth_cached[key] = groups_cached(depth_groups(depth_bits(key[0]), self._projective()),
                                                    "C" if key[1] else "A")  # fmt: skip
        return self._depth_cached[key]

    def _projective(self) -> bool:
        return self.cfg.map.sensor.depth_integration == "projective"

    def _depth_kernels(self, key: tuple) -> None:
        """A depth image encoding's kernels, before its first frame is cast: loaded (a warm run's
        since its first image was read), or compiled by the first run's children. An encoding no
        run compiled before (a 32FC1 log after 16UC1 ones: 14 s of compiling, which the progress
        showed nothing of) is compiled in children of its own, the progress saying so; a layout
        the children do not compile (a strided image), here, saying so."""
        if self._compile is not None:  # a first run: its children compiled their encoding
            if key != self._compiled_depth:
                self._report_progress(None, force=True, phase=COMPILING)
        elif not self._depth_is_cached(key):
            if key[1]:
                self._compile = BackgroundCompile(depth_groups(depth_bits(key[0]), self._projective()))
                with self.timer("warmup"):
                    self._wait_compile()
                self._compile = None  # (its children ended: another encoding is checked as this one)
            else:
                self._report_progress(None, force=True, phase=COMPILING)
        with self.timer("warmup"):
            if self._loading is not None:
                self._loading.depth(key).result()
            else:
                warm_depth(self.cfg.map, *key)

    def _wait_compile(self) -> None:
        """Wait for the compiling children, the progress saying how many groups have ended."""
        self._report_progress(None, force=True, phase=COMPILING + (
            ": waiting for another ltmap's compiling" if self._compile.waiting else ""))
        t0 = time.perf_counter()
        self._compile.wait(lambda ended, total: self._report_progress(
            None, force=True, phase=f"{COMPILING}: {ended} of {total} kernel groups compiled"))
        self._compile_wait_s += time.perf_counter() - t0

    def _warm_up(self) -> None:
        """The kernels' first calls, before the first frame is cast: so a log whose frames are all
        skipped fails before any compiling is waited for, and no frame's time includes it."""
        self._warm = True
        if self._compile_pending:
            self._start_compile(None)
        with self.timer("warmup"):
            if self._compile is not None:
                self._wait_compile()
            if self._compile_groups:  # a warm run's group no run compiled before: compiled just now
                self._compile = None  # (its children ended: a depth encoding's may come, _depth_kernels)
            if self._loading is not None:  # (loading since the run began)
                if self._compile_groups:
                    self._loading.add(self._compile_groups)
                self._loading.common.result()
            else:  # (the depth kernels: at their first frame)
                warm_up(self.cfg.map, replay_groups(self.cfg.replay, lists=self._lists))

    def _warm_lists(self) -> None:
        """A scan whose box may be too big for masks (``warmup.scan_box_blocks``: a level laser
        of more than 70 m at 0.05 m, a tilted one of less): the lists group's kernels, compiled
        here the first time (7 s; the progress says so), before its frame is cast."""
        self._lists = True
        with self.timer("warmup"):
            if not groups_cached(["lists"]):
                self._report_progress(None, force=True, phase=COMPILING)
            warm_up(self.cfg.map, ["lists"])

    def _integrate(self, placed: Placed, cast: CastFrame, wait_s: float | None) -> None:
        run, timer, c = self.state, self.timer, self.counts
        frame = placed.frame
        if placed.robot is None:
            c.no_footprint += 1
        else:
            run.robot_xy = (float(placed.robot[0, 3]), float(placed.robot[1, 3]))
            run.trajectory.append((frame.stamp_ns - run.log_start_ns) / NS, *run.robot_xy)
        for end_ns in self.ticker.advance(frame.stamp_ns):
            self._tick(end_ns)
        if wait_s is not None:
            timer.add("rays_wait", wait_s)
        timer.add("rays", cast.rays_s)
        timer.add("cast", cast.cast_s)
        run.mapped_log_ns = max(run.mapped_log_ns, placed.log_ns)
        if wait_s is not None:  # cast in a worker thread
            self._workers_cpu_s += cast.cpu_s
        t0 = time.perf_counter()
        r = run.lmap.apply_voxels(cast.hits, cast.misses, cast.n_rays, cast.masks)
        integrate_s = time.perf_counter() - t0
        timer.add("integrate", integrate_s)
        if cast.filtered_pixels >= 0:
            c.depth_filtered_frames += 1
            c.depth_filtered_pixels += cast.filtered_pixels
        c.used[placed.topic] += 1
        c.used_by_log[frame.log] += 1
        c.rays += r.rays
        done = FrameDone(placed.topic, frame, placed.T, run.lmap.frame_id,
                         placed.lookup_s + cast.rays_s + cast.cast_s + integrate_s)  # fmt: skip
        self._call(self._frame_sinks, "on_frame", "frame_stage", done)

    def _tick(self, end_ns: int) -> None:
        run, timer = self.state, self.timer
        t0 = time.perf_counter()
        tr = run.lmap.end_tick()
        dt = time.perf_counter() - t0
        timer.add("ticks", dt)
        tick = TickDone(end_ns, (end_ns - run.log_start_ns) / NS, end_ns - self.ticker.t0_ns, tr, dt)
        self._call(self._tick_sinks, "on_tick", "tick_stage", tick)

    def _call(self, sinks: list[Sink], hook: str, stage: str, event: FrameDone | TickDone) -> None:
        """``hook`` of each sink with ``event``; each one's time counts to its stage and to the
        event's cost, which the metrics sink (last) records."""
        for s in sinks:
            t0 = time.perf_counter()
            getattr(s, hook)(self.state, event)
            dt = time.perf_counter() - t0
            if s is not self.metrics:
                self.timer.add(getattr(s, stage), dt)
                event.cost_s += dt

    def _report_progress(self, log_ns: int | None, force: bool = False, phase: str | None = None) -> None:
        if self.progress is None:
            return
        now = time.perf_counter()
        if not force and now - self._last_progress < 0.2:
            return
        self._last_progress = now
        if log_ns is not None:
            self._done_s = min(max((log_ns - self._window_start_ns) / NS, 0.0), self.log_total_s)
        # the speed and time left are those of mapping: a first run's half minute of compiling
        # made the bar say 0.2x real time and four times the time left
        wall = now - self._t_wall0 - self.timer.seconds["warmup"]
        self.progress(Progress(self._done_s, self.log_total_s, sum(self.counts.used.values()), wall, phase))


STAMP_JUMP_NS = 10**9  # header stamps going back more than this (a clock reset) are reported

# the optical frame's axes in a camera body frame (x forward, y left, z up): z forward, x right, y down
BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    return str(o)
