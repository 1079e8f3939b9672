"""How good a map is against a reference, for ``--localize`` (docs/localization.md): the
fraction of a map's occupied columns on a published map's walls, and how thick its walls are.
Pure numpy."""

from __future__ import annotations

import numpy as np

from ..io.mapfile import GridMap
from . import in_bounds, occupied_centres, occupied_mask, world_to_cell


def dilate(mask: np.ndarray, n: int) -> np.ndarray:
    """``mask`` grown by ``n`` cells (a square), without wrapping at the borders."""
    h, w = mask.shape
    pad = np.zeros((h + 2 * n, w + 2 * n), dtype=bool)
    pad[n:n + h, n:n + w] = mask
    out = np.zeros_like(mask)
    for dy in range(2 * n + 1):
        for dx in range(2 * n + 1):
            out |= pad[dy:dy + h, dx:dx + w]
    return out


def fraction_on_walls(xy: np.ndarray, walls: GridMap, cells: int = 2) -> float:
    """Fraction of points (N, 2) within ``cells`` cells (a square) of an occupied cell of
    ``walls``; points outside the map count as off the walls."""
    if len(xy) == 0:
        return 0.0
    near = dilate(occupied_mask(walls), cells)
    r, c = world_to_cell(walls, xy[:, 0], xy[:, 1])
    ok = in_bounds(walls, r, c)
    return float(near[r[ok], c[ok]].sum()) / len(xy)


def wall_distance(xy: np.ndarray, walls: GridMap) -> np.ndarray:
    """Distance (m) of each point (N, 2) to the centre of the nearest occupied cell of ``walls``."""
    w = occupied_centres(walls)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    out = np.empty(len(xy))
    step = max(1, (1 << 22) // max(len(w), 1))  # points per chunk: at most 4 M distances at a time
    for a in range(0, len(xy), step):
        p = xy[a:a + step]
        out[a:a + step] = np.sqrt(((p[:, None, :] - w[None, :, :]) ** 2).sum(-1).min(axis=1))
    return out


def raster(xy: np.ndarray, resolution: float) -> np.ndarray:
    """A bool grid (row = y) with the cells of the points (N, 2) set."""
    lo = xy.min(0) - 1.0
    ij = np.round((xy - lo) / resolution).astype(int)
    g = np.zeros(tuple(ij.max(0)[::-1] + 2), dtype=bool)
    g[ij[:, 1], ij[:, 0]] = True
    return g


def wall_thickness(occ: np.ndarray, resolution: float, band: float = 0.5, samples: int = 4000) -> dict:
    """How thick the walls of an occupancy grid (bool, row = y) are. At each occupied cell (at
    most ``samples`` of them) whose occupied neighbours within 0.5 m lie along a line (the
    principal axis of their spread at least 6x the other: a straight wall, not a corner or
    clutter), count the occupied cells on the line through it along the other axis (the wall's
    normal) within +-``band`` m, times the cell size. A wall seen sharply is one or two cells
    thick; a wall smeared by pose errors is as thick as the smear. Returns the median and the
    90th percentile (m) and how many cells were measured."""
    pts = np.argwhere(occ).astype(float)
    r = int(round(0.5 / resolution))
    nb = int(round(band / resolution))
    steps = np.arange(-nb, nb + 1)
    th = []
    for p in pts[:: max(1, len(pts) // samples)]:
        near = pts[np.max(np.abs(pts - p), axis=1) <= r]
        if len(near) < 8:
            continue
        w, v = np.linalg.eigh(np.cov((near - p).T))
        if w[1] < 6 * max(w[0], 1e-9):
            continue
        n = v[:, 0]
        rr = np.round(p[0] + steps * n[0]).astype(int)
        cc = np.round(p[1] + steps * n[1]).astype(int)
        ok = (rr >= 0) & (rr < occ.shape[0]) & (cc >= 0) & (cc < occ.shape[1])
        th.append(int(occ[rr[ok], cc[ok]].sum()) * resolution)
    a = np.array(th)
    return {"cells": int(occ.sum()), "walls_measured": len(a),
            "median_m": round(float(np.median(a)), 3) if len(a) else None,
            "p90_m": round(float(np.percentile(a, 90)), 3) if len(a) else None}  # fmt: skip
