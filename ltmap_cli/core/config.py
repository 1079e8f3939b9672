"""Parameters of the map core (SPEC sections 2.1-2.3), with the spec's defaults.

Plain dataclasses: no file formats here (``ltmap_cli.config`` loads and dumps them as YAML).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..thresholds import FREE_THRESH, OCCUPIED_THRESH


def logodds(p):
    """log(p / (1 - p)) of a probability (a float) or of an array of them."""
    return math.log(p / (1.0 - p)) if type(p) in (int, float) else np.log(p / (1.0 - p))


DEPTH_INTEGRATIONS = ("exact", "projective")


@dataclass
class SensorConfig:
    """Sensor integration into O, OctoMap's rules and defaults."""

    prob_hit: float = 0.7  # log-odds +0.847
    prob_miss: float = 0.4  # log-odds -0.405
    clamp_min_logodds: float = -2.0  # p = 0.12
    clamp_max_logodds: float = 3.5  # p = 0.97
    depth_max_range: float = 8.0  # m; lasers use their message's range_max
    ground_tolerance: float = 0.05  # m; returns with |z| <= this clear but do not mark
    clear_no_return: bool = True  # a LaserScan +inf / > range_max beam clears up to max_range
    dedupe_dense: bool = True  # depth images / clouds: one ray per end voxel (OctoMap's discretize)
    # Hz per depth topic (0: every frame): images closer than 0.9 / rate to the last one used are
    # not integrated (nor decoded); an approximation for speed, see docs/performance.md
    depth_max_rate: float = 0.0
    # depth images: "exact" (every ray walked whole by the DDA) or "projective" (rays walked over
    # their last projective_band m + 2 voxels; free space farther in front of the returns by
    # projecting voxels onto the image: core.projective)
    depth_integration: str = "projective"
    projective_band: float = 0.2  # m

    @property
    def hit_logodds(self) -> float:
        return logodds(self.prob_hit)

    @property
    def miss_logodds(self) -> float:
        return logodds(self.prob_miss)


@dataclass
class RobotConfig:
    """The robot's own body, never marked: a box in the robot (base) frame."""

    base_frame: str = "base_link"
    footprint_min: list[float] = field(default_factory=lambda: [-0.25, -0.25, -0.10])
    footprint_max: list[float] = field(default_factory=lambda: [0.25, 0.25, 1.50])


@dataclass
class LayerConfig:
    """Update tick rules for ST and LT (SPEC 2.2)."""

    tick: float = 0.2  # s of log time
    st_rise_s: float = 15.0
    st_fall_s: float = 1.0
    st_forget_s: float = 60.0
    lt_fall_s: float = 3.0
    static_margin_cells: int = 1  # obstacles within this many voxels of S are S's own
    max_gap_s: float = 1.0  # a voxel re-observed after a gap counts the gap (up to this) as observed time


@dataclass
class ProjectionConfig:
    """The 2D projection P (SPEC 2.3) and reading [0, 1] layers as occupied / free."""

    z_min: float = 0.05
    z_max: float = 1.5
    occupied_thresh: float = OCCUPIED_THRESH
    free_thresh: float = FREE_THRESH
    footprint_radius: float = 0.2  # m: cells within this of the robot's path are free in P (0: off)


@dataclass
class MapConfig:
    resolution: float = 0.05
    sensor: SensorConfig = field(default_factory=SensorConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    layers: LayerConfig = field(default_factory=LayerConfig)
    projection: ProjectionConfig = field(default_factory=ProjectionConfig)

    def validate(self) -> list[str]:
        """Return a list of problems (empty when the configuration is usable)."""
        problems = []
        if not (0.005 <= self.resolution <= 2.0):
            problems.append(f"map.resolution must be within [0.005, 2.0] m, got {self.resolution}")
        s = self.sensor
        if not (0.5 < s.prob_hit < 1.0):
            problems.append(f"map.sensor.prob_hit must be within (0.5, 1), got {s.prob_hit}")
        if not (0.0 < s.prob_miss < 0.5):
            problems.append(f"map.sensor.prob_miss must be within (0, 0.5), got {s.prob_miss}")
        if not (s.clamp_min_logodds < 0.0 < s.clamp_max_logodds):
            problems.append("map.sensor.clamp_min_logodds < 0 < map.sensor.clamp_max_logodds must hold")
        if not (s.depth_max_rate >= 0):
            problems.append(f"map.sensor.depth_max_rate must be >= 0 (0: every frame), got {s.depth_max_rate}")
        if s.depth_integration not in DEPTH_INTEGRATIONS:
            problems.append(f"map.sensor.depth_integration must be one of {', '.join(DEPTH_INTEGRATIONS)}, "
                            f"got {s.depth_integration!r}")  # fmt: skip
        if not (s.projective_band >= 0):
            problems.append(f"map.sensor.projective_band must be >= 0 m, got {s.projective_band}")
        if s.depth_max_range <= 0:
            problems.append(f"map.sensor.depth_max_range must be > 0, got {s.depth_max_range}")
        lay = self.layers
        for name in ("tick", "st_rise_s", "st_fall_s", "st_forget_s", "lt_fall_s", "max_gap_s"):
            if getattr(lay, name) <= 0:
                problems.append(f"map.layers.{name} must be > 0, got {getattr(lay, name)}")
        if lay.static_margin_cells < 0:
            problems.append("map.layers.static_margin_cells must be >= 0")
        p = self.projection
        if p.z_max <= p.z_min:
            problems.append(f"map.projection.z_max ({p.z_max}) must exceed z_min ({p.z_min})")
        if not (p.footprint_radius >= 0):
            problems.append(f"map.projection.footprint_radius must be >= 0 (0: off), got {p.footprint_radius}")
        if not (0.0 <= p.free_thresh < p.occupied_thresh <= 1.0):
            problems.append("map.projection: 0 <= free_thresh < occupied_thresh <= 1 must hold")
        r = self.robot
        if len(r.footprint_min) != 3 or len(r.footprint_max) != 3:
            problems.append("map.robot.footprint_min / footprint_max must have 3 values (x, y, z)")
        return problems
