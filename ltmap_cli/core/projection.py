"""The projected map P and the virtual scan (SPEC 2.3).

P takes the maximum of F = max(S, LT) over the voxels of each column whose z-interval meets
[z_min, z_max] with positive length. A cell is occupied when that maximum reaches the occupied
threshold, free when some voxel of its band was seen free in O (or S says free) and none is
occupied, unknown otherwise.

The virtual scan is a LaserScan whose range per beam is the distance to the nearest cell that is
occupied in max(P, current obstacles in O): it shows the local planner what the 2D laser misses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .grid import BLOCK, BLOCK_BITS, BLOCK_MASK, band_k_range, find_block, voxel_offset

UNKNOWN, FREE, OCCUPIED = -1, 0, 100




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



@njit(cache=True)
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


@njit(cache=True)
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
) -> Projection:
    """P of a ``LayeredMap`` over the band [z_min, z_max] (defaults from its config).

    The flags leave layers out: ``use_static=False`` projects LT alone (``long_term.pgm``);
    ``use_lt=False, use_o_free=False`` projects S alone (``static.pgm``)."""
    pc = lmap.cfg.projection
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


@njit(cache=True)
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


@njit(cache=True)
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


