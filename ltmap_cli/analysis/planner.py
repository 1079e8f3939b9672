"""A* on an occupancy grid, with the robot radius inflated.

Library API (the replay calls these every tick to time the planner's reaction):

- ``inflate(occupied, radius_cells) -> blocked``: a cell is blocked when the centre of an occupied
  cell lies within ``radius_cells`` of its centre (Euclidean, ``<=``).
- ``blocked_grid(grid, robot_radius, allow_unknown) -> blocked``: the cells a robot centre may
  not occupy on a ``GridMap`` (inflated occupied cells, plus unknown cells unless allowed).
- ``plan_path(blocked, start_rc, goal_rc) -> PathResult | None``: 8-connected A* with octile
  costs (1 per straight step, sqrt(2) per diagonal step) and the octile-distance heuristic
  (admissible and consistent, so the path is optimal). A diagonal step is allowed only when
  both cells it cuts past are free (no squeezing between two blocked cells that touch at a
  corner). ``None`` when no path exists, including when start or goal is blocked.
- ``plan_on_grid(grid, start_xy, goal_xy, ...) -> PlanResult``: the whole thing in world
  coordinates with user-facing errors (InputError naming start or goal, NoPathError).

The kernels are numba ``njit(cache=True)``; A* uses a binary heap over flat arrays.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, NoPathError
from ..io.mapfile import GridMap
from ..jit import njit
from . import cell_to_world, in_bounds, occupied_mask, unknown_mask, world_to_cell

_EPS = 1e-9


@dataclass
class PathResult:
    path_rc: np.ndarray  # int64 (K, 2): row, col of each cell from start to goal
    length_cells: float  # octile length in cells (sum of 1 and sqrt(2) steps)
    expanded: int  # cells taken off the open list and expanded


@dataclass
class PlanResult:
    grid: GridMap
    blocked: np.ndarray  # bool (H, W) as planned on
    start_xy: tuple[float, float]
    goal_xy: tuple[float, float]
    start_rc: tuple[int, int]
    goal_rc: tuple[int, int]
    robot_radius: float
    allow_unknown: bool
    path_rc: np.ndarray
    path_xy: np.ndarray  # float (K, 2): world x, y of the path's cell centres
    length_cells: float
    length_m: float
    expanded: int
    seconds: float  # wall-clock time of the search alone (not its kernel's compiling: 4.5 s on a first run)


# ---------------------------------------------------------------------------------------------
# kernels (numba; compiled on first call, cached on disk)


@njit(cache=True, nogil=True)
def _row_distance(occ):
    # horizontal distance (cells) from each cell to the nearest occupied cell of its row
    h, w = occ.shape
    big = 1 << 30
    d = np.empty((h, w), np.int32)
    for r in range(h):
        last = -big
        for c in range(w):
            if occ[r, c]:
                last = c
            d[r, c] = min(c - last, big)
        last = big + w
        for c in range(w - 1, -1, -1):
            if occ[r, c]:
                last = c
            v = last - c
            if v < d[r, c]:
                d[r, c] = v
    return d


@njit(cache=True, nogil=True)
def _disk_dilate(rowd, r2, ri):
    # out[r, c] = exists dy in [-ri, ri] with rowd[r+dy, c]^2 + dy^2 <= r2
    h, w = rowd.shape
    out = np.zeros((h, w), np.bool_)
    for r in range(h):
        lo = max(0, r - ri)
        hi = min(h - 1, r + ri)
        for c in range(w):
            for rr in range(lo, hi + 1):
                dx = rowd[rr, c]
                if dx <= ri:
                    dy = rr - r
                    if dx * dx + dy * dy <= r2:
                        out[r, c] = True
                        break
    return out


@njit(cache=True, nogil=True)
def _connected(free, w_pad, start, goal):
    # Are start and goal in one 4-connected component of ``free`` (flat, padded with a blocked
    # border)? 8-connected moves without corner cutting connect exactly the same cells. Two
    # breadth-first floods, one from each end, advance in turn; the answer is known when they
    # meet (True) or when either runs out of cells (False), so an enclosed start or goal costs
    # only its own small region. Each cell is queued at most once: the start's queue grows up
    # from 0 and the goal's down from the end of one shared array.
    n = free.size
    mark = np.zeros(n, np.uint8)
    queue = np.empty(n, np.int64)
    offs = np.array([-w_pad, w_pad, -1, 1])
    mark[start] = 1
    mark[goal] = 2
    queue[0] = start
    queue[n - 1] = goal
    a_head, a_tail = 0, 1  # queue[a_head:a_tail]
    b_head, b_tail = n - 1, n - 2  # queue[b_tail+1 : b_head+1], taken from b_head down
    while True:
        if a_head == a_tail or b_head == b_tail:
            return False
        node = queue[a_head]
        a_head += 1
        for k in range(4):
            nb = node + offs[k]
            if free[nb]:
                m = mark[nb]
                if m == 2:
                    return True
                if m == 0:
                    mark[nb] = 1
                    queue[a_tail] = nb
                    a_tail += 1
        node = queue[b_head]
        b_head -= 1
        for k in range(4):
            nb = node + offs[k]
            if free[nb]:
                m = mark[nb]
                if m == 1:
                    return True
                if m == 0:
                    mark[nb] = 2
                    queue[b_tail] = nb
                    b_tail -= 1


@njit(cache=True, nogil=True)
def _astar(blocked, sr, sc, gr, gc):
    # blocked: uint8 (H, W). Returns (found, length, expanded, path (K, 2) int64).
    # The grid is copied into a flat array with a one-cell blocked border (no bounds checks);
    # the open list is an indexed binary heap (decrease-key, no duplicates) keyed by
    # (f, h): among equal f the node nearer the goal first. ``expanded`` counts A*'s
    # expansions only (not the cells of the connectivity check).
    h, w = blocked.shape
    W = w + 2
    H = h + 2
    n = H * W
    free = np.zeros(n, np.uint8)
    for r in range(h):
        base = (r + 1) * W + 1
        for c in range(w):
            free[base + c] = 1 - blocked[r, c]
    sqrt2 = math.sqrt(2.0)
    g = np.full(n, np.inf)
    parent = np.empty(n, np.int64)
    pos = np.full(n, -1, np.int64)  # -1 never opened, -2 closed, else heap index
    cap = 1024
    hf = np.empty(cap)
    hh = np.empty(cap)
    hn = np.empty(cap, np.int64)
    off = np.array([-W, W, -1, 1, -W - 1, -W + 1, W - 1, W + 1])
    o1 = np.array([0, 0, 0, 0, -W, -W, W, W])  # row-neighbour for diagonal
    o2 = np.array([0, 0, 0, 0, -1, 1, -1, 1])
    start = (sr + 1) * W + sc + 1
    goal = (gr + 1) * W + gc + 1
    g[start] = 0.0
    parent[start] = -1
    adx = abs(sc - gc)
    ady = abs(sr - gr)
    h0 = (adx + ady) + (sqrt2 - 2.0) * min(adx, ady)
    hf[0] = h0
    hh[0] = h0
    hn[0] = start
    pos[start] = 0
    size = 1
    expanded = 0
    found = False
    # a long search may be one that cannot succeed: then check connectivity once (cheap
    # flood fill) instead of expanding every reachable cell before giving up
    check_at = max(1 << 16, n // 16)
    while size > 0:
        node = hn[0]
        pos[node] = -2
        size -= 1
        if size > 0:
            # sift down the last element from the root (hole technique)
            lf = hf[size]
            lh = hh[size]
            ln = hn[size]
            i = 0
            while True:
                left = 2 * i + 1
                if left >= size:
                    break
                best = left
                right = left + 1
                if right < size and (
                    hf[right] < hf[left] or (hf[right] == hf[left] and hh[right] < hh[left])
                ):
                    best = right
                if hf[best] < lf or (hf[best] == lf and hh[best] < lh):
                    hf[i] = hf[best]
                    hh[i] = hh[best]
                    hn[i] = hn[best]
                    pos[hn[i]] = i
                    i = best
                else:
                    break
            hf[i] = lf
            hh[i] = lh
            hn[i] = ln
            pos[ln] = i
        expanded += 1
        if node == goal:
            found = True
            break
        if expanded == check_at and not _connected(free, W, start, goal):
            break
        gnode = g[node]
        for k in range(8):
            nb = node + off[k]
            if not free[nb]:
                continue
            p = pos[nb]
            if p == -2:
                continue
            if k >= 4:
                if not free[node + o1[k]] or not free[node + o2[k]]:
                    continue
                ng = gnode + sqrt2
            else:
                ng = gnode + 1.0
            if ng < g[nb]:
                g[nb] = ng
                parent[nb] = node
                nr = nb // W
                nc = nb - nr * W
                adx = abs(nc - gc - 1)
                ady = abs(nr - gr - 1)
                hv = (adx + ady) + (sqrt2 - 2.0) * min(adx, ady)
                fv = ng + hv
                if p == -1:
                    if size == cap:
                        ncap = cap * 2
                        hf2 = np.empty(ncap)
                        hh2 = np.empty(ncap)
                        hn2 = np.empty(ncap, np.int64)
                        for r in range(size):  # (element by element: a slice assignment makes numba
                            hf2[r] = hf[r]  # compile its shape-mismatch message, seconds of a first run)
                            hh2[r] = hh[r]
                            hn2[r] = hn[r]
                        hf = hf2
                        hh = hh2
                        hn = hn2
                        cap = ncap
                    i = size
                    size += 1
                else:
                    i = p
                # sift up from i (decrease-key or insert)
                while i > 0:
                    q = (i - 1) // 2
                    if fv < hf[q] or (fv == hf[q] and hv < hh[q]):
                        hf[i] = hf[q]
                        hh[i] = hh[q]
                        hn[i] = hn[q]
                        pos[hn[i]] = i
                        i = q
                    else:
                        break
                hf[i] = fv
                hh[i] = hv
                hn[i] = nb
                pos[nb] = i
    if not found:
        return False, np.inf, expanded, np.empty((0, 2), np.int64)
    count = 0
    node = goal
    while node != -1:
        count += 1
        node = parent[node]
    path = np.empty((count, 2), np.int64)
    node = goal
    for i in range(count - 1, -1, -1):
        path[i, 0] = node // W - 1
        path[i, 1] = node % W - 1
        node = parent[node]
    return True, g[goal], expanded, path


# ---------------------------------------------------------------------------------------------
# library API


def inflate(occupied: np.ndarray, radius_cells: float) -> np.ndarray:
    """bool (H, W): cells whose centre is within ``radius_cells`` (Euclidean, inclusive) of the
    centre of an occupied cell. ``radius_cells`` < 1 leaves ``occupied`` as it is."""
    occ = np.ascontiguousarray(occupied, dtype=np.bool_)
    if occ.ndim != 2:
        raise ValueError(f"inflate: occupied must be 2D, got shape {occ.shape}")
    if radius_cells < 0:
        raise ValueError(f"inflate: radius_cells must be >= 0, got {radius_cells}")
    r = float(radius_cells) + _EPS
    ri = int(math.floor(r))
    if ri < 1 or occ.size == 0:
        return occ.copy()
    return _disk_dilate(_row_distance(occ), r * r, ri)


def blocked_grid(grid: GridMap, robot_radius: float = 0.2, allow_unknown: bool = False) -> np.ndarray:
    """bool (H, W): cells a robot centre may not occupy: occupied cells inflated by
    ``robot_radius`` (m), plus unknown cells unless ``allow_unknown``."""
    blocked = inflate(occupied_mask(grid), robot_radius / grid.resolution)
    if not allow_unknown:
        blocked |= unknown_mask(grid)
    return blocked


def plan_path(blocked: np.ndarray, start_rc, goal_rc) -> PathResult | None:
    """Optimal 8-connected A* path on ``blocked`` (bool (H, W), True = not traversable) from
    ``start_rc`` to ``goal_rc`` (row, col). ``None`` when there is no path (including a blocked
    start or goal). Raises ValueError for a cell outside the grid."""
    b = np.ascontiguousarray(blocked)
    b = b.view(np.uint8) if b.dtype == np.bool_ else (b != 0).view(np.uint8)
    if b.ndim != 2:
        raise ValueError(f"plan_path: blocked must be 2D, got shape {b.shape}")
    h, w = b.shape
    sr, sc = (int(v) for v in start_rc)
    gr, gc = (int(v) for v in goal_rc)
    for name, (r, c) in (("start", (sr, sc)), ("goal", (gr, gc))):
        if not (0 <= r < h and 0 <= c < w):
            raise ValueError(f"plan_path: {name} cell ({r}, {c}) is outside the {h} x {w} grid")
    if b[sr, sc] or b[gr, gc]:
        return None
    found, length, expanded, path = _astar(b, sr, sc, gr, gc)
    if not found:
        return None
    return PathResult(path, float(length), int(expanded))


def _endpoint(
    grid: GridMap,
    blocked_inflated: np.ndarray,
    unknown: np.ndarray,
    occ: np.ndarray,
    name: str,
    xy,
    allow_unknown: bool,
) -> tuple[int, int]:
    x, y = float(xy[0]), float(xy[1])
    r, c = world_to_cell(grid, x, y)
    where = f"{name} ({x:g}, {y:g})"
    if not in_bounds(grid, r, c):
        xmin, ymin = grid.origin[0], grid.origin[1]
        xmax = xmin + grid.width * grid.resolution
        ymax = ymin + grid.height * grid.resolution
        raise InputError(
            f"{where} is off the map (x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g} m); "
            f"give a {name} inside the map"
        )
    if occ[r, c]:
        raise InputError(
            f"{where} is inside an obstacle (cell row {r}, col {c}); move the {name} to free space"
        )
    if blocked_inflated[r, c]:
        raise InputError(
            f"{where} is within the robot radius of an obstacle (cell row {r}, col {c}); move the "
            f"{name} away from obstacles or lower --robot-radius"
        )
    if unknown[r, c] and not allow_unknown:
        raise InputError(
            f"{where} is in an unknown cell (row {r}, col {c}); move the {name} or pass --allow-unknown"
        )
    return r, c


def plan_on_grid(
    grid: GridMap,
    start_xy,
    goal_xy,
    robot_radius: float = 0.2,
    allow_unknown: bool = False,
) -> PlanResult:
    """Plan from ``start_xy`` to ``goal_xy`` (world metres) on ``grid``. Raises InputError when the
    start or goal is off the map or blocked (naming which), NoPathError when no path exists."""
    if not robot_radius >= 0 or not math.isfinite(robot_radius):  # NaN fails every comparison
        raise InputError(f"--robot-radius {robot_radius:g} is not a radius; give a finite number >= 0 m")
    occ = occupied_mask(grid)
    unknown = unknown_mask(grid)
    inflated = inflate(occ, robot_radius / grid.resolution)
    start_rc = _endpoint(grid, inflated, unknown, occ, "start", start_xy, allow_unknown)
    goal_rc = _endpoint(grid, inflated, unknown, occ, "goal", goal_xy, allow_unknown)
    blocked = inflated | unknown if not allow_unknown else inflated
    _astar(np.zeros((1, 2), dtype=np.uint8), 0, 0, 0, 1)  # compiled (a first run) or loaded before the clock
    t0 = time.perf_counter()
    res = plan_path(blocked, start_rc, goal_rc)
    seconds = time.perf_counter() - t0
    if res is None:
        hint = "" if allow_unknown else ", --allow-unknown"
        raise NoPathError(
            f"no path from start ({start_xy[0]:g}, {start_xy[1]:g}) to goal ({goal_xy[0]:g}, {goal_xy[1]:g}) "
            f"with robot radius {robot_radius:g} m: obstacles separate them; "
            f"try a smaller --robot-radius{hint} or other points"
        )
    xs, ys = cell_to_world(grid, res.path_rc[:, 0], res.path_rc[:, 1])
    return PlanResult(
        grid=grid,
        blocked=blocked,
        start_xy=(float(start_xy[0]), float(start_xy[1])),
        goal_xy=(float(goal_xy[0]), float(goal_xy[1])),
        start_rc=start_rc,
        goal_rc=goal_rc,
        robot_radius=float(robot_radius),
        allow_unknown=bool(allow_unknown),
        path_rc=res.path_rc,
        path_xy=np.column_stack([xs, ys]),
        length_cells=res.length_cells,
        length_m=res.length_cells * grid.resolution,
        expanded=res.expanded,
        seconds=seconds,
    )
