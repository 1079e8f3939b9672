"""Sinks: what the replay does with the map besides building it.

Every sink has the same interface: ``on_tf`` (a tf sample taken in), ``on_frame`` (a frame was
integrated), ``on_tick`` (a tick's rules were applied) and ``finish`` (after the last tick),
which writes its outputs and returns its part of the report: ``{"outputs": {...}, <report field>:
value, ...}``. Optional features are sinks that are in the list or not. Each sink names the stage
its time counts to. The replay calls them in list order, so a sink may read what an earlier
one (or one it was given) finished.
"""

from __future__ import annotations

import shlex
from array import array
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..analysis.events import event_histories, events_csv, find_events, percentiles, voxel_keys
from ..analysis.plan_tracker import PlanTracker
from ..core.grid import band_k_range, coord_to_pos
from ..core.layers import LayeredMap
from ..core.projection import FootprintTrace, Projection, project, static_fills, virtual_scan
from ..io.atomic import write_text_atomic
from ..io.frames import OdometrySample, ScanFrame, TfSample
from ..io.mapfile import GridMap, write_map
from ..io.transforms import norm
from ..outputs.snapshots import SNAPSHOTS, write_snapshot

NS = 1_000_000_000
SNAPSHOT_FREE_MARGIN = 64 << 20  # a periodic snapshot needs this free beside room for 3 like the last one


@dataclass
class FrameDone:
    """A frame integrated into O: ``cost_s`` its processing time so far (lookups, rays, casting,
    integration and the sinks before the one reading it)."""

    topic: str
    frame: object
    T: np.ndarray
    frame_id: int  # LayeredMap.frame_id after this frame
    cost_s: float


@dataclass
class TickDone:
    end_ns: int  # the tick's end (header time)
    t_log_s: float  # seconds since the log's start
    run_ns: int  # ns since tick 0's start
    transition: object  # LayeredMap.end_tick's TickResult
    cost_s: float  # the tick's time so far (rules and the sinks before the one reading it)


class Track:
    """The robot's path as the replay goes: (t_s, x, y) rows in a flat float64 ``array`` (24 bytes
    a row; a list of tuples of floats took about 150, some 30 MB per hour of log at 45 frames a
    second). ``len``, slices (as (n, 3) arrays, copied) and ``xy()``."""

    def __init__(self):
        self._a = array("d")

    def append(self, t_s: float, x: float, y: float) -> None:
        self._a.extend((t_s, x, y))

    def __len__(self) -> int:
        return len(self._a) // 3

    def __getitem__(self, rows: slice) -> np.ndarray:
        start, stop, step = rows.indices(len(self))
        if step != 1:
            raise ValueError("Track rows: a step of 1 only")
        return np.array(self._a[3 * start:3 * max(stop, start)], dtype=np.float64).reshape(-1, 3)  # only these rows

    def xy(self) -> np.ndarray:
        """(n, 2) positions."""
        return self[:][:, 1:]


class RunState:
    """What the sinks share: the map, the run's frames and the robot's path, and P projected once
    per map state (frames and ticks change it)."""

    def __init__(self, cfg, lmap: LayeredMap, out: Path, final: Path):
        self.cfg = cfg
        self.lmap = lmap
        self.out = out  # where files are written (a staging folder)
        self.final = final  # the folder the user named: paths in the report
        self.log_start_ns = 0
        self.mapped_log_ns = 0  # the latest record time of a sensor frame integrated so far
        self.fixed_frame: str | None = None
        self.robot_xy: tuple[float, float] | None = None
        self.trajectory = Track()  # (t_s, x, y) of the robot per frame
        self._p_key: tuple | None = None
        self._p: Projection | None = None
        self._lt_key: tuple | None = None
        self._lt: tuple[np.ndarray, Projection] | None = None
        self._footprint = FootprintTrace(cfg.map.projection.footprint_radius, lmap.resolution)

    def p_now(self) -> Projection:
        """P as it is now; the cells the robot's footprint covered along its path are free unless
        occupied (SPEC 2.3: the robot stood there, as nav2's costmaps clear the footprint)."""
        key = (self.lmap.frame_id, self.lmap.tick_index)
        if self._p_key != key:
            cells = self._footprint.update(self.trajectory)
            self._p_key, self._p = key, project(self.lmap, footprint=cells)
        return self._p

    def lt_now(self) -> tuple[np.ndarray, Projection]:
        """LT as it is now: its occupied voxel keys (N, 3) and its projection alone (no S), made
        once per map state for the sinks that publish, save, group and draw it."""
        key = (self.lmap.frame_id, self.lmap.tick_index)
        if self._lt_key != key:
            self._lt_key = key
            self._lt = (self.lmap.occupied_keys("LT"), project(self.lmap, use_static=False))
        return self._lt

    def grid_now(self) -> GridMap:
        p = self.p_now()
        return GridMap(p.data, p.resolution, p.origin)


class Sink:
    name = "sink"
    frame_stage = "output"
    tick_stage = "output"
    finish_stage = "output"
    phase: str | None = None  # what the progress bar names while ``finish`` runs, if it takes a while
    ends_mapping = False  # the map is done when this sink has finished (the mapping speed's end)

    def start(self, run: RunState, tf) -> None:
        """The log is open (``run.log_start_ns`` known), before its first message."""

    def on_tf(self, run: RunState, sample, source: str | None = None) -> None:
        pass

    def on_frame(self, run: RunState, done: FrameDone) -> None:
        pass

    def on_tick(self, run: RunState, tick: TickDone) -> None:
        pass

    def finish(self, run: RunState) -> dict:
        return {}

    def abort(self) -> None:
        """The run failed: drop what is half-written."""


# ------------------------------------------------------------------------------------------
class PlannerSink(Sink):
    """A* from the robot's current position on the current P every ``plan_period`` (planner
    latency, SPEC 6); annotates the events with the tick their path changed."""

    name = "planner"
    tick_stage = "projection"

    def __init__(self, cfg):
        self.tracker = PlanTracker(tuple(cfg.replay.plan_goal), cfg.replay.robot_radius)
        self.period = cfg.replay.plan_period
        self.next_s = 0.0

    def on_tick(self, run, tick) -> None:
        if run.robot_xy is None or tick.t_log_s < self.next_s:
            return
        self.next_s = tick.t_log_s + self.period
        self.tracker.update(tick.t_log_s, run.grid_now(), run.robot_xy)

    def annotate(self, events: list[dict], resolution: float) -> dict:
        self.tracker.attribute(events, resolution)
        return self.tracker.summary()


# ------------------------------------------------------------------------------------------
class McapSink(Sink):
    """replay.mcap (SPEC 4): /map, /long_term_map, the occupied (and static) voxels, /scan_fused
    and the tf the replay used, at recorded time."""

    name = "mcap"
    frame_stage = "projection"
    FILE = "replay.mcap"

    def __init__(self, run: RunState, mounts):
        from ..io.mcap_out import ReplayMcapWriter

        self.writer = ReplayMcapWriter(run.out / self.FILE)
        self.cfg = run.cfg
        self.mounts = mounts
        self.next_map_ns: int | None = None
        self.dirty = True
        self.p_latest: Projection | None = None
        self.published = None  # ((shape, origin), data) of the last /map written
        self.frame_log: deque = deque()  # (stamp ns, lmap.frame_id) of the frames of the last seconds
        self.last_stamp = 0
        self.tf = None

    def start(self, run: RunState, tf) -> None:
        """The --tf mounts go to /tf_static at the log's start, like the log's own, so that a
        viewer places the sensors where the replay did."""
        self.tf = tf
        for m in self.mounts:
            self.writer.write_tf(run.log_start_ns, [(m.parent, m.child, m.translation, m.rotation_xyzw)], static=True)

    def on_tf(self, run, item, source: str | None = None) -> None:
        """/tf and /tf_static: the transforms the replay used, as it used them. A sample the tf
        buffer ignored (an edge a --tf mount, /tf or --localize owns) is not copied; a pose from
        nav_msgs/Odometry (no /tf for that edge) and the estimates of --localize go to /tf."""
        static = isinstance(item, TfSample) and item.static
        if source is None:
            source = "odom" if isinstance(item, OdometrySample) else ("static" if static else "tf")
        edge = self.tf.edges.get(norm(item.child))
        if edge is None or edge.source != source or edge.parent != norm(item.parent):
            return
        self.writer.write_tf(run.log_start_ns if static else item.stamp_ns,
                             [(norm(item.parent), norm(item.child), item.translation, item.rotation_xyzw)],
                             static=static)  # fmt: skip

    def on_frame(self, run, done) -> None:
        stamp = done.frame.stamp_ns
        self.last_stamp = max(self.last_stamp, stamp)
        self.frame_log.append((stamp, done.frame_id))
        keep_ns = stamp - 2 * int(self.cfg.replay.scan_fused_window_s * NS) - NS
        while len(self.frame_log) > 1 and self.frame_log[0][0] < keep_ns:
            self.frame_log.popleft()
        if isinstance(done.frame, ScanFrame):
            self._fused_scan(run, done.frame, done.T)

    def on_tick(self, run, tick) -> None:
        if tick.transition.lt_entered or tick.transition.lt_left:
            self.dirty = True
        self._publish_maps(run, tick.end_ns)

    def finish(self, run) -> dict:
        self._publish_maps(run, self.last_stamp, force=True)
        self.writer.close()
        return {"outputs": {"mcap": str(run.final / self.FILE), "mcap_messages": dict(self.writer.counts)}}

    def abort(self) -> None:
        self.writer.abort()

    def _publish_maps(self, run, stamp_ns: int, force: bool = False) -> None:
        """/map, /long_term_map and /ltmap/occupied_voxels at a tick where P changed (an obstacle
        entered or left LT, or free space grew), at most every map_period; the static voxels once."""
        lmap, frame, w = run.lmap, run.fixed_frame, self.writer
        if self.next_map_ns is None:
            self.next_map_ns = stamp_ns
            if lmap.static is not None:
                keys = lmap.static.voxel_keys()
                w.write_cloud("/ltmap/static_voxels", stamp_ns, coord_to_pos(keys, lmap.resolution), frame)
        if not force and stamp_ns < self.next_map_ns:
            return
        p = run.p_now()
        sig = (p.data.shape, tuple(p.origin))
        last = self.published
        self.next_map_ns = stamp_ns + int(self.cfg.replay.map_period * NS)  # checked at most once a period
        if not force and not self.dirty and last is not None and last[0] == sig and np.array_equal(last[1], p.data):
            return
        self.published = (sig, p.data)
        self.p_latest = p
        w.write_grid("/map", stamp_ns, p.data, p.resolution, p.origin, frame)
        keys, lt = run.lt_now()
        w.write_grid("/long_term_map", stamp_ns, lt.data, lt.resolution, lt.origin, frame)
        w.write_cloud("/ltmap/occupied_voxels", stamp_ns, coord_to_pos(keys, lmap.resolution), frame,
                      values=lmap.values("LT", keys), value_name="long_term")  # fmt: skip
        self.dirty = False

    def _fused_scan(self, run, scan: ScanFrame, T: np.ndarray) -> None:
        """/scan_fused: the virtual scan of SPEC 2.3 (per beam the nearest occupied cell of
        max(P, current obstacles in O)) in the laser's frame and angles."""
        if self.p_latest is None:
            self.p_latest = run.p_now()
        yaw = float(np.arctan2(T[1, 0], T[0, 0]))
        sign = 1.0 if T[2, 2] >= 0 else -1.0  # an upside-down laser turns the other way
        # current obstacles in O: updated by a frame stamped within the window before this scan
        t_from = scan.stamp_ns - int(self.cfg.replay.scan_fused_window_s * NS)
        since = next((fid for stamp, fid in self.frame_log if stamp >= t_from), run.lmap.frame_id + 1)
        ranges = virtual_scan(run.lmap, self.p_latest, (T[0, 3], T[1, 3], yaw), sign * scan.angles, scan.range_min,
                              scan.range_max, o_since_frame=since)  # fmt: skip
        self.writer.write_scan("/scan_fused", scan.stamp_ns, scan.frame_id, scan.angle_min, scan.angle_increment,
                               scan.range_min, scan.range_max, ranges)  # fmt: skip


# ------------------------------------------------------------------------------------------
class LocalizationSink(Sink):
    """localization.csv (--localize): the pre-pass's map -> odom estimate per scan, its match score
    and whether it was accepted; its summary goes to the report."""

    name = "localization"
    FILE = "localization.csv"

    def __init__(self, result):
        self.result = result

    def finish(self, run) -> dict:
        write_text_atomic(run.out / self.FILE, self.result.csv_text())
        return {"localization": self.result.summary, "outputs": {"localization": str(run.final / self.FILE)}}


# ------------------------------------------------------------------------------------------
class SnapshotSink(Sink):
    """snapshots/: the long-term layer every ``snapshot_every`` s of log time and at the end, as
    .ot, .ply and the exact state that --resume loads (SPEC 4)."""

    name = "snapshots"
    FOLDER = SNAPSHOTS
    ends_mapping = True

    def __init__(self, cfg):
        self.every_ns = int(round(cfg.replay.snapshot_every * NS))
        self.next_ns = self.every_ns
        self.written: list[dict] = []
        self.last_bytes = 0  # the last snapshot's size
        self.skipped = 0  # periodic snapshots left out for want of disk

    def on_tick(self, run, tick) -> None:
        if tick.run_ns >= self.next_ns:
            if self._room(run, tick.run_ns / NS):
                self._write(run, tick.run_ns / NS)
            self.next_ns += self.every_ns

    def _room(self, run, t_s: float) -> bool:
        """Whether the disk of the output folder has room for this periodic snapshot and still for
        what the run's end writes (the final snapshot, the maps): 3 snapshots the size of the
        last one and SNAPSHOT_FREE_MARGIN. Hours of log write hundreds of snapshots; filling the
        disk would fail the whole run at its end, so the periodic ones stop (said once) and start
        again when room comes back."""
        import shutil

        free = shutil.disk_usage(run.out).free
        need = SNAPSHOT_FREE_MARGIN + 3 * self.last_bytes
        if free >= need:
            return True
        if not self.skipped:
            import warnings

            from ..errors import LtmapWarning, human

            warnings.warn(LtmapWarning(
                f"the disk of {run.final} has {human(free)} free: the snapshots every {self.every_ns / NS:g} s stop at "
                f"{t_s:.0f} s of log while it has less than {human(need)} (the final snapshot, the maps and the "
                f"report are still written); free some space, or give --snapshot-every a longer period"),
                stacklevel=2)  # fmt: skip
        self.skipped += 1
        return False

    def finish(self, run) -> dict:
        self._write(run, None)
        return {"snapshots": self.written, "snapshots_skipped_low_disk": self.skipped}

    def _write(self, run, t_s: float | None) -> None:
        # mapped_to_s: the log time (s from the log's first message) up to which the sensor frames
        # are in this snapshot, the --start that maps the rest (a killed run's last snapshot is
        # kept for that: outputs.folder.recover)
        mapped = round((run.mapped_log_ns - run.log_start_ns) / NS, 3) if run.mapped_log_ns else None
        paths = write_snapshot(run.lmap, run.out / self.FOLDER, t_s, {"fixed_frame": run.fixed_frame,
                                                                      "mapped_to_s": mapped})  # fmt: skip
        self.last_bytes = sum(Path(v).stat().st_size for v in paths.values())
        final = run.final / self.FOLDER
        self.written.append({"log_time_s": t_s, **{k: str(final / Path(v).name) for k, v in paths.items()}})


# ------------------------------------------------------------------------------------------
class MapsSink(Sink):
    """map.*, long_term.* and static.*: P, LT alone and S alone as map_server grids."""

    name = "maps"
    finish_stage = "projection"

    def finish(self, run) -> dict:
        cfg, lmap = run.cfg, run.lmap
        pc = cfg.map.projection
        written = {}

        def save(name: str, p: Projection, mode: str) -> None:
            data = p.scale_data() if mode in ("scale", "raw") else p.data
            write_map(run.out / f"{name}.yaml", GridMap(data, p.resolution, p.origin), mode=mode,
                      occupied_thresh=pc.occupied_thresh, free_thresh=pc.free_thresh,
                      negate=cfg.replay.negate)  # fmt: skip
            written[name] = str(run.final / f"{name}.yaml")

        save("map", run.p_now(), cfg.replay.mode)
        save("long_term", run.lt_now()[1], cfg.replay.mode)
        if lmap.static is not None:
            save("static", project(lmap, use_lt=False, use_o_free=False), "trinary")
        return {"outputs": written}


# ------------------------------------------------------------------------------------------
class MetricsSink(Sink):
    """Processing latency (SPEC 6): wall time per frame (by topic) and per tick, with p50/p95/p99
    against the frame period. Last in the list, so a frame's and a tick's cost include the other
    sinks'."""

    name = "metrics"

    def __init__(self, tick_s: float):
        self.tick_s = tick_s
        # per frame and tick, 8 bytes each (``array``: Python floats in lists took about 32)
        self.frame_ms: dict[str, array] = {}
        self.stamps: dict[str, array] = {}
        self.tick_ms = array("d")
        self._summary: tuple[dict, dict] | None = None

    def on_frame(self, run, done) -> None:
        self.frame_ms.setdefault(done.topic, array("d")).append(done.cost_s * 1e3)
        self.stamps.setdefault(done.topic, array("q")).append(done.frame.stamp_ns)

    def on_tick(self, run, tick) -> None:
        self.tick_ms.append(tick.cost_s * 1e3)

    def summary(self) -> tuple[dict, dict]:
        """(processing latency per topic and tick, frame period in ms per topic and tick)."""
        if self._summary is None:
            processing, periods = {}, {}
            for topic, ms in self.frame_ms.items():
                stamps = np.sort(np.asarray(self.stamps[topic], dtype=np.int64))
                period = float(np.median(np.diff(stamps)) / 1e6) if len(stamps) > 1 else None
                periods[topic] = period
                processing[topic] = {**percentiles(ms), "frame_period_ms": period,
                                     "keeps_up": (bool(np.percentile(ms, 95) < period) if period else None)}  # fmt: skip
            tick_period = self.tick_s * 1e3
            processing["tick"] = {**percentiles(self.tick_ms), "frame_period_ms": tick_period}
            periods["tick"] = tick_period
            self._summary = processing, periods
        return self._summary

    def finish(self, run) -> dict:
        return {"processing_latency_ms": self.summary()[0]}


# ------------------------------------------------------------------------------------------
class EventsSink(Sink):
    """events.csv (SPEC 6): connected groups of voxels that entered or left LT, with their add /
    remove latencies (and planner latency when a planner sink annotates them)."""

    name = "events"
    FILE = "events.csv"

    def __init__(self, ticker, planner: PlannerSink | None = None, history_events: int | None = None):
        self.ticker = ticker
        self.annotators = [planner] if planner is not None else []
        self.history_events = history_events  # ST / LT histories of the first this many events (None: all)
        self.events: list[dict] = []
        self.members: dict[int, np.ndarray] = {}  # event id -> its D voxel ids
        self.histories: dict = {}
        self.latencies: dict[str, list] = {}

    def finish(self, run) -> dict:
        lmap, cfg = run.lmap, run.cfg
        clock = self.ticker.analysis_clock(run.log_start_ns)
        pc = cfg.map.projection
        k_lo, k_hi = band_k_range(pc.z_min, pc.z_max, lmap.resolution)
        lt_keys = run.lt_now()[0]
        final_cols = lt_keys[(lt_keys[:, 2] >= k_lo) & (lt_keys[:, 2] <= k_hi), :2]
        rc = cfg.replay
        filtered: dict = {}
        events, members = find_events(
            lmap.events.transitions, lmap.D.block_coords[: lmap.D.n_blocks], lmap.resolution, clock,
            window_s=rc.event_window_s, link_m=rc.event_link_m, min_voxels=rc.event_min_voxels,
            min_p_cells=rc.event_min_p_cells, filtered=filtered, drop_surface=rc.event_drop_surface,
            final_cols=final_cols, static_cols=lambda cols: static_fills(lmap, cols),
        )  # fmt: skip
        extra = {}
        for a in self.annotators:
            extra["plan"] = a.annotate(events, lmap.resolution)
        write_text_atomic(run.out / self.FILE, events_csv(events))
        self.events, self.members = events, members
        hist_i, hist_v = lmap.events.history
        drawn = events if self.history_events is None else events[: self.history_events]
        self.histories = event_histories(
            hist_i, hist_v, {e["id"]: members[e["id"]] for e in drawn}, clock,
            {e["id"]: (e["t_start_s"] if e["t_start_s"] is not None else e["t_lt_s"]) - 5.0 for e in drawn})  # fmt: skip
        lat = {"add": [e["latency_s"] for e in events if e["kind"] == "appear" and e["latency_s"] is not None],
               "remove": [e["latency_s"] for e in events if e["kind"] == "disappear" and e["latency_s"] is not None]}  # fmt: skip
        if self.annotators:
            lat["planner"] = [e["planner_latency_s"] for e in events if e.get("planner_latency_s") is not None]
        self.latencies = lat
        summary = {
            "count": len(events),
            "appear": sum(e["kind"] == "appear" for e in events),
            "disappear": sum(e["kind"] == "disappear" for e in events),
            # groups left out: below event_min_voxels and changing fewer than event_min_p_cells cells
            # of P, or (drop_surface) only shifting the edge of something that stays
            "filtered": {**filtered, "min_voxels": rc.event_min_voxels, "min_p_cells": rc.event_min_p_cells,
                         "drop_surface": rc.event_drop_surface},
            "add_latency_s": percentiles(lat["add"]),
            "remove_latency_s": percentiles(lat["remove"]),
            "planner_latency_s": percentiles(lat["planner"]) if "planner" in lat else None,
            "list": events,
            **extra,
        }
        return {"events": summary, "outputs": {"events": str(run.final / self.FILE)}}

    def event_cells(self, lmap: LayeredMap) -> dict[int, np.ndarray]:
        """{event id: (N, 2) lower-left corners (m) of the xy cells its voxels cover}."""
        coords = lmap.D.block_coords[: lmap.D.n_blocks]
        return {eid: np.unique(voxel_keys(vids // 512, vids % 512, coords)[:, :2], axis=0) * lmap.resolution
                for eid, vids in self.members.items()}  # fmt: skip


# ------------------------------------------------------------------------------------------
class PlotsSink(Sink):
    """plots/: ST and LT of each event over time (the paper's Fig. 4), latency box plots
    (Fig. 5), the processing-time histogram, the final map with events (and path), map_3d.png."""

    name = "plots"
    FOLDER = "plots"

    phase = "writing plots"

    def __init__(self, events: EventsSink, metrics: MetricsSink, planner: PlannerSink | None = None):
        self.events = events
        self.metrics = metrics
        self.planner = planner

    def start(self, run, tf) -> None:
        from ..viz.render3d import start_probe

        start_probe()  # whether open3d can render offscreen, found out while the log is mapped

    def finish(self, run) -> dict:
        from ..viz.plots import write_summary_plots

        lmap, cfg, ev = run.lmap, run.cfg, self.events
        for e in ev.events:
            h = ev.histories.get(e["id"])
            if h is None:
                continue
            first = "first seen" if e["kind"] == "appear" else "first seen free"
            shown = "in P" if e["kind"] == "appear" else "out of P"
            h["marks"] = {k: v for k, v in ((first, e["t_start_s"]), (shown, e["t_in_map_s"]),
                                            ("path changed", e.get("t_plan_change_s"))) if v is not None}  # fmt: skip
        keys = run.lt_now()[0]
        static_keys = lmap.static.voxel_keys() if lmap.static is not None else None
        traj = run.trajectory.xy() if len(run.trajectory) else None
        lay = cfg.map.layers
        _, periods = self.metrics.summary()
        files = write_summary_plots(
            run.out / self.FOLDER, grid=run.grid_now(), events=ev.events, histories=ev.histories,
            latencies=ev.latencies,
            processing_ms={k: np.array(v) for k, v in self.metrics.frame_ms.items()}
            | {"tick": np.array(self.metrics.tick_ms)},
            periods_ms=periods,
            path_xy=self.planner.tracker.final_path_xy if self.planner is not None else None, robot_xy=traj,
            occupied_thresh=cfg.map.projection.occupied_thresh,
            targets={"add": lay.st_rise_s, "remove": lay.lt_fall_s}, event_cells=ev.event_cells(lmap),
            map3d={"centers": coord_to_pos(keys, lmap.resolution), "values": lmap.values("LT", keys),
                   "resolution": lmap.resolution,
                   "static_centers": coord_to_pos(static_keys, lmap.resolution) if static_keys is not None else None,
                   "title": None},  # the renderer says what it shows (and whether there is a static layer)
        )  # fmt: skip
        return {"outputs": {"plots": {k: str(run.final / self.FOLDER / Path(v).name) for k, v in files.items()}}}


def inputs_comment(logs, static, resume, final: Path) -> str:
    """config.yaml's header: the inputs of this run, which are not parameters, so that the run can
    be repeated with ``ltmap replay LOGS --config config.yaml`` and these options."""
    args = ["ltmap", "replay", *(str(p) for p in logs)]
    if static is not None:
        args += ["--static", str(static)]
    if resume is not None:
        args += ["--resume", str(resume)]
    args += ["-o", str(final), "--config", str(final / "config.yaml")]
    return f"# every parameter of this run; its inputs were:\n# {shlex.join(args)}\n"
