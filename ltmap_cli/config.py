"""The one typed configuration of a run: defaults from the spec, YAML in and out.

``config.yaml`` written with every output holds every effective parameter; ``--config FILE``
reads the same names back. Unknown keys and wrong types are errors that name the key.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .core.config import MapConfig
from .errors import ConfigError, shown
from .io import safe_yaml
from .io.bounded import DEFAULT_MAX_MESSAGE_MB
from .static.memory import DEFAULT_MAX_STATIC_MB


@dataclass
class LocalizationConfig:
    """``ltmap replay --localize`` (analysis/localization.py, docs/localization.md)."""

    resolution: float = 0.05  # m: the matching grid (distance field) cell
    min_range: float = 0.2  # m: nearer returns (the robot itself) are not matched
    max_range: float = 10.0  # m: farther returns are not matched
    surface_distance: float = 0.3  # m: a point farther than this from any surface is an outlier
    inlier_distance: float = 0.1  # m: a point this close to a surface counts for the match score
    align_window_s: float = 3.0  # s of the first scans (in odom) that the start alignment uses
    align_yaw_step_deg: float = 1.0  # yaw steps of the start alignment's search
    align_min_score: float = 0.5  # start alignment below this score: "cannot align", recorded poses
    align_min_margin: float = 0.1  # ... or less than this above a clearly different alignment (ambiguous)
    min_score: float = 0.5  # a scan's match below this score is rejected (the previous correction holds)
    max_jump_m: float = 0.5  # a match that moves the robot more than this from the prediction is rejected
    max_jump_deg: float = 10.0  # ... or turns it more than this
    max_step_m: float = 0.2  # the correction moves the laser at most this much per scan (no jumps that tear the map)
    max_step_deg: float = 4.0  # ... and turns it at most this much per scan
    map_min_hits: int = 2  # a cell of the map built so far is a surface after this many scans hit it
    sensor_height: float = 0.2  # m: z of a laser that no tf places (a scan-only log without --tf)
    initial_pose: list[float] = field(default_factory=list)  # [x, y, yaw]: the first correction without --static

    def validate(self) -> list[str]:
        out = []
        for name in ("resolution", "max_range", "surface_distance", "inlier_distance", "align_yaw_step_deg",
                     "max_jump_m", "max_jump_deg", "max_step_m", "max_step_deg"):
            if getattr(self, name) <= 0:
                out.append(f"replay.localization.{name} must be > 0")
        if self.min_range < 0 or self.min_range >= self.max_range:
            out.append("replay.localization.min_range must be >= 0 and below max_range")
        if self.align_window_s < 0:
            out.append("replay.localization.align_window_s must be >= 0")
        for name in ("align_min_score", "align_min_margin", "min_score"):
            if not 0 <= getattr(self, name) <= 1:
                out.append(f"replay.localization.{name} must be in [0, 1]")
        if self.initial_pose and len(self.initial_pose) != 3:
            out.append(f"replay.localization.initial_pose must be [x, y, yaw], got {self.initial_pose}")
        if self.map_min_hits < 1:
            out.append("replay.localization.map_min_hits must be >= 1")
        return out


@dataclass
class ReplayConfig:
    fixed_frame: str = ""  # empty: `map` when the log has it, else `odom`
    start_s: float = 0.0  # map the sensor frames from this many s of log time after the log's first message ...
    end_s: float = 0.0  # ... up to this many (0: to the log's end)
    snapshot_every: float = 60.0  # s of log time
    mode: str = "trinary"  # map.pgm mode (map_server): trinary | scale | raw
    negate: bool = False  # map_server negate: images inverted (trinary, scale), flag only in raw
    scan_topics: list[str] = field(default_factory=list)
    cloud_topics: list[str] = field(default_factory=list)
    depth_topics: list[str] = field(default_factory=list)
    tf: list[str] = field(default_factory=list)  # extra mounts: parent:child=x,y,z,roll,pitch,yaw
    camera_info: list[str] = field(default_factory=list)  # [TOPIC=]FILE: a depth camera's calibration YAML (io.camera_file)
    allow_truncated: bool = False
    max_message_mb: float = DEFAULT_MAX_MESSAGE_MB  # largest chunk / message read (uncompressed); more is refused
    tf_wait: float = 0.5  # s of log time a sensor frame waits for the tf samples after its stamp
    sensor_stamps: str = "header"  # header: place a sensor frame at its header stamp; log: at its record time
    depth_frame_axes: str = "optical"  # a depth image's frame: optical (z forward, y down) or body (x forward, z up)
    tf_tolerance: float = 0.0  # s a stamp may lie outside an edge's samples (0: no extrapolation)
    static_wall_height: float = 2.5  # m: walls of a plain map_server YAML given to --static
    max_static_mb: float = DEFAULT_MAX_STATIC_MB  # memory S may take on the voxel lattice; more is refused
    event_window_s: float = 5.0  # voxels crossing LT's threshold this close in time ...
    event_link_m: float = 0.15  # ... and this close in space (chained) are one event
    event_min_voxels: int = 4  # an event is a group of at least this many voxels ...
    event_min_p_cells: int = 3  # ... or one that changed this many cells of P (0: no); others are counted
    event_drop_surface: bool = True  # a group that only moves the boundary of what stays (a wall) by a cell is no event
    plan_goal: list[float] = field(default_factory=list)  # [x, y] in the fixed frame: time the planner's reaction
    robot_radius: float = 0.2  # m, obstacle inflation for the planner
    plan_period: float = 0.0  # s of log time between plans (0: every tick)
    mcap_out: bool = False  # write OUT/replay.mcap for Foxglove / RViz
    plots: bool = True  # write OUT/plots/*.png
    map_period: float = 1.0  # s of log time between map messages in replay.mcap (when they changed)
    scan_fused_window_s: float = 1.0  # /scan_fused: O's occupied voxels count when updated this recently
    depth_outlier_filter: bool = False  # drop flying pixels at depth jumps (open3d radius outlier removal)
    depth_outlier_radius: float = 0.02  # m: a jump pixel needs ...
    depth_outlier_min_neighbors: int = 3  # ... this many other points within the radius to stay
    workers: int = 0  # threads computing the frames' rays (0: one per usable core, at most 8); the map is the same
    localize: bool = False  # --localize: correct map -> odom by scan matching (against --static if given)
    localization: LocalizationConfig = field(default_factory=LocalizationConfig)


@dataclass
class Config:
    map: MapConfig = field(default_factory=MapConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)

    def validate(self) -> None:
        problems = _non_finite(self)
        problems += self.map.validate()
        if self.replay.depth_frame_axes not in ("optical", "body"):
            problems.append(f"replay.depth_frame_axes must be optical or body, got {shown(self.replay.depth_frame_axes)}")
        if self.replay.sensor_stamps not in ("header", "log"):
            problems.append(f"replay.sensor_stamps must be header or log, got {shown(self.replay.sensor_stamps)}")
        if self.replay.mode not in ("trinary", "scale", "raw"):
            problems.append(f"replay.mode must be trinary, scale or raw, got {shown(self.replay.mode)}")
        elif not problems:  # static.* is always trinary
            from .errors import ConfigError as _Bad
            from .io.mapfile import _check_trinary_levels

            pc = self.map.projection
            try:  # thresholds the trinary writer would refuse at the end of a long run: say so now
                _check_trinary_levels(pc.occupied_thresh, pc.free_thresh, self.replay.negate)
            except _Bad as err:
                problems.append(f"map.projection thresholds: {err}")
        if self.replay.snapshot_every <= 0:
            problems.append("replay.snapshot_every must be > 0")
        if self.replay.start_s < 0 or self.replay.end_s < 0:
            problems.append(f"replay.start_s and replay.end_s must be >= 0 (s of log time from the log's first "
                            f"message), got {self.replay.start_s:g} and {self.replay.end_s:g}")
        elif 0 < self.replay.end_s <= self.replay.start_s:
            problems.append(f"replay.end_s ({self.replay.end_s:g} s) must be after replay.start_s "
                            f"({self.replay.start_s:g} s), or 0 (to the log's end)")
        if self.replay.plan_goal and len(self.replay.plan_goal) != 2:
            problems.append(f"replay.plan_goal must be [x, y], got {self.replay.plan_goal}")
        if not self.replay.max_static_mb > 0:
            problems.append(f"replay.max_static_mb must be > 0, got {self.replay.max_static_mb}")
        if not self.replay.max_message_mb > 0:
            problems.append(f"replay.max_message_mb must be > 0, got {self.replay.max_message_mb}")
        if self.replay.workers < 0:
            problems.append(f"replay.workers must be >= 0 (0: one per usable core), got {self.replay.workers}")
        if self.replay.map_period < 0:
            problems.append("replay.map_period must be >= 0")
        if self.replay.scan_fused_window_s < 0:
            problems.append("replay.scan_fused_window_s must be >= 0")
        if self.replay.event_min_voxels < 1:
            problems.append("replay.event_min_voxels must be >= 1")
        if self.replay.event_min_p_cells < 0:
            problems.append("replay.event_min_p_cells must be >= 0 (0: a P change alone does not make an event)")
        if self.replay.robot_radius < 0:
            problems.append("replay.robot_radius must be >= 0")
        if self.replay.depth_outlier_radius <= 0:
            problems.append("replay.depth_outlier_radius must be > 0")
        problems += self.replay.localization.validate()
        if self.replay.depth_outlier_min_neighbors < 1:
            problems.append("replay.depth_outlier_min_neighbors must be >= 1")
        if problems:
            raise ConfigError("invalid configuration: " + "; ".join(problems))


def _non_finite(obj: Any, prefix: str = "") -> list[str]:
    """Every float parameter (and float in a list) must be a finite number: NaN or inf would slip
    through the range checks below (``nan < 0`` is False)."""
    out = []
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(v):
            out += _non_finite(v, key + ".")
        elif isinstance(v, float) and not math.isfinite(v):
            out.append(f"{key} must be a finite number, got {v}")
        elif isinstance(v, (list, tuple)) and any(isinstance(x, float) and not math.isfinite(x) for x in v):
            out.append(f"{key} must hold finite numbers, got {list(v)}")
    return out


def to_dict(obj: Any) -> Any:
    """A dataclass tree as plain dicts and lists (YAML-ready)."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    return obj


def _coerce(value: Any, tp: Any, key: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return _coerce(value, args[0], key)
    if origin is list:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config key {key} must be a list, got {shown(value)}")
        (item_tp,) = typing.get_args(tp) or (Any,)
        return [_coerce(v, item_tp, f"{key}[{i}]") for i, v in enumerate(value)]
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"config key {key} must be true or false, got {shown(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"config key {key} must be an integer, got {shown(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"config key {key} must be a number, got {shown(value)}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"config key {key} must be a string, got {shown(value)}")
        return value
    return value


def update_from_dict(obj: Any, data: dict, prefix: str = "") -> None:
    """Set the fields of dataclass ``obj`` from nested ``data``; unknown keys are errors."""
    if not isinstance(data, dict):
        raise ConfigError(f"config section {prefix or '(top)'} must be a mapping, got {shown(data)}")
    hints = typing.get_type_hints(type(obj))
    names = {f.name for f in dataclasses.fields(obj)}
    for key, value in data.items():
        full = f"{prefix}{key if isinstance(key, str) and len(key) <= 80 else shown(key)}"
        if key not in names:
            raise ConfigError(
                f"unknown config key {full}; known keys here: {', '.join(sorted(names))}"
            )
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            update_from_dict(current, value, prefix=f"{full}.")
        else:
            setattr(obj, key, _coerce(value, hints[key], full))


def set_dotted(cfg: Config, dotted: str, value: Any) -> None:
    """Set one parameter by its dotted name (``map.layers.tick``)."""
    parts = dotted.split(".")
    nested: dict = {}
    cur = nested
    for p in parts[:-1]:
        cur = cur.setdefault(p, {})
    cur[parts[-1]] = value
    update_from_dict(cfg, nested)


def load_config(path: str | Path | None = None) -> Config:
    """Defaults, updated from a YAML file when given (read by ``io.safe_yaml``: bounded, aliases
    counted, ``1e9`` a number)."""
    cfg = Config()
    if path is None:
        return cfg
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"config file {p} does not exist; write one with `ltmap replay --dump-config`")
    data = safe_yaml.load_file(p, "config file", ConfigError) or {}
    update_from_dict(cfg, data)
    cfg.validate()
    return cfg


def parse_set(values: tuple[str, ...] | list[str]) -> list[tuple[str, object]]:
    """``--set KEY=VALUE`` items as (dotted key, value): the value is YAML (``1e9``, ``[1, 2]``,
    ``true``), read by ``io.safe_yaml``."""
    out = []
    for v in values:
        if "=" not in v:
            raise ConfigError(f"--set {shown(v)}: expected KEY=VALUE, e.g. --set map.layers.tick=0.1")
        key, raw = v.split("=", 1)
        try:
            out.append((key.strip(), safe_yaml.loads(raw)))
        except safe_yaml.YamlLimitError as exc:
            raise ConfigError(f"--set {key.strip()[:80]}: the value {exc}; give a plain value") from None
        except Exception:  # noqa: BLE001 - yaml.YAMLError and its C-parser kin
            raise ConfigError(f"--set {shown(v)}: the value is not valid YAML; quote strings, e.g. "
                              f"--set replay.fixed_frame=map") from None
    return out


def dump_config(cfg: Config) -> str:
    import yaml

    return yaml.safe_dump(to_dict(cfg), sort_keys=False)
