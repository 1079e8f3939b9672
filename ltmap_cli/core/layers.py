"""The layered map: S (static), O (sensor log-odds), ST (short-term), LT (long-term).

SPEC 2.2. ``LayeredMap.integrate`` fuses one sensor frame into O; ``LayeredMap.end_tick``
applies the tick rules to every voxel some frame of the tick observed:

- obstacle: O occupied (log-odds > 0), some frame of this tick hit the voxel, and S has no
  occupied voxel within ``static_margin``;
- seen free: O free (log-odds < 0);
- held: O occupied but the voxel was only missed in this tick (an object just removed: O needs
  several misses to turn free): ST and LT keep their values, so nothing rises from a stale O.

ST rises by ``tick / st_rise_s`` for obstacles and falls by ``tick / st_fall_s`` for voxels seen
free, clamped to [0, 1]; a voxel not observed as an obstacle for ``st_forget_s`` drops to 0.
A voxel whose ST reaches 1 is set to LT = 1; a voxel with LT > 0 seen free while ST == 0 falls
by ``tick / lt_fall_s``. A voxel that is not observed keeps its LT value for ever.
F = max(S, LT) and its projection P are computed by ``ltmap_cli.core.projection``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..errors import CoreError
from ..jit import njit
from .config import MapConfig
from .grid import (
    BLOCK,
    BLOCK_BITS,
    BLOCK_MASK,
    VoxelGrid,
    band_k_range,
    find_block,
    get_or_add_block,
    voxel_offset,
)
from .projective import (
    LISTED_VOXELS_MAX_BLOCKS,
    PROJECTIVE_CHUNK_BLOCKS,
    TAIL_BITMAP_MAX_BLOCKS,
    TAIL_OVERLAP_VOXELS,
    depth_projection_blocks,
    ends_box,
    pixel_range_factors,
    projective_blocks,
    projective_refill,
    tail_masks,
)
from .raycast import (
    DEPTH_CAP_MIN,
    FV_HITS,
    FV_MISSES,
    FV_PHASE,
    FV_STATE_SLOTS,
    GROW_DENSE,
    GROW_MISSES,
    QUIET_ALL,
    SEEN_GROW,
    SEEN_I0,
    SEEN_K0,
    SEEN_MAX_WORDS,
    SEEN_META_SLOTS,
    SEEN_NX,
    SEEN_NZ,
    SEEN_PAD,
    SEEN_SPARSE_GEN,
    SEEN_WORDS,
    SEEN_WORDS_CAP,
    STATUS_DONE,
    STATUS_NEED_BLOCKS,
    STATUS_NEED_CHANGED,
    apply_mask_updates,
    apply_voxels_kernel,
    classify_rays,
    dedupe_endpoints,
    depth_image_rays,
    depth_rays_cap,
    frame_voxels,
    quiet_after_tick,
    quiet_count,
    quiet_update,
    sparse_grown,
    still_clear,
)

O_CHANNELS = {
    "logodds": (np.float32, 0.0),
    "stamp": (np.int32, 0),  # id of the last frame that updated the voxel (0: never: unknown)
    "hit": (np.uint8, 0),  # 1: some frame of the current tick hit the voxel (the tick rules clear it)
}
# O's channels that belong to the tick in progress, not to a map's state: not written by
# state_arrays, zero after load_state_arrays (so states from before such a channel load too)
O_TRANSIENT = ("hit",)
O_STATE_CHANNELS = {k: v for k, v in O_CHANNELS.items() if k not in O_TRANSIENT}
D_CHANNELS = {
    "st": (np.float32, 0.0),
    "lt": (np.float32, 0.0),
    "last_obs": (np.int32, -1),  # last tick seen as an obstacle
    "last_seen": (np.int32, -1),  # last tick observed at all (obstacle or free)
    "obst_since": (np.int32, -1),  # tick the current obstacle streak began (ST rose from 0)
    "free_since": (np.int32, -1),  # tick the current seen-free streak began while LT > 0
}
SNAP_EPS = 1e-4  # ST / LT within this of 0 or 1 are snapped (float steps such as 0.2/15)
NO_STATIC = -(1 << 30)


def top_k_from_height(height: np.ndarray, resolution: float) -> np.ndarray:
    """Highest voxel index k whose interval [k r, (k+1) r) meets [0, h); -1 where h <= 0."""
    h = np.asarray(height, dtype=np.float64)
    top = np.ceil(h / resolution - 1e-9).astype(np.int64) - 1
    return np.where(h > 0, top, -1).astype(np.int32)


@dataclass
class StaticGrid:
    """S on the map lattice: a 2D trinary grid extruded from the floor.

    ``occ[row, col]`` (row = j - j0, col = i - i0) is -1 unknown, 0 free, 100 occupied;
    ``top_k`` is the highest voxel index of the static obstacle in the column (-1: none), so the
    column's static voxels are k = 0 .. top_k.
    """

    occ: np.ndarray  # int8 (H, W)
    top_k: np.ndarray  # int32 (H, W)
    i0: int
    j0: int
    resolution: float

    @classmethod
    def from_height_map(
        cls,
        occ: np.ndarray,
        height: np.ndarray,
        resolution: float,
        origin: tuple[float, float, float],
        lattice_resolution: float,
    ) -> StaticGrid:
        """Resample a 2D map (row 0 = lowest y, origin = (x, y, yaw) of cell (0,0)'s corner,
        heights in metres) onto the voxel lattice. A lattice cell is occupied when the source
        cell under its centre is, or when the centre of any source cell inside it is (so thin
        walls survive downsampling); free likewise when not occupied; heights take the max."""
        occ = np.asarray(occ, dtype=np.int8)
        height = np.asarray(height, dtype=np.float32)
        if occ.shape != height.shape or occ.ndim != 2:
            raise CoreError("static map: occupancy and height grids must have the same 2D shape")
        H, W = occ.shape
        ox, oy, yaw = (float(v) for v in origin)
        c, s = np.cos(yaw), np.sin(yaw)
        r = float(lattice_resolution)
        corners = np.array([[0, 0], [W, 0], [0, H], [W, H]], dtype=np.float64) * resolution
        wx = ox + c * corners[:, 0] - s * corners[:, 1]
        wy = oy + s * corners[:, 0] + c * corners[:, 1]
        i0 = int(np.floor(wx.min() / r + 1e-9))
        j0 = int(np.floor(wy.min() / r + 1e-9))
        i1 = int(np.ceil(wx.max() / r - 1e-9))
        j1 = int(np.ceil(wy.max() / r - 1e-9))
        TW, TH = max(i1 - i0, 1), max(j1 - j0, 1)
        out_occ = np.full((TH, TW), -1, dtype=np.int8)
        out_h = np.zeros((TH, TW), dtype=np.float32)

        # (a) each lattice cell samples the source cell under its centre
        jj, ii = np.mgrid[0:TH, 0:TW]
        cx = (ii + i0 + 0.5) * r - ox
        cy = (jj + j0 + 0.5) * r - oy
        col = np.floor((c * cx + s * cy) / resolution).astype(np.int64)
        row = np.floor((-s * cx + c * cy) / resolution).astype(np.int64)
        inside = (col >= 0) & (col < W) & (row >= 0) & (row < H)
        out_occ[inside] = occ[row[inside], col[inside]]
        out_h[inside] = height[row[inside], col[inside]]

        # (b) every source cell centre marks the lattice cell it falls in (max: occupied wins)
        if resolution < r:
            sr, sc = np.mgrid[0:H, 0:W]
            lx = (sc + 0.5) * resolution
            ly = (sr + 0.5) * resolution
            ti = np.floor((ox + c * lx - s * ly) / r).astype(np.int64) - i0
            tj = np.floor((oy + s * lx + c * ly) / r).astype(np.int64) - j0
            ok = (ti >= 0) & (ti < TW) & (tj >= 0) & (tj < TH)
            rank = np.full((TH, TW), -1, dtype=np.int8)  # -1 unknown, 0 free, 1 occupied
            src_rank = np.where(occ >= 100, 1, np.where(occ == 0, 0, -1)).astype(np.int8)
            np.maximum.at(rank, (tj[ok], ti[ok]), src_rank[ok])
            np.maximum.at(out_h, (tj[ok], ti[ok]), height[ok])
            cur = np.where(out_occ >= 100, 1, np.where(out_occ == 0, 0, -1)).astype(np.int8)
            best = np.maximum(rank, cur)
            out_occ = np.where(best == 1, 100, np.where(best == 0, 0, -1)).astype(np.int8)
        top = top_k_from_height(np.where(out_occ >= 100, out_h, 0.0), r)
        return cls(out_occ, top, i0, j0, r)

    def near_top(self, margin: int) -> tuple[np.ndarray, int, int]:
        """Top k of static voxels dilated by ``margin`` cells in x, y and z: (grid, i0, j0).
        Column values are the highest k within ``margin``, or NO_STATIC."""
        m = int(margin)
        H, W = self.top_k.shape
        base = np.where(self.top_k >= 0, self.top_k + m, NO_STATIC).astype(np.int32)
        out = np.full((H + 2 * m, W + 2 * m), NO_STATIC, dtype=np.int32)
        for dj in range(2 * m + 1):
            for di in range(2 * m + 1):
                view = out[dj : dj + H, di : di + W]
                np.maximum(view, base, out=view)
        return out, self.i0 - m, self.j0 - m

    def voxel_keys(self) -> np.ndarray:
        """Keys (M, 3) of every static voxel (the columns k = 0 .. top_k)."""
        rows, cols = np.nonzero(self.top_k >= 0)
        counts = self.top_k[rows, cols].astype(np.int64) + 1
        kk = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
        return np.stack([np.repeat(cols, counts) + self.i0, np.repeat(rows, counts) + self.j0, kk], axis=1).astype(
            np.int64
        )

    def is_occupied(self, keys: np.ndarray) -> np.ndarray:
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        col = keys[:, 0] - self.i0
        row = keys[:, 1] - self.j0
        H, W = self.top_k.shape
        ok = (col >= 0) & (col < W) & (row >= 0) & (row < H)
        out = np.zeros(len(keys), dtype=bool)
        top = self.top_k[row[ok], col[ok]]
        out[ok] = (keys[ok, 2] >= 0) & (keys[ok, 2] <= top)
        return out


TR_APPEAR = 1  # transition kinds recorded by the tick kernel
TR_DISAPPEAR = 2
# the columns of a transition row (EventLog.tr)
TR_KIND, TR_BLOCK, TR_OFF, TR_TICK, TR_SINCE = 0, 1, 2, 3, 4
# the tick kernel's counters
C_OBSTACLES, C_SEEN_FREE, C_LT_ENTERED, C_LT_LEFT, C_HELD = 0, 1, 2, 3, 4
TICK_DONE = -1


class TickSettings(NamedTuple):
    """The tick kernel's scalars (a numba named tuple: one argument, fields by name)."""

    rise: float  # ST step per tick of an obstacle: tick / st_rise_s
    fall: float  # ST step per tick seen free: tick / st_fall_s
    lt_fall: float  # LT step per tick seen free with ST == 0: tick / lt_fall_s
    occ_thr: float  # LT crossing this is an event transition
    k_lo: int  # the z band of P (transitions and history are recorded inside it)
    k_hi: int
    max_gap: int  # ticks of gap credit at most
    static_margin: int  # voxels
    near_i0: int  # cell (0, 0) of the static layer's dilated top grid
    near_j0: int
    tick_index: int
    record_all: bool  # record every observed band voxel's values in the history this tick
    forget_due: int  # the tick an obstacle seen in this tick is forgotten at, unless seen again


class DLayers(NamedTuple):
    """The D grid (ST, LT and their clocks) as the tick kernel takes it."""

    keys: np.ndarray
    vals: np.ndarray
    coords: np.ndarray
    meta: np.ndarray
    st: np.ndarray
    lt: np.ndarray
    last_obs: np.ndarray
    last_seen: np.ndarray
    obst_since: np.ndarray
    free_since: np.ndarray


class ForgetQueue(NamedTuple):
    """The forget queue as the tick kernel appends to it: voxel ids (D block * 512 + offset), the
    tick each is due, in no order, and [entries] (``LayeredMap._fq_meta``)."""

    vid: np.ndarray
    due: np.ndarray
    meta: np.ndarray


class EventBuffers(NamedTuple):
    """EventLog's arrays as the kernels take them."""

    tr: np.ndarray
    tr_meta: np.ndarray
    hist_i: np.ndarray
    hist_v: np.ndarray
    hist_p: np.ndarray
    hist_meta: np.ndarray


@njit(cache=True, inline="always")
def _record_history(hist_i, hist_v, hist_p, hist_meta, tick_index, vid, st_v, lt_v, periodic):
    n = hist_meta[0]
    hist_i[n, 0] = tick_index
    hist_i[n, 1] = vid
    hist_v[n, 0] = st_v
    hist_v[n, 1] = lt_v
    hist_p[n] = 1 if periodic else 0
    hist_meta[0] = n + 1


@njit(cache=True, inline="always")
def _record_transition(ev, kind, db, doff, tick_index, since):
    n = ev.tr_meta[0]
    ev.tr[n, TR_KIND] = kind
    ev.tr[n, TR_BLOCK] = db
    ev.tr[n, TR_OFF] = doff
    ev.tr[n, TR_TICK] = tick_index
    ev.tr[n, TR_SINCE] = since
    ev.tr_meta[0] = n + 1


@njit(cache=True, nogil=True)
def _tick_kernel(tb_block, tb_off, n_tb, start, o_coords, logodds, hit_mark, d, near, s, ev, fq, counters):
    """Tick rules for the voxels observed in this tick (``tb_block``/``tb_off``[start:n_tb]):
    O's ``logodds`` and ``hit_mark`` (``o_coords`` its block coordinates), D's layers ``d``
    (``DLayers``), the static layer's dilated top grid ``near``, the settings ``s``
    (``TickSettings``), the event buffers ``ev`` (``EventBuffers``).

    Returns TICK_DONE, or the index to resume from when the D pool, an event buffer or the forget
    queue ``fq`` (``ForgetQueue``) is full (nothing of that item was changed). A voxel that becomes an
    obstacle (ST was 0) is appended to the forget queue, due at ``s.forget_due``; one seen again
    is not (``_forget_due`` queues it anew at its due tick, ``last_obs + forget_ticks``), so the
    queue holds about one entry per obstacle voxel, not one per sighting (a room seen for the
    queue's 60 s: 7.5 M entries, 90 MB).
    ``counters``: C_OBSTACLES, C_SEEN_FREE, C_LT_ENTERED, C_LT_LEFT, C_HELD. A voxel O says occupied is an obstacle only when a frame of this tick hit
    it (``hit_mark``, cleared here); observed only as a miss it is *held*: ST and LT keep their
    values (an object just removed: O needs several misses to turn free).
    For voxels inside the z band [k_lo, k_hi] (what P shows), LT crossing ``occ_thr`` is recorded
    in ``ev.tr`` as (kind, D block, offset, tick, tick the streak began), and ST / LT values in the
    history (every tick when ``record_all``, else at transitions).

    Rates are per tick of time, not per observation: a voxel observed again ``g`` ticks after
    it was last observed at all (a depth camera slower than the tick) changes by
    ``min(g, max_gap)`` steps, so a layer's behaviour does not depend on the sensor rate. A first
    sighting counts one step, and a voxel seen free in between gets no credit for the gap."""
    NH, NW = near.shape
    tick_index = s.tick_index
    st, lt, last_seen = d.st, d.lt, d.last_seen
    # the D block of the last O block met (the buffer holds runs of one block): O block b and D
    # block db have the same coordinates, so db depends on b alone, until this kernel adds it
    last_b, last_db = np.int64(-1), np.int64(-1)
    for t in range(start, n_tb):
        if (ev.tr_meta[0] >= ev.tr.shape[0] or ev.hist_meta[0] >= ev.hist_i.shape[0]
                or fq.meta[0] >= fq.vid.shape[0]):  # fmt: skip
            return t
        b = tb_block[t]
        off = tb_off[t]
        lo = logodds[b, off]
        hit = hit_mark[b, off] != 0
        if lo == 0.0:
            hit_mark[b, off] = 0
            continue
        i = (np.int64(o_coords[b, 0]) << BLOCK_BITS) | ((off >> (2 * BLOCK_BITS)) & BLOCK_MASK)
        j = (np.int64(o_coords[b, 1]) << BLOCK_BITS) | ((off >> BLOCK_BITS) & BLOCK_MASK)
        k = (np.int64(o_coords[b, 2]) << BLOCK_BITS) | (off & BLOCK_MASK)
        in_band = s.k_lo <= k <= s.k_hi
        if lo > 0.0 and not hit:  # held: only missed while O still says occupied
            hit_mark[b, off] = 0
            counters[C_HELD] += 1
            if b != last_b:
                last_b, last_db = b, find_block(d.keys, d.vals, i >> BLOCK_BITS, j >> BLOCK_BITS, k >> BLOCK_BITS)
            db = last_db
            if db >= 0:
                doff = voxel_offset(i, j, k)
                if last_seen[db, doff] >= 0:
                    last_seen[db, doff] = tick_index  # observed: no gap credit for these ticks
            continue
        if lo > 0.0:
            r = j - s.near_j0
            c = i - s.near_i0
            if 0 <= r < NH and 0 <= c < NW and -s.static_margin <= k <= near[r, c]:
                hit_mark[b, off] = 0
                continue  # S's own: a wall seen where the static map has it
            if b != last_b or last_db < 0:
                last_b, last_db = b, get_or_add_block(d.keys, d.vals, d.coords, d.meta, i >> BLOCK_BITS,
                                                      j >> BLOCK_BITS, k >> BLOCK_BITS)  # fmt: skip
            db = last_db
            if db < 0:
                return t
            hit_mark[b, off] = 0
            doff = voxel_offset(i, j, k)
            counters[C_OBSTACLES] += 1
            old = st[db, doff]
            steps = 1
            if old == 0.0:
                d.obst_since[db, doff] = tick_index
            elif last_seen[db, doff] >= 0:  # unobserved since then: credit the gap
                steps = min(max(tick_index - last_seen[db, doff], 1), s.max_gap)
            d.free_since[db, doff] = -1
            v = old + s.rise * steps
            d.last_obs[db, doff] = tick_index
            last_seen[db, doff] = tick_index
            if old == 0.0:  # a new obstacle: queued once; seen again, _forget_due queues it anew
                q = fq.meta[0]  # (room for it: checked above)
                fq.vid[q] = np.int64(db) * 512 + doff
                fq.due[q] = s.forget_due
                fq.meta[0] = q + 1
            entered = False
            if v >= 1.0 - 1e-4:
                v = 1.0
                if lt[db, doff] < 1.0:
                    if lt[db, doff] < s.occ_thr:
                        counters[C_LT_ENTERED] += 1
                        entered = in_band
                    lt[db, doff] = 1.0
            st[db, doff] = v
            if entered:
                _record_transition(ev, TR_APPEAR, db, doff, tick_index, d.obst_since[db, doff])
            if in_band and (s.record_all or entered):
                _record_history(ev.hist_i, ev.hist_v, ev.hist_p, ev.hist_meta, tick_index, db * 512 + doff, v,
                                lt[db, doff], not entered)  # fmt: skip
        else:
            hit_mark[b, off] = 0
            counters[C_SEEN_FREE] += 1
            if b != last_b:
                last_b, last_db = b, find_block(d.keys, d.vals, i >> BLOCK_BITS, j >> BLOCK_BITS, k >> BLOCK_BITS)
            db = last_db
            if db < 0:
                continue
            doff = voxel_offset(i, j, k)
            old_st = st[db, doff]
            w = lt[db, doff]
            if old_st == 0.0 and w == 0.0:
                continue  # nothing to fall
            steps = 1
            if d.free_since[db, doff] >= 0 and last_seen[db, doff] >= 0:
                steps = min(max(tick_index - last_seen[db, doff], 1), s.max_gap)
            if d.free_since[db, doff] < 0:
                d.free_since[db, doff] = tick_index
            last_seen[db, doff] = tick_index
            v = old_st - s.fall * steps
            if v <= 1e-4:
                v = 0.0
                d.obst_since[db, doff] = -1
            st[db, doff] = v
            left = False
            if w > 0.0 and v == 0.0:
                w2 = w - s.lt_fall * steps
                if w2 <= 1e-4:
                    w2 = 0.0
                if w >= s.occ_thr > w2:
                    counters[C_LT_LEFT] += 1
                    left = in_band
                lt[db, doff] = w2
            if left:
                _record_transition(ev, TR_DISAPPEAR, db, doff, tick_index, d.free_since[db, doff])
            if in_band and (s.record_all or left):
                _record_history(ev.hist_i, ev.hist_v, ev.hist_p, ev.hist_meta, tick_index, db * 512 + doff, v,
                                lt[db, doff], not left)  # fmt: skip
    return TICK_DONE


@njit(cache=True, nogil=True)
def _take_due(vid, due, meta, tick_index):
    """The ids of the forget queue's entries due by ``tick_index``, taken out of it (the others
    moved up in their place, ``meta[0]`` entries left): one pass over the queue."""
    n = meta[0]
    out = np.empty(n, dtype=np.int64)
    m = 0
    keep = 0
    for t in range(n):
        v = vid[t]
        if due[t] <= tick_index:
            out[m] = v
            m += 1
        else:
            vid[keep] = v
            due[keep] = due[t]
            keep += 1
    meta[0] = keep
    return out[:m]


@njit(cache=True, nogil=True)
def _forget_due(vids, start, d_coords, st, lt, last_obs, obst_since, tick_index, forget_ticks, k_lo, k_hi, hist_i,
                hist_v, hist_p, hist_meta, fq, counts):  # fmt: skip
    """``_forget_kernel``'s rule for the queued voxels due by this tick (``vids``: their ids,
    sorted and unique, ``LayeredMap._due_voxels``), from ``vids[start]`` on, in the same (block,
    offset) order, so with the same history records: a voxel with ST > 0 was queued when it became
    an obstacle, or when it last came due, at ``last_obs + forget_ticks`` of then; the rule applies
    to it when no obstacle was seen there since (``tick_index - last_obs >= forget_ticks``), else
    it is queued again at its due tick now (``last_obs + forget_ticks``: the first tick the rule
    can apply to it). Cost per tick: the voxels due, not the map. ``fq``: the forget queue
    (``ForgetQueue``), with room for ``vids`` more; ``counts[0]`` counts the voxels forgotten.
    Returns -1, or the index to go on from when the history buffer must grow first."""
    for q in range(start, vids.shape[0]):
        vid = vids[q]
        b = vid >> 9
        o = vid & 511
        if not st[b, o] > 0.0:
            continue
        if tick_index - last_obs[b, o] < forget_ticks:  # seen since it was queued: due later
            t = fq.meta[0]
            fq.vid[t] = vid
            fq.due[t] = last_obs[b, o] + forget_ticks
            fq.meta[0] = t + 1
            continue
        k = np.int64(d_coords[b, 2]) * BLOCK + (o & BLOCK_MASK)
        if k_lo <= k <= k_hi:
            if hist_meta[0] >= hist_i.shape[0]:
                return q
            _record_history(hist_i, hist_v, hist_p, hist_meta, tick_index, vid, 0.0, lt[b, o], False)
        st[b, o] = 0.0
        obst_since[b, o] = -1
        counts[0] += 1
    return -1


HISTORY_MAX_ROWS = 1 << 22  # history rows (17 bytes each: 68 MB) before its periodic samples are thinned


class EventLog:
    """What the tick kernel records for the measurements of SPEC 6 (plain growable arrays).

    ``transitions`` rows (columns TR_KIND, TR_BLOCK, TR_OFF, TR_TICK, TR_SINCE): (kind TR_APPEAR /
    TR_DISAPPEAR, D block, offset, tick, tick the obstacle / seen-free streak began); ``history``
    rows (tick, D voxel id = block * 512 + offset) with (ST, LT) after that tick: a voxel's
    transitions and forgetting, and periodic samples of every voxel observed (``hist_p`` 1).

    The periodic samples grow with the log's length (a room seen from one end: 12 k rows a second
    of log), so they are bounded: when the rows reach ``max_rows``, the periodic samples older than
    this tick at every other sampling tick are dropped and the sampling period doubles
    (``sample_every``), so hours of log keep a history of fixed size, coarser in time the longer
    the log. Transitions and forgetting are kept whole (the events are made of them)."""

    def __init__(self, max_rows: int = HISTORY_MAX_ROWS):
        self.tr = np.zeros((1024, 5), dtype=np.int32)
        self.tr_meta = np.zeros(1, dtype=np.int64)
        self.hist_i = np.zeros((1 << 16, 2), dtype=np.int32)
        self.hist_v = np.zeros((1 << 16, 2), dtype=np.float32)
        self.hist_p = np.zeros(1 << 16, dtype=np.uint8)
        self.hist_meta = np.zeros(1, dtype=np.int64)
        self.max_rows = max_rows
        self.thinned = 0  # times the periodic samples were thinned: their period is 2 ** thinned x the map's

    def sample_every(self, every: int) -> int:
        """Ticks between periodic samples, for the map's ``history_every`` (0: none)."""
        return every << self.thinned

    def grow(self, tick_index: int = 0, every: int = 0) -> None:
        """Room for the next record: the buffers doubled, or (the history at ``max_rows``) its
        periodic samples thinned first (``tick_index``: the tick being recorded, kept whole;
        ``every``: the map's ``history_every``)."""
        if self.tr_meta[0] >= len(self.tr):
            self.tr = np.concatenate([self.tr, np.zeros_like(self.tr)])
        n = int(self.hist_meta[0])
        if n < len(self.hist_i):
            return
        if n >= self.max_rows and every > 0:
            self._thin(n, tick_index, every)
            n = int(self.hist_meta[0])
            if 4 * n <= 3 * len(self.hist_i):  # a quarter free at least: no bigger buffer
                return
        self.hist_i = np.concatenate([self.hist_i, np.zeros_like(self.hist_i)])
        self.hist_v = np.concatenate([self.hist_v, np.zeros_like(self.hist_v)])
        self.hist_p = np.concatenate([self.hist_p, np.zeros_like(self.hist_p)])

    def _thin(self, n: int, tick_index: int, every: int) -> None:
        period = 2 * self.sample_every(every)
        ticks = self.hist_i[:n, 0]
        keep = (self.hist_p[:n] == 0) | (ticks % period == 0) | (ticks >= tick_index)
        m = int(keep.sum())
        self.hist_i[:m] = self.hist_i[:n][keep]
        self.hist_v[:m] = self.hist_v[:n][keep]
        self.hist_p[:m] = self.hist_p[:n][keep]
        self.hist_meta[0] = m
        self.thinned += 1

    @property
    def transitions(self) -> np.ndarray:
        return self.tr[: int(self.tr_meta[0])]

    @property
    def history(self) -> tuple[np.ndarray, np.ndarray]:
        n = int(self.hist_meta[0])
        return self.hist_i[:n], self.hist_v[:n]


@dataclass
class FrameResult:
    rays: int
    hits: int  # voxels that got the hit update
    misses: int  # voxels that got the miss update


@dataclass
class TickResult:
    tick_index: int
    observed: int  # voxels observed in the tick
    obstacles: int
    seen_free: int
    lt_entered: int  # voxels whose LT crossed the occupied threshold upwards
    lt_left: int  # voxels whose LT fell below the occupied threshold
    st_forgotten: int
    held: int = 0  # voxels O says occupied that the tick observed only as misses (ST, LT kept)


KEY_LIMIT = (1 << 20) - 2  # voxel keys within +-KEY_LIMIT: the packed keys of the end-point dedupe
# hold 21 bits per axis (block keys: 21 bits of block coordinates), so farther voxels would collide


RANGE_FACTORS_KEPT = 4  # depth cameras (calibration, image size) whose pixel_range_factors a map keeps
MAX_PLAIN_RANGE = 1000.0  # m: a max_range up to this bounds the reach of a frame's rays as it is


def check_extent(origin: np.ndarray, reach: float, resolution: float, what: str = "sensor") -> None:
    """CoreError unless ``origin`` is finite and every voxel within ``reach`` metres of it has
    keys within +-KEY_LIMIT (+-52 km at 0.05 m): beyond, voxels would silently share keys."""
    if not np.isfinite(origin).all():
        raise CoreError(f"{what} origin is not finite ({origin.tolist()}); check the poses (tf, odometry)")
    limit_m = KEY_LIMIT * resolution
    if float(np.abs(origin).max()) + reach >= limit_m:
        raise CoreError(
            f"{what} at ({origin[0]:.1f}, {origin[1]:.1f}, {origin[2]:.1f}) m, reaching {reach:g} m, is beyond "
            f"+-{limit_m / 1000:.1f} km of the fixed frame's origin, the extent of ltmap's voxel keys at "
            f"{resolution:g} m; use a fixed frame near the robot (--fixed-frame, e.g. a local map or odom) "
            f"or a coarser --resolution"
        )


def _sparse_bitmap(slots: int) -> tuple[np.ndarray, ...]:
    """frame_voxels' sparse bitmap for up to slots / 2 blocks: hash keys, generations (0: empty
    in every frame), block indices, 8 words of bits per block."""
    return (np.zeros(slots, dtype=np.int64), np.zeros(slots, dtype=np.int64), np.zeros(slots, dtype=np.int64),
            np.zeros(4 * slots, dtype=np.uint64))  # fmt: skip


_NO_KEYS = np.empty(0, dtype=np.int64)
_NO_MASKS = np.empty((0, 8), dtype=np.uint64)
_NO_VALS = np.empty(0, dtype=np.int32)


class _QuietBlocks:
    """The record of quiet O blocks and quarters that ``LayeredMap.apply_voxels`` keeps: per O
    block and quarter (4 x 4 x 4, ``core.raycast.quarter_of``) the count of voxels clamped free
    (``nfree`` (B, 8)) and per block its quiet quarters (``qquiet``, a bit each; the block is
    quiet, and the workers' projection skips it, when all eight are: ``quiet``); and per block
    its still voxels (``still`` (B, 8) uint64, ``voxel_offset`` bits), the workers' projection's
    to leave out: a bit is set only while its voxel is clamped free with no ST or LT (the kernels
    set and clear it as the voxel enters and leaves ``lo_min``; LT seeded into a free voxel, or a
    D replaced, clears it in ``revalidate``; the tick rules give ST and LT only to voxels above
    log-odds 0), so a miss there changes nothing. A voxel whose ST and LT the tick rules bring
    back to 0 gets its bit when it next enters ``lo_min``."""

    NFREE, FLAG = np.int32, np.uint8  # the dtypes of ``nfree`` and ``qquiet`` (the kernels compile for them)

    def __init__(self, lmap: LayeredMap, lo_min: float):
        o, d = lmap.O, lmap.D
        self.o, self.lo_min, self.active = o, lo_min, lmap.quiet_blocks
        self.tick = lmap.tick_index  # the tick whose ST and LT the flags follow (after_tick)
        self.nfree = np.zeros((o.max_blocks, 8), dtype=self.NFREE)
        self.qquiet = np.zeros(o.max_blocks, dtype=self.FLAG)
        self.still = np.zeros((o.max_blocks, 8), dtype=np.uint64)
        self.changed = np.empty(1 << 12, dtype=np.int64)
        self.ch_meta = np.zeros(1, dtype=np.int64)
        n = o.n_blocks
        quiet_count(o.data["logodds"], n, lo_min, self.nfree, self.still, o.block_coords, d.table_keys, d.table_vals,
                    d.data["st"], d.data["lt"])  # fmt: skip
        self.update(lmap, n, np.arange(n, dtype=np.int64))

    def fit(self, max_blocks: int) -> None:
        if len(self.nfree) < max_blocks:
            extra = max_blocks - len(self.nfree)
            self.nfree = np.concatenate([self.nfree, np.zeros((extra, 8), dtype=self.nfree.dtype)])
            self.qquiet = np.concatenate([self.qquiet, np.zeros(extra, dtype=self.qquiet.dtype)])
            self.still = np.concatenate([self.still, np.zeros((extra, 8), dtype=self.still.dtype)])

    @property
    def quiet(self) -> np.ndarray:
        """Per O block: quiet (all eight quarters), as bools."""
        return self.qquiet == QUIET_ALL

    def update(self, lmap: LayeredMap, n: int, blocks: np.ndarray | None = None) -> None:
        """Quiet flags of ``blocks[:n]`` (default: those with a quarter whose count the last frame
        moved to or from 64)."""
        d, o = lmap.D, lmap.O
        quiet_update(self.changed if blocks is None else blocks, n, self.nfree, self.qquiet, o.block_coords,
                     d.table_keys, d.table_vals, d.data["st"], d.data["lt"])  # fmt: skip
        self.d, self.d_blocks = d, d.n_blocks

    def revalidate(self, lmap: LayeredMap) -> None:
        """D gained blocks (the tick rules' obstacles, long-term seeds) or was replaced, or LT
        was seeded: quiet quarters that now have ST or LT are quiet no more, nor are such voxels
        still (all of D's blocks after a seed or a new D, else its new blocks: the tick rules'
        obstacles are above log-odds 0, not still already, but it costs nothing)."""
        d, o = lmap.D, lmap.O
        first = self.d_blocks if self.d is d and self.d_blocks >= 0 else 0
        still_clear(first, d.n_blocks, d.block_coords, d.data["st"], d.data["lt"], o.table_keys, o.table_vals,
                    self.still)  # fmt: skip
        qb = np.nonzero(self.qquiet[: o.n_blocks])[0].astype(np.int64)
        self.update(lmap, len(qb), qb)

    def after_tick(self, lmap: LayeredMap) -> None:
        """A tick ended: quarters all clamped free whose ST and LT the tick rules brought to 0 are
        quiet (the D block of something seen once stays: the office bench scene's person left 40
        such blocks in each frame's frustum, 22 % of the masks' miss bits, never quiet)."""
        d = lmap.D
        quiet_after_tick(lmap.O.n_blocks, self.nfree, self.qquiet, lmap.O.block_coords, d.table_keys, d.table_vals,
                         d.data["st"], d.data["lt"])  # fmt: skip
        self.tick = lmap.tick_index


_NO_QUARTERS = np.empty(0, dtype=_QuietBlocks.FLAG)


class FrameMasks(NamedTuple):
    """One frame's voxel updates as block masks, for ``LayeredMap.apply_voxels``: per block its
    packed coordinates and its voxels' bits (``grid.voxel_offset`` order), the misses, and the
    hits in masks of their own. A depth frame's projection (``LayeredMap.depth_projection``,
    ``core.projective.projective_blocks``) also gives its box, the blocks whose quiet quarters
    or still voxels it left out, and what ``projective_refill`` needs to fill them in; whole rays (``ray_voxels``:
    scans, clouds, exact depth) give keys, masks and hits only."""

    keys: np.ndarray  # (n,) int64, ascending
    masks: np.ndarray  # (n, 8) uint64
    box: np.ndarray | None = None  # (6,) int64: the frame's voxel box (ends_box)
    skipped: np.ndarray | None = None  # (m, 2) int64: block numbers in the box * 256 + quarters left as quiet, O block
    skipped_still: np.ndarray | None = None  # (m, 8) uint64: those blocks' voxels left as still
    fill: tuple | None = None  # projective_refill's first arguments
    hits: tuple | None = None  # (keys, masks): the frame's hits as block masks (core.projective.tail_masks)


def _depth_view(depth: np.ndarray) -> tuple[np.ndarray, bool]:
    """Raw depth pixels as the kernels take them: native byte order and read-only (as a log's
    buffer gives them: one compiled specialization, not one per writeable flag); and whether they
    are uint16 millimetres (else float32 metres)."""
    if not depth.dtype.isnative:
        depth = depth.astype(depth.dtype.newbyteorder("="))
    if depth.flags.writeable:
        depth = depth.view()
        depth.flags.writeable = False
    if depth.dtype == np.uint16:
        return depth, True
    if depth.dtype == np.float32:
        return depth, False
    raise CoreError(f"a depth image must be uint16 (mm) or float32 (m), got {depth.dtype}")


class LayeredMap:
    """S, O, ST and LT on one voxel lattice, with SPEC 2's update rules."""

    quiet_blocks = True  # misses in quiet blocks are skipped (see apply_voxels); False: every miss updates
    _quiet: _QuietBlocks | None = None

    def __init__(self, cfg: MapConfig | None = None, static: StaticGrid | None = None):
        self.cfg = cfg or MapConfig()
        problems = self.cfg.validate()
        if problems:
            raise CoreError("invalid map configuration: " + "; ".join(problems))
        self.resolution = float(self.cfg.resolution)
        self.O = VoxelGrid(self.resolution, O_CHANNELS, initial_blocks=1024)
        self.D = VoxelGrid(self.resolution, D_CHANNELS, initial_blocks=64)
        self.frame_id = 0
        self.tick_index = 0
        self._tick_first = 1
        self._tb_block = np.empty(1 << 16, dtype=np.int32)
        self._tb_off = np.empty(1 << 16, dtype=np.int16)
        self._tb_meta = np.zeros(1, dtype=np.int64)
        # per thread: the frame's "updated already" bitmap of frame_voxels, grown on demand
        self._scratch = threading.local()
        self._range_factors_kept: dict[tuple, np.ndarray] = {}  # (_range_factors)
        self._range_factors_lock = threading.Lock()
        self.seen_max_words = SEEN_MAX_WORDS  # a frame whose box needs more goes without it
        self.static: StaticGrid | None = None
        self.set_static(static)
        self.events = EventLog()
        self.history_every = 5  # ticks between ST / LT history samples (0: transitions only)
        # forget queue (ST forgetting without scanning the map): voxel ids (D block * 512 + offset)
        # and the tick each is due, about one entry per voxel with ST > 0, in no order
        self._fq_vid = np.empty(1 << 16, dtype=np.int64)
        self._fq_due = np.empty(1 << 16, dtype=np.int32)
        self._fq_meta = np.zeros(1, dtype=np.int64)  # [entries]

    # -- static layer -------------------------------------------------------------------------
    def set_static(self, static: StaticGrid | None) -> None:
        if static is not None and abs(static.resolution - self.resolution) > 1e-9:
            raise CoreError(
                f"static layer resolution {static.resolution} differs from the map's {self.resolution}; "
                "resample it with StaticGrid.from_height_map"
            )
        self.static = static
        m = self.cfg.layers.static_margin_cells
        if static is None:
            self._near = np.full((1, 1), NO_STATIC, dtype=np.int32)
            self._near_i0 = self._near_j0 = 0
        else:
            self._near, self._near_i0, self._near_j0 = static.near_top(m)

    # -- sensor integration -------------------------------------------------------------------
    def _footprint(self, robot_pose):
        rc = self.cfg.robot
        if robot_pose is not None:
            T = np.asarray(robot_pose, dtype=np.float64)
            R, t = T[:3, :3], T[:3, 3]
            fp_inv = np.ascontiguousarray(np.hstack([R.T, (-R.T @ t)[:, None]]))
            use_fp = True
        else:
            fp_inv = np.zeros((3, 4))
            use_fp = False
        return (fp_inv, np.asarray(rc.footprint_min, dtype=np.float64),
                np.asarray(rc.footprint_max, dtype=np.float64), use_fp)  # fmt: skip

    def rays(
        self,
        origin,
        points,
        returns=None,
        max_range: float = 0.0,
        robot_pose: np.ndarray | None = None,
        dedupe: bool = False,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The rays ``integrate`` would cast for this frame: (ends (N, 3), kind (N,)). Reads no
        map state, so it may run in another thread than ``integrate_rays``."""
        origin = np.ascontiguousarray(origin, dtype=np.float64).reshape(3)
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        if returns is None:
            rets = np.ones(len(pts), dtype=np.bool_)
        else:
            rets = np.ascontiguousarray(returns, dtype=np.bool_).reshape(-1)
            if len(rets) != len(pts):
                raise CoreError(f"integrate: {len(pts)} points but {len(rets)} return flags")
        # the rays reach at most max_range (the usual case: no pass over the points); without a
        # sensible one (0, inf as pointcloud_to_laserscan publishes, 1e6), the farthest finite point
        if 0 < max_range <= MAX_PLAIN_RANGE:
            reach = float(max_range)
        else:
            fin = pts[np.isfinite(pts).all(axis=1)]
            reach = float(np.abs(fin - origin).max()) if len(fin) else 0.0
            if 0 < max_range < reach:
                reach = float(max_range)
        check_extent(origin, reach + self.resolution, self.resolution)
        fp_inv, fp_min, fp_max, use_fp = self._footprint(robot_pose)
        ends, kind = classify_rays(
            origin, pts, rets, float(max_range), float(self.cfg.sensor.ground_tolerance), fp_inv, fp_min, fp_max,
            use_fp,
        )  # fmt: skip
        if dedupe:
            dedupe_endpoints(ends, kind, 1.0 / self.resolution)
        return ends, kind

    def depth_rays(
        self,
        depth: np.ndarray,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        T: np.ndarray,
        max_range: float,
        robot_pose: np.ndarray | None = None,
        dedupe: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The rays of one depth image, fused in one kernel: (ends (M, 3), kind (M,)).

        ``depth``: raw (H, W) pixels, uint16 millimetres (0 invalid) or float32 metres (NaN, <= 0
        invalid), native byte order; ``T``: 4x4 optical frame -> fixed frame. Gives bit for bit the
        rays that ``integrate(T[:3, 3], transform_points(T, depth_to_points(metres, ...)), None,
        max_range, robot_pose, dedupe)`` casts (without the dropped ones). Reads no map state, so
        it may run in another thread than ``integrate_rays``."""
        depth, unit_mm = _depth_view(depth)
        T = np.ascontiguousarray(T, dtype=np.float64)
        if 0 < max_range <= MAX_PLAIN_RANGE:
            reach = float(max_range)
        elif unit_mm:
            reach = 65.535 * 4.0  # the largest 16UC1 depth, as a range at a 150 deg FOV's corners
        else:  # only without a finite max_range: a pass over the image
            fin = depth[np.isfinite(depth)]
            reach = float(fin.max()) * 4.0 if len(fin) else 0.0
        check_extent(T[:3, 3], reach + self.resolution, self.resolution, "depth camera")
        fp_inv, fp_min, fp_max, use_fp = self._footprint(robot_pose)
        scratch = self._scratch  # this thread's dedupe set size, from its previous frame (unused without dedupe)
        cap = getattr(scratch, "depth_cap", DEPTH_CAP_MIN) if dedupe else DEPTH_CAP_MIN
        ends, kind = depth_image_rays(
            depth, unit_mm, float(fx), float(fy), float(cx), float(cy), T,
            float(max_range), float(self.cfg.sensor.ground_tolerance), fp_inv, fp_min, fp_max, use_fp,
            bool(dedupe), 1.0 / self.resolution, np.int64(cap),
        )  # fmt: skip
        if dedupe:
            scratch.depth_cap = depth_rays_cap(len(kind), depth.size)
        return ends, kind

    def depth_projection(self, depth: np.ndarray, fx: float, fy: float, cx: float, cy: float, T: np.ndarray,
                         max_range: float, ends: np.ndarray) -> FrameMasks:
        """What ``apply_voxels`` needs to make the projective misses of one depth image (the
        frame's ``depth_rays`` gave ``ends``). A worker thread's part: of the map it reads only
        what ``_map_seen`` gives, as a hint that ``apply_voxels`` checks."""
        depth, unit_mm = _depth_view(depth)
        T = np.ascontiguousarray(T, dtype=np.float64)
        R, t = T[:3, :3], T[:3, 3]
        Tinv = np.ascontiguousarray(np.hstack([R.T, (-R.T @ t)[:, None]]))
        band = float(self.cfg.sensor.projective_band)
        seen = self._map_seen()
        fac = self._range_factors(depth.shape, float(fx), float(fy), float(cx), float(cy))
        keys, masks, n, skipped, sstill, ns, nxt, reach, tmin, tmax, dil, box = depth_projection_blocks(
            depth, unit_mm, fac, float(fx), float(fy), float(cx), float(cy), np.ascontiguousarray(t), Tinv,
            float(max_range), band, ends, self.resolution, PROJECTIVE_CHUNK_BLOCKS, *seen,
        )  # fmt: skip
        while nxt >= 0:  # the arrays are full: twice the room, and on from the block it stopped at
            if n == len(keys):
                keys = np.concatenate([keys[:n], np.empty(n, dtype=np.int64)])
                masks = np.concatenate([masks[:n], np.empty((n, 8), dtype=np.uint64)])
            if ns == len(skipped):
                skipped = np.concatenate([skipped[:ns], np.empty((ns, 2), dtype=np.int64)])
                sstill = np.concatenate([sstill[:ns], np.empty((ns, 8), dtype=np.uint64)])
            m, ns, nxt = projective_blocks(reach, tmin, tmax, dil, float(fx), float(fy), float(cx), float(cy), Tinv,
                                           box, self.resolution, band, keys[n:], masks[n:], nxt, *seen, skipped,
                                           sstill, ns)  # fmt: skip
            n += m
        keys, masks, skipped, sstill = keys[:n], masks[:n], skipped[:ns], sstill[:ns]
        if not len(skipped):
            return FrameMasks(keys, masks, box)
        return FrameMasks(keys, masks, box, skipped, sstill, (reach, tmin, tmax, dil, float(fx), float(fy), float(cx),
                                                              float(cy), Tinv, box, self.resolution, band))  # fmt: skip

    def _range_factors(self, shape: tuple[int, int], fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
        """The camera's ``pixel_range_factors``, made once per calibration and image size (8 bytes
        a pixel: 2.5 MB for 640x480), the last ``RANGE_FACTORS_KEPT`` kept. (Worker threads may
        make the same one at once: the same array either way.)"""
        key = (int(shape[0]), int(shape[1]), fx, fy, cx, cy)
        fac = self._range_factors_kept.get(key)
        if fac is None:
            fac = pixel_range_factors(key[0], key[1], fx, fy, cx, cy)
            with self._range_factors_lock:
                kept = self._range_factors_kept
                while len(kept) >= RANGE_FACTORS_KEPT:
                    del kept[next(iter(kept))]
                kept[key] = fac
        return fac

    def _map_seen(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the workers' projection reads of the map to leave out the misses that change
        nothing (``projective_blocks``): O's hash table, the quiet quarters and still voxels by
        O block, the arrays as they are now (the map thread goes on writing them; the map thread
        checks what was read before it applies the frame); empty ones without quiet blocks."""
        q = self._quiet
        if not self.quiet_blocks or q is None or q.o is not self.O:
            return _NO_KEYS, _NO_VALS, _NO_QUARTERS, _NO_MASKS
        return self.O.table_keys, self.O.table_vals, q.qquiet, q.still

    def projective_tail(self) -> float:
        """How far before its end a depth ray is walked in projective mode (m): the band and an
        overlap of ``TAIL_OVERLAP_VOXELS``."""
        return float(self.cfg.sensor.projective_band) + TAIL_OVERLAP_VOXELS * self.resolution

    def integrate(
        self,
        origin,
        points,
        returns=None,
        max_range: float = 0.0,
        robot_pose: np.ndarray | None = None,
        dedupe: bool = False,
    ) -> FrameResult:
        """Fuse one frame into O.

        origin: sensor origin (3,) in the fixed frame; points: (N, 3) end points in the fixed
        frame; returns: (N,) bool, False for beams without a return (clear only; default all
        True); max_range: rays are cut there (<= 0: no limit); robot_pose: 4x4 robot (base) to
        fixed transform, for the footprint box (None: no footprint test); dedupe: cast one ray
        per end voxel (dense depth images and clouds; OctoMap's ``discretize``).
        """
        ends, kind = self.rays(origin, points, returns, max_range, robot_pose, dedupe)
        return self.integrate_rays(origin, ends, kind)

    def integrate_depth(self, depth: np.ndarray, fx: float, fy: float, cx: float, cy: float, T: np.ndarray,
                        max_range: float, robot_pose: np.ndarray | None = None) -> FrameResult:
        """Fuse one depth image (raw pixels, as ``depth_rays`` takes them) into O as the replay
        does, by ``map.sensor.depth_integration``: exact (every ray walked whole) or projective
        (``depth_projection``: the rays' tails and the projection)."""
        T = np.ascontiguousarray(T, dtype=np.float64)
        ends, kind = self.depth_rays(depth, fx, fy, cx, cy, T, max_range, robot_pose,
                                     dedupe=self.cfg.sensor.dedupe_dense)  # fmt: skip
        hits, misses, projection = self.depth_voxels(depth, fx, fy, cx, cy, T, max_range, ends, kind)
        return self.apply_voxels(hits, misses, int((kind > 0).sum()), projection)

    def depth_voxels(self, depth: np.ndarray, fx: float, fy: float, cx: float, cy: float, T: np.ndarray,
                     max_range: float, ends: np.ndarray, kind: np.ndarray):
        """The cast half of a depth image whose rays are (``ends``, ``kind``), by
        ``map.sensor.depth_integration``: (hits, misses, projection) for ``apply_voxels``; exact:
        whole rays, no projection; projective: ``depth_projection`` and the rays' tails, the
        tails' misses set in the projection's block masks and the hits in masks of their own
        (``tail_masks``; listed by ``frame_voxels`` only in a box of more than
        ``LISTED_VOXELS_MAX_BLOCKS`` blocks, or when a step leaves the box). A worker thread's
        part (of the map, the projection reads only ``_map_seen``'s hint)."""
        if self.cfg.sensor.depth_integration != "projective":
            return self.ray_voxels(T[:3, 3], ends, kind)
        projection = self.depth_projection(depth, fx, fy, cx, cy, T, max_range, ends)
        return self.ray_voxels(T[:3, 3], ends, kind, self.projective_tail(), projection)

    def integrate_rays(self, origin, ends: np.ndarray, kind: np.ndarray) -> FrameResult:
        """Fuse rays from ``rays`` or ``depth_rays`` into O: ``apply_voxels(ray_voxels(...))``."""
        hits, misses, masks = self.ray_voxels(origin, ends, kind)
        return self.apply_voxels(hits, misses, int((kind > 0).sum()), masks)

    def ray_voxels(self, origin, ends: np.ndarray, kind: np.ndarray, tail: float = 0.0,
                   projection: FrameMasks | None = None) -> tuple[np.ndarray, np.ndarray, FrameMasks | None]:
        """The voxels these rays update, for ``apply_voxels``: (hits, misses, masks). Each ray is
        walked whole, or over its last ``tail`` metres with a depth frame's ``projection``
        (``depth_voxels``), whose masks the misses join. As block masks
        (``core.projective.tail_masks`` over the frame's box: each voxel's bit set however many
        rays pass it; the map thread then looks each block up once, not each voxel, and drops
        quiet quarters a word at a time), with no lists; as lists (``frame_voxels``) beside the
        projection's masks in a box of more than ``LISTED_VOXELS_MAX_BLOCKS`` blocks or when a
        step leaves it. Either way the map gets the same updates: each voxel once, a hit first.
        Reads no map state (a worker thread's part)."""
        origin = np.ascontiguousarray(origin, dtype=np.float64).reshape(3)
        inv_res = 1.0 / self.resolution
        if projection is not None:
            pkeys, pmasks, box = projection.keys, projection.masks, projection.box
        else:  # (no box kept in the masks: it would make apply_voxels publish quiet blocks for it)
            pkeys, pmasks, box = _NO_KEYS, _NO_MASKS, ends_box(origin, ends, inv_res)
            # (rays() and depth_rays() checked already; rays handed to integrate_rays may not be)
            lo, hi = box[:3] * self.resolution, (box[3:] + 1) * self.resolution
            check_extent(origin, float(np.max(np.maximum(origin - lo, hi - origin))), self.resolution)
        keys, masks, hk, hm, ok = tail_masks(origin, ends, kind, inv_res, self.resolution, float(tail), pkeys, pmasks,
                                             box, LISTED_VOXELS_MAX_BLOCKS, TAIL_BITMAP_MAX_BLOCKS)  # fmt: skip
        if ok:
            done = FrameMasks(keys, masks) if projection is None else projection._replace(keys=keys, masks=masks)
            return _NO_KEYS, _NO_KEYS, done._replace(hits=(hk, hm))
        hits, misses = self.frame_voxels(origin, ends, kind, tail)
        return hits, misses, projection

    def frame_voxels(self, origin, ends: np.ndarray, kind: np.ndarray, tail: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The voxels these rays update, each once, in update order: (hits, misses), packed keys
        (``core.raycast.frame_voxels``: the DDA). Reads no map state, so it may run in other
        threads than ``apply_voxels`` (each thread has its own scratch bitmap). ``tail`` > 0: each
        ray is walked over its last ``tail`` metres only (projective depth integration)."""
        origin = np.ascontiguousarray(origin, dtype=np.float64).reshape(3)
        scratch = self._scratch
        if not hasattr(scratch, "seen"):
            scratch.seen = np.empty(0, dtype=np.uint64)
            scratch.meta = np.zeros(SEEN_META_SLOTS, dtype=np.int64)
            scratch.misses = np.empty(1 << 16, dtype=np.int64)
            scratch.sparse = _sparse_bitmap(1 << 10)
        meta = scratch.meta
        meta[SEEN_WORDS_CAP] = self.seen_max_words
        inv_res = 1.0 / self.resolution
        hits = np.empty(len(kind), dtype=np.int64)
        state = np.zeros(FV_STATE_SLOTS, dtype=np.int64)  # [phase, ray, hits listed, misses listed]
        checked = False
        while True:
            ok = frame_voxels(origin, ends, kind, inv_res, self.resolution, scratch.seen, meta, hits, scratch.misses,
                              *scratch.sparse, state, float(tail))  # fmt: skip
            if state[FV_PHASE] > 0 and not checked:  # the frame's box is known: within the keys' extent?
                # (rays() and depth_rays() checked already; rays handed to integrate_rays may not be)
                box0 = meta[SEEN_I0 : SEEN_K0 + 1]
                lo = (box0 + SEEN_PAD) * self.resolution
                hi = (box0 + meta[SEEN_NX : SEEN_NZ + 1] - SEEN_PAD) * self.resolution
                check_extent(origin, float(np.max(np.maximum(origin - lo, hi - origin))), self.resolution)
                checked = True
            if ok:
                misses = scratch.misses[: state[FV_MISSES]]
                # hand the buffer over with the list (no copy) and start the next frame's buffer at
                # the size this one needed, with room to spare
                scratch.misses = np.empty(max(1 << 16, state[FV_MISSES] + state[FV_MISSES] // 4), dtype=np.int64)
                return hits[: state[FV_HITS]], misses
            if meta[SEEN_GROW] == GROW_DENSE:  # before any voxel is listed: the frame starts again
                scratch.seen = np.empty(int(meta[SEEN_WORDS]), dtype=np.uint64)
            elif meta[SEEN_GROW] == GROW_MISSES:  # go on where it stopped, with what is listed
                bigger = np.empty(2 * len(scratch.misses), dtype=np.int64)
                bigger[: state[FV_MISSES]] = scratch.misses[: state[FV_MISSES]]
                scratch.misses = bigger
            else:
                scratch.sparse = sparse_grown(*scratch.sparse, meta[SEEN_SPARSE_GEN], 4 * len(scratch.sparse[0]))

    def apply_voxels(self, hits: np.ndarray, misses: np.ndarray, rays: int = 0,
                     masks: FrameMasks | None = None) -> FrameResult:
        """Give one frame's voxels the hit and miss updates: the frame's stateful half, in the
        thread that owns the map. The voxels come listed (``hits``, ``misses``: ``frame_voxels``)
        or as block masks (``masks``: ``ray_voxels``, ``depth_voxels``), or both.

        Quiet quarters and blocks (``quiet_blocks``, default on): a 4 x 4 x 4 quarter of an O
        block all of whose 64 voxels are clamped free (log-odds at ``clamp_min_logodds``) and
        that has no ST or LT anywhere in it (no D block, or one whose ST and LT the tick rules
        brought back to 0) is quiet; a block whose eight quarters are is quiet (the workers'
        projection skips it). A miss there changes nothing: the log-odds stay clamped, and the
        tick rules do nothing for a clamped-free voxel without ST or LT. So a miss in a quarter
        that is quiet when the frame begins is skipped: the voxel is not stamped again (its stamp
        stays that of the frame that clamped it) nor put in the tick buffer. O's log-odds, each D
        voxel's values and the events are those of updating every voxel; those stamps differ (a
        voxel is known, stamp > 0, exactly when it is either way), and D's blocks may be stored in
        another order (a voxel skipped, then hit enough times in the same tick to be an obstacle,
        enters the tick buffer later, so its D block is made later: the office bench scene's
        person). A hit un-quiets its quarter from the next frame on. Decided here, in frame order,
        so every path (serial, threads) gives the same map bit for bit."""
        q = self._quiet_sync()
        self.frame_id += 1
        counters = np.zeros(2, dtype=np.int64)
        q.ch_meta[0] = 0
        if masks is not None and masks.skipped is not None:  # blocks a worker took as quiet or still: checked
            masks = self._fill_stale(q, masks)  # against the map as the frame begins, before its hits
        if masks is not None and masks.hits is not None:  # the frame's hits as block masks
            self._apply_masks(q, *masks.hits, counters, hit=True)
        if len(hits) or len(misses):  # (none: nothing to do, and a first run's projective16 warm-up
            self._apply(q, hits, misses, 0, counters)  # group leaves this kernel to the lists group)
        if masks is not None:  # the misses (the projection's and the rays'), block by block
            self._apply_masks(q, masks.keys, masks.masks, counters)
        if self.quiet_blocks and q.ch_meta[0]:
            q.update(self, int(q.ch_meta[0]))
        return FrameResult(rays=rays, hits=int(counters[0]), misses=int(counters[1]))

    def _fill_stale(self, q: _QuietBlocks, projection: FrameMasks) -> FrameMasks:
        """The projection with the voxels its worker left out as quiet or still that are not
        now (the worker read the map as it was some frames before: ``_map_seen``) filled in, in
        key order: what it would have been with the map as the frame begins
        (``projective_refill``)."""
        o = self.O
        keys, masks, _ = projective_refill(*projection.fill, projection.skipped, projection.skipped_still,
                                           o.block_coords, o.n_blocks, q.qquiet, q.still, projection.keys,
                                           projection.masks)  # fmt: skip
        return projection._replace(keys=keys, masks=masks)

    def _apply(self, q: _QuietBlocks, hits: np.ndarray, misses: np.ndarray, phase: int, counters: np.ndarray) -> None:
        """``apply_voxels_kernel`` from ``phase`` (0: hits then misses; 1: misses only), growing
        storage as it asks."""
        sc = self.cfg.sensor
        use_quiet = self.quiet_blocks
        start = 0
        while True:
            o = self.O
            status, phase, start = apply_voxels_kernel(
                hits, misses,
                o.table_keys, o.table_vals, o.block_coords, o.meta, o.data["logodds"], o.data["stamp"], o.data["hit"],
                self.frame_id, self._tick_first, self._tb_block, self._tb_off, self._tb_meta,
                sc.hit_logodds, sc.miss_logodds, sc.clamp_min_logodds, sc.clamp_max_logodds,
                phase, start, counters, q.nfree, q.qquiet, q.still, use_quiet, q.changed, q.ch_meta,
                self.D.table_keys, self.D.table_vals, self.D.data["st"], self.D.data["lt"],
            )  # fmt: skip
            if status == STATUS_DONE:
                break
            self._grow_for(status, q)

    def _apply_masks(self, q: _QuietBlocks, keys: np.ndarray, masks: np.ndarray, counters: np.ndarray,
                     hit: bool = False) -> None:
        """``apply_mask_updates``: the projection's misses (or the hits of ``hit``), the blocks'
        masks applied as their voxels listed in key order would be, growing storage as it asks."""
        sc = self.cfg.sensor
        start = 0
        while True:
            o = self.O
            status, start = apply_mask_updates(
                keys, masks, start, hit,
                o.table_keys, o.table_vals, o.block_coords, o.meta, o.data["logodds"], o.data["stamp"], o.data["hit"],
                self.frame_id, self._tick_first, self._tb_block, self._tb_off, self._tb_meta,
                sc.hit_logodds, sc.miss_logodds, sc.clamp_min_logodds, sc.clamp_max_logodds, counters,
                q.nfree, q.qquiet, q.still, self.quiet_blocks, q.changed, q.ch_meta,
                self.D.table_keys, self.D.table_vals, self.D.data["st"], self.D.data["lt"],
            )  # fmt: skip
            if status == STATUS_DONE:
                break
            self._grow_for(status, q)

    def _grow_for(self, status: int, q: _QuietBlocks) -> None:
        """Grow what an apply kernel stopped for: O's blocks, the quiet blocks' change list, or
        the tick buffer."""
        if status == STATUS_NEED_BLOCKS:
            self.O.grow()
            q.fit(self.O.max_blocks)
        elif status == STATUS_NEED_CHANGED:
            q.changed = np.resize(q.changed, 2 * len(q.changed))
        else:
            self._grow_tick_buffer()

    def _quiet_sync(self) -> _QuietBlocks:
        """The quiet blocks' state for the map as it is now: made afresh when O was replaced (a
        loaded state) or the clamp changed, checked against D when D gained blocks."""
        q = self._quiet
        lo_min = float(np.float32(self.cfg.sensor.clamp_min_logodds))
        if q is None or q.o is not self.O or q.lo_min != lo_min or q.active != self.quiet_blocks:
            q = self._quiet = _QuietBlocks(self, lo_min)
        elif q.d is not self.D or q.d_blocks != self.D.n_blocks:
            q.revalidate(self)
        if q.tick != self.tick_index:
            q.after_tick(self)
        q.fit(self.O.max_blocks)
        return q

    def _grow_tick_buffer(self) -> None:
        n = len(self._tb_block) * 2
        self._tb_block = np.resize(self._tb_block, n)
        self._tb_off = np.resize(self._tb_off, n)

    # -- tick ---------------------------------------------------------------------------------
    def end_tick(self) -> TickResult:
        """Apply the tick rules to the voxels observed since the last tick."""

        lay = self.cfg.layers
        rise = lay.tick / lay.st_rise_s
        fall = lay.tick / lay.st_fall_s
        lt_fall = lay.tick / lay.lt_fall_s
        forget_ticks = max(1, int(round(lay.st_forget_s / lay.tick)))
        max_gap = max(1, int(round(lay.max_gap_s / lay.tick)))
        pc = self.cfg.projection
        k_lo, k_hi = band_k_range(pc.z_min, pc.z_max, self.resolution)
        every = self.events.sample_every(self.history_every)
        record_all = every > 0 and self.tick_index % every == 0
        ev = self.events
        n_tb = int(self._tb_meta[0])
        counters = np.zeros(5, dtype=np.int64)
        settings = TickSettings(
            rise=float(rise), fall=float(fall), lt_fall=float(lt_fall), occ_thr=float(pc.occupied_thresh),
            k_lo=int(k_lo), k_hi=int(k_hi), max_gap=int(max_gap), static_margin=int(lay.static_margin_cells),
            near_i0=int(self._near_i0), near_j0=int(self._near_j0), tick_index=int(self.tick_index),
            record_all=bool(record_all), forget_due=int(self.tick_index + forget_ticks),
        )  # fmt: skip
        start = 0
        while True:  # the arrays are taken anew after a growth
            d = self.D
            dl = DLayers(d.table_keys, d.table_vals, d.block_coords, d.meta, d.data["st"], d.data["lt"],
                         d.data["last_obs"], d.data["last_seen"], d.data["obst_since"], d.data["free_since"])  # fmt: skip
            bufs = EventBuffers(ev.tr, ev.tr_meta, ev.hist_i, ev.hist_v, ev.hist_p, ev.hist_meta)
            fq = ForgetQueue(self._fq_vid, self._fq_due, self._fq_meta)
            start = _tick_kernel(self._tb_block, self._tb_off, n_tb, start, self.O.block_coords,
                                 self.O.data["logodds"], self.O.data["hit"], dl, self._near, settings, bufs, fq,
                                 counters)  # fmt: skip
            if start == TICK_DONE:
                break
            if self.D.n_blocks >= self.D.max_blocks:
                self.D.grow()
            if self._fq_meta[0] >= len(self._fq_vid):
                self._grow_forget_queue()
            ev.grow(self.tick_index, self.history_every)
        d = self.D
        vids = self._due_voxels()
        if self._fq_meta[0] + len(vids) > len(self._fq_vid):  # (room for every one to be queued again)
            self._grow_forget_queue(len(vids))
        fq = ForgetQueue(self._fq_vid, self._fq_due, self._fq_meta)
        counts = np.zeros(1, dtype=np.int64)
        at = 0
        while True:
            at = _forget_due(vids, at, d.block_coords, d.data["st"], d.data["lt"], d.data["last_obs"],
                             d.data["obst_since"], self.tick_index, forget_ticks, k_lo, k_hi, ev.hist_i, ev.hist_v,
                             ev.hist_p, ev.hist_meta, fq, counts)  # fmt: skip
            if at < 0:
                break
            ev.grow(self.tick_index, self.history_every)
        forgotten = int(counts[0])
        result = TickResult(
            tick_index=self.tick_index,
            observed=n_tb,
            obstacles=int(counters[C_OBSTACLES]),
            seen_free=int(counters[C_SEEN_FREE]),
            lt_entered=int(counters[C_LT_ENTERED]),
            lt_left=int(counters[C_LT_LEFT]),
            st_forgotten=int(forgotten),
            held=int(counters[C_HELD]),
        )
        self.tick_index += 1
        self._tb_meta[0] = 0
        self._tick_first = self.frame_id + 1
        return result

    def _due_voxels(self) -> np.ndarray:
        """The forget queue's voxels due by this tick, taken out of it: their ids, sorted and
        unique (block, then offset, as the full scan visits them). The queue holds about one
        entry per voxel with ST > 0, in no order (``_take_due``: one pass)."""
        return np.unique(_take_due(self._fq_vid, self._fq_due, self._fq_meta, np.int64(self.tick_index)))

    def _grow_forget_queue(self, more: int = 0) -> None:
        """Double the queue until it has room for ``more`` entries beyond one."""
        n, cap = int(self._fq_meta[0]), len(self._fq_vid)
        new_cap = cap * 2
        while new_cap < n + more:
            new_cap *= 2
        vid = np.empty(new_cap, dtype=np.int64)
        due = np.empty(new_cap, dtype=np.int32)
        vid[:n] = self._fq_vid[:n]
        due[:n] = self._fq_due[:n]
        self._fq_vid, self._fq_due = vid, due

    def _seed_forget_queue(self) -> None:
        """Queue every voxel with ST > 0 of a loaded state at ``last_obs + forget_ticks`` (the
        queue otherwise learns them when they are seen)."""
        lay = self.cfg.layers
        forget_ticks = max(1, int(round(lay.st_forget_s / lay.tick)))
        st = self.D.channel("st")
        b, o = np.nonzero(st > 0)
        due = self.D.channel("last_obs")[b, o].astype(np.int64) + forget_ticks
        n = len(due)
        cap = max(1 << 16, 1 << int(np.ceil(np.log2(max(2 * n, 1)))))
        self._fq_vid = np.empty(cap, dtype=np.int64)
        self._fq_due = np.empty(cap, dtype=np.int32)
        self._fq_vid[:n] = b.astype(np.int64) * 512 + o
        self._fq_due[:n] = np.clip(due, -(2**31), 2**31 - 1)
        self._fq_meta[0] = n

    # -- long-term seeds ----------------------------------------------------------------------
    def seed_long_term(self, keys: np.ndarray, values) -> None:
        """Set LT at voxel keys (N, 3), e.g. from --resume or furniture drawn as long-term."""
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        vals = np.broadcast_to(np.asarray(values, dtype=np.float32), (len(keys),))
        if len(keys) and (vals.min() < 0 or vals.max() > 1):
            raise CoreError("long-term values must lie in [0, 1]")
        if len(keys) and int(np.abs(keys).max()) > KEY_LIMIT:
            far = keys[np.abs(keys).max(axis=1).argmax()] * self.resolution
            check_extent(far.astype(np.float64), 0.0, self.resolution, "long-term voxel")
        self.D.set("lt", keys, vals)
        if self._quiet is not None:  # (into D blocks that exist, too: quiet blocks with no ST or LT)
            self._quiet.d_blocks = -1

    # -- queries ------------------------------------------------------------------------------
    def occupied_keys(self, layer: str = "O") -> np.ndarray:
        """Keys (M, 3) of voxels occupied in a layer: O (log-odds > 0), ST or LT (>= the
        occupied threshold), S, or F = max(S, LT)."""
        thr = self.cfg.projection.occupied_thresh
        if layer == "O":
            return self.O.voxels_where(self.O.channel("logodds") > 0)
        if layer == "ST":
            return self.D.voxels_where(self.D.channel("st") >= thr)
        if layer == "LT":
            return self.D.voxels_where(self.D.channel("lt") >= thr)
        if layer == "S":
            return self._static_keys()
        if layer == "F":
            lt = self.occupied_keys("LT")
            s = self._static_keys()
            both = np.concatenate([lt, s]) if len(s) else lt
            return np.unique(both, axis=0) if len(both) else both
        raise CoreError(f"unknown layer {layer!r}; use O, ST, LT, S or F")

    def _static_keys(self) -> np.ndarray:
        if self.static is None:
            return np.zeros((0, 3), dtype=np.int64)
        return self.static.voxel_keys()

    def values(self, layer: str, keys: np.ndarray) -> np.ndarray:
        """Values of a layer at voxel keys: O log-odds (0 unknown), ST / LT in [0, 1], S 0/1."""
        if layer == "O":
            return self.O.get("logodds", keys)
        if layer in ("ST", "LT"):
            return self.D.get(layer.lower(), keys)
        if layer == "S":
            return (self.static.is_occupied(keys) if self.static else np.zeros(len(keys), bool)).astype(np.float32)
        if layer == "F":
            return np.maximum(self.values("S", keys), self.values("LT", keys))
        raise CoreError(f"unknown layer {layer!r}; use O, ST, LT, S or F")

    def known(self, keys: np.ndarray) -> np.ndarray:
        """True where O was ever updated."""
        return self.O.get("stamp", keys) > 0

    def nbytes(self) -> int:
        extra = self._tb_block.nbytes + self._tb_off.nbytes + self._near.nbytes
        if self.static is not None:
            extra += self.static.occ.nbytes + self.static.top_k.nbytes
        return self.O.nbytes() + self.D.nbytes() + extra

    # -- exact state --------------------------------------------------------------------------
    def state_arrays(self) -> dict[str, np.ndarray]:
        """Everything needed to continue exactly where this map stands (plain arrays; the voxel
        arrays are views of the map's: write them out or copy them before the map changes)."""
        out = {
            "resolution": np.array(self.resolution),
            "frame_id": np.array(self.frame_id),
            "tick_index": np.array(self.tick_index),
        }
        out.update({k: v for k, v in self.O.to_arrays("O_").items() if k[2:] not in O_TRANSIENT})
        out.update(self.D.to_arrays("D_"))
        return out

    def load_state_arrays(self, arrays: dict[str, np.ndarray], long_term_only: bool = False) -> None:
        """Load a state written by ``state_arrays``: everything, or only LT (what --resume
        carries from day 1 to day 2; O, ST and the clocks start afresh)."""
        res = float(arrays["resolution"])
        if abs(res - self.resolution) > 1e-9:
            raise CoreError(f"state resolution {res} differs from the map's {self.resolution}")
        D = VoxelGrid.from_arrays(res, D_CHANNELS, arrays, "D_")
        if long_term_only:
            keys = D.voxels_where(D.channel("lt") > 0)
            self.seed_long_term(keys, D.get("lt", keys))
            return
        self.D = D
        # the hit marks belong to a tick in progress, which a loaded state does not resume (states
        # written before the channel existed have none)
        o_arrays = {**arrays, **{f"O_{c}": np.full(np.shape(arrays["O_logodds"]), O_CHANNELS[c][1], dtype=O_CHANNELS[c][0])
                                 for c in O_TRANSIENT}}  # fmt: skip
        self.O = VoxelGrid.from_arrays(res, O_CHANNELS, o_arrays, "O_")
        self.frame_id = int(arrays["frame_id"])
        self.tick_index = int(arrays["tick_index"])
        self._tick_first = self.frame_id + 1
        self._tb_meta[0] = 0
        self._seed_forget_queue()


__all__ = [
    "BLOCK",
    "EventLog",
    "FrameResult",
    "LayeredMap",
    "StaticGrid",
    "TickResult",
    "top_k_from_height",
]
