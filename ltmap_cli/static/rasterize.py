"""Rasterize plan geometry (metres, map frame) onto the map lattice, vectorized with numpy.

The lattice: cell (row i, col j) covers ``[x0 + j r, x0 + (j+1) r) x [y0 + i r, y0 + (i+1) r)``,
row 0 the lowest y (the ``GridMap`` convention). Two rules make a wall cell:

- *centre rule*: the cell's centre lies inside a wall polygon. A centre exactly on the boundary
  counts as inside (closed polygons), so a symmetric wall gives a symmetric band of cells.
- *thin rule*: every cell a *spine* passes through (supercover: all cells the segment touches,
  4-connected) is a wall too. Spines are the centre lines of strokes thinner than ``sqrt(2) r``
  and the outlines of the parts of filled shapes thinner than that, so a wall thinner than a cell
  still leaves an unbroken line. Walls at least ``sqrt(2) r`` thick need no spine: the centre rule
  already covers every cell their centre line passes through.

Polygons are filled by an even-odd scanline over their rings (one pass per block of rows, numpy
within the block), segments by listing their grid-line crossings; neither loops per cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

_EPS = 1e-7  # in cells: a centre this close to a boundary counts as on it (inside)
_ROW_BLOCK = 1024


@dataclass(frozen=True)
class Lattice:
    """A 2D axis-aligned lattice: ``x0, y0`` of cell (0, 0)'s lower-left corner, ``r`` metres."""

    x0: float
    y0: float
    r: float
    height: int  # rows
    width: int  # columns

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    @classmethod
    def covering(cls, bounds: tuple[float, float, float, float], r: float) -> Lattice:
        """The smallest lattice with corners on multiples of ``r`` that covers ``bounds``
        (minx, miny, maxx, maxy), so it lines up with the replay's voxel lattice."""
        minx, miny, maxx, maxy = bounds
        i0 = math.floor(minx / r + 1e-9)
        j0 = math.floor(miny / r + 1e-9)
        i1 = max(math.ceil(maxx / r - 1e-9), i0 + 1)
        j1 = max(math.ceil(maxy / r - 1e-9), j0 + 1)
        return cls(round(i0 * r, 12), round(j0 * r, 12), r, j1 - j0, i1 - i0)

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell-centre coordinates: x (W,) and y (H,)."""
        return (
            self.x0 + (np.arange(self.width) + 0.5) * self.r,
            self.y0 + (np.arange(self.height) + 0.5) * self.r,
        )


def _rings(geom) -> list[np.ndarray]:
    """All rings (exterior and holes) of a (multi)polygon as (N, 2) coordinate arrays."""
    import shapely

    out = []
    for poly in shapely.get_parts(geom):
        if poly.is_empty or poly.geom_type != "Polygon":
            continue
        out.append(np.asarray(poly.exterior.coords, dtype=np.float64))
        out.extend(np.asarray(h.coords, dtype=np.float64) for h in poly.interiors)
    return out


def polygon_mask(geom, lat: Lattice) -> np.ndarray:
    """Boolean (H, W): cells whose centre lies inside ``geom`` (a shapely (multi)polygon),
    boundary included."""
    mask = np.zeros(lat.shape, dtype=bool)
    rings = _rings(geom) if geom is not None else []
    if not rings:
        return mask
    # edges in cell units, relative to the lattice corner
    segs = []
    for ring in rings:
        u = (ring[:, 0] - lat.x0) / lat.r
        v = (ring[:, 1] - lat.y0) / lat.r
        segs.append(np.column_stack([u[:-1], v[:-1], u[1:], v[1:]]))
    e = np.concatenate(segs)
    e = e[e[:, 1] != e[:, 3]]  # horizontal edges never cross a scanline
    if len(e) == 0:
        return mask
    # the closed rule in y: a row is inside when it is inside just below or just above its centre
    for dv in (-_EPS, _EPS):
        _scanline(e, lat, dv, mask)
    return mask


def _scanline(e: np.ndarray, lat: Lattice, dv: float, mask: np.ndarray) -> None:
    H, W = lat.shape
    ua, va, ub, vb = e[:, 0], e[:, 1], e[:, 2], e[:, 3]
    vlo, vhi = np.minimum(va, vb), np.maximum(va, vb)
    # rows whose (shifted) centre c = i + 0.5 + dv satisfies vlo <= c < vhi
    r_lo = np.clip(np.ceil(vlo - 0.5 - dv), 0, H).astype(np.int64)
    r_hi = np.clip(np.ceil(vhi - 0.5 - dv), 0, H).astype(np.int64)
    keep = r_hi > r_lo
    ua, va, ub, vb, r_lo, r_hi = ua[keep], va[keep], ub[keep], vb[keep], r_lo[keep], r_hi[keep]
    slope = (ub - ua) / (vb - va)
    for b0 in range(0, H, _ROW_BLOCK):
        b1 = min(b0 + _ROW_BLOCK, H)
        lo = np.maximum(r_lo, b0)
        hi = np.minimum(r_hi, b1)
        sel = hi > lo
        if not sel.any():
            continue
        lo, hi = lo[sel], hi[sel]
        n = hi - lo
        idx = np.repeat(np.nonzero(sel)[0], n)
        rows = np.repeat(lo, n) + (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))
        xc = ua[idx] + (rows + 0.5 + dv - va[idx]) * slope[idx]
        order = np.lexsort((xc, rows))
        rows, xc = rows[order], xc[order]
        # even-odd: consecutive crossings of one row pair up (a valid polygon has an even count)
        x_in, x_out, row = xc[0::2], xc[1::2], rows[0::2]
        # cells with centre j + 0.5 in [x_in, x_out] (closed, with a tolerance)
        j_lo = np.clip(np.ceil(x_in - 0.5 - _EPS), 0, W).astype(np.int64)
        j_hi = np.clip(np.floor(x_out - 0.5 + _EPS) + 1, 0, W).astype(np.int64)
        ok = j_hi > j_lo
        row, j_lo, j_hi = row[ok] - b0, j_lo[ok], j_hi[ok]
        nb = b1 - b0
        diff = np.zeros(nb * (W + 1), dtype=np.int32)
        np.add.at(diff, row * (W + 1) + j_lo, 1)
        np.add.at(diff, row * (W + 1) + j_hi, -1)
        block = np.cumsum(diff.reshape(nb, W + 1), axis=1)[:, :W] > 0
        mask[b0:b1] |= block


def segments_mask(segs: np.ndarray, lat: Lattice) -> np.ndarray:
    """Boolean (H, W): every cell a segment passes through ((N, 4) x0, y0, x1, y1 in metres),
    4-connected (a segment through a cell corner marks a neighbour too)."""
    mask = np.zeros(lat.shape, dtype=bool)
    rows, cols = segment_cells(segs, lat)
    ok = (rows >= 0) & (rows < lat.height) & (cols >= 0) & (cols < lat.width)
    mask[rows[ok], cols[ok]] = True
    return mask


def segment_cells(segs: np.ndarray, lat: Lattice) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the cells the segments pass through (may repeat, may be off-lattice)."""
    segs = np.asarray(segs, dtype=np.float64).reshape(-1, 4)
    if len(segs) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # cell units, snapped so that a coordinate on a grid line is exactly on it
    u0 = np.round((segs[:, 0] - lat.x0) / lat.r, 9)
    v0 = np.round((segs[:, 1] - lat.y0) / lat.r, 9)
    u1 = np.round((segs[:, 2] - lat.x0) / lat.r, 9)
    v1 = np.round((segs[:, 3] - lat.y0) / lat.r, 9)
    du, dv = u1 - u0, v1 - v0
    # parameters t in (0, 1) where the segment crosses a vertical (u = k) or horizontal line
    ts = [np.zeros(len(segs)), np.ones(len(segs))]
    ids = [np.arange(len(segs)), np.arange(len(segs))]
    for a, d in ((u0, du), (v0, dv)):
        lo = np.floor(np.minimum(a, a + d)) + 1
        hi = np.ceil(np.maximum(a, a + d)) - 1
        n = np.maximum(hi - lo + 1, 0).astype(np.int64)
        n[d == 0] = 0
        if n.sum() == 0:
            continue
        sid = np.repeat(np.arange(len(segs)), n)
        k = np.repeat(lo, n) + (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))
        ts.append((k - a[sid]) / d[sid])
        ids.append(sid)
    t = np.concatenate(ts)
    sid = np.concatenate(ids)
    order = np.lexsort((t, sid))
    t, sid = t[order], sid[order]
    # cells: the midpoint of each interval between consecutive parameters of one segment
    same = sid[1:] == sid[:-1]
    tm = 0.5 * (t[1:] + t[:-1])[same]
    ms = sid[1:][same]
    cols = np.floor(u0[ms] + tm * du[ms]).astype(np.int64)
    rows = np.floor(v0[ms] + tm * dv[ms]).astype(np.int64)
    # 4-connect: where consecutive cells of one segment differ in both indices, add both corners
    cont = ms[1:] == ms[:-1]
    diag = cont & (cols[1:] != cols[:-1]) & (rows[1:] != rows[:-1])
    extra_r = np.concatenate([rows[:-1][diag], rows[1:][diag]])
    extra_c = np.concatenate([cols[1:][diag], cols[:-1][diag]])
    return np.concatenate([rows, extra_r]), np.concatenate([cols, extra_c])


def lines_to_segments(lines: list[np.ndarray]) -> np.ndarray:
    """Polylines ((N, 2) arrays) to an (M, 4) array of segments; a single point gives a
    zero-length segment (it still marks its cell)."""
    out = []
    for pts in lines:
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        if len(pts) == 1:
            out.append(np.concatenate([pts, pts], axis=1))
        elif len(pts) > 1:
            out.append(np.concatenate([pts[:-1], pts[1:]], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 4))


def thin_parts(geom, r: float):
    """The parts of a (multi)polygon thinner than ``sqrt(2) r`` (where the centre rule may
    leave gaps): the polygon minus its morphological opening. Slivers that are only rounding
    noise (area below 1e-4 of a cell) are dropped. Returns a geometry (maybe empty)."""
    import shapely

    if geom is None or geom.is_empty:
        return None
    h = r / math.sqrt(2.0)
    opened = geom.buffer(-h, join_style="mitre").buffer(h, join_style="mitre")
    rest = geom.difference(opened)
    parts = [p for p in shapely.get_parts(rest) if p.geom_type == "Polygon" and p.area > 1e-4 * r * r]
    if not parts:
        return None
    return shapely.union_all(parts)


def outline_lines(geom) -> list[np.ndarray]:
    """The rings of a (multi)polygon as polylines."""
    return _rings(geom) if geom is not None else []
