"""The 3D static layer S on disk: what ``ltmap build-static`` writes and ``ltmap replay --static``
loads.

A ``StaticLayer`` is a 2D map (``GridMap``: walls occupied 100, inside the plan free 0, outside
unknown -1) plus the top z of the static obstacle in each cell: the column from z = 0 to
``height[row, col]`` is static. Walls are extruded to ``wall_height``; furniture built with
``--furniture static`` to its own height. ``lt_seed_height`` (``--furniture long-term``) holds the
top z of objects that seed the initial long-term layer instead.

Files: ``static.pgm`` + ``static.yaml`` (+ ``static.png``), written by ``mapfile.write_map``, and
``static_layer.npz`` beside them with the grid, the heights and the metadata. ``load_static_input``
takes a build-static folder, its ``static.yaml``, the ``.npz`` itself, or any map_server YAML
(occupied cells become walls of ``wall_height``), so that an existing SLAM map can serve as S.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import MapFileError
from ..thresholds import FREE_THRESH, OCCUPIED_MIN
from .atomic import atomic_path
from .mapfile import GridMap, read_map_yaml

LAYER_FILE = "static_layer.npz"
MAP_YAML = "static.yaml"
FORMAT = "ltmap-static-layer"
VERSION = 1
FREE_PERCENT = FREE_THRESH * 100  # map_server's free_thresh, as a 0..100 cell value


@dataclass
class StaticLayer:
    grid: GridMap  # trinary: -1 unknown, 0 free, 100 occupied; row 0 = lowest y
    height: np.ndarray  # float32 (H, W): top z (m) of the static obstacle in each cell, 0 where none
    lt_seed_height: np.ndarray | None = None  # float32 (H, W) or None: top z of LT seeds
    wall_height: float = 2.5
    doors: int = 0

    @property
    def occupied(self) -> np.ndarray:
        return self.grid.data >= 100


def trinary(data: np.ndarray) -> np.ndarray:
    """0..100 / -1 occupancy to trinary int8 with map_server's thresholds: >= 65 occupied (100),
    <= 19.6 free (0), anything else (including -1) unknown (-1)."""
    d = np.asarray(data)
    out = np.full(d.shape, -1, dtype=np.int8)
    out[(d >= 0) & (d <= FREE_PERCENT)] = 0
    out[d >= OCCUPIED_MIN] = 100
    return out


def layer_from_grid(grid: GridMap, wall_height: float = 2.5, doors: int = 0) -> StaticLayer:
    """A static layer from a plain 2D map: occupied cells are walls of ``wall_height``."""
    data = trinary(grid.data)
    height = np.where(data == 100, np.float32(wall_height), np.float32(0)).astype(np.float32)
    return StaticLayer(GridMap(data, float(grid.resolution), tuple(grid.origin)), height, None,
                       float(wall_height), int(doors))


def _layer_path(folder_or_path: str | Path) -> Path:
    p = Path(folder_or_path)
    if p.suffix == ".npz":
        return p
    if p.suffix in (".yaml", ".yml"):
        return p.with_name(LAYER_FILE)
    return p / LAYER_FILE


def write_static_layer(folder_or_path: str | Path, layer: StaticLayer) -> Path:
    """Write ``static_layer.npz`` atomically: into a folder, beside a ``static.yaml`` given as the
    path, or to an explicit ``.npz`` path. Returns the path written."""
    path = _layer_path(folder_or_path)
    g = layer.grid
    seed = layer.lt_seed_height
    arrays = {
        "format": np.array(FORMAT),
        "version": np.array(VERSION, dtype=np.int32),
        "data": np.ascontiguousarray(g.data, dtype=np.int8),
        "resolution": np.array(float(g.resolution)),
        "origin": np.array([float(v) for v in g.origin], dtype=np.float64),
        "height": np.ascontiguousarray(layer.height, dtype=np.float32),
        "has_lt_seed": np.array(seed is not None),
        "lt_seed_height": (np.ascontiguousarray(seed, dtype=np.float32) if seed is not None
                           else np.zeros((0, 0), dtype=np.float32)),
        "wall_height": np.array(float(layer.wall_height)),
        "doors": np.array(int(layer.doors), dtype=np.int64),
    }
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return path


def read_static_layer(path: str | Path) -> StaticLayer:
    """Read ``static_layer.npz`` (or the one in a folder / beside a static.yaml). Raises
    MapFileError with a one-line message when it is missing or inconsistent."""
    p = _layer_path(path)
    if not p.is_file():
        raise MapFileError(f"{p}: no such static layer file; build one with `ltmap build-static`")
    try:
        with np.load(p, allow_pickle=False) as z:
            if str(z["format"]) != FORMAT:
                raise MapFileError(f"{p}: not an ltmap static layer (format {z['format']!s}); "
                                   "rebuild it with `ltmap build-static`")
            if int(z["version"]) > VERSION:
                raise MapFileError(f"{p}: static layer version {int(z['version'])} is newer than this "
                                   f"ltmap reads ({VERSION}); upgrade ltmap")
            data = np.array(z["data"], dtype=np.int8)
            resolution = float(z["resolution"])
            origin = tuple(float(v) for v in np.asarray(z["origin"]).reshape(-1))
            height = np.array(z["height"], dtype=np.float32)
            seed = np.array(z["lt_seed_height"], dtype=np.float32) if bool(z["has_lt_seed"]) else None
            wall_height = float(z["wall_height"])
            doors = int(z["doors"])
    except MapFileError:
        raise
    except (KeyError, ValueError, OSError, EOFError) as exc:
        raise MapFileError(f"{p}: unreadable static layer ({exc}); rebuild it with "
                           "`ltmap build-static`") from exc
    if data.ndim != 2 or height.shape != data.shape or (seed is not None and seed.shape != data.shape):
        raise MapFileError(f"{p}: grid and height arrays differ in shape; rebuild it with `ltmap build-static`")
    if not (math.isfinite(resolution) and resolution > 0) or len(origin) != 3:
        raise MapFileError(f"{p}: bad resolution or origin; rebuild it with `ltmap build-static`")
    if not np.isfinite(height).all() or (seed is not None and not np.isfinite(seed).all()):
        raise MapFileError(f"{p}: heights are not finite; rebuild it with `ltmap build-static`")
    return StaticLayer(GridMap(data, resolution, origin), height, seed, wall_height, doors)


def _same_frame(a: GridMap, b: GridMap) -> bool:
    return (a.data.shape == b.data.shape and abs(a.resolution - b.resolution) < 1e-9 * a.resolution
            and all(abs(x - y) < 1e-6 for x, y in zip(a.origin, b.origin)))


def _with_map(layer: StaticLayer, grid: GridMap) -> StaticLayer:
    """The layer's heights under the map YAML's cells: the YAML wins (a person may have edited
    the PGM): newly occupied cells get ``wall_height``, cells no longer occupied lose theirs."""
    if not _same_frame(layer.grid, grid):
        return layer_from_grid(grid, layer.wall_height, layer.doors)
    data = trinary(grid.data)
    occ = data == 100
    h = np.where(occ, np.where(layer.height > 0, layer.height, np.float32(layer.wall_height)), 0)
    return StaticLayer(GridMap(data, layer.grid.resolution, layer.grid.origin), h.astype(np.float32),
                       layer.lt_seed_height, layer.wall_height, layer.doors)


def load_static_input(path: str | Path, wall_height: float = 2.5) -> StaticLayer:
    """S from what a user passes to ``replay --static``:

    - a ``build-static`` output folder (``static.yaml`` and/or ``static_layer.npz`` in it);
    - its ``static.yaml`` (the ``static_layer.npz`` beside it gives the heights);
    - a ``static_layer.npz``;
    - any map_server YAML (PGM or PNG image): occupied cells become walls of ``wall_height``.

    When both the YAML and the ``.npz`` exist, the YAML's cells win (it may have been edited),
    the ``.npz`` gives heights and the long-term seed. Raises MapFileError (one line).
    """
    p = Path(path)
    if not p.exists():
        raise MapFileError(f"{p}: no such file or folder; give a build-static output folder or a map YAML")
    if p.is_dir():
        yaml_p, npz_p = p / MAP_YAML, p / LAYER_FILE
        if npz_p.is_file():
            layer = read_static_layer(npz_p)
            return _with_map(layer, read_map_yaml(yaml_p, saver_unknown=True)) if yaml_p.is_file() else layer
        if yaml_p.is_file():
            return layer_from_grid(read_map_yaml(yaml_p, saver_unknown=True), wall_height)
        raise MapFileError(f"{p}: folder holds neither {MAP_YAML} nor {LAYER_FILE}; give a "
                           "build-static output folder or a map YAML")
    if p.suffix == ".npz":
        return read_static_layer(p)
    if p.suffix.lower() in (".yaml", ".yml"):
        grid = read_map_yaml(p, saver_unknown=True)
        npz_p = p.with_name(LAYER_FILE)
        if p.name == MAP_YAML and npz_p.is_file():
            return _with_map(read_static_layer(npz_p), grid)
        return layer_from_grid(grid, wall_height)
    raise MapFileError(f"{p}: not a map YAML, {LAYER_FILE} or build-static folder; give one of those")
