"""The projected map P and the virtual scan (SPEC 2.3).

P takes the maximum of F = max(S, LT) over the voxels of each column whose z-interval meets
[z_min, z_max] with positive length. A cell is occupied when that maximum reaches the occupied
threshold, free when some voxel of its band was seen free in O (or S says free) and none is
occupied, unknown otherwise. The cells the robot's footprint covered along its path (a disc of
``footprint_radius`` around each pose) are free unless occupied: the robot stood there (nav2's
costmaps clear the footprint likewise), so a path can be planned from where it is.

The virtual scan is a LaserScan whose range per beam is the distance to the nearest cell that is
occupied in max(P, current obstacles in O): it shows the local planner what the 2D laser misses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..jit import helper, njit
from .grid import BLOCK, BLOCK_BITS, BLOCK_MASK, band_k_range, find_block, voxel_offset

UNKNOWN, FREE, OCCUPIED = -1, 0, 100


def footprint_cells(path_xy, radius: float, resolution: float) -> np.ndarray:
    """The (i, j) lattice cells (M, 2), unique, whose centre lies within ``radius`` of a pose of
    ``path_xy`` (N, 2 metres; poses farther apart than half a cell are joined by points on the
    segment between them, so a fast robot sweeps a band, not beads). Poses are snapped to the
    centres of a grid of quarter cells (within 0.9 cm at 0.05 m), so thousands of frames of a
    standing robot cost a few points. Empty for radius <= 0."""
    pts = np.asarray(path_xy, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if radius <= 0 or not len(pts):
        return np.zeros((0, 2), dtype=np.int64)
    step = 0.5 * resolution
    if len(pts) > 1:
        seg = np.diff(pts, axis=0)
        n = np.maximum(np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / step).astype(np.int64), 1)
        if n.max() > 1:  # fill the gaps
            idx = np.repeat(np.arange(len(seg)), n)
            frac = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
            pts = np.concatenate([pts[idx] + seg[idx] * frac[:, None], pts[-1:]])
    q = np.unique(np.floor(pts / (0.25 * resolution)).astype(np.int64), axis=0)
    centres = (q + 0.5) * (0.25 * resolution)
    reach = int(np.ceil(radius / resolution)) + 1
    di, dj = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    di, dj = di.ravel(), dj.ravel()
    base = np.floor(centres / resolution).astype(np.int64)
    ci = base[:, 0:1] + di[None, :]
    cj = base[:, 1:2] + dj[None, :]
    dx = (ci + 0.5) * resolution - centres[:, 0:1]
    dy = (cj + 0.5) * resolution - centres[:, 1:2]
    inside = dx * dx + dy * dy <= radius * radius + 1e-12
    cells = np.stack([ci[inside], cj[inside]], axis=1)
    return np.unique(cells, axis=0) if len(cells) else np.zeros((0, 2), dtype=np.int64)


class FootprintTrace:
    """The footprint cells of a path that grows (a replay's trajectory), taken in incrementally:
    each ``update`` looks only at the poses added since the last one."""

    def __init__(self, radius: float, resolution: float):
        self.radius = float(radius)
        self.resolution = float(resolution)
        self.cells = np.zeros((0, 2), dtype=np.int64)
        self._keys = np.zeros(0, dtype=np.int64)  # the cells packed, sorted
        self._n = 0
        self._last: np.ndarray | None = None

    def update(self, path) -> np.ndarray:
        """The cells (M, 2) of ``path``: a sequence of rows whose last two values are x, y in
        metres (e.g. (t, x, y)), the same sequence as before with rows appended. Cost: the new
        poses and a merge into the sorted cells (a long drive has 10^5 cells: no sort of them)."""
        if len(path) > self._n:
            new = np.asarray(path[self._n :], dtype=np.float64).reshape(len(path) - self._n, -1)[:, -2:]
            pts = new if self._last is None else np.concatenate([self._last, new])
            cells = footprint_cells(pts, self.radius, self.resolution)
            if len(cells):
                keys = np.unique(((cells[:, 0] + _FP_OFF) << 32) | (cells[:, 1] + _FP_OFF))
                pos = np.searchsorted(self._keys, keys)
                known = np.zeros(len(keys), dtype=bool)
                if len(self._keys):
                    known = (pos < len(self._keys)) & (self._keys[np.minimum(pos, len(self._keys) - 1)] == keys)
                if not known.all():
                    self._keys = np.insert(self._keys, pos[~known], keys[~known])
                    self.cells = np.stack([(self._keys >> 32) - _FP_OFF, (self._keys & 0xFFFFFFFF) - _FP_OFF], axis=1)
            self._last = new[-1:]
            self._n = len(path)
        return self.cells


_FP_OFF = np.int64(1 << 30)  # packed footprint cells: (i + off) << 32 | (j + off)


@dataclass
class Projection:
    """P on the lattice: ``data[row, col]`` for cell (i0 + col, j0 + row); row 0 = lowest y."""

    data: np.ndarray  # int8 trinary: -1 unknown, 0 free, 100 occupied
    value: np.ndarray  # float32 max of F over the band (0 where nothing)
    seen_free: np.ndarray  # bool: some band voxel seen free in O, or S free
    i0: int
    j0: int
    resolution: float

    @property
    def origin(self) -> tuple[float, float, float]:
        return (self.i0 * self.resolution, self.j0 * self.resolution, 0.0)

    def scale_data(self) -> np.ndarray:
        """0..100 from the max of F for known cells, -1 unknown (map_server scale mode)."""
        known = (self.data != UNKNOWN) | (self.value > 0)
        out = np.where(known, np.rint(self.value * 100.0), -1)
        return out.astype(np.int8)



@njit(cache=True, nogil=True)
def _project_o(coords, n_blocks, logodds, stamp, k_lo, k_hi, i0, j0, seen_free):
    H, W = seen_free.shape
    for b in range(n_blocks):
        bz0 = np.int64(coords[b, 2]) * BLOCK
        if bz0 + BLOCK - 1 < k_lo or bz0 > k_hi:
            continue
        bx0 = np.int64(coords[b, 0]) * BLOCK
        by0 = np.int64(coords[b, 1]) * BLOCK
        for li in range(BLOCK):
            c = bx0 + li - i0
            if c < 0 or c >= W:
                continue
            for lj in range(BLOCK):
                r = by0 + lj - j0
                if r < 0 or r >= H or seen_free[r, c]:
                    continue
                base = (li << (2 * BLOCK_BITS)) | (lj << BLOCK_BITS)
                for lk in range(BLOCK):
                    k = bz0 + lk
                    if k < k_lo or k > k_hi:
                        continue
                    off = base | lk
                    if stamp[b, off] > 0 and logodds[b, off] < 0.0:
                        seen_free[r, c] = True
                        break


@njit(cache=True, nogil=True)
def _project_lt(coords, n_blocks, lt, k_lo, k_hi, i0, j0, value):
    H, W = value.shape
    for b in range(n_blocks):
        bz0 = np.int64(coords[b, 2]) * BLOCK
        if bz0 + BLOCK - 1 < k_lo or bz0 > k_hi:
            continue
        bx0 = np.int64(coords[b, 0]) * BLOCK
        by0 = np.int64(coords[b, 1]) * BLOCK
        for off in range(BLOCK * BLOCK * BLOCK):
            v = lt[b, off]
            if v <= 0.0:
                continue
            k = bz0 + (off & BLOCK_MASK)
            if k < k_lo or k > k_hi:
                continue
            c = bx0 + ((off >> (2 * BLOCK_BITS)) & BLOCK_MASK) - i0
            r = by0 + ((off >> BLOCK_BITS) & BLOCK_MASK) - j0
            if 0 <= r < H and 0 <= c < W and v > value[r, c]:
                value[r, c] = v


def project(
    lmap,
    z_min: float | None = None,
    z_max: float | None = None,
    use_static: bool = True,
    use_lt: bool = True,
    use_o_free: bool = True,
    footprint=None,
) -> Projection:
    """P of a ``LayeredMap`` over the band [z_min, z_max] (defaults from its config).

    The flags leave layers out: ``use_static=False`` projects LT alone (``long_term.pgm``);
    ``use_lt=False, use_o_free=False`` projects S alone (``static.pgm``). ``footprint``: the
    robot's path, float (N, 2) x, y in metres (its cells: ``footprint_cells`` with the config's
    ``footprint_radius``), or the cells themselves, integer (M, 2) i, j; those cells are free
    unless occupied (None: no footprint)."""
    pc = lmap.cfg.projection
    fp = None
    if footprint is not None:
        fp = np.asarray(footprint)
        if fp.dtype.kind == "f":
            fp = footprint_cells(fp, pc.footprint_radius, lmap.resolution)
        fp = fp.astype(np.int64).reshape(-1, 2)
    z_min = pc.z_min if z_min is None else z_min
    z_max = pc.z_max if z_max is None else z_max
    r = lmap.resolution
    k_lo, k_hi = band_k_range(z_min, z_max, r)
    boxes = []
    grids = ([lmap.O] if use_o_free else []) + ([lmap.D] if use_lt else [])
    for grid in grids:
        if grid.n_blocks:
            bc = grid.block_coords[: grid.n_blocks].astype(np.int64)
            zin = (bc[:, 2] * BLOCK + BLOCK - 1 >= k_lo) & (bc[:, 2] * BLOCK <= k_hi)
            if zin.any():
                bc = bc[zin]
                boxes.append((bc[:, 0].min() * BLOCK, bc[:, 1].min() * BLOCK,
                              (bc[:, 0].max() + 1) * BLOCK, (bc[:, 1].max() + 1) * BLOCK))  # fmt: skip
    s = lmap.static if use_static else None
    if s is not None:
        boxes.append((s.i0, s.j0, s.i0 + s.occ.shape[1], s.j0 + s.occ.shape[0]))
    if fp is not None and len(fp):
        boxes.append((fp[:, 0].min(), fp[:, 1].min(), fp[:, 0].max() + 1, fp[:, 1].max() + 1))
    if not boxes:
        return Projection(np.full((1, 1), UNKNOWN, np.int8), np.zeros((1, 1), np.float32),
                           np.zeros((1, 1), bool), 0, 0, r)  # fmt: skip
    b = np.array(boxes, dtype=np.int64)
    i0, j0, i1, j1 = int(b[:, 0].min()), int(b[:, 1].min()), int(b[:, 2].max()), int(b[:, 3].max())
    H, W = j1 - j0, i1 - i0
    value = np.zeros((H, W), dtype=np.float32)
    seen_free = np.zeros((H, W), dtype=np.bool_)
    if use_o_free:
        o = lmap.O
        _project_o(o.block_coords, o.n_blocks, o.data["logodds"], o.data["stamp"], k_lo, k_hi, i0, j0, seen_free)
    if use_lt:
        d = lmap.D
        _project_lt(d.block_coords, d.n_blocks, d.data["lt"], k_lo, k_hi, i0, j0, value)
    if s is not None:
        rs, cs = s.j0 - j0, s.i0 - i0
        h, w = s.occ.shape
        sub_v = value[rs : rs + h, cs : cs + w]
        sub_f = seen_free[rs : rs + h, cs : cs + w]
        s_occ = (s.occ >= OCCUPIED) & (s.top_k >= k_lo)
        sub_v[s_occ] = 1.0
        sub_f |= s.occ == FREE
    occ = value >= pc.occupied_thresh
    if fp is not None and len(fp):
        seen_free[fp[:, 1] - j0, fp[:, 0] - i0] = True  # the robot stood there
    data = np.where(occ, OCCUPIED, np.where(seen_free, FREE, UNKNOWN)).astype(np.int8)
    return Projection(data, value, seen_free, i0, j0, r)


def static_fills(lmap, cols: np.ndarray) -> np.ndarray:
    """Bool per (i, j) column of ``cols`` (N, 2): the static layer makes it occupied in P (a static
    occupied cell whose wall reaches the z band), so nothing in LT changes that cell."""
    cols = np.asarray(cols, dtype=np.int64).reshape(-1, 2)
    out = np.zeros(len(cols), dtype=bool)
    s = lmap.static
    if s is None or not len(cols):
        return out
    k_lo, _ = band_k_range(lmap.cfg.projection.z_min, lmap.cfg.projection.z_max, lmap.resolution)
    r, c = cols[:, 1] - s.j0, cols[:, 0] - s.i0
    h, w = s.occ.shape
    inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
    ri, ci = r[inside], c[inside]
    out[inside] = (s.occ[ri, ci] >= OCCUPIED) & (s.top_k[ri, ci] >= k_lo)
    return out


@helper()
def _o_column_occupied(table_keys, table_vals, logodds, stamp, since, i, j, k_lo, k_hi):
    bx = i >> BLOCK_BITS
    by = j >> BLOCK_BITS
    for bz in range(k_lo >> BLOCK_BITS, (k_hi >> BLOCK_BITS) + 1):
        b = find_block(table_keys, table_vals, bx, by, bz)
        if b < 0:
            continue
        for lk in range(BLOCK):
            k = bz * BLOCK + lk
            if k < k_lo or k > k_hi:
                continue
            off = voxel_offset(i, j, k)
            if logodds[b, off] > 0.0 and stamp[b, off] >= since:
                return True
    return False


@njit(cache=True, nogil=True)
def _virtual_scan_kernel(
    x, y, yaw, angles, range_min, range_max, res,
    p_data, p_i0, p_j0, table_keys, table_vals, logodds, stamp, since, k_lo, k_hi, use_o,
):  # fmt: skip
    n = angles.shape[0]
    out = np.full(n, np.inf, dtype=np.float32)
    H, W = p_data.shape
    inv = 1.0 / res
    for a in range(n):
        th = yaw + angles[a]
        dx = np.cos(th)
        dy = np.sin(th)
        ci = np.int64(np.floor(x * inv))
        cj = np.int64(np.floor(y * inv))
        si = 1 if dx > 0 else (-1 if dx < 0 else 0)
        sj = 1 if dy > 0 else (-1 if dy < 0 else 0)
        tmx = (((ci + (1 if si > 0 else 0)) * res) - x) / dx if si != 0 else 1e300
        tmy = (((cj + (1 if sj > 0 else 0)) * res) - y) / dy if sj != 0 else 1e300
        tdx = res / abs(dx) if si != 0 else 1e300
        tdy = res / abs(dy) if sj != 0 else 1e300
        t_enter = 0.0
        while t_enter <= range_max:
            if t_enter >= range_min:
                r = cj - p_j0
                c = ci - p_i0
                hit = False
                if 0 <= r < H and 0 <= c < W and p_data[r, c] >= 100 or use_o and _o_column_occupied(table_keys, table_vals, logodds, stamp, since, ci, cj, k_lo, k_hi):
                    hit = True
                if hit:
                    out[a] = t_enter
                    break
            if tmx < tmy:
                t_enter = tmx
                ci += si
                tmx += tdx
            else:
                t_enter = tmy
                cj += sj
                tmy += tdy
    return out


def virtual_scan(
    lmap,
    projection: Projection,
    pose_xy_yaw: tuple[float, float, float],
    angles: np.ndarray,
    range_min: float,
    range_max: float,
    include_o: bool = True,
    o_since_frame: int = 0,
) -> np.ndarray:
    """Ranges (float32, +inf for no return) of a scan from (x, y, yaw) in the fixed frame over
    max(P, current obstacles in O within the z band). Range = distance to the cell boundary
    where the beam enters the first occupied cell at or beyond ``range_min``. *Current* obstacles
    in O: log-odds > 0 and updated by frame ``o_since_frame`` or later (``LayeredMap.frame_id``
    counts integrated frames; 0: whenever), so a voxel a person left behind where no sensor looks
    again does not stay in the scan."""
    x, y, yaw = (float(v) for v in pose_xy_yaw)
    pc = lmap.cfg.projection
    k_lo, k_hi = band_k_range(pc.z_min, pc.z_max, lmap.resolution)
    o = lmap.O
    return _virtual_scan_kernel(
        x, y, yaw, np.ascontiguousarray(angles, dtype=np.float64), float(range_min), float(range_max),
        lmap.resolution, projection.data, projection.i0, projection.j0,
        o.table_keys, o.table_vals, o.data["logodds"], o.data["stamp"], int(o_since_frame), k_lo, k_hi, include_o,
    )  # fmt: skip


