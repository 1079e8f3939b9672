"""map_server maps: YAML + PGM/PNG, read with nav2 map_io semantics, written like map_saver.

``GridMap`` is the project's plain 2D grid, in the ROS ``nav_msgs/OccupancyGrid`` convention:
``data[row, col]`` with row 0 the *bottom* row (lowest y) and col 0 the lowest x; values -1
unknown, 0..100 occupancy percent. ``origin`` is (x, y, yaw) of the lower-left corner of cell
(0, 0). The image on disk has row 0 at the *top*; the reader and writer flip.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

UNKNOWN = -1
FREE = 0
OCCUPIED = 100


@dataclass
class GridMap:
    data: np.ndarray  # int8 (H, W): -1 unknown, 0..100; row 0 = bottom (lowest y)
    resolution: float  # m / cell
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)  # x, y, yaw of cell (0,0)'s lower-left corner

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])


def read_map_yaml(path: str | Path) -> GridMap:
    """Read a map_server YAML and its image with nav2 map_io semantics (modes trinary, scale,
    raw; negate; occupied_thresh / free_thresh). Raises MapFileError with a one-line message."""
    raise NotImplementedError


def write_map(
    yaml_path: str | Path,
    grid: GridMap,
    mode: str = "trinary",
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
    png: bool = True,
) -> None:
    """Write ``<stem>.pgm`` + ``<stem>.yaml`` (+ ``<stem>.png`` preview) atomically, like
    map_saver: trinary occupied 0, free 254, unknown 205; scale writes 254..0 for 0..100."""
    raise NotImplementedError
