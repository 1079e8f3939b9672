"""Map analysis: diff of two maps and A* planning on one.

This package root holds what both share: how a map cell is classified, world <-> cell
conversion for a ``GridMap`` (yaw honoured), and ``load_grid``, which turns whatever the user
named on the command line (a map YAML, a replay output folder, a ``.ot`` or exact-state ``.npz``
snapshot) into a ``GridMap``. Only numpy is imported here; numba and matplotlib are imported where
they are used.

Cell classes: a cell is *unknown* when its value is negative (-1), *occupied* when its value is
at least ``OCCUPIED_MIN`` (65: map_saver's default ``occupied_thresh`` 0.65 as a percentage),
and *free* otherwise. Maps read by ``read_map_yaml`` in trinary mode hold only -1 / 0 / 100.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..core.config import ProjectionConfig
from ..errors import MapFileError
from ..io.mapfile import GridMap
from ..thresholds import OCCUPIED_MIN  # noqa: F401 - a cell value >= this is occupied (re-exported)

# what a map argument may be, for messages
KINDS = "a map YAML, a replay output folder (ltmap replay -o DIR), a .ot snapshot or a state .npz snapshot"
Z_BAND = (ProjectionConfig.z_min, ProjectionConfig.z_max)  # m: the band .ot and state snapshots are projected over


def occupied_mask(grid: GridMap) -> np.ndarray:
    """bool (H, W): cells whose value is >= OCCUPIED_MIN."""
    return np.asarray(grid.data) >= OCCUPIED_MIN


def unknown_mask(grid: GridMap) -> np.ndarray:
    """bool (H, W): cells whose value is negative (-1)."""
    return np.asarray(grid.data) < 0


# ---------------------------------------------------------------------------------------------
# world <-> cell (row 0 = lowest y, col 0 = lowest x; origin = lower-left corner of cell (0,0))


def world_to_cell(grid: GridMap, x, y):
    """The (row, col) of the cell containing world point (x, y); arrays broadcast.

    The cell may lie outside the grid: check with ``in_bounds``. The origin's yaw is honoured
    (the point is rotated into the map frame first)."""
    ox, oy, yaw = grid.origin
    dx = np.asarray(x, dtype=np.float64) - ox
    dy = np.asarray(y, dtype=np.float64) - oy
    if yaw:
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = c * dx + s * dy, -s * dx + c * dy
    col = np.floor(dx / grid.resolution).astype(np.int64)
    row = np.floor(dy / grid.resolution).astype(np.int64)
    if col.ndim == 0:
        return int(row), int(col)
    return row, col


def cell_to_world(grid: GridMap, row, col):
    """World (x, y) of the centre of cell (row, col); arrays broadcast."""
    ox, oy, yaw = grid.origin
    lx = (np.asarray(col, dtype=np.float64) + 0.5) * grid.resolution
    ly = (np.asarray(row, dtype=np.float64) + 0.5) * grid.resolution
    if yaw:
        c, s = math.cos(yaw), math.sin(yaw)
        lx, ly = c * lx - s * ly, s * lx + c * ly
    x, y = lx + ox, ly + oy
    if np.ndim(x) == 0:
        return float(x), float(y)
    return x, y


def occupied_centres(grid: GridMap) -> np.ndarray:
    """World (x, y) centres (M, 2) of the grid's occupied cells (``occupied_mask``)."""
    rows, cols = np.nonzero(occupied_mask(grid))
    x, y = cell_to_world(grid, rows, cols)
    return np.stack([np.atleast_1d(x), np.atleast_1d(y)], axis=1).astype(np.float64)


def in_bounds(grid: GridMap, row, col):
    """True where (row, col) is a cell of the grid."""
    return (
        (np.asarray(row) >= 0)
        & (np.asarray(row) < grid.height)
        & (np.asarray(col) >= 0)
        & (np.asarray(col) < grid.width)
    )


# ---------------------------------------------------------------------------------------------
# inputs


def resolve_map_path(path: str | Path, what: str = "map") -> Path:
    """The file behind a command-line map argument: a YAML, a replay folder's map.yaml, a .ot or a
    state .npz."""
    p = Path(path)
    if p.is_dir():
        y = p / "map.yaml"
        if not y.is_file():
            raise MapFileError(f"{what} {p}: folder has no map.yaml; give {KINDS}")
        return y
    if not p.exists():
        raise MapFileError(f"{what} {p}: no such file; give {KINDS}")
    return p


def load_grid(path: str | Path, what: str = "map", z_band: tuple[float, float] = Z_BAND) -> GridMap:
    """Read a map argument as a GridMap: map_server YAML, replay output folder, .ot snapshot
    (projected over ``z_band``: occupied where a voxel with log-odds > 0 meets the band, free
    where only voxels with log-odds <= 0 do, unknown elsewhere) or exact-state .npz snapshot
    (projected as the .ot written beside it, see ``project_state``)."""
    p = resolve_map_path(path, what)
    suffix = p.suffix.lower()
    if suffix in (".yaml", ".yml"):
        from ..io.mapfile import read_map_yaml

        return read_map_yaml(p)
    if suffix == ".ot":
        from ..io.ot import read_ot

        keys, logodds, res = read_ot(p)
        return project_voxels(keys, logodds, res, z_band)
    if suffix == ".npz":
        return project_state(p, z_band)
    raise MapFileError(f"{what} {p}: unknown kind of file '{p.suffix}'; give {KINDS}")


def project_state(path: Path, z_band: tuple[float, float] = Z_BAND) -> GridMap:
    """An exact-state snapshot (``snapshots/state_*.npz``) projected as the ``.ot`` written beside
    it: the same voxels and log-odds (``snapshots.read_snapshot_voxels``: LT > 0, and free where
    its sensor map saw free space) through ``project_voxels``, so ``plan`` and ``diff`` give the
    same answer on either file. A state holds no static layer, so this is the replay's
    ``long_term`` map, not ``map``; it can differ from ``long_term.pgm`` in a column whose
    long-term voxels are being forgotten (0 < LT < occupied_thresh: seen free, LT falling) while
    no band voxel is free in O at that moment: free here and in the ``.ot`` (log-odds < 0),
    unknown in ``long_term.pgm``."""
    from ..outputs.snapshots import read_snapshot_voxels

    keys, logodds, res = read_snapshot_voxels(path)
    return project_voxels(keys, logodds, res, z_band)


def band_mask(k: np.ndarray, resolution: float, z_band: tuple[float, float]) -> np.ndarray:
    """True for voxel layers k whose interval [k*res, (k+1)*res) meets the band with positive length."""
    lo = k.astype(np.float64) * resolution
    hi = lo + resolution
    overlap = np.minimum(hi, z_band[1]) - np.maximum(lo, z_band[0])
    return overlap > 1e-9 * max(resolution, 1.0)


def project_voxels(
    keys: np.ndarray, logodds: np.ndarray, resolution: float, z_band: tuple[float, float] = Z_BAND
) -> GridMap:
    """Project voxels (keys (N,3) int i,j,k; log-odds (N,)) to a trinary GridMap over ``z_band``.

    The grid spans the columns of the voxels that meet the band; its origin is the lower-left
    corner of the lowest (i, j) voxel column, so its cells coincide with the voxel columns."""
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    logodds = np.asarray(logodds, dtype=np.float32).reshape(-1)
    sel = band_mask(keys[:, 2], resolution, z_band)
    keys, logodds = keys[sel], logodds[sel]
    if len(keys) == 0:
        return GridMap(np.full((1, 1), -1, dtype=np.int8), float(resolution), (0.0, 0.0, 0.0))
    i0, j0 = keys[:, 0].min(), keys[:, 1].min()
    w = int(keys[:, 0].max() - i0 + 1)
    h = int(keys[:, 1].max() - j0 + 1)
    data = np.full((h, w), -1, dtype=np.int8)
    rows = keys[:, 1] - j0
    cols = keys[:, 0] - i0
    occ = logodds > 0
    data[rows[~occ], cols[~occ]] = 0
    data[rows[occ], cols[occ]] = 100
    return GridMap(data, float(resolution), (float(i0 * resolution), float(j0 * resolution), 0.0))
