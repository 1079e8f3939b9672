"""Projective free space for depth images: each voxel of the camera's frustum visited once.

A dense depth frame's rays converge on the camera, so the DDA walks the voxels near it many
times (a 640x480 frame of a room seen along its length: 3.5 M steps for 250 k distinct voxels).
With ``map.sensor.depth_integration: projective`` a depth frame is integrated in two parts:

- near its returns, exactly as before: every ray (one per end voxel) is walked by the DDA over
  its last ``band`` + ``TAIL_OVERLAP_VOXELS`` only (``tail_masks``, with ``core.raycast``'s DDA),
  so the hits, and the misses of the voxels next to surfaces, are those of the exact traversal;
- farther in front of the returns, by projection: a voxel of the frustum whose centre projects
  onto a pixel with a return (or a clear ray cut at ``max_range``) and is nearer the camera than
  that pixel's range minus ``band``, or one of the pixels at the rim of its projection is, is a
  miss (``projective_blocks``, from ``depth_range_image``'s ranges and tiles), within the box
  of the voxels of the camera and the rays' ends, which holds every voxel a ray passes. The worker
  threads run it, leaving out the quiet O blocks and quarters (4 x 4 x 4 voxels all clamped
  free, no ST or LT) and the still voxels (one such voxel), where a miss changes nothing, as
  they read them from the map while the map thread works on earlier frames; the thread that
  owns the map fills in those that are not quiet or still by the time the frame's turn comes
  (``projective_refill``) and applies the blocks' masks in frame order
  (``core.raycast.apply_mask_updates``), the tails' misses set in them too (``tail_masks``).

It differs from the exact traversal only in free space farther than ``band`` from a return
(voxels a ray passes but whose centre and rim project onto nearer pixels, voxels beyond the
image's border that a border ray grazes, and voxels between the cast rays that no ray passes):
there it decides free versus unknown, not what is occupied near a surface.
"""
from __future__ import annotations

import numpy as np

from ..jit import helper, njit
from .grid import BLOCK, BLOCK_BITS, BLOCK_VOXELS, find_block, pack_block, unpack_block, voxel_offset
from .raycast import (
    QUARTER_KEEP,
    QUIET_ALL,
    RAY_CHUNK,
    RAY_HIT,
    RAY_SKIP,
    RS_CI,
    RS_CJ,
    RS_CK,
    RS_EI,
    RS_EJ,
    RS_EK,
    RS_LENGTH,
    RS_SI,
    RS_SJ,
    RS_SK,
    RS_TDX,
    RS_TDY,
    RS_TDZ,
    RS_TMX,
    RS_TMY,
    RS_TMZ,
    RS_WALK,
    ray_max_steps,
    ray_start_buffers,
    ray_starts,
    ray_state,
    ray_step,
)

# a block whose quiet quarters a worker skipped is listed as (its number in the box << SKIP_SHIFT)
# | those quarters (projective_blocks, projective_refill)
SKIP_SHIFT = 8
# the exact rays' tail reaches this many voxels beyond the band, so the two parts overlap
TAIL_OVERLAP_VOXELS = 2
PROJECTIVE_CHUNK_BLOCKS = 1 << 14  # blocks with misses listed per call of projective_blocks (1.2 MB)


@njit(cache=True, nogil=True)
def ends_box(origin, ends, inv_res):
    """[i0, j0, k0, i1, j1, k1]: the voxel keys' box (inclusive) of the origin and the rays'
    ends (one pass; numpy's ``min`` / ``max(axis=0)`` over the (N, 3) ends took about 1 ms a
    frame). The bounds in six scalars: kept in two arrays indexed by axis, the loop took 7 ns
    an end (0.17 to 0.23 ms a room or hall frame), about twice the time (0.08 to 0.10 ms)."""
    x0 = x1 = origin[0]
    y0 = y1 = origin[1]
    z0 = z1 = origin[2]
    for r in range(ends.shape[0]):
        x, y, z = ends[r, 0], ends[r, 1], ends[r, 2]
        x0, x1 = min(x0, x), max(x1, x)
        y0, y1 = min(y0, y), max(y1, y)
        z0, z1 = min(z0, z), max(z1, z)
    box = np.empty(6, dtype=np.int64)
    box[0], box[1], box[2] = np.floor(x0 * inv_res), np.floor(y0 * inv_res), np.floor(z0 * inv_res)
    box[3], box[4], box[5] = np.floor(x1 * inv_res), np.floor(y1 * inv_res), np.floor(z1 * inv_res)
    return box


TILE = 8  # pixels per side of the tiles whose min / max range bound whole blocks and voxel rims
# the rim of a voxel's projection: the 8 pixels at its centre +- RIM voxel sizes, projected. Inside
# the voxel's silhouette (a voxel seen face on spans +-0.5), so the rays they stand for pass
# through the voxel, not along a face it shares with a surface: at 0.5, a voxel just under a table
# top seen at a grazing 5 deg was cleared by the pixels seeing past the table's far edge in most
# frames (P's IoU against exact rays 0.986 on the room with a 1280x720 camera; 0.42: 0.996, and
# the other bench scenes 0.993-1.0 -> 0.995-1.0; docs/performance.md, session 17)
RIM = 0.42


@njit(cache=True, nogil=True, error_model="numpy")
def pixel_range_factors(h, w, fx, fy, cx, cy):
    """(h, w) float64: per pixel its ray's length per metre of depth, sqrt(1 + x^2 + y^2) with
    x = (u - cx) / fx, y = (v - cy) / fy, for ``depth_range_image``. It depends on the camera
    alone, so a map keeps it per calibration (``LayeredMap._range_factors``): computed for every
    frame, its square roots were 40 % of the range image (0.345 -> 0.215 ms a room frame)."""
    xx = np.empty(w, dtype=np.float64)
    for u in range(w):
        xr = (np.float64(u) - cx) / fx
        xx[u] = 1.0 + xr * xr
    fac = np.empty((h, w), dtype=np.float64)
    for v in range(h):
        yv = (np.float64(v) - cy) / fy
        yy = yv * yv
        for u in range(w):
            fac[v, u] = np.sqrt(xx[u] + yy)
    return fac


@njit(cache=True, nogil=True, error_model="numpy")
def depth_range_image(depth, unit_mm, fac, max_range, band):
    """(reach, tile minima, tile maxima, dilated tile maxima) of one depth image. ``reach``: per
    pixel the range (m, float32) from the camera to its return along the pixel's ray (its depth
    times ``fac``, ``pixel_range_factors``), cut at ``max_range`` (a return beyond it clears up
    to there), minus ``band``; -1 - band where the pixel is invalid (16UC1: 0; 32FC1: NaN, inf or
    <= 0). The tiles: the least and greatest range (not minus band) over each TILE x TILE tile
    and over 2 x 2 of those and so on (``LEVELS`` levels), and the greatest over the 3 x 3 tiles
    of 2 TILE pixels around each of those. The camera-frame arithmetic of ``depth_image_rays``."""
    h, w = depth.shape
    out = np.empty((h, w), dtype=np.float32)
    th, tw = (h + TILE - 1) // TILE, (w + TILE - 1) // TILE
    tmin = np.full((th, tw), np.inf, dtype=np.float32)
    tmax = np.full((th, tw), -np.inf, dtype=np.float32)
    mm = np.float32(0.001)
    cut = max_range if max_range > 0.0 else np.inf
    row = np.empty(tw * TILE, dtype=np.float32)  # the row's ranges, its last tile padded with its last pixel
    fb = np.float32(band)
    for v in range(h):
        orow = out[v]
        frow = fac[v]
        for u in range(w):  # no branches: vectorized
            raw = depth[v, u]
            if unit_mm:
                z = np.float64(np.float32(raw) * mm)
                valid = raw != 0
            else:
                z = np.float64(np.float32(raw))
                valid = np.isfinite(z) & (z > 0)
            r = min(z * frow[u], cut)
            x = np.float32(r) if valid else np.float32(-1.0)
            row[u] = x
            orow[u] = x - fb
        for u in range(w, tw * TILE):
            row[u] = row[w - 1]
        tr = v // TILE
        for t in range(tw):  # each tile's 8 pixels of the row at once (was a pixel at a time: 2.6x slower)
            a = row[t * TILE]
            b = a
            for q in range(1, TILE):
                x = row[t * TILE + q]
                a = min(a, x)
                b = max(b, x)
            tmin[tr, t] = min(tmin[tr, t], a)
            tmax[tr, t] = max(tmax[tr, t], b)
    # (the flag through np.int64, not a literal bool: numba compiled each of _pyramid and
    # _tiles_query twice, once per literal, 2 s of a first run's compiling)
    pmax = _pyramid(tmax, np.int64(1))
    nh, nw = (th + 1) >> 1, (tw + 1) >> 1
    dil = np.empty((nh, nw), dtype=np.float32)  # the greatest range over the 3 x 3 level-1 tiles around
    for a in range(nh):
        for b in range(nw):
            m = np.float32(-1.0)
            for da in range(max(a - 1, 0), min(a + 2, nh)):
                for db in range(max(b - 1, 0), min(b + 2, nw)):
                    m = max(m, pmax[1, da, db])
            dil[a, b] = m
    return out, _pyramid(tmin, np.int64(0)), pmax, dil


LEVELS = 6  # tile pyramid levels: tiles of TILE, 2 TILE, ... 32 TILE pixels


@njit(cache=True, nogil=True)
def _pyramid(t0, use_max):
    """(LEVELS, th, tw): level 0 the tiles ``t0``, level l the max (``use_max`` != 0; else the
    min) over 2 x 2 tiles of level l - 1 (in its top-left (th >> l) x (tw >> l) corner, rounded up)."""
    th, tw = t0.shape
    pyr = np.empty((LEVELS, th, tw), dtype=np.float32)
    for a in range(th):  # (element by element: an array assigned to a slice makes numba compile its
        for b in range(tw):  # shape-mismatch message, string formatting, seconds of a first run's compiling)
            pyr[0, a, b] = t0[a, b]
    ph, pw = th, tw
    for lv in range(1, LEVELS):
        nh, nw = (ph + 1) // 2, (pw + 1) // 2
        for a in range(nh):
            for b in range(nw):
                m = pyr[lv - 1, 2 * a, 2 * b]
                for da in range(2):
                    for db in range(2):
                        if 2 * a + da < ph and 2 * b + db < pw:
                            x = pyr[lv - 1, 2 * a + da, 2 * b + db]
                            m = max(m, x) if use_max else min(m, x)
                pyr[lv, a, b] = m
        ph, pw = nh, nw
    return pyr


@helper()
def _tiles_query(pyr, u0, u1, v0, v1, use_max):
    """The greatest (``use_max`` != 0; else the least) range over pixels [u0, u1] x [v0, v1]
    (clipped to the image), bounded from the pyramid: over at most 9 x 9 tiles of the finest level
    whose tiles cover the rectangle in 8 of them per axis (the tiles may reach beyond it: a looser,
    safe bound; 8 rather than 2 culls a tenth more of the room's quarters for the reads)."""
    _, th, tw = pyr.shape
    t0, t1 = max(np.int64(u0) // TILE, 0), min(np.int64(u1) // TILE, tw - 1)
    s0, s1 = max(np.int64(v0) // TILE, 0), min(np.int64(v1) // TILE, th - 1)
    lv = 0
    while lv < LEVELS - 1 and (t1 - t0 >= 8 or s1 - s0 >= 8):
        lv += 1
        t0, t1, s0, s1 = t0 >> 1, t1 >> 1, s0 >> 1, s1 >> 1
    m = np.float32(-1.0) if use_max else np.float32(np.inf)
    for a in range(s0, s1 + 1):
        for b in range(t0, t1 + 1):
            x = pyr[lv, a, b]
            m = max(m, x) if use_max else min(m, x)
    return np.float64(m)


CULLED, FRONT, MIXED = 0, 1, 2


@helper(error_model="numpy")
def _classify(qx, qy, qz, nvox, ex0, ex1, ex2, ey0, ey1, ey2, ez0, ez1, ez2, res, band, far, fx, fy, cx, cy, w, h,
              planes, tmin, tmax):  # fmt: skip
    """(class, lo, hi) of a cube of ``nvox`` voxels a side centred at (qx, qy, qz) (optical
    frame). Class: CULLED when no voxel of it can be a miss (outside the frustum's side planes,
    behind the camera, beyond every range, or farther than every range its voxels and their rims
    project onto), FRONT when every voxel is (nearer than every range its voxels' centres project
    onto, minus band), else MIXED. For a MIXED cube, bounds on its voxels' tests: a voxel whose
    centre is nearer than ``lo`` (> 0) is a miss (the reach of every pixel its centre can project
    onto is beyond it), one at ``hi`` or beyond is not (no pixel its centre or rim can project
    onto reaches beyond it); lo and hi are the least and greatest reach exactly, in
    ``depth_range_image``'s float32 arithmetic."""
    al, ar, at, ab, nl, nr, nt, nb = planes[0], planes[1], planes[2], planes[3], planes[4], planes[5], planes[6], planes[7]
    half = 0.5 * nvox * res
    rad = half * np.sqrt(3.0)  # the cube's bounding sphere (the side planes: the rims reach past the centres)
    # the bounding sphere of its voxels' centres, a cube of nvox - 1 voxel steps: a voxel's test
    # takes its centre's distance and the pixels under its centre and rim (9.5 % less projection
    # time than the whole cube's on room, hall and office frames: fewer quarters tested by voxel)
    radc = 0.5 * (nvox - 1) * res * np.sqrt(3.0)
    if qz < -rad:
        return CULLED, 0.0, 0.0
    if (qx - al * qz) * nl < -rad or (ar * qz - qx) * nr < -rad:
        return CULLED, 0.0, 0.0
    if (qy - at * qz) * nt < -rad or (ab * qz - qy) * nb < -rad:
        return CULLED, 0.0, 0.0
    dist = np.sqrt(qx * qx + qy * qy + qz * qz)
    if dist - radc >= far:
        return CULLED, 0.0, 0.0
    zn = qz - radc  # the least z of a centre
    if zn <= 0.05 * res:  # reaches the camera's plane: test its voxels
        return MIXED, -1.0, np.inf
    k = 0.5 * (nvox - 1)  # the centres' cube's corners, in voxel steps: its centres project inside theirs
    u0, u1, v0, v1 = np.inf, -np.inf, np.inf, -np.inf
    for cnr in range(8):
        sx = k if cnr & 1 else -k
        sy = k if cnr & 2 else -k
        sz = k if cnr & 4 else -k
        xx = qx + ex0 * sx + ey0 * sy + ez0 * sz
        yy = qy + ex1 * sx + ey1 * sy + ez1 * sz
        zz = max(qz + ex2 * sx + ey2 * sy + ez2 * sz, zn)
        uu, vv = fx * xx / zz + cx, fy * yy / zz + cy
        u0, u1, v0, v1 = min(u0, uu), max(u1, uu), min(v0, vv), max(v1, vv)
    inside = u0 >= 0.0 and u1 < w - 1.0 and v0 >= 0.0 and v1 < h - 1.0
    # lo and hi: the least and greatest reach of the pixels in the tiles, as depth_range_image
    # computes reach (float32 range - float32 band: monotonic, so exactly the extremes)
    fb = np.float32(band)
    lo = -1.0
    if inside:
        rmin = _tiles_query(tmin, u0, u1 + 1.0, v0, v1 + 1.0, np.int64(0))
        lo = np.float64(np.float32(rmin) - fb)
        if lo > dist + radc:
            return FRONT, -1.0, np.inf
    rim = RIM * res * max(fx, fy) / zn + 1.0
    rmax = _tiles_query(tmax, u0 - rim, u1 + rim + 1.0, v0 - rim, v1 + rim + 1.0, np.int64(1))
    hi = np.float64(np.float32(rmax) - fb)
    if hi <= dist - radc:
        return CULLED, 0.0, 0.0
    return MIXED, lo, hi


@njit(cache=True, nogil=True, error_model="numpy")
def _frame_setup(tmax, fx, fy, cx, cy, w, h, Tinv, res, band):
    """The frame's constants for ``_block_class`` / ``_block_fill``: (far: the greatest reach,
    <= 0 when nothing is seen; the frustum's side planes; a voxel step along x, y, z in the
    optical frame, 9 numbers)."""
    rmax = -1.0
    for a in range(tmax.shape[1]):
        for b in range(tmax.shape[2]):
            rmax = max(rmax, np.float64(tmax[0, a, b]))
    far = np.float64(np.float32(rmax) - np.float32(band))  # (depth_range_image's reach: exactly the greatest)
    # the frustum's side planes through the camera centre (pixel edges -0.5 and w - 0.5), unit normals
    planes = np.empty(8)
    planes[0], planes[1] = (-0.5 - cx) / fx, (w - 0.5 - cx) / fx
    planes[2], planes[3] = (-0.5 - cy) / fy, (h - 0.5 - cy) / fy
    for t in range(4):
        planes[4 + t] = 1.0 / np.sqrt(1.0 + planes[t] * planes[t])
    e = np.empty(9)
    for c in range(3):  # e[3 c + r]: a voxel step along axis c, row r of the optical frame
        for r in range(3):
            e[3 * c + r] = Tinv[r, c] * res
    return far, planes, e


@helper(error_model="numpy")
def _cube_class(bi, bj, bk, nvox, tmin, tmax, fx, fy, cx, cy, w, h, Tinv, res, band, far, planes, e):
    """(class, px0, py0, pz0) of the cube of ``nvox`` voxels a side from block (bi, bj, bk)'s
    voxel (0, 0, 0): ``_classify``'s class of it, and the centre of that voxel in the optical
    frame. A block (``nvox`` BLOCK, as an np.int64: a literal made numba compile ``_classify`` a
    second time, beside ``_block_fill``'s quarters), or 2 x 2 x 2 of them from an even block
    (2 BLOCK): a cube that holds no miss holds none in any of its blocks (each of the tests
    bounds its blocks' too), so ``projective_blocks`` culls a frame box's blocks outside the
    frustum eight at a time (a depot seen to the depth range from a 90 deg camera: 3,500 of its
    box's 6,800 blocks, 0.8 ms of classes a frame)."""
    cx0 = (bi * BLOCK + 0.5) * res
    cy0 = (bj * BLOCK + 0.5) * res
    cz0 = (bk * BLOCK + 0.5) * res
    px0 = Tinv[0, 0] * cx0 + Tinv[0, 1] * cy0 + Tinv[0, 2] * cz0 + Tinv[0, 3]
    py0 = Tinv[1, 0] * cx0 + Tinv[1, 1] * cy0 + Tinv[1, 2] * cz0 + Tinv[1, 3]
    pz0 = Tinv[2, 0] * cx0 + Tinv[2, 1] * cy0 + Tinv[2, 2] * cz0 + Tinv[2, 3]
    ex0, ex1, ex2, ey0, ey1, ey2, ez0, ez1, ez2 = e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7], e[8]
    g = 0.5 * (nvox - 1)  # the cube's centre, in voxel steps from voxel (0, 0, 0)
    cls, _, _ = _classify(px0 + (ex0 + ey0 + ez0) * g, py0 + (ex1 + ey1 + ez1) * g, pz0 + (ex2 + ey2 + ez2) * g,
                          nvox, ex0, ex1, ex2, ey0, ey1, ey2, ez0, ez1, ez2, res, band, far, fx, fy, cx, cy, w, h,
                          planes, tmin, tmax)  # fmt: skip
    return cls, px0, py0, pz0


@helper(error_model="numpy")
def _block_class(bi, bj, bk, tmin, tmax, fx, fy, cx, cy, w, h, Tinv, res, band, far, planes, e):
    """``_cube_class`` of block (bi, bj, bk)."""
    return _cube_class(bi, bj, bk, np.int64(BLOCK), tmin, tmax, fx, fy, cx, cy, w, h, Tinv, res, band, far, planes, e)


@helper()
def _box_outside(bi, bj, bk, box, out):
    """The voxels of block (bi, bj, bk) outside the frame's voxel box ``box`` ([i0, j0, k0, i1,
    j1, k1], inclusive) as ``_block_fill``'s mask bits into ``out`` (8,); True when it has any.
    No ray of the frame passes them (a segment's voxels lie in the box of its ends' voxels), so
    the projection makes none of them misses: the box's blocks reach up to 7 voxels beyond it (a
    floor's block below it, a wall's behind it), and their voxels were tested for nothing."""
    i0, i1 = max(box[0] - bi * BLOCK, 0), min(box[3] - bi * BLOCK, BLOCK - 1)
    j0, j1 = max(box[1] - bj * BLOCK, 0), min(box[4] - bj * BLOCK, BLOCK - 1)
    k0, k1 = max(box[2] - bk * BLOCK, 0), min(box[5] - bk * BLOCK, BLOCK - 1)
    if i0 == 0 and j0 == 0 and k0 == 0 and i1 == BLOCK - 1 and j1 == BLOCK - 1 and k1 == BLOCK - 1:
        for t in range(8):
            out[t] = 0
        return False
    zrow = np.uint64(((1 << (k1 - k0 + 1)) - 1) << k0)
    inside = np.uint64(0)
    for c in range(j0, j1 + 1):
        inside |= zrow << np.uint64(c * BLOCK)
    for t in range(8):
        out[t] = ~inside if i0 <= t <= i1 else ~np.uint64(0)
    return True


@njit(cache=True, nogil=True)
def _fill_scratch():
    """``_block_fill``'s per-voxel rows for a quarter's 64 voxels, allocated once per call of the
    block loop: (4, 64) float64 (squared distance, u, v, 1 / z) and (2, 64) int64 (pixel index,
    the test's outcome)."""
    return np.empty((4, 64)), np.empty((2, 64), dtype=np.int64)


@helper(error_model="numpy")
def _block_fill(cls, px0, py0, pz0, reach, tmin, tmax, dil, fx, fy, cx, cy, w, h, res, band, far, planes, e, mask,
                fs, ks, qskip, still):  # fmt: skip
    """The miss bits of a FRONT or MIXED block into ``mask`` (8,), but for its quarters in
    ``qskip`` (a bit each, ``core.raycast.quarter_of``'s numbering: quiet ones) and its voxels
    in ``still`` (8 words, ``mask``'s bits: still ones, not tested); True when it has any.
    ``fs``, ``ks``: ``_fill_scratch``."""
    ex0, ex1, ex2, ey0, ey1, ey2, ez0, ez1, ez2 = e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7], e[8]
    full = ~np.uint64(0)
    Q = BLOCK // 2
    vd2, vu, vv, viz = fs[0], fs[1], fs[2], fs[3]
    vpix, vcode = ks[0], ks[1]
    flat = reach.reshape(-1)
    if cls == FRONT:  # every voxel's centre is nearer than its pixel's range - band
        anyb = np.uint64(0)
        for t in range(8):  # (word t: voxels x = t; its quarters' bits are those of x half t >> 2)
            mask[t] = full & QUARTER_KEEP[(qskip >> ((t >> 2) << 2)) & 15] & ~still[t]
            anyb |= mask[t]
        return anyb != 0
    for t in range(8):
        mask[t] = 0
    found = False
    for sub in range(8):  # the block's quarters (4 x 4 x 4)
        if (qskip >> sub) & 1:
            continue
        sa, sc, se = (sub >> 2) * Q, ((sub >> 1) & 1) * Q, (sub & 1) * Q
        g2 = 0.5 * (Q - 1)
        qcls, qlo, qhi = _classify(px0 + ex0 * (sa + g2) + ey0 * (sc + g2) + ez0 * (se + g2),
                                   py0 + ex1 * (sa + g2) + ey1 * (sc + g2) + ez1 * (se + g2),
                                   pz0 + ex2 * (sa + g2) + ey2 * (sc + g2) + ez2 * (se + g2), Q,
                                   ex0, ex1, ex2, ey0, ey1, ey2, ez0, ez1, ez2, res, band, far, fx, fy, cx, cy, w,
                                   h, planes, tmin, tmax)  # fmt: skip
        if qcls == CULLED:
            continue
        if qcls == FRONT:  # all its 64 voxels: word a of the mask holds voxels (a, c, e) as bits c * 8 + e
            pat = np.uint64(0)
            for c in range(sc, sc + Q):
                pat |= np.uint64((1 << Q) - 1) << np.uint64(c * BLOCK + se)
            for a in range(sa, sa + Q):
                mask[a] |= pat & ~still[a]
                found |= (pat & ~still[a]) != 0
            continue
        # its still voxels, bit t as t below counts them (x, y, z 2 bits each): skipped whole
        # when all are, else left out of the tests (a room frame's voxel tests 0.74x)
        sq = np.uint64(0)
        for a in range(Q):
            for c in range(Q):
                sq |= ((still[sa + a] >> np.uint64((sc + c) * BLOCK + se)) & np.uint64(15)) << np.uint64(a * 16 + c * 4)
        if sq == full:
            continue
        qlo2 = qlo * qlo if qlo > 0.0 else -1.0  # (a miss needs reach > 0)
        qhi2 = qhi * qhi if qhi > 0.0 else -1.0
        # pass 1, no branches (vectorized): each voxel's centre, its pixel and that pixel's test
        for t in range(64):
            a, c, ee = sa + (t >> 4), sc + ((t >> 2) & 3), se + (t & 3)
            x = px0 + a * ex0 + c * ey0 + ee * ez0  # the voxel's centre in the optical frame
            y = py0 + a * ex1 + c * ey1 + ee * ez1
            z = pz0 + a * ex2 + c * ey2 + ee * ez2
            d2 = x * x + y * y + z * z
            iz = 1.0 / z
            uf = fx * x * iz + cx + 0.5
            vf = fy * y * iz + cy + 0.5
            inside = (uf >= 0.0) & (uf < w) & (vf >= 0.0) & (vf < h)
            vd2[t] = d2
            vu[t] = uf
            vv[t] = vf
            viz[t] = iz
            vpix[t] = (np.int64(np.int32(vf)) * w + np.int32(uf)) if inside else -1  # (through int32: see depth_image_rays)
            sb = (sq >> np.uint64(t)) & np.uint64(1)
            vcode[t] = 0 if (z <= 0.0) | (d2 >= qhi2) | (sb != 0) else (1 if d2 < qlo2 else 2)
        for t in range(64):
            code = vcode[t]
            if code == 0:
                continue
            d2 = vd2[t]
            free = code == 1
            if not free:  # its pixel
                uf, vf, iz = vu[t], vv[t], viz[t]
                su, sv = RIM * res * fx * iz, RIM * res * fy * iz
                rim = True  # test the pixels at the rim of its projection
                pix = vpix[t]
                if pix >= 0:
                    ui, vi = np.int64(uf), np.int64(vf)
                    r = np.float64(flat[pix])
                    free = r > 0.0 and r * r > d2
                    if not free and su < TILE and sv < TILE:  # any range far enough in the tiles
                        # of the rim's pixels? A span under 2 TILE a side: 2 x 2 tiles of level 0,
                        # or of level 1 when it crosses 3 of level 0 (the corners alone left out
                        # the middle ones: a voxel seen past a far patch above it was no miss)
                        t0 = max(np.int64(uf - su), 0) // TILE
                        t1 = min(np.int64(uf + su), w - 1) // TILE
                        s0 = max(np.int64(vf - sv), 0) // TILE
                        s1 = min(np.int64(vf + sv), h - 1) // TILE
                        lv = np.int64((t1 - t0 > 1) | (s1 - s0 > 1))
                        t0, t1, s0, s1 = t0 >> lv, t1 >> lv, s0 >> lv, s1 >> lv
                        r = max(max(tmax[lv, s0, t0], tmax[lv, s0, t1]), max(tmax[lv, s1, t0], tmax[lv, s1, t1]))
                        r = np.float64(r) - band
                        rim = r > 0.0 and r * r > d2
                    elif not free and su < 2 * TILE and sv < 2 * TILE:  # within the 3 x 3 tiles around
                        r = np.float64(dil[(vi // TILE) >> 1, (ui // TILE) >> 1]) - band
                        rim = r > 0.0 and r * r > d2
                else:  # outside the image: its rim too, unless within RIM voxels of it
                    rim = uf >= -su and uf < w + su and vf >= -sv and vf < h + sv
                if not free and rim:  # partly seen past an occluding edge? The 8 pixels at
                    # centre +- (su, sv) and +- su, +- sv alone: their columns and rows once (-1:
                    # outside the image), then each pixel's reach
                    ua, ub, va, vb = uf - su, uf + su, vf - sv, vf + sv
                    c0 = np.int64(ua) if ua >= 0.0 and ua < w else -1
                    c1 = np.int64(uf) if uf >= 0.0 and uf < w else -1
                    c2 = np.int64(ub) if ub >= 0.0 and ub < w else -1
                    for rr in range(3):
                        vg = va if rr == 0 else (vf if rr == 1 else vb)
                        if not (vg >= 0.0 and vg < h):
                            continue
                        base = np.int64(vg) * w
                        for cc in range(3):
                            if rr == 1 and cc == 1:  # (the centre: tested above)
                                continue
                            col = c0 if cc == 0 else (c1 if cc == 1 else c2)
                            if col < 0:
                                continue
                            r = np.float64(flat[base + col])
                            if r > 0.0 and r * r > d2:
                                free = True
                                break
                        if free:
                            break
            if free:
                found = True
                off = ((sa + (t >> 4)) << (2 * BLOCK_BITS)) | ((sc + ((t >> 2) & 3)) << BLOCK_BITS) | (se + (t & 3))
                mask[off >> 6] |= np.uint64(1) << np.uint64(off & 63)
    return found


@njit(cache=True, nogil=True, error_model="numpy")
def projective_blocks(reach, tmin, tmax, dil, fx, fy, cx, cy, Tinv, box, res, band, keys, masks, start,
                      o_keys, o_vals, qquiet, still, skipped, skipped_still, n_skipped):  # fmt: skip
    """The voxels of the frame's box (voxel keys ``box`` = [i0, j0, k0, i1, j1, k1], inclusive;
    its blocks' voxels beyond it are left out: ``_box_outside``) that the projection makes
    misses, block by block: the block's packed coordinates
    (``grid.pack_block``) into ``keys`` and its voxels' bits (``grid.voxel_offset`` order) into
    ``masks`` (n, 8), from block number ``start`` of the box (x, y, z order); returns (n, the
    blocks skipped so far, the block to go on from when ``keys`` or ``skipped`` is full, -1 when
    done). A worker thread's part.

    ``reach``, ``tmin``, ``tmax``, ``dil``: ``depth_range_image``; ``Tinv`` (3, 4): fixed frame ->
    optical frame. A voxel is a miss when its centre (z > 0 in the optical frame) is nearer than
    r - band for the range r of the pixel it projects onto (round(u), round(v)), or of one of the 8
    pixels at the rim of its projection (centre +- RIM voxel sizes, projected: a voxel partly
    seen past an occluding edge, which rays passing its corner would clear). Blocks, then their
    4 x 4 x 4 quarters, that surely hold no miss are skipped and those that surely are all misses
    are taken whole (``_classify``), without testing their voxels.

    Where a miss changes nothing it is not made: ``o_keys``, ``o_vals`` (O's hash table),
    ``qquiet`` and ``still`` (``layers._QuietBlocks``: an O block's quiet quarters and still
    voxels) are the map thread's, read as they are while it works on earlier frames (empty: none
    read). A block's quiet quarters are not filled (a block all quiet not at all) nor are its
    still voxels tested; its number in the box and those quarters (``SKIP_SHIFT``) go to
    ``skipped`` with the O block read (``skipped[t, 1]``) and the still bits read to
    ``skipped_still`` (from ``n_skipped`` on), for the map thread to fill in those that are
    quiet or still no more when the frame's turn comes (``projective_refill``). So what was
    read, however old, changes only the work, not the map."""
    h, w = reach.shape
    bi0, bj0, bk0 = box[0] >> BLOCK_BITS, box[1] >> BLOCK_BITS, box[2] >> BLOCK_BITS
    bi1, bj1, bk1 = box[3] >> BLOCK_BITS, box[4] >> BLOCK_BITS, box[5] >> BLOCK_BITS
    nbj, nbk = bj1 - bj0 + 1, bk1 - bk0 + 1
    nblocks = (bi1 - bi0 + 1) * nbj * nbk
    far, planes, e = _frame_setup(tmax, fx, fy, cx, cy, w, h, Tinv, res, band)
    if far <= 0.0:
        return 0, n_skipped, -1
    fs, ks = _fill_scratch()
    n = 0
    cap = keys.shape[0]
    # (the map thread may swap O's table for a larger one between reading keys and values: a
    # block is looked up only in a table whose halves match, and its index used only below both
    # arrays' sizes)
    lookup = o_keys.shape[0] > 0 and o_keys.shape[0] == o_vals.shape[0]
    n_known = min(qquiet.shape[0], still.shape[0])
    words = np.zeros(8, dtype=np.uint64)
    outside = np.zeros(8, dtype=np.uint64)
    # the pairs of blocks along each axis (_cube_class of 2 BLOCK): 0 not known yet, 1 culled, 2 not
    si0, sj0, sk0 = bi0 >> 1, bj0 >> 1, bk0 >> 1
    nsj, nsk = (bj1 >> 1) - sj0 + 1, (bk1 >> 1) - sk0 + 1
    pairs = np.zeros(((bi1 >> 1) - si0 + 1) * nsj * nsk, dtype=np.int8)
    for b in range(start, nblocks):
        if n == cap or n_skipped == skipped.shape[0]:
            return n, n_skipped, b
        bi = bi0 + b // (nbj * nbk)
        bj = bj0 + (b // nbk) % nbj
        bk = bk0 + b % nbk
        s = (((bi >> 1) - si0) * nsj + ((bj >> 1) - sj0)) * nsk + ((bk >> 1) - sk0)
        if pairs[s] == 0:
            pcls, _, _, _ = _cube_class(bi >> 1 << 1, bj >> 1 << 1, bk >> 1 << 1, np.int64(2 * BLOCK), tmin, tmax, fx, fy,
                                        cx, cy, w, h, Tinv, res, band, far, planes, e)  # fmt: skip
            pairs[s] = 1 if pcls == CULLED else 2
        if pairs[s] == 1:
            continue
        cls, px0, py0, pz0 = _block_class(bi, bj, bk, tmin, tmax, fx, fy, cx, cy, w, h, Tinv, res, band, far,
                                          planes, e)  # fmt: skip
        if cls == CULLED:
            continue
        qskip = np.int64(0)
        anyw = np.uint64(0)
        for t in range(8):
            words[t] = 0
        ob = find_block(o_keys, o_vals, bi, bj, bk) if lookup else -1
        if 0 <= ob < n_known:
            qskip = np.int64(qquiet[ob])
            for t in range(8):
                words[t] = still[ob, t]
                anyw |= words[t]
            if qskip != 0 or anyw != 0:
                skipped[n_skipped, 0] = (b << SKIP_SHIFT) | qskip
                skipped[n_skipped, 1] = ob
                for t in range(8):
                    skipped_still[n_skipped, t] = words[t]
                n_skipped += 1
                if qskip == QUIET_ALL:
                    continue
        keys[n] = pack_block(bi, bj, bk)
        if _box_outside(bi, bj, bk, box, outside):  # (left out as still voxels are, not recorded as such)
            for t in range(8):
                words[t] |= outside[t]
        if _block_fill(cls, px0, py0, pz0, reach, tmin, tmax, dil, fx, fy, cx, cy, w, h, res, band, far, planes,
                       e, masks[n], fs, ks, qskip, words):  # fmt: skip
            n += 1
    return n, n_skipped, -1


@njit(cache=True, nogil=True, error_model="numpy")
def projective_refill(reach, tmin, tmax, dil, fx, fy, cx, cy, Tinv, box, res, band, skipped, skipped_still, o_coords,
                      n_blocks, qquiet, still, keys, masks):  # fmt: skip
    """The projection's ``keys``, ``masks`` (``projective_blocks``) with the voxels its worker
    left out that are not quiet or still now filled in: of each block in ``skipped`` /
    ``skipped_still`` (its quarters left as quiet, its voxels left as still), the voxels neither
    in a quiet quarter (``qquiet``) nor still (``still``) by O's state now are tested as
    ``projective_blocks`` tests them, and their misses set in the block's row (in place when
    the blocks had rows, else in new arrays with rows made in key order). The worker's O block
    is the block when ``o_coords`` (O's block coordinates, ``n_blocks`` of them) say so (a map
    loaded since: not; no hash lookup). Returns (keys, masks, the blocks that had such voxels).
    Reads the map: the thread that owns it, before the frame's updates."""
    h, w = reach.shape
    bi0, bj0, bk0 = box[0] >> BLOCK_BITS, box[1] >> BLOCK_BITS, box[2] >> BLOCK_BITS
    nbj, nbk = (box[4] >> BLOCK_BITS) - bj0 + 1, (box[5] >> BLOCK_BITS) - bk0 + 1
    m = skipped.shape[0]
    add_keys = np.empty(m, dtype=np.int64)
    add_masks = np.empty((m, 8), dtype=np.uint64)
    n_add = 0
    n_stale = 0
    far, planes, e = _frame_setup(tmax, fx, fy, cx, cy, w, h, Tinv, res, band)
    fs, ks = _fill_scratch()
    keep = np.empty(8, dtype=np.uint64)  # the voxels not to test: all but those to fill in
    out = np.empty(8, dtype=np.uint64)
    outside = np.empty(8, dtype=np.uint64)
    for t in range(m):
        b, qs, ob = skipped[t, 0] >> SKIP_SHIFT, skipped[t, 0] & QUIET_ALL, skipped[t, 1]
        bi, bj, bk = bi0 + b // (nbj * nbk), bj0 + (b // nbk) % nbj, bk0 + b % nbk
        if not (0 <= ob < n_blocks and o_coords[ob, 0] == bi and o_coords[ob, 1] == bj and o_coords[ob, 2] == bk):
            ob = -1
        qq = np.int64(qquiet[ob]) if ob >= 0 else np.int64(0)
        _box_outside(bi, bj, bk, box, outside)
        anyb = np.uint64(0)
        for wd in range(8):
            sh = (wd >> 2) << 2
            left = ~QUARTER_KEEP[(qs >> sh) & 15] | skipped_still[t, wd]  # what the worker left out
            fine = ~QUARTER_KEEP[(qq >> sh) & 15] | (still[ob, wd] if ob >= 0 else np.uint64(0))  # may be now
            keep[wd] = ~(left & ~fine) | outside[wd]
            anyb |= ~keep[wd]
        if anyb == 0:
            continue
        n_stale += 1
        cls, px0, py0, pz0 = _block_class(bi, bj, bk, tmin, tmax, fx, fy, cx, cy, w, h, Tinv, res, band, far,
                                          planes, e)  # fmt: skip
        if cls == CULLED or far <= 0.0:
            continue
        if _block_fill(cls, px0, py0, pz0, reach, tmin, tmax, dil, fx, fy, cx, cy, w, h, res, band, far, planes,
                       e, out, fs, ks, np.int64(0), keep):  # fmt: skip
            add_keys[n_add] = pack_block(bi, bj, bk)
            for wd in range(8):
                add_masks[n_add, wd] = out[wd]
            n_add += 1
    if n_add == 0:
        return keys, masks, n_stale
    n = keys.shape[0]
    rows = np.empty(n_add, dtype=np.int64)  # each block's row, by bisection (-1: none)
    missing = 0
    for j in range(n_add):
        lo, hi = 0, n
        while lo < hi:
            mid = (lo + hi) >> 1
            if keys[mid] < add_keys[j]:
                lo = mid + 1
            else:
                hi = mid
        rows[j] = lo if lo < n and keys[lo] == add_keys[j] else -1
        missing += rows[j] < 0
    if missing == 0:
        for j in range(n_add):
            for wd in range(8):
                masks[rows[j], wd] |= add_masks[j, wd]
        return keys, masks, n_stale
    # merged into the rows, in key order (the blocks came in the box's order: pack_block's)
    new_keys = np.empty(n + n_add, dtype=np.int64)
    new_masks = np.empty((n + n_add, 8), dtype=np.uint64)
    i, j, r = 0, 0, 0
    while i < n or j < n_add:
        if j == n_add or (i < n and keys[i] < add_keys[j]):
            new_keys[r] = keys[i]
            for wd in range(8):
                new_masks[r, wd] = masks[i, wd]
            i += 1
        elif i == n or add_keys[j] < keys[i]:
            new_keys[r] = add_keys[j]
            for wd in range(8):
                new_masks[r, wd] = add_masks[j, wd]
            j += 1
        else:
            new_keys[r] = keys[i]
            for wd in range(8):
                new_masks[r, wd] = masks[i, wd] | add_masks[j, wd]
            i += 1
            j += 1
        r += 1
    return new_keys[:r], new_masks[:r], n_stale


@njit(cache=True, nogil=True, error_model="numpy")
def depth_projection_blocks(depth, unit_mm, fac, fx, fy, cx, cy, origin, Tinv, max_range, band, ends, res, chunk,
                            o_keys, o_vals, qquiet, still):  # fmt: skip
    """``depth_range_image``, the frame's box (``ends_box``) and ``projective_blocks`` in one call
    (a worker thread then takes the GIL once for them instead of three times, with numpy in
    between): (keys, masks, n, skipped, skipped_still, ns, nxt, reach, tmin, tmax, dil, box):
    ``n`` blocks with misses in ``keys``, ``masks``, ``ns`` blocks with quarters skipped as quiet
    or voxels as still (``o_keys``, ``o_vals``, ``qquiet``, ``still``: ``projective_blocks``) in
    ``skipped``, ``skipped_still``, and the range image, tiles and box (``projective_refill`` needs
    them). ``fac``: the camera's ``pixel_range_factors``. The arrays hold ``chunk`` blocks (memory
    follows the frustum's free space, not the box: a box at 0.01 m holds millions of blocks); when
    they are full, ``nxt`` >= 0 is the block to go
    on from with ``projective_blocks`` in larger arrays (``LayeredMap.depth_projection``; in
    Python: the growth loop here cost a first run about 1.5 s of compiling). ``origin``: the
    camera's position; ``Tinv`` (3, 4): fixed frame -> optical frame."""
    reach, tmin, tmax, dil = depth_range_image(depth, unit_mm, fac, max_range, band)
    box = ends_box(origin, ends, 1.0 / res)
    nb = np.int64(1)
    for a in range(3):
        nb *= (box[3 + a] >> BLOCK_BITS) - (box[a] >> BLOCK_BITS) + 1
    cap = min(nb, chunk)
    keys = np.empty(cap, dtype=np.int64)
    masks = np.empty((cap, 8), dtype=np.uint64)
    skipped = np.empty((cap, 2), dtype=np.int64)
    skipped_still = np.empty((cap, 8), dtype=np.uint64)
    zero = np.int64(0)  # (not a literal 0: numba would compile projective_blocks twice, 1.2 s)
    n, ns, nxt = projective_blocks(reach, tmin, tmax, dil, fx, fy, cx, cy, Tinv, box, res, band, keys, masks, zero,
                                   o_keys, o_vals, qquiet, still, skipped, skipped_still, zero)  # fmt: skip
    return keys, masks, n, skipped, skipped_still, ns, nxt, reach, tmin, tmax, dil, box


# a frame box of more blocks keeps its hits and tail misses as lists (tail_masks' table of the
# box's blocks, 4 bytes each, would be over 1 MB: only at resolutions far finer than 0.05 m)
LISTED_VOXELS_MAX_BLOCKS = 1 << 18
# tail_masks sets the tails' misses in a bitmap of the box's blocks up to this many (64 bytes a
# block: 4 MB; zeroing and reading it each frame costs what the rows would save in a larger box)
TAIL_BITMAP_MAX_BLOCKS = 1 << 16


@njit(cache=True, nogil=True)
def _rows_in_key_order(slot, keys, masks, m, w0):
    """The rows of ``keys[:m]`` with any bit in words ``w0`` to ``w0`` + 7 of ``masks``, in key
    order (the box's blocks walked in x, y, z order, ``pack_block``'s order; no sort: numba's
    argsort took 2 s of a first run's compiling): (keys, masks (n, 8))."""
    out_keys = np.empty(m, dtype=np.int64)
    out_masks = np.empty((m, 8), dtype=np.uint64)
    t = 0
    for idx in range(slot.shape[0]):
        o = slot[idx]
        if o < 0:
            continue
        any_bit = np.uint64(0)
        for w in range(8):
            out_masks[t, w] = masks[o, w0 + w]
            any_bit |= masks[o, w0 + w]
        if any_bit != 0:
            out_keys[t] = keys[o]
            t += 1
    return out_keys[:t], out_masks[:t]


@helper()
def _new_row(idx, box_blocks, slot, keys, masks, m):
    """``tail_masks``' row ``m`` made for block number ``idx`` of the box (``box_blocks``: its
    first block and its blocks along each axis), empty; returns the rows now made (m + 1). (Not
    in the loops over voxels: a helper there took 1.15x the time of the whole kernel.)"""
    nbj, nbk = box_blocks[4], box_blocks[5]
    slot[idx] = m
    bi, bj, bk = box_blocks[0] + idx // (nbj * nbk), box_blocks[1] + (idx // nbk) % nbj, box_blocks[2] + idx % nbk
    keys[m] = pack_block(bi, bj, bk)
    for w in range(16):
        masks[m, w] = 0
    return m + 1


NOT_WALKED = -1  # _tail_walks' record of a ray that walks no more
# rays whose tails tail_masks walks in lockstep at once (in ray_starts' buffers of RAY_CHUNK): a
# chunk walks as many steps as its longest tail, so fewer rays waste fewer steps (tails 0.95x to
# 0.97x the time of chunks of 256 on room, hall and office frames; 16 and 8: slower again)
TAIL_CHUNK = 32


@helper(error_model="numpy")
def _tail_walks(af, ai, n, box_blocks, rec, max_steps, max_it):
    """The DDA walks of a chunk of ``n`` rays (``ray_starts``' buffers ``af``, ``ai``, updated
    in place) in lockstep: at iteration ``it`` every ray that still walks records its voxel in
    ``rec[it * RAY_CHUNK + q]`` as (its block's number in the box << 9) | ``voxel_offset`` (a ray
    that walks no more: ``NOT_WALKED``), then takes ``ray_step``'s step: the same tie breaking,
    stop rule and step count, as selects with no branch, so the compiler runs it on vectors,
    several rays at once (walked a ray at a time, the axis of a step is a branch the CPU
    mispredicts about every other step). ``box_blocks``: the box's first block and its blocks
    along each axis (bi0, bj0, bk0, nbi, nbj, nbk); ``max_steps``: room for ``ray_state``'s
    max_steps of each ray (int32, ``RAY_CHUNK``). Returns (the iterations made, -1 when some ray
    still walks after ``max_it``; whether a walked voxel lies outside the box)."""
    C = RAY_CHUNK
    bi0, bj0, bk0 = box_blocks[0], box_blocks[1], box_blocks[2]
    nbj, nbk = box_blocks[4], box_blocks[5]
    ubi, ubj, ubk = np.uint64(box_blocks[3]), np.uint64(nbj), np.uint64(nbk)
    outside = False
    for q in range(n):  # (ray_state's, from the first voxel walked)
        max_steps[q] = ray_max_steps(ai[RS_EI * C + q], ai[RS_EJ * C + q], ai[RS_EK * C + q], ai[RS_CI * C + q],
                                     ai[RS_CJ * C + q], ai[RS_CK * C + q])  # fmt: skip
    for it in range(max_it):
        walking = np.int32(0)
        for q in range(n):  # (no branches: vectorized)
            w = ai[RS_WALK * C + q] != 0
            ci, cj, ck = ai[RS_CI * C + q], ai[RS_CJ * C + q], ai[RS_CK * C + q]
            bi = np.int64(ci >> BLOCK_BITS) - bi0
            bj = np.int64(cj >> BLOCK_BITS) - bj0
            bk = np.int64(ck >> BLOCK_BITS) - bk0
            outside |= w & ~((np.uint64(bi) < ubi) & (np.uint64(bj) < ubj) & (np.uint64(bk) < ubk))
            code = (((bi * nbj + bj) * nbk + bk) << (3 * BLOCK_BITS)) | np.int64(voxel_offset(ci, cj, ck))
            rec[it * C + q] = code if w else np.int64(NOT_WALKED)
            tmx, tmy, tmz = af[RS_TMX * C + q], af[RS_TMY * C + q], af[RS_TMZ * C + q]
            xy = tmx < tmy  # ray_step's axis: x when tmx < tmy and tmx < tmz, y when tmy <= tmx and
            d0 = xy & (tmx < tmz)  # tmy < tmz, else z
            d1 = (~xy) & (tmy < tmz)
            d2 = ~(d0 | d1)
            ci = ci + (ai[RS_SI * C + q] if d0 else np.int32(0))
            cj = cj + (ai[RS_SJ * C + q] if d1 else np.int32(0))
            ck = ck + (ai[RS_SK * C + q] if d2 else np.int32(0))
            tmx = tmx + af[RS_TDX * C + q] if d0 else tmx
            tmy = tmy + af[RS_TDY * C + q] if d1 else tmy
            tmz = tmz + af[RS_TDZ * C + q] if d2 else tmz
            ei, ej, ek = ai[RS_EI * C + q], ai[RS_EJ * C + q], ai[RS_EK * C + q]
            at_end = (ci == ei) & (cj == ej) & (ck == ek)
            past = min(tmx, min(tmy, tmz)) > af[RS_LENGTH * C + q]
            # a ray walking at iteration it has made it steps before this one
            w = w & ~at_end & ~past & (it + 1 <= max_steps[q])
            ai[RS_CI * C + q] = ci
            ai[RS_CJ * C + q] = cj
            ai[RS_CK * C + q] = ck
            af[RS_TMX * C + q] = tmx
            af[RS_TMY * C + q] = tmy
            af[RS_TMZ * C + q] = tmz
            ai[RS_WALK * C + q] = np.int32(w)
            walking |= np.int32(w)
        if walking == 0:
            return it + 1, outside
    return -1, outside


@njit(cache=True, nogil=True)
def tail_masks(origin, ends, kind, inv_res, res, tail, pkeys, pmasks, box, max_blocks, bitmap_max_blocks):
    """The rays' tails and hits of a depth frame straight into block masks, with the
    projection's: (keys, masks, hit keys, hit masks, True), keys ascending; the masks hold the
    projection's blocks (``pkeys`` ascending, ``pmasks``) with the misses of every ray's last
    ``tail`` metres (``core.raycast``'s DDA: ``ray_starts``, ``ray_step``) set in them, the hit
    masks the end voxels of the hit rays. (empty, empty, empty, empty, False) when the frame's
    voxel box ``box`` holds more than ``max_blocks`` blocks (``LISTED_VOXELS_MAX_BLOCKS``) or a
    voxel lies outside it (a step past a ray's end): the caller lists the frame's voxels
    instead (``frame_voxels``).

    The tails (``tail`` > 0) are walked ``TAIL_CHUNK`` rays at a time in lockstep (``_tail_walks``:
    0.79x to 0.84x the time of walking them one by one on room, hall and office frames, the same
    masks), their voxels set in a bitmap of the box's blocks (64 bytes a block; in a box of at
    most ``bitmap_max_blocks``, ``TAIL_BITMAP_MAX_BLOCKS``: the bench scenes' depth frames hold
    340 to 2,400) with no branch and no row search per voxel, and ORed into the rows once a frame
    (0.86x to 0.88x the time of setting them in the rows voxel by voxel, as a larger box still
    does); whole rays (``tail`` 0: scans, exact depth) one by one.

    One table row per block of the box that has any: words 0 to 7 its misses, 8 to 15 its hits.
    A voxel set twice is set once, so no "listed already" bitmap is kept and nothing is listed;
    a tail's miss on a voxel this frame hits is left to the map thread, which updates a voxel at
    most once a frame, hits first (``apply_mask_updates``). The map thread then applies the
    misses block by block (no hash lookup per voxel, quiet quarters dropped a word at a time):
    each voxel once a frame, after the frame's hits, with the values of the rays' order; only
    the order voxels enter the tick buffer in differs. Reads no map state (a worker's part)."""
    bi0, bj0, bk0 = box[0] >> BLOCK_BITS, box[1] >> BLOCK_BITS, box[2] >> BLOCK_BITS
    nbi = (box[3] >> BLOCK_BITS) - bi0 + 1
    nbj = (box[4] >> BLOCK_BITS) - bj0 + 1
    nbk = (box[5] >> BLOCK_BITS) - bk0 + 1
    ubi, ubj, ubk = np.uint64(nbi), np.uint64(nbj), np.uint64(nbk)
    nb = nbi * nbj * nbk
    no_masks = np.empty((0, 8), dtype=np.uint64)
    refused = (pkeys[:0], no_masks, pkeys[:0], no_masks, False)
    if nb > max_blocks:
        return refused
    rays = 0
    for r in range(kind.shape[0]):
        rays += kind[r] != RAY_SKIP
    # rows: at most one per block of the box, and a ray sets its hit and at most max_steps + 1
    # voxels of its tail (ray_state: its voxel span + 3, + 1), so no growth in the loop
    span = np.int64(np.ceil(tail * inv_res)) + 1
    per_ray = 3 * span + 5 if tail > 0.0 else nb
    n = pkeys.shape[0]
    cap = min(nb, n + rays * per_ray)
    slot = np.empty(nb, dtype=np.int32)
    for t in range(nb):
        slot[t] = -1
    keys = np.empty(cap, dtype=np.int64)
    masks = np.empty((cap, 16), dtype=np.uint64)
    for t in range(n):
        bi, bj, bk = unpack_block(pkeys[t])
        if not (bi0 <= bi < bi0 + nbi and bj0 <= bj < bj0 + nbj and bk0 <= bk < bk0 + nbk):
            return refused
        slot[((bi - bi0) * nbj + (bj - bj0)) * nbk + (bk - bk0)] = t
        keys[t] = pkeys[t]
        for w in range(8):
            masks[t, w] = pmasks[t, w]
            masks[t, 8 + w] = 0
    m = n
    ox, oy, oz = origin[0], origin[1], origin[2]
    ki0 = np.int64(np.floor(ox * inv_res))
    kj0 = np.int64(np.floor(oy * inv_res))
    kk0 = np.int64(np.floor(oz * inv_res))
    af, ai = ray_start_buffers()
    # the tails' records (_tail_walks): a ray records at most max_steps + 1 <= per_ray voxels
    rec = np.empty(per_ray * RAY_CHUNK if tail > 0.0 else 0, dtype=np.int64)
    # the tails' misses, in a box of at most bitmap_max_blocks blocks: a bitmap of its blocks
    # (8 words each, in the box's block order; one more block for the records of rays that walk
    # no more), set with no branch and no row search per record, then ORed into the rows once
    dense = tail > 0.0 and nb <= bitmap_max_blocks
    sink = np.int64(nb) << (3 * BLOCK_BITS)
    tbits = np.zeros((nb + 1) * 8 if dense else 0, dtype=np.uint64)
    step_caps = np.empty(RAY_CHUNK, dtype=np.int32)  # (_tail_walks' room for each ray's max_steps)
    box_blocks = np.array([bi0, bj0, bk0, nbi, nbj, nbk], dtype=np.int64)
    nr = ends.shape[0]
    chunk = TAIL_CHUNK if tail > 0.0 else RAY_CHUNK
    for c0 in range(0, nr, chunk):  # a chunk of rays: their starts at once, then their hits, their walks
        c1 = min(nr, c0 + chunk)
        ray_starts(ends, c0, c1 - c0, ox, oy, oz, ki0, kj0, kk0, inv_res, res, tail, af, ai)
        for r in range(c0, c1):  # the hits (words 8 to 15): the end voxels of the hit rays
            if kind[r] != RAY_HIT:
                continue
            _, ei, ej, ek, _, _, _, _, _, _, _, _, _, _, _, _, _, _ = ray_state(af, ai, r - c0)
            bi, bj, bk = (ei >> BLOCK_BITS) - bi0, (ej >> BLOCK_BITS) - bj0, (ek >> BLOCK_BITS) - bk0
            if not ((np.uint64(bi) < ubi) & (np.uint64(bj) < ubj) & (np.uint64(bk) < ubk)):
                return refused
            idx = (bi * nbj + bj) * nbk + bk
            s = np.int64(slot[idx])
            if s < 0:  # the block's row, made empty (written out in both loops: a helper returning
                s = m  # (row, rows) took 1.15x the time of the whole kernel)
                slot[idx] = m
                keys[m] = pack_block(ei >> BLOCK_BITS, ej >> BLOCK_BITS, ek >> BLOCK_BITS)
                for w in range(16):
                    masks[m, w] = 0
                m += 1
            off = voxel_offset(ei, ej, ek)
            masks[s, 8 + (off >> 6)] |= np.uint64(1) << np.uint64(off & 63)
        if tail > 0.0:  # the tails, all of a chunk at once (_tail_walks), then their voxels' bits
            for r in range(c0, c1):
                if kind[r] == RAY_SKIP:
                    ai[RS_WALK * RAY_CHUNK + r - c0] = 0
            iters, outside = _tail_walks(af, ai, c1 - c0, box_blocks, rec, step_caps, per_ray)
            if outside or iters < 0:
                return refused
            if dense:  # (in memory order)
                for it in range(iters):
                    for q in range(c1 - c0):
                        code = rec[it * RAY_CHUNK + q]
                        code = sink if code == NOT_WALKED else code
                        tbits[code >> 6] |= np.uint64(1) << np.uint64(code & 63)
                continue
            for it in range(iters):  # (a larger box: the rows by the block's number)
                for q in range(c1 - c0):
                    code = rec[it * RAY_CHUNK + q]
                    if code == NOT_WALKED:
                        continue
                    idx = code >> (3 * BLOCK_BITS)
                    s = np.int64(slot[idx])
                    if s < 0:
                        s, m = m, _new_row(idx, box_blocks, slot, keys, masks, m)
                    off = code & (BLOCK_VOXELS - 1)
                    masks[s, off >> 6] |= np.uint64(1) << np.uint64(off & 63)
            continue
        for r in range(c0, c1):  # whole rays, one by one (their lengths differ widely): each voxel a
            if kind[r] == RAY_SKIP:  # walk passes up to the end voxel (not walked) is a miss
                continue
            walk, ei, ej, ek, ci, cj, ck, si, sj, sk, tmx, tmy, tmz, tdx, tdy, tdz, length, max_steps = ray_state(
                af, ai, r - c0)  # fmt: skip
            steps = 0
            pbi, pbj, pbk, s = np.int64(-1), np.int64(-1), np.int64(-1), np.int64(0)  # the block of the last step
            while walk:
                bi, bj, bk = (ci >> BLOCK_BITS) - bi0, (cj >> BLOCK_BITS) - bj0, (ck >> BLOCK_BITS) - bk0
                if bi != pbi or bj != pbj or bk != pbk:  # (a walk stays in a block for several steps: one lookup)
                    if not ((np.uint64(bi) < ubi) & (np.uint64(bj) < ubj) & (np.uint64(bk) < ubk)):
                        return refused
                    idx = (bi * nbj + bj) * nbk + bk
                    s = np.int64(slot[idx])
                    if s < 0:
                        s = m
                        slot[idx] = m
                        keys[m] = pack_block(ci >> BLOCK_BITS, cj >> BLOCK_BITS, ck >> BLOCK_BITS)
                        for w in range(16):
                            masks[m, w] = 0
                        m += 1
                    pbi, pbj, pbk = bi, bj, bk
                off = voxel_offset(ci, cj, ck)
                masks[s, off >> 6] |= np.uint64(1) << np.uint64(off & 63)
                _, ci, cj, ck, tmx, tmy, tmz, steps, walk = ray_step(ci, cj, ck, tmx, tmy, tmz, si, sj, sk, tdx, tdy, tdz,
                                                                     ei, ej, ek, length, steps, max_steps)  # fmt: skip
    for idx in range(nb if dense else 0):  # the tails' bits into the blocks' rows
        any_bit = np.uint64(0)
        for w in range(8):
            any_bit |= tbits[idx * 8 + w]
        if any_bit == 0:
            continue
        s = np.int64(slot[idx])
        if s < 0:
            s, m = m, _new_row(idx, box_blocks, slot, keys, masks, m)
        for w in range(8):
            masks[s, w] |= tbits[idx * 8 + w]
    okeys, omasks = _rows_in_key_order(slot, keys, masks, m, np.int64(0))
    hkeys, hmasks = _rows_in_key_order(slot, keys, masks, m, np.int64(8))
    return okeys, omasks, hkeys, hmasks, True
