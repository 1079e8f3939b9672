"""Sensor integration into O: 3D DDA ray casting with OctoMap's per-frame rules.

For one frame (sensor origin + end points in the fixed frame):

1. Each end point is classified (``classify_rays``): NaN dropped; beyond ``max_range`` the ray
   is cut there and the cut end marks nothing; a return within ``ground_tolerance`` of z = 0 or
   inside the robot's footprint box clears its ray but is not a hit; a no-return ray clears up
   to its end and marks nothing.
2. Hits are applied first: the end voxel of every hit ray gets the hit log-odds once.
3. Rays are traversed with the Amanatides & Woo DDA exactly as OctoMap's computeRayKeys does
   (origin voxel included, end voxel excluded, same tie breaking and stop rule); each voxel not
   yet updated in this frame gets the miss log-odds.

A frame is cast in two halves. ``frame_voxels`` (reads no map state: it may run in worker
threads) lists the voxels steps 2 and 3 update, each once, in the order they update them: a
bitmap over the frame's box drops the repeats (a dense depth frame steps through each voxel about
15 times). ``apply_voxels_kernel`` (the thread that owns the map) gives them their update. A
per-voxel ``stamp`` channel holds the id of the last frame that updated the voxel: a voxel is
updated at most once per frame and a hit wins over a miss (hits go first), which is OctoMap's
rule without its hash sets. ``stamp == 0`` means never updated (unknown). Every voxel updated
for the first time in the current tick is appended to the tick buffer for the tick rules, and a
hit sets the voxel's ``hit`` mark (the tick rules need to know whether a frame of the tick hit it).
"""

from __future__ import annotations

import numpy as np

from ..jit import helper, njit
from .grid import (
    _PACK_BITS,
    BLOCK_BITS,
    BLOCK_MASK,
    BLOCK_VOXELS,
    _slot,
    find_block,
    get_or_add_block,
    pack_block,
    unpack_block,
    voxel_offset,
)

RAY_SKIP = 0  # dropped (NaN)
RAY_CLEAR = 1  # clears up to its end, end marks nothing
RAY_HIT = 2  # clears up to its end, end voxel is a hit

STATUS_DONE = 0
STATUS_NEED_BLOCKS = 1
STATUS_NEED_TICK_BUFFER = 2
STATUS_NEED_CHANGED = 3
SEEN_MAX_WORDS = 1 << 23  # 64 MB, 537 M voxels: a frame whose box is bigger takes the sparse bitmap


# the slots of frame_voxels' bitmap state ``seen_meta`` (int64 array, read and written by kernels)
(SEEN_DENSE, SEEN_I0, SEEN_J0, SEEN_K0, SEEN_NX, SEEN_NY, SEEN_NZ, SEEN_WORDS, SEEN_WORDS_CAP, SEEN_SPARSE_USED,
 SEEN_SPARSE_GEN, SEEN_GROW) = range(12)  # fmt: skip
SEEN_META_SLOTS = 12
# the slots of its progress ``state``: phase (0 new frame, 1 hits, 2 misses), next ray, hits and
# misses listed so far
FV_PHASE, FV_RAY, FV_HITS, FV_MISSES = range(4)
FV_STATE_SLOTS = 4
# what frame_voxels needs grown when it returns False (seen_meta[SEEN_GROW])
GROW_DENSE, GROW_MISSES, GROW_SPARSE = 1, 2, 3

# quiet quarters: an O block's 4 x 4 x 4 quarters, numbered as core.projective's block loop takes
# them (bit 2: x half, bit 1: y half, bit 0: z half); a block's quiet flags are a byte, one bit a
# quarter, and the block is quiet when all eight are
QUARTER_VOXELS = BLOCK_VOXELS // 8
QUIET_ALL = 255


def _quarter_keep() -> np.ndarray:
    """``QUARTER_KEEP[m]``: the bits of one 64-bit word of a block's miss mask (the voxels of one
    x slice, bit y * 8 + z) outside the quarters of the 4-bit set ``m`` (bit 1: y half, bit 0: z
    half) of that slice's x half."""
    keep = np.empty(16, dtype=np.uint64)
    for m in range(16):
        drop = 0
        for s in range(4):
            if m >> s & 1:
                for y in range((s >> 1) * 4, (s >> 1) * 4 + 4):
                    drop |= 0xF << (y * 8 + (s & 1) * 4)
        keep[m] = ~np.uint64(drop)
    return keep


QUARTER_KEEP = _quarter_keep()


# the index of a 64-bit word's only set bit: _DEBRUIJN_BIT[(bit * _DEBRUIJN) >> 58]
_DEBRUIJN = np.uint64(0x03F79D71B4CB0A89)
_DEBRUIJN_BIT = np.zeros(64, dtype=np.int64)
_DEBRUIJN_BIT[[((int(_DEBRUIJN) << b) & (2**64 - 1)) >> 58 for b in range(64)]] = np.arange(64)


@njit(cache=True, nogil=True, inline="always")
def quarter_of(off):
    """The quarter (0..7) of the voxel at offset ``off`` in its block (``voxel_offset``)."""
    return ((off >> 6) & 4) | ((off >> 4) & 2) | ((off >> 2) & 1)


@njit(cache=True, nogil=True)
def classify_rays(origin, points, returns, max_range, ground_tol, fp_inv, fp_min, fp_max, use_fp):
    """Per end point: (end point actually used (N, 3), kind (N,) int8).

    ``returns[i]`` is False for a beam that had no return (its point is where clearing stops).
    ``fp_inv`` (3, 4) maps fixed-frame points into the robot frame for the footprint test.
    """
    n = points.shape[0]
    ends = np.empty((n, 3), dtype=np.float64)
    kind = np.empty(n, dtype=np.int8)
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        if not (np.isfinite(px) and np.isfinite(py) and np.isfinite(pz)):
            kind[i] = RAY_SKIP
            ends[i, 0] = origin[0]
            ends[i, 1] = origin[1]
            ends[i, 2] = origin[2]
            continue
        k = RAY_HIT if returns[i] else RAY_CLEAR
        dx, dy, dz = px - origin[0], py - origin[1], pz - origin[2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        if max_range > 0.0 and length > max_range:
            s = max_range / length
            px, py, pz = origin[0] + dx * s, origin[1] + dy * s, origin[2] + dz * s
            k = RAY_CLEAR
        if k == RAY_HIT and ground_tol >= 0.0 and abs(pz) <= ground_tol:
            k = RAY_CLEAR
        if k == RAY_HIT and use_fp:
            lx = fp_inv[0, 0] * px + fp_inv[0, 1] * py + fp_inv[0, 2] * pz + fp_inv[0, 3]
            ly = fp_inv[1, 0] * px + fp_inv[1, 1] * py + fp_inv[1, 2] * pz + fp_inv[1, 3]
            lz = fp_inv[2, 0] * px + fp_inv[2, 1] * py + fp_inv[2, 2] * pz + fp_inv[2, 3]
            if fp_min[0] <= lx <= fp_max[0] and fp_min[1] <= ly <= fp_max[1] and fp_min[2] <= lz <= fp_max[2]:
                k = RAY_CLEAR
        kind[i] = k
        ends[i, 0] = px
        ends[i, 1] = py
        ends[i, 2] = pz
    return ends, kind


# voxel keys are packed as block coordinates are (grid.pack_block / unpack_block: 3 x 21 bits,
# each + 2^20; keys within +-core.layers.KEY_LIMIT)
SEEN_PAD = 4  # the dense bitmap's box: the ends and the origin, and this many voxels around


@helper()
def _seen_setup(origin, ends, kind, inv_res, seen, seen_meta):
    """Lay this frame's ``seen`` bitmap over the box of voxels its rays can visit (their ends
    and the origin, padded) and clear it. ``seen_meta`` = [dense on, i0, j0, k0, nx, ny, nz,
    words needed, most words, sparse blocks used, sparse generation, what to grow]; the box
    (i0.., nx..) is recorded either way. Returns False when ``seen`` is too small for the box
    (the caller grows it); a box of more than the most words (SEEN_MAX_WORDS: rays of hundreds
    of metres) leaves the dense bitmap off for the frame: the sparse one takes every voxel."""
    ki0 = np.int64(np.floor(origin[0] * inv_res))
    kj0 = np.int64(np.floor(origin[1] * inv_res))
    kk0 = np.int64(np.floor(origin[2] * inv_res))
    lo_i, hi_i, lo_j, hi_j, lo_k, hi_k = ki0, ki0, kj0, kj0, kk0, kk0
    for r in range(ends.shape[0]):
        if kind[r] == RAY_SKIP:
            continue
        i = np.int64(np.floor(ends[r, 0] * inv_res))
        j = np.int64(np.floor(ends[r, 1] * inv_res))
        k = np.int64(np.floor(ends[r, 2] * inv_res))
        lo_i = min(lo_i, i)
        hi_i = max(hi_i, i)
        lo_j = min(lo_j, j)
        hi_j = max(hi_j, j)
        lo_k = min(lo_k, k)
        hi_k = max(hi_k, k)
    pad = SEEN_PAD  # a ray may step past its end voxel (the stop rule allows a few steps)
    nx, ny, nz = hi_i - lo_i + 1 + 2 * pad, hi_j - lo_j + 1 + 2 * pad, hi_k - lo_k + 1 + 2 * pad
    seen_meta[SEEN_I0], seen_meta[SEEN_J0], seen_meta[SEEN_K0] = lo_i - pad, lo_j - pad, lo_k - pad
    seen_meta[SEEN_NX], seen_meta[SEEN_NY], seen_meta[SEEN_NZ] = nx, ny, nz
    words_f = (np.float64(nx) * np.float64(ny) * np.float64(nz) + 63.0) / 64.0  # no int64 overflow
    if words_f > np.float64(seen_meta[SEEN_WORDS_CAP]):
        seen_meta[SEEN_DENSE] = 0
        seen_meta[SEEN_WORDS] = 0
        return True
    words = (nx * ny * nz + 63) >> 6
    seen_meta[SEEN_WORDS] = words
    if words > seen.shape[0]:
        return False
    seen[:words] = 0
    seen_meta[SEEN_DENSE] = 1
    return True


@njit(cache=True, nogil=True, inline="always")
def _sparse_visit(i, j, k, sp_keys, sp_gen, sp_vals, sp_words, seen_meta, cache):
    """Voxel (i, j, k) in the sparse bitmap: 1 and its bit set when this frame has not listed it
    yet, 0 when it has, -1 when the bitmap is full. ``cache`` = [bx, by, bz, slot] of the last
    block looked up."""
    bx, by, bz = i >> BLOCK_BITS, j >> BLOCK_BITS, k >> BLOCK_BITS
    if bx != cache[0] or by != cache[1] or bz != cache[2] or cache[3] < 0:
        cache[3] = _sparse_slot(bx, by, bz, sp_keys, sp_gen, sp_vals, sp_words, seen_meta)
        cache[0], cache[1], cache[2] = bx, by, bz
        if cache[3] < 0:
            return -1
    off = voxel_offset(i, j, k)
    w = 8 * cache[3] + (off >> 6)
    bm = np.uint64(1) << np.uint64(off & 63)
    if sp_words[w] & bm:
        return 0
    sp_words[w] |= bm
    return 1


@njit(cache=True, nogil=True)
def sparse_grown(sp_keys, sp_gen, sp_vals, sp_words, gen, slots):
    """The sparse bitmap with ``slots`` hash slots, holding this generation's blocks and bits."""
    keys = np.zeros(slots, dtype=np.int64)
    gens = np.zeros(slots, dtype=np.int64)
    vals = np.zeros(slots, dtype=np.int64)
    words = np.zeros(4 * slots, dtype=np.uint64)
    mask = slots - 1
    for s in range(sp_keys.shape[0]):
        if sp_gen[s] != gen:
            continue
        t = _slot(sp_keys[s], mask)
        while gens[t] == gen:
            t = (t + 1) & mask
        keys[t], gens[t], vals[t] = sp_keys[s], gen, sp_vals[s]
    words[: sp_words.shape[0]] = sp_words
    return keys, gens, vals, words


@njit(cache=True, nogil=True, inline="always")
def _sparse_slot(bx, by, bz, sp_keys, sp_gen, sp_vals, sp_words, seen_meta):
    """Slot (8 words: the 512 voxels' bits) of block (bx, by, bz) in the sparse bitmap, a hash
    of blocks whose entries count only in this frame's generation (nothing to clear per frame);
    -1 when it is full (the caller grows it)."""
    mask = sp_keys.shape[0] - 1
    gen = seen_meta[SEEN_SPARSE_GEN]
    packed = pack_block(bx, by, bz)
    s = _slot(packed, mask)
    while sp_gen[s] == gen:
        if sp_keys[s] == packed:
            return sp_vals[s]
        s = (s + 1) & mask
    n = seen_meta[SEEN_SPARSE_USED]
    if 2 * (n + 1) > sp_keys.shape[0] or 8 * (n + 1) > sp_words.shape[0]:
        return np.int64(-1)
    sp_gen[s] = gen
    sp_keys[s] = packed
    sp_vals[s] = n
    sp_words[8 * n:8 * n + 8] = 0
    seen_meta[SEEN_SPARSE_USED] = n + 1
    return n


@njit(cache=True, nogil=True, inline="always")
def _seen_bit(seen, bit):
    return (seen[bit >> 6] >> np.uint64(bit & 63)) & np.uint64(1)



RAY_FAR = 1e300  # a DDA's next crossing along an axis the ray does not move along: never


RAY_CHUNK = 256  # rays whose DDA starts ray_starts computes at once
# the rows of ray_starts' buffers (each RAY_CHUNK long): floats, then int32s
(RS_TMX, RS_TMY, RS_TMZ, RS_TDX, RS_TDY, RS_TDZ, RS_LENGTH, RS_EX, RS_EY, RS_EZ) = range(10)  # fmt: skip
(RS_EI, RS_EJ, RS_EK, RS_CI, RS_CJ, RS_CK, RS_SI, RS_SJ, RS_SK, RS_WALK) = range(10)  # fmt: skip
RS_ROWS = 10
RS_KEY_LIMIT = float(1 << 30)  # voxel coordinates are clamped here before int32 (keys are within +-2^20)


@njit(cache=True, nogil=True)
def ray_start_buffers():
    """``ray_starts``' buffers: (floats, int32s), ``RS_ROWS`` rows of ``RAY_CHUNK`` each."""
    return np.empty(RS_ROWS * RAY_CHUNK, dtype=np.float64), np.empty(RS_ROWS * RAY_CHUNK, dtype=np.int32)


@helper(error_model="numpy")
def ray_starts(ends, r0, n, ox, oy, oz, ki0, kj0, kk0, inv_res, res, tail, af, ai):
    """The Amanatides & Woo DDA's start for rays ``r0`` to ``r0 + n`` (n <= ``RAY_CHUNK``) from
    (ox, oy, oz) (voxel (ki0, kj0, kk0)) to ``ends``, OctoMap's ``computeRayKeys`` arithmetic,
    into the buffers ``af``, ``ai`` (``ray_start_buffers``; ``ray_state`` reads a ray's back).
    ``tail`` > 0: a ray longer than ``tail`` is walked from ``tail`` metres before its end (the
    rays' tails of projective depth integration), and its length is tail. No walk when the end
    lies in the origin's voxel, or a tail starts in the end voxel.

    Every ray's arithmetic is done, whatever it turns out to be (selects, no branches, and
    ``error_model="numpy"``: no zero-division checks), so the loop runs on vectors: 4 rays' nine
    divisions and square root at once (it was a third of a depth frame's tails done ray by ray).
    IEEE division and square root round the same on vectors, so the values are those of the
    scalar code."""
    C = RAY_CHUNK
    for q in range(n):  # the end points in rows of their own (interleaved loads do not vectorize)
        af[RS_EX * C + q] = ends[r0 + q, 0]
        af[RS_EY * C + q] = ends[r0 + q, 1]
        af[RS_EZ * C + q] = ends[r0 + q, 2]
    hres = res * 0.5
    cutting = tail > 0.0
    lim = RS_KEY_LIMIT
    for q in range(n):
        ex, ey, ez = af[RS_EX * C + q], af[RS_EY * C + q], af[RS_EZ * C + q]
        ei = np.int32(min(max(np.floor(ex * inv_res), -lim), lim))
        ej = np.int32(min(max(np.floor(ey * inv_res), -lim), lim))
        ek = np.int32(min(max(np.floor(ez * inv_res), -lim), lim))
        dx, dy, dz = ex - ox, ey - oy, ez - oz
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        dx = dx / length
        dy = dy / length
        dz = dz / length
        cut = cutting & (length > tail)
        rx = ex - dx * tail if cut else ox  # where the walk starts
        ry = ey - dy * tail if cut else oy
        rz = ez - dz * tail if cut else oz
        ci = np.int32(min(max(np.floor(rx * inv_res), -lim), lim))  # (the origin's voxel when not cut)
        cj = np.int32(min(max(np.floor(ry * inv_res), -lim), lim))
        ck = np.int32(min(max(np.floor(rz * inv_res), -lim), lim))
        in_origin = (ei == ki0) & (ej == kj0) & (ek == kk0)
        in_end = cut & (ci == ei) & (cj == ej) & (ck == ek)
        si = np.int32(dx > 0.0) - np.int32(dx < 0.0)
        sj = np.int32(dy > 0.0) - np.int32(dy < 0.0)
        sk = np.int32(dz > 0.0) - np.int32(dz < 0.0)
        # the first crossing and the step along each axis; never (RAY_FAR) along an axis the ray
        # does not move along
        tx = ((ci + 0.5) * res + si * hres - rx) / dx
        ty = ((cj + 0.5) * res + sj * hres - ry) / dy
        tz = ((ck + 0.5) * res + sk * hres - rz) / dz
        af[RS_TMX * C + q] = tx if si != 0 else RAY_FAR
        af[RS_TMY * C + q] = ty if sj != 0 else RAY_FAR
        af[RS_TMZ * C + q] = tz if sk != 0 else RAY_FAR
        af[RS_TDX * C + q] = res / abs(dx) if si != 0 else RAY_FAR
        af[RS_TDY * C + q] = res / abs(dy) if sj != 0 else RAY_FAR
        af[RS_TDZ * C + q] = res / abs(dz) if sk != 0 else RAY_FAR
        af[RS_LENGTH * C + q] = tail if cut else length
        ai[RS_EI * C + q] = ei
        ai[RS_EJ * C + q] = ej
        ai[RS_EK * C + q] = ek
        ai[RS_CI * C + q] = ci
        ai[RS_CJ * C + q] = cj
        ai[RS_CK * C + q] = ck
        ai[RS_SI * C + q] = si
        ai[RS_SJ * C + q] = sj
        ai[RS_SK * C + q] = sk
        ai[RS_WALK * C + q] = np.int32(not (in_origin | in_end))


@njit(cache=True, nogil=True, inline="always")
def ray_max_steps(ei, ej, ek, ci, cj, ck):
    """The steps a walk from voxel (ci, cj, ck) to end voxel (ei, ej, ek) may take: their L1
    distance and 3 (a walk that passes beside its end voxel stops there)."""
    return abs(ei - ci) + abs(ej - cj) + abs(ek - ck) + 3


@njit(cache=True, nogil=True, inline="always")
def ray_state(af, ai, q):
    """Ray ``q`` of the chunk ``ray_starts`` computed: (walk, ei, ej, ek, ci, cj, ck, si, sj, sk,
    tmx, tmy, tmz, tdx, tdy, tdz, length, max_steps), (ei, ej, ek) the end voxel, (ci, cj, ck)
    the first voxel walked; ``ray_step`` takes the walk on from there."""
    C = RAY_CHUNK
    ei, ej, ek = np.int64(ai[RS_EI * C + q]), np.int64(ai[RS_EJ * C + q]), np.int64(ai[RS_EK * C + q])
    ci, cj, ck = np.int64(ai[RS_CI * C + q]), np.int64(ai[RS_CJ * C + q]), np.int64(ai[RS_CK * C + q])
    si, sj, sk = np.int64(ai[RS_SI * C + q]), np.int64(ai[RS_SJ * C + q]), np.int64(ai[RS_SK * C + q])
    max_steps = ray_max_steps(ei, ej, ek, ci, cj, ck)
    return (ai[RS_WALK * C + q] != 0, ei, ej, ek, ci, cj, ck, si, sj, sk, af[RS_TMX * C + q], af[RS_TMY * C + q],
            af[RS_TMZ * C + q], af[RS_TDX * C + q], af[RS_TDY * C + q], af[RS_TDZ * C + q], af[RS_LENGTH * C + q],
            max_steps)  # fmt: skip


@njit(cache=True, nogil=True, inline="always")
def ray_step(ci, cj, ck, tmx, tmy, tmz, si, sj, sk, tdx, tdy, tdz, ei, ej, ek, length, steps, max_steps):
    """One DDA step from voxel (ci, cj, ck), OctoMap's tie breaking (strict < picks the lower
    axis only when smaller) and stop rule: (the axis stepped along, ci, cj, ck, tmx, tmy, tmz,
    steps, more). more is False when the walk ends (the end voxel reached, which is not walked,
    past ``length``, or more than ``max_steps`` steps)."""
    if tmx < tmy:
        dim = 0 if tmx < tmz else 2
    else:
        dim = 1 if tmy < tmz else 2
    if dim == 0:
        ci += si
        tmx += tdx
    elif dim == 1:
        cj += sj
        tmy += tdy
    else:
        ck += sk
        tmz += tdz
    if ci == ei and cj == ej and ck == ek:
        return dim, ci, cj, ck, tmx, tmy, tmz, steps, False
    if min(tmx, min(tmy, tmz)) > length:
        return dim, ci, cj, ck, tmx, tmy, tmz, steps, False
    steps += 1
    return dim, ci, cj, ck, tmx, tmy, tmz, steps, steps <= max_steps


@njit(cache=True, nogil=True)
def frame_voxels(origin, ends, kind, inv_res, res, seen, seen_meta, hits, misses, sp_keys, sp_gen, sp_vals, sp_words,
                 state, tail):  # fmt: skip
    """See ``_frame_voxels``: the dense bitmap's loop, or the sparse one's when the frame's box is
    too big for a dense bitmap (both compiled from the one loop: ``seen`` None or not)."""
    if state[FV_PHASE] == 0:  # a new frame
        seen_meta[SEEN_SPARSE_USED] = 0  # a new generation of the sparse bitmap: empty
        seen_meta[SEEN_SPARSE_GEN] += 1
        if not _seen_setup(origin, ends, kind, inv_res, seen, seen_meta):
            seen_meta[SEEN_GROW] = GROW_DENSE
            return False
        state[FV_PHASE] = 1
    seen_meta[SEEN_GROW] = 0
    if seen_meta[SEEN_DENSE] != 0:
        return _frame_voxels(origin, ends, kind, inv_res, res, seen, seen_meta, hits, misses, sp_keys, sp_gen,
                             sp_vals, sp_words, state, tail)  # fmt: skip
    return _frame_voxels(origin, ends, kind, inv_res, res, None, seen_meta, hits, misses, sp_keys, sp_gen, sp_vals,
                         sp_words, state, tail)  # fmt: skip


@njit(cache=True, nogil=True)
def _frame_voxels(origin, ends, kind, inv_res, res, seen, seen_meta, hits, misses, sp_keys, sp_gen, sp_vals, sp_words,
                  state, tail):  # fmt: skip
    """The voxels one frame updates, in the order OctoMap's per-frame rules update them, as
    packed keys (``grid.pack_block``): hits into ``hits[:state[FV_HITS]]`` (at most one per ray), misses into
    ``misses[:state[FV_MISSES]]``. Returns True when done; False when a buffer must grow first:
    ``seen_meta[SEEN_GROW]`` says which (1 the dense bitmap, ``seen_meta[SEEN_WORDS]`` words; 2 the miss buffer;
    3 the sparse bitmap). ``state`` = [phase (0 a new frame, 1 hits, 2 rays), ray, hits listed,
    misses listed]: the caller grows the buffer (keeping what is listed) and calls again, which
    goes on from the ray it stopped in (its voxels listed so far are marked: not listed twice).

    Hits first (the end voxel of every hit ray), then the rays are traversed with the Amanatides
    & Woo DDA exactly as OctoMap's computeRayKeys does (origin voxel included, end voxel
    excluded, same tie breaking and stop rule); every voxel on a ray is a miss. A voxel is
    listed once, at its first update: a dense bitmap over the frame's box (``_seen_setup``)
    drops the repeats (a dense depth frame steps through each voxel about 15 times, every ray
    passing the voxels near the camera); when the box is too big for a dense bitmap (long lidar
    rays, fine resolutions) a sparse one (``_sparse_visit``) takes every voxel. Reads no map
    state, so it may run in another thread than ``apply_voxels``."""
    si0, sj0, sk0 = seen_meta[SEEN_I0], seen_meta[SEEN_J0], seen_meta[SEEN_K0]
    snx, sny, snz = seen_meta[SEEN_NX], seen_meta[SEEN_NY], seen_meta[SEEN_NZ]
    usnx, usny, usnz = np.uint64(snx), np.uint64(sny), np.uint64(snz)
    n = ends.shape[0]
    sp_cache = np.empty(4, dtype=np.int64)  # the sparse bitmap's last block and its slot: none yet
    sp_cache[0] = -(1 << 40)
    sp_cache[3] = -1
    n_hit = state[FV_HITS]
    r0 = state[FV_RAY] if state[FV_PHASE] == 1 else n
    for r in range(r0, n):
        if kind[r] != RAY_HIT:
            continue
        i = np.int64(np.floor(ends[r, 0] * inv_res))
        j = np.int64(np.floor(ends[r, 1] * inv_res))
        k = np.int64(np.floor(ends[r, 2] * inv_res))
        if seen is None:
            first = _sparse_visit(i, j, k, sp_keys, sp_gen, sp_vals, sp_words, seen_meta, sp_cache)
            if first < 0:
                seen_meta[SEEN_GROW] = GROW_SPARSE
                state[FV_RAY], state[FV_HITS] = r, n_hit
                return False
            if first == 0:
                continue
        else:  # an end voxel is always in the box
            bit = ((i - si0) * sny + (j - sj0)) * snz + (k - sk0)
            if _seen_bit(seen, bit):
                continue
            seen[bit >> 6] |= np.uint64(1) << np.uint64(bit & 63)
        hits[n_hit] = pack_block(i, j, k)
        n_hit += 1
    if state[FV_PHASE] == 1:
        state[FV_PHASE], state[FV_RAY], state[FV_HITS] = 2, 0, n_hit

    cap = misses.shape[0]
    n_miss = state[FV_MISSES]
    ox, oy, oz = origin[0], origin[1], origin[2]
    ki0 = np.int64(np.floor(ox * inv_res))
    kj0 = np.int64(np.floor(oy * inv_res))
    kk0 = np.int64(np.floor(oz * inv_res))
    af, ai = ray_start_buffers()
    c0, c1 = 0, 0  # the rays whose starts ray_starts holds: none yet
    for r in range(state[FV_RAY], n):
        if kind[r] == RAY_SKIP:
            continue
        if r >= c1:
            c0, c1 = r, min(n, r + RAY_CHUNK)
            ray_starts(ends, c0, c1 - c0, ox, oy, oz, ki0, kj0, kk0, inv_res, res, tail, af, ai)
        walk, ei, ej, ek, ci, cj, ck, si, sj, sk, tmx, tmy, tmz, tdx, tdy, tdz, length, max_steps = ray_state(af, ai,
                                                                                                           r - c0)  # fmt: skip
        if not walk:
            continue
        steps = 0
        if n_miss + max_steps + 2 > cap:  # room for this ray's voxels, or the caller grows the buffer
            seen_meta[SEEN_GROW] = GROW_MISSES
            state[FV_RAY], state[FV_MISSES] = r, n_miss
            return False
        lin = ((ci - si0) * sny + (cj - sj0)) * snz + (ck - sk0)  # bit of (ci, cj, ck) when in the box
        lsx, lsy, lsz = si * sny * snz, sj * snz, sk
        while True:
            # the voxel (ci, cj, ck) is on the ray and is not the end voxel: a miss, unless this
            # frame updated it already
            if seen is None:  # the sparse bitmap (numba compiles this loop twice: seen None or not)
                first = _sparse_visit(ci, cj, ck, sp_keys, sp_gen, sp_vals, sp_words, seen_meta, sp_cache)
                if first < 0:
                    seen_meta[SEEN_GROW] = GROW_SPARSE
                    state[FV_RAY], state[FV_MISSES] = r, n_miss
                    return False
            else:  # the dense one; outside its box (a ray's last steps past its end voxel, rare) a
                # voxel is listed at each step: apply_voxels drops those repeats by their stamps
                first = 1
                if (np.uint64(ci - si0) < usnx) & (np.uint64(cj - sj0) < usny) & (np.uint64(ck - sk0) < usnz):
                    if _seen_bit(seen, lin):
                        first = 0
                    else:
                        seen[lin >> 6] |= np.uint64(1) << np.uint64(lin & 63)
            if first > 0:
                misses[n_miss] = pack_block(ci, cj, ck)
                n_miss += 1
            dim, ci, cj, ck, tmx, tmy, tmz, steps, more = ray_step(ci, cj, ck, tmx, tmy, tmz, si, sj, sk, tdx, tdy, tdz,
                                                                   ei, ej, ek, length, steps, max_steps)  # fmt: skip
            lin += lsx if dim == 0 else (lsy if dim == 1 else lsz)
            if not more:
                break
    state[FV_RAY], state[FV_MISSES] = n, n_miss
    return True


@njit(cache=True, nogil=True, inline="always")
def _count_free(nfree, still, b, off, now_free, now_still, changed, n_ch):
    """The voxel at ``off`` of O block b became clamped free (``now_free``) or left it: its
    quarter's count follows, and the block is appended to ``changed`` when that count reaches
    or leaves 64; its bit in ``still`` (B, 8) is set when it is still now (``now_still``:
    clamped free, no ST or LT), else cleared. Returns the new length of ``changed``. (Only on
    such a change, so rare that the call costs nothing; the per-voxel update around it is
    written out in each kernel.)"""
    bit = np.uint64(1) << np.uint64(off & 63)
    if now_still:
        still[b, off >> 6] |= bit
    else:
        still[b, off >> 6] &= ~bit
    qi = quarter_of(off)
    if now_free:
        nfree[b, qi] += 1
        if nfree[b, qi] == QUARTER_VOXELS:
            changed[n_ch] = b
            n_ch += 1
    else:
        if nfree[b, qi] == QUARTER_VOXELS:
            changed[n_ch] = b
            n_ch += 1
        nfree[b, qi] -= 1
    return n_ch


@njit(cache=True, nogil=True)
def apply_mask_updates(
    bkeys, masks, start, hit,
    table_keys, table_vals, block_coords, meta, logodds, stamp, hit_mark,
    frame_id, tick_first, tb_block, tb_off, tb_meta,
    hit_lo, miss_lo, lo_min, lo_max, counters,
    nfree, qquiet, still_bits, use_quiet, changed, ch_meta, d_keys, d_vals, d_st, d_lt,
):  # fmt: skip
    """The misses (``hit`` False) or the hits (True) of blocks given as bit masks (``bkeys``
    packed block keys, ``masks`` (B, 8) uint64: bit ``off`` of a block's 512, in key order,
    offsets ascending): what ``apply_voxels_kernel`` does with those voxels listed as keys in
    that order (phase 1, or phase 0), the same updates in the same order, block by block without
    listing them (a depth frame's projection: 2.3x less time than listing and applying the keys).
    From block ``start``; returns (status, block to go on from). A block is done whole: room for
    its 512 voxels in the tick buffer and eight entries in ``changed`` is made sure of first
    (misses only raise a quarter's count of clamped-free voxels and hits only lower it, so each
    of the eight crosses 64 at most once a call). The misses of quiet quarters and of the voxels
    set in ``still_bits`` are dropped a word at a time (``QUARTER_KEEP``; a still voxel's miss
    changes nothing: the tails' misses there made this kernel take 1.33x its time), and so is the miss
    of a still voxel whose bit is not set (``use_quiet``: clamped free, no ST or LT in D's
    ``d_st``, ``d_lt``; as ``apply_voxels_kernel``) voxel by voxel. The per-voxel update is
    written out here as in
    ``apply_voxels_kernel``: numba's call to a shared helper, even inline="always", took 3x the
    time of the update itself."""
    lo = np.float32(hit_lo) if hit else np.float32(miss_lo)
    lo_min32 = np.float32(lo_min)
    lo_max32 = np.float32(lo_max)
    n_tb = tb_meta[0]
    tb_cap = tb_block.shape[0]
    n_ch = ch_meta[0]
    ch_cap = changed.shape[0]
    n_done = 0
    for t in range(start, bkeys.shape[0]):
        if n_tb + BLOCK_VOXELS > tb_cap or (use_quiet and n_ch + 8 > ch_cap):
            tb_meta[0] = n_tb
            ch_meta[0] = n_ch
            counters[0 if hit else 1] += n_done
            return STATUS_NEED_TICK_BUFFER if n_tb + BLOCK_VOXELS > tb_cap else STATUS_NEED_CHANGED, t
        bx, by, bz = unpack_block(bkeys[t])
        b = get_or_add_block(table_keys, table_vals, block_coords, meta, bx, by, bz)
        if b < 0:
            tb_meta[0] = n_tb
            ch_meta[0] = n_ch
            counters[0 if hit else 1] += n_done
            return STATUS_NEED_BLOCKS, t
        qq = np.int64(qquiet[b]) if use_quiet and not hit else np.int64(0)
        if qq == QUIET_ALL:
            continue
        still = use_quiet and not hit
        db = find_block(d_keys, d_vals, bx, by, bz) if still else np.int64(-1)
        for wd in range(8):
            word = masks[t, wd]
            if qq != 0:
                word &= QUARTER_KEEP[(qq >> ((wd >> 2) << 2)) & 15]
            if still:  # the voxels known still (their bits: no other voxel's is set) a word at a time
                word &= ~still_bits[b, wd]
            while word != 0:  # the set bits, lowest first: each found by a de Bruijn multiply
                low = word & (~word + np.uint64(1))
                word ^= low
                off = wd * 64 + _DEBRUIJN_BIT[(low * _DEBRUIJN) >> np.uint64(58)]
                st = stamp[b, off]
                if st == frame_id:
                    continue
                old = logodds[b, off]
                if still and old == lo_min32 and (db < 0 or (d_st[db, off] == 0.0 and d_lt[db, off] == 0.0)):
                    continue
                if st < tick_first:
                    tb_block[n_tb] = b
                    tb_off[n_tb] = off
                    n_tb += 1
                v = old + lo
                if hit:
                    v = lo_max32 if v > lo_max32 else v
                    hit_mark[b, off] = 1
                else:
                    v = lo_min32 if v < lo_min32 else v
                logodds[b, off] = v
                stamp[b, off] = frame_id
                n_done += 1
                if use_quiet and (old == lo_min32) != (v == lo_min32):
                    now_still = v == lo_min32 and (db < 0 or (d_st[db, off] == 0.0 and d_lt[db, off] == 0.0))
                    n_ch = _count_free(nfree, still_bits, b, off, v == lo_min32, now_still, changed, n_ch)
    tb_meta[0] = n_tb
    ch_meta[0] = n_ch
    counters[0 if hit else 1] += n_done
    return STATUS_DONE, -1


@njit(cache=True, nogil=True)
def apply_voxels_kernel(
    hits, misses,
    table_keys, table_vals, block_coords, meta, logodds, stamp, hit_mark,
    frame_id, tick_first, tb_block, tb_off, tb_meta,
    hit_lo, miss_lo, lo_min, lo_max,
    phase, start, counters,
    nfree, qquiet, still_bits, use_quiet, changed, ch_meta, d_keys, d_vals, d_st, d_lt,
):  # fmt: skip
    """Give the voxels of ``frame_voxels`` their update, hits (phase 0) then misses (phase 1),
    from (phase, start). Returns (status, phase, index); on a status other than DONE the caller
    grows storage and calls again from there. A voxel whose stamp is this frame's was updated
    already: it is left alone (``frame_voxels`` lists each voxel once, so this is a guard), so
    each voxel is updated once per frame and a hit wins over a miss. A hit also sets
    ``hit_mark`` (O's ``hit`` channel: hit in this tick; the tick rules read and clear it).
    ``counters`` accumulates [hits applied, misses applied].

    Quiet quarters (``use_quiet``): ``nfree[b, q]`` counts the voxels of quarter q of O block b
    at ``lo_min`` (clamped free), kept here; ``qquiet[b]`` (bit q set by ``quiet_update`` between
    frames: the quarter's 64 voxels clamped free, none with ST or LT) is read as it was when the
    frame began. A miss in a quiet quarter is no update: its log-odds would stay at ``lo_min``,
    and the tick rules have nothing to do for a clamped-free voxel without ST or LT, so it is
    neither stamped nor put in the tick buffer. So is a miss on a still voxel in any quarter: one
    clamped free with no ST or LT (D's ``d_st``, ``d_lt``; no D block: none), the same rule a
    voxel at a time (a 2D laser scan fills one voxel layer of a quarter's four: its quarters are
    never quiet). Blocks of a quarter whose count reached or left 64 are appended to ``changed``
    (``ch_meta[0]`` of them) for ``quiet_update``."""
    hit_lo32 = np.float32(hit_lo)
    miss_lo32 = np.float32(miss_lo)
    lo_min32 = np.float32(lo_min)
    lo_max32 = np.float32(lo_max)
    n_tb = tb_meta[0]
    tb_cap = tb_block.shape[0]
    n_ch = ch_meta[0]
    ch_cap = changed.shape[0]
    last_bx = np.int64(-(1 << 40))
    last_by = np.int64(0)
    last_bz = np.int64(0)
    last_b = np.int64(-1)
    last_qq = np.int64(0)
    last_db = np.int64(-1)
    while phase < 2:
        keys = hits if phase == 0 else misses
        lo = hit_lo32 if phase == 0 else miss_lo32
        n_done = 0
        for r in range(start, keys.shape[0]):
            key = keys[r]
            i, j, k = unpack_block(key)
            bx, by, bz = i >> BLOCK_BITS, j >> BLOCK_BITS, k >> BLOCK_BITS
            if bx != last_bx or by != last_by or bz != last_bz or last_b < 0:
                last_b = get_or_add_block(table_keys, table_vals, block_coords, meta, bx, by, bz)
                last_bx, last_by, last_bz = bx, by, bz
                if last_b < 0:
                    tb_meta[0] = n_tb
                    ch_meta[0] = n_ch
                    counters[phase] += n_done
                    return STATUS_NEED_BLOCKS, phase, r
                last_qq = np.int64(qquiet[last_b]) if use_quiet and phase == 1 else np.int64(0)
                last_db = find_block(d_keys, d_vals, bx, by, bz) if use_quiet and phase == 1 else np.int64(-1)
            if last_qq == QUIET_ALL:
                continue
            off = voxel_offset(i, j, k)
            if last_qq != 0 and (last_qq >> quarter_of(off)) & 1:
                continue
            st = stamp[last_b, off]
            if st == frame_id:
                continue
            old = logodds[last_b, off]
            if (use_quiet and phase == 1 and old == lo_min32
                    and (last_db < 0 or (d_st[last_db, off] == 0.0 and d_lt[last_db, off] == 0.0))):  # fmt: skip
                continue  # a still voxel
            if use_quiet and n_ch >= ch_cap:  # before anything of voxel r is written: it is done again
                tb_meta[0] = n_tb
                ch_meta[0] = n_ch
                counters[phase] += n_done
                return STATUS_NEED_CHANGED, phase, r
            if st < tick_first:
                if n_tb >= tb_cap:
                    tb_meta[0] = n_tb
                    ch_meta[0] = n_ch
                    counters[phase] += n_done
                    return STATUS_NEED_TICK_BUFFER, phase, r
                tb_block[n_tb] = last_b
                tb_off[n_tb] = off
                n_tb += 1
            v = old + lo
            if phase == 0:
                v = lo_max32 if v > lo_max32 else v
                hit_mark[last_b, off] = 1
            else:
                v = lo_min32 if v < lo_min32 else v
            logodds[last_b, off] = v
            stamp[last_b, off] = frame_id
            n_done += 1
            if use_quiet and (old == lo_min32) != (v == lo_min32):
                now_still = v == lo_min32 and (last_db < 0 or (d_st[last_db, off] == 0.0 and d_lt[last_db, off] == 0.0))
                n_ch = _count_free(nfree, still_bits, last_b, off, v == lo_min32, now_still, changed, n_ch)
        counters[phase] += n_done
        phase += 1
        start = 0
        last_b = np.int64(-1)
    tb_meta[0] = n_tb
    ch_meta[0] = n_ch
    return STATUS_DONE, 2, 0


@helper()
def _quiet_quarters(b, want, nfree, block_coords, d_keys, d_vals, st, lt):
    """Of the quarters ``want`` (bits) of O block b, those quiet: all 64 voxels clamped free
    (``nfree[b, q] == 64``) and none with ST or LT (no D block there, or its voxels' ST and LT 0
    in that quarter: something seen there once, a person walking through, and gone since)."""
    full = np.int64(0)
    for q in range(8):
        if (want >> q) & 1 and nfree[b, q] == QUARTER_VOXELS:
            full |= np.int64(1) << q
    if full == 0:
        return full
    db = find_block(d_keys, d_vals, np.int64(block_coords[b, 0]), np.int64(block_coords[b, 1]),
                    np.int64(block_coords[b, 2]))  # (int64: one find_block compiled, not one per int width)
    if db < 0:
        return full
    for q in range(8):
        if not (full >> q) & 1:
            continue
        a0, c0, e0 = (q >> 2) * 4, ((q >> 1) & 1) * 4, (q & 1) * 4
        clear = True
        for a in range(a0, a0 + 4):
            for c in range(c0, c0 + 4):
                base = a * 64 + c * 8 + e0
                for e in range(4):
                    if st[db, base + e] != 0.0 or lt[db, base + e] != 0.0:
                        clear = False
        if not clear:
            full &= ~(np.int64(1) << q)
    return full


@njit(cache=True, nogil=True)
def quiet_update(blocks, n, nfree, qquiet, block_coords, d_keys, d_vals, st, lt):
    """Set the quiet quarters ``qquiet[b]`` (``_quiet_quarters``; the block is quiet when all
    eight are: ``QUIET_ALL``) of the O blocks ``blocks[:n]``."""
    every = np.int64(QUIET_ALL)  # (not the literal: numba would compile _quiet_quarters once more for it)
    for t in range(n):
        b = blocks[t]
        qquiet[b] = _quiet_quarters(b, every, nfree, block_coords, d_keys, d_vals, st, lt)


@njit(cache=True, nogil=True)
def quiet_after_tick(n_blocks, nfree, qquiet, block_coords, d_keys, d_vals, st, lt):
    """After a tick: the quarters all clamped free that were not quiet for their ST or LT and
    have none left (the tick rules lowered them to 0) are quiet (a quiet quarter stays so: the
    tick rules do nothing there). Returns how many blocks gained quiet quarters."""
    n = 0
    for b in range(n_blocks):
        qq = np.int64(qquiet[b])
        if qq == QUIET_ALL:
            continue
        want = QUIET_ALL & ~qq
        for q in range(8):
            if (want >> q) & 1 and nfree[b, q] != QUARTER_VOXELS:
                want &= ~(np.int64(1) << q)
        if want == 0:
            continue
        got = _quiet_quarters(b, want, nfree, block_coords, d_keys, d_vals, st, lt)
        if got != 0:
            qquiet[b] = qq | got
            n += 1
    return n


@njit(cache=True, nogil=True)
def quiet_count(logodds, n_blocks, lo_min, nfree, still, block_coords, d_keys, d_vals, st, lt):
    """``nfree[b, q]``: voxels of quarter q of block b at ``lo_min``, for the first ``n_blocks``
    blocks; ``still[b]`` (8 words, ``voxel_offset`` bits): those with no ST or LT."""
    lo32 = np.float32(lo_min)
    for b in range(n_blocks):
        for q in range(8):
            nfree[b, q] = 0
        for w in range(8):
            still[b, w] = 0
        db = find_block(d_keys, d_vals, np.int64(block_coords[b, 0]), np.int64(block_coords[b, 1]),
                        np.int64(block_coords[b, 2]))  # (int64: one find_block compiled, not one per int width)
        for off in range(BLOCK_VOXELS):
            if logodds[b, off] == lo32:
                nfree[b, quarter_of(off)] += 1
                if db < 0 or (st[db, off] == 0.0 and lt[db, off] == 0.0):
                    still[b, off >> 6] |= np.uint64(1) << np.uint64(off & 63)


@njit(cache=True, nogil=True)
def still_clear(d_from, d_n, d_coords, st, lt, o_keys, o_vals, still):
    """Clear the ``still`` bits (``quiet_count``) of the voxels with ST or LT in D blocks
    ``d_from`` to ``d_n`` - 1 (LT seeded into them, or D replaced)."""
    for db in range(d_from, d_n):
        ob = find_block(o_keys, o_vals, np.int64(d_coords[db, 0]), np.int64(d_coords[db, 1]), np.int64(d_coords[db, 2]))
        if ob < 0:
            continue
        for off in range(BLOCK_VOXELS):
            if st[db, off] != 0.0 or lt[db, off] != 0.0:
                still[ob, off >> 6] &= ~(np.uint64(1) << np.uint64(off & 63))


# the dedupe key of an invalid pixel (and an empty slot of the dedupe set): never a voxel's, whose
# keys are within +-KEY_LIMIT (-1 would need z = 2^20 - 1)
NO_KEY = -1


@njit(cache=True, nogil=True, inline="always")
def _dedupe_key(i, j, k, hit):
    """The key of one ray in the end-point dedupe: its end voxel and whether it is a hit."""
    return pack_block(i, j, k) * 2 + (1 if hit else 0)


# a dedupe key's voxel key with the low BLOCK_BITS of each coordinate cleared: its block's key
_DEDUPE_BLOCK_KEEP = ~np.int64(
    (BLOCK_MASK << (2 * _PACK_BITS)) | (BLOCK_MASK << _PACK_BITS) | BLOCK_MASK
)  # fmt: skip
DEDUPE_BLOCK_WORDS = 2 * BLOCK_VOXELS // 64  # a block's dedupe bits: two a voxel (clear, hit)
DEDUPE_DONE, DEDUPE_FULL, DEDUPE_BLOCKS = range(3)  # how a pass of _depth_rays_pass ended


@njit(cache=True, nogil=True, inline="always")
def _dedupe_block(key):
    """(the block's key, the bit) of dedupe key ``key`` (``_dedupe_key``) in a block's
    ``DEDUPE_BLOCK_WORDS`` words: two bits a voxel, in ``voxel_offset`` order."""
    v = key >> 1
    m = np.int64(BLOCK_MASK)
    off = voxel_offset((v >> (2 * _PACK_BITS)) & m, (v >> _PACK_BITS) & m, v & m)
    return v & _DEDUPE_BLOCK_KEEP, (off << 1) | (key & 1)


@njit(cache=True, nogil=True)
def dedupe_endpoints(ends, kind, inv_res):
    """Keep one ray per (end voxel, kind): later duplicates become RAY_SKIP (in place).

    OctoMap's ``discretize`` idea for dense depth images and clouds, where tens of pixels end in
    the same voxel; the first ray to a voxel is kept with its exact end point. Returns the number
    of rays dropped."""
    n = ends.shape[0]
    cap = 16
    while cap < 2 * n:
        cap *= 2
    mask = cap - 1
    table = np.full(cap, -1, dtype=np.int64)
    dropped = 0
    for r in range(n):
        kd = kind[r]
        if kd == RAY_SKIP:
            continue
        i = np.int64(np.floor(ends[r, 0] * inv_res))
        j = np.int64(np.floor(ends[r, 1] * inv_res))
        k = np.int64(np.floor(ends[r, 2] * inv_res))
        packed = _dedupe_key(i, j, k, kd == RAY_HIT)
        s = _slot(packed, mask)
        while True:
            t = table[s]
            if t == packed:
                kind[r] = RAY_SKIP
                dropped += 1
                break
            if t == -1:
                table[s] = packed
                break
            s = (s + 1) & mask
    return dropped


ROW_PAD = 16  # float64s between the depth kernel's row buffers (128 bytes)


@njit(cache=True, nogil=True, error_model="numpy")
def _depth_rays_pass(
    depth, unit_mm, fx, fy, cx, cy, T,
    max_range, ground_tol, fp_inv, fp_min, fp_max, use_fp,
    dedupe, inv_res, cap, by_block,
):  # fmt: skip
    """``depth_image_rays`` with a dedupe set of ``cap`` slots: (ends, kind, ``DEDUPE_DONE``), or
    (empty, empty, ``DEDUPE_FULL``) when cap / 2 end voxels are kept and a pixel is still to look
    up, or (empty, empty, ``DEDUPE_BLOCKS``) when ``by_block`` and the end voxels lie in more
    than cap / 16 blocks.

    Row by row in two passes. The first has no branches, so the compiler vectorizes it (hence
    ``error_model="numpy"``: no zero-division checks): every pixel's end point, its kind and its
    dedupe key, with the arithmetic of ``classify_rays`` and ``dedupe_endpoints``; it counts the
    pixels whose ray may be longer than max_range, and only a row with some walks its pixels
    again for the max-range cut (its square root and division, computed for every pixel, were a
    third of the pass). It also marks the pixels whose key equals that of one of the three pixels
    before it or of the five nearest above it (near the row's ends: those that exist): those keys
    are in the dedupe set already, so the pixel adds nothing (an invalid pixel's key is
    ``NO_KEY``, which no voxel's equals: the comparisons need no validity flags beside the keys,
    and with int64 keys only they vectorize better; 0.89x of the kernel's time on room, hall and
    office frames). The second pass walks the row's
    other pixels in order (an index list, no branch per pixel) and looks them up: the set sees
    the same keys in the same order minus repeats, so the rays kept (the first per key) are the
    same, in the same order. About 4x faster than one branchy loop over the pixels (4.4 -> 1.2 ms
    for a 640x480 frame of the bench log).

    With ``by_block`` the set holds the end voxels' blocks (a hash table of block keys, at most
    half full) and a row of bits per block, two a voxel (``_dedupe_block``); a pixel looks its
    block up only when it is not the previous pixel's, and sets its bit with no branch on whether
    it was set: the ray is stored either way and counted only when new. The set of the voxels'
    keys, probed by every pixel (without ``by_block``), took 1.12x the kernel's time (room, hall
    and office frames); it is kept for frames whose end voxels are spread over many blocks
    (noise), where 128 bytes of bits a block took 2.8x the memory (a 1280x720 frame of noise:
    623 k blocks, 130 MB against 46 MB).
    """
    h, w = depth.shape
    n_max = cap // 2 if dedupe else h * w  # with dedupe, at most half the set's slots are kept
    ends = np.empty((n_max, 3), dtype=np.float64)
    kind = np.empty(n_max, dtype=np.int8)
    ox, oy, oz = T[0, 3], T[1, 3], T[2, 3]
    t00, t01, t02, t03 = T[0, 0], T[0, 1], T[0, 2], T[0, 3]
    t10, t11, t12, t13 = T[1, 0], T[1, 1], T[1, 2], T[1, 3]
    t20, t21, t22, t23 = T[2, 0], T[2, 1], T[2, 2], T[2, 3]
    f00, f01, f02, f03 = fp_inv[0, 0], fp_inv[0, 1], fp_inv[0, 2], fp_inv[0, 3]
    f10, f11, f12, f13 = fp_inv[1, 0], fp_inv[1, 1], fp_inv[1, 2], fp_inv[1, 3]
    f20, f21, f22, f23 = fp_inv[2, 0], fp_inv[2, 1], fp_inv[2, 2], fp_inv[2, 3]
    bx0, by0, bz0 = fp_min[0], fp_min[1], fp_min[2]
    bx1, by1, bz1 = fp_max[0], fp_max[1], fp_max[2]
    # the dedupe set: the end voxels' blocks (a hash table of their keys -> a row of bits),
    # and the blocks' rows (allocated for the most blocks the set may hold, touched as used)
    table = np.full(cap, -1, dtype=np.int64)
    table_row = np.empty(cap if by_block else 0, dtype=np.int64)
    # rows used at most: 8 bytes a slot, as the table's (allocated for cap / 2, touched as used:
    # allocated for cap / 16, the kernel took 1.0x to 1.15x the time of the set of voxels' keys
    # on room and hall frames, against 0.88x to 0.92x; measured, not explained)
    rows_max = cap // 16 if by_block else 0
    bits = np.empty((cap // 2 if by_block else 0, DEDUPE_BLOCK_WORDS), dtype=np.uint64)
    n_rows = 0
    mask = cap - 1
    last_block = np.int64(-1)
    brow = np.int64(0)
    m = 0
    mm = np.float32(0.001)
    # the float rows in one block, at fixed offsets from each other. With the cut out of pass 1,
    # the kernel took 0.59x to 0.69x of its time before in every process so; with each row
    # allocated on its own, 1.4x to 1.75x in some processes (AMD Zen 3: the offsets malloc gave)
    row = w + ROW_PAD
    blk = np.empty(4 * row, dtype=np.float64)
    xr = blk[0:w]  # (u - cx) / fx, as depth_to_points computes it
    for u in range(w):
        xr[u] = (np.float64(u) - cx) / fx
    # a ray is cut only beyond max_range: below this squared length it surely is not (no sqrt)
    safe2 = (max_range * (1.0 - 1e-9)) ** 2 if max_range > 0.0 else np.inf
    use_ground = ground_tol >= 0.0
    # the robot's footprint box: a point in it is at most the distance from the camera to the
    # box's farthest corner (a box is convex), and a pixel's range is at least its depth z, so
    # a pixel deeper than zfp is surely not in it (pass 1 compares z alone; pass 1a tests the
    # rows with nearer pixels: the box's test on every pixel was 0.29 of pass 1's 1.02 ms)
    zfp = -np.inf
    if use_fp:
        cx_r = f00 * ox + f01 * oy + f02 * oz + f03  # the camera in the robot's frame
        cy_r = f10 * ox + f11 * oy + f12 * oz + f13
        cz_r = f20 * ox + f21 * oy + f22 * oz + f23
        far2 = max((bx0 - cx_r) ** 2, (bx1 - cx_r) ** 2) + max((by0 - cy_r) ** 2, (by1 - cy_r) ** 2) \
            + max((bz0 - cz_r) ** 2, (bz1 - cz_r) ** 2)
        zfp = np.sqrt(far2) * (1.0 + 1e-6) + 1e-6
    # row buffers: end point, kind, dedupe key (NO_KEY: no ray); the row above's keys; pixels to look up
    rx = blk[row : row + w]
    ry = blk[2 * row : 2 * row + w]
    rz = blk[3 * row : 3 * row + w]
    rkind = np.empty(w, dtype=np.int8)
    key = np.empty(w, dtype=np.int64)
    key_up = np.full(w, NO_KEY, dtype=np.int64)  # (the first row has none above)
    look = np.empty(w, dtype=np.bool_)
    idx = np.empty(w, dtype=np.int64)
    for v in range(h):
        yv = (np.float64(v) - cy) / fy
        n_far = np.int32(0)  # the row's pixels that may be beyond max_range (an integer sum vectorizes)
        n_near = np.int32(0)  # ... and those that may be in the robot's footprint box
        for u in range(w):  # pass 1: no branches
            raw = depth[v, u]
            if unit_mm:
                z32 = np.float32(raw) * mm
                valid = raw != 0
            else:
                z32 = np.float32(raw)
                valid = np.isfinite(z32) and z32 > 0
            z = np.float64(z32)
            x = xr[u] * z
            y = yv * z
            px = t00 * x + t01 * y + t02 * z + t03
            py = t10 * x + t11 * y + t12 * z + t13
            pz = t20 * x + t21 * y + t22 * z + t23
            valid = valid & np.isfinite(px) & np.isfinite(py) & np.isfinite(pz)
            dx, dy, dz = px - ox, py - oy, pz - oz
            # (a hole, NaN in 32FC1, has no key: the cut skips it; counted, a float image's holes
            # sent nearly every row through the cut's walk: 0.5 ms of a frame with 4 % holes)
            n_far += np.int32(valid & (not (dx * dx + dy * dy + dz * dz < safe2)))
            n_near += np.int32(valid & (z <= zfp))  # (a hole's z is 0)
            hit = not (use_ground & (abs(pz) <= ground_tol))  # (the footprint box: pass 1a)
            # the voxel through int32 (keys are within +-2^20): AVX2 has no vector conversion of
            # doubles to int64, so int64 here made the loop convert one lane at a time (10 % of
            # the kernel on an AMD Zen 3)
            i = np.int32(np.floor(px * inv_res))
            j = np.int32(np.floor(py * inv_res))
            k = np.int32(np.floor(pz * inv_res))
            rx[u] = px
            ry[u] = py
            rz[u] = pz
            rkind[u] = RAY_HIT if hit else RAY_CLEAR
            key[u] = _dedupe_key(i, j, k, hit) if valid else NO_KEY
        # pass 1a, on the rows that may hold a pixel in the footprint box or beyond max_range: the
        # box's test of classify_rays (a ray ending in the robot marks nothing: clear), then its
        # max-range cut (computed for every pixel, its square root and division were a third of
        # pass 1 on an AMD Zen 3): a cut ray ends at max_range and marks nothing
        if n_near > 0:
            for u in range(w):  # no branches (vectorized); a hit's key is its clear key + 1 (_dedupe_key)
                px, py, pz = rx[u], ry[u], rz[u]
                lx = f00 * px + f01 * py + f02 * pz + f03
                ly = f10 * px + f11 * py + f12 * pz + f13
                lz = f20 * px + f21 * py + f22 * pz + f23
                in_fp = (bx0 <= lx) & (lx <= bx1) & (by0 <= ly) & (ly <= by1) & (bz0 <= lz) & (lz <= bz1)
                kd = rkind[u]
                kk = key[u]
                ch = in_fp & (kd == RAY_HIT) & (kk != NO_KEY)
                rkind[u] = RAY_CLEAR if ch else kd
                key[u] = kk - np.int64(ch)
        if n_far > 0:
            for u in range(w):
                px, py, pz = rx[u], ry[u], rz[u]
                dx, dy, dz = px - ox, py - oy, pz - oz
                d2 = dx * dx + dy * dy + dz * dz
                if d2 < safe2 or key[u] == NO_KEY:
                    continue
                length = np.sqrt(d2)
                if not (max_range > 0.0 and length > max_range):
                    continue
                sc = max_range / length
                px, py, pz = ox + dx * sc, oy + dy * sc, oz + dz * sc
                rx[u] = px
                ry[u] = py
                rz[u] = pz
                rkind[u] = RAY_CLEAR
                key[u] = _dedupe_key(np.int32(np.floor(px * inv_res)), np.int32(np.floor(py * inv_res)),
                                     np.int32(np.floor(pz * inv_res)), False)  # fmt: skip
        if dedupe:  # pass 1b: pixels whose key is surely in the set already
            for u in range(3, w - 2):  # every neighbour exists: no branches (vectorized)
                kk = key[u]
                rep = (key_up[u] == kk) | (key[u - 1] == kk) | (key[u - 2] == kk) | (key[u - 3] == kk)
                rep = rep | (key_up[u - 1] == kk) | (key_up[u + 1] == kk) | (key_up[u - 2] == kk) | (key_up[u + 2] == kk)
                look[u] = (kk != NO_KEY) & ~rep
            for e in range(5):  # the row's ends (0, 1, 2, w - 2, w - 1): the pixel above, those before
                u = e if e < 3 else w - 5 + e
                if u >= w or u < 0 or (e >= 3 and u < 3):  # out of the row, or done as one of 0, 1, 2
                    continue
                kk = key[u]
                rep = key_up[u] == kk
                for d in range(1, min(u, 3) + 1):
                    rep = rep | (key[u - d] == kk)
                look[u] = (kk != NO_KEY) & ~rep
        else:  # (a loop: a slice copy would compile numba's shape-mismatch error path, 2 s)
            for u in range(w):
                look[u] = key[u] != NO_KEY
        n_look = 0
        for u in range(w):  # the pixels left, in order (no branch)
            idx[n_look] = u
            n_look += np.int64(look[u])
        for q in range(n_look):  # pass 2: in order, the pixels left
            u = idx[q]
            new = np.int64(1)
            if dedupe and 2 * (m + 1) > cap:  # the set is half full: start again, 4x bigger
                return ends[:0], kind[:0], DEDUPE_FULL
            if dedupe and not by_block:  # the key in the set of voxels
                packed = key[u]
                s = _slot(packed, mask)
                while True:
                    t = table[s]
                    if t == packed:
                        new = 0
                        break
                    if t == -1:
                        table[s] = packed
                        break
                    s = (s + 1) & mask
            elif dedupe:  # the key's bit in its block's row (a row found again only when the block changes)
                blk, bit = _dedupe_block(key[u])
                if blk != last_block:
                    s = _slot(blk, mask)
                    while True:
                        t = table[s]
                        if t == blk:
                            brow = table_row[s]
                            break
                        if t == -1:
                            if n_rows == rows_max:  # spread over too many blocks: start again, by voxel
                                return ends[:0], kind[:0], DEDUPE_BLOCKS
                            table[s] = blk
                            table_row[s] = n_rows
                            brow = n_rows
                            for wd in range(DEDUPE_BLOCK_WORDS):
                                bits[brow, wd] = 0
                            n_rows += 1
                            break
                        s = (s + 1) & mask
                    last_block = blk
                # set it, and keep the ray only when it was not (stored either way: no branch on
                # whether it was, which the CPU mispredicts; 0.88x of the kernel's time)
                was = bits[brow, bit >> 6]
                b1 = np.uint64(1) << np.uint64(bit & 63)
                bits[brow, bit >> 6] = was | b1
                new = np.int64((was & b1) == 0)
            ends[m, 0] = rx[u]
            ends[m, 1] = ry[u]
            ends[m, 2] = rz[u]
            kind[m] = rkind[u]
            m += new
        key, key_up = key_up, key
    return ends[:m], kind[:m], DEDUPE_DONE


@njit(cache=True, nogil=True)
def depth_image_rays(
    depth, unit_mm, fx, fy, cx, cy, T,
    max_range, ground_tol, fp_inv, fp_min, fp_max, use_fp,
    dedupe, inv_res, cap,
):  # fmt: skip
    """One depth image straight to the rays ``frame_voxels`` casts: (ends (M, 3), kind (M,)).

    Fuses ``depth_metres`` + ``depth_to_points`` + ``transform_points`` + ``classify_rays`` +
    ``dedupe_endpoints`` with the same arithmetic in the same order, so the rays are bit for bit
    those of the separate steps (minus the RAY_SKIP entries, which ``frame_voxels`` ignores).

    depth: (H, W) raw pixels, uint16 millimetres (``unit_mm``, 0 invalid) or float32 metres (NaN /
    <= 0 invalid); T: 4x4 optical frame -> fixed frame. The dedupe set is sized by the voxels
    kept (a few ten thousand), not by the pixels: ``cap`` slots (a power of two,
    ``depth_rays_cap``: from the previous frame's count) for the end voxels' blocks, and rows of
    bits for up to cap / 16 blocks, touched as used; a frame with more end voxels than it holds
    is done again with a set 4x bigger (the pass stops when the set is half full, so a cap too
    small costs up to a whole pass: 1.2 of 3.6 ms on a room frame of 24 k end voxels), and one
    with more blocks, with a set of the voxels' keys (``_depth_rays_pass``). A pixel that ends
    in the same voxel as one of its neighbours before it skips the lookup.
    """
    by_block = np.bool_(True)  # (not the literal: numba would compile _depth_rays_pass once more for it, 2 s)
    while True:
        ends, kind, status = _depth_rays_pass(depth, unit_mm, fx, fy, cx, cy, T, max_range, ground_tol, fp_inv,
                                              fp_min, fp_max, use_fp, dedupe, inv_res, cap, by_block)  # fmt: skip
        if status == DEDUPE_DONE:
            return ends, kind
        if status == DEDUPE_FULL:
            cap *= 4
        else:
            by_block = False


DEPTH_CAP_MIN = 1 << 15  # the least dedupe set of depth_image_rays (slots)


def depth_rays_cap(n_ends: int, pixels: int) -> int:
    """The dedupe set for the frame after one that kept ``n_ends`` rays: a quarter full (the next
    may keep twice as many without a second pass; a bigger set costs little, 2.25 -> 2.26 ms), and
    no bigger than an image of ``pixels`` pixels can fill (a frame of noise, every pixel its own
    voxel, must not make the next frames' sets 4x its pixels)."""
    cap = DEPTH_CAP_MIN
    while 4 * n_ends > cap and cap < 2 * (pixels + 1):
        cap *= 2
    return cap


@njit(cache=True, nogil=True)
def transform_points_kernel(T, points):
    """``T`` (4x4) applied to points (N, 3), row by row as ``T[r,0] x + T[r,1] y + T[r,2] z + T[r,3]``
    (the arithmetic of ``depth_image_rays`` and ``core.sensors.transform_points``)."""
    n = points.shape[0]
    out = np.empty((n, 3), dtype=np.float64)
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        out[i, 0] = T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3]
        out[i, 1] = T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3]
        out[i, 2] = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
    return out
