"""Projective depth integration (issue 17, ``core.projective``; the default
``map.sensor.depth_integration``): depth rays walked by the DDA over their last
``projective_band`` + 2 voxels only, free space farther in front of the returns by projecting
voxels onto the image.

Hand-made frames of a camera at (0.01, 0.01, 1.01) looking along +x at a wall 3 m away:
- on the optical axis, a voxel 1 m out is a miss by projection, one within the band of the wall
  a miss by the exact ray tails only, the wall voxel a hit, one behind the wall unknown;
- a voxel whose centre projects onto a near box but which is partly seen past its edge (the
  rays to the wall pass through its corner) is a miss, as in the exact traversal;
- a removed box is forgotten: its voxels turn free as fast as with exact rays (the approximation
  the merged-rays experiment made did not: docs/performance.md);
- quiet blocks take no projective miss; exact mode stays one setting away, bit for bit the old
  path;
- the house sample replayed both ways: occupied voxels of O, LT and P agree (IoU >= 0.99).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ltmap_cli.config import Config
from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.core.projection import project
from ltmap_cli.core.projective import RIM

ROOT = Path(__file__).resolve().parent.parent
HOUSE = ROOT / "sample_logs" / "scenarios" / "06_house" / "log.mcap"

ORIGIN = np.array([0.01, 0.01, 1.01])
# optical frame (z forward, x right, y down) -> fixed frame: looking along +x
POSE = np.eye(4)
POSE[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
POSE[:3, 3] = ORIGIN
W, H, F = 160, 120, 100.0
CX, CY = (W - 1) / 2, (H - 1) / 2


# projective_blocks' view of the map: none (no O table, no quiet quarters or still voxels)
_NOT_SEEN = (np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int32), np.empty(0, dtype=np.uint8),
             np.empty((0, 8), dtype=np.uint64))  # fmt: skip


def _map(mode: str = "projective") -> LayeredMap:
    cfg = MapConfig()
    cfg.sensor.depth_integration = mode
    return LayeredMap(cfg)


def _wall(mm: int = 3000) -> np.ndarray:
    """A 16UC1 image of a plane ``mm`` millimetres away along the optical axis."""
    return np.full((H, W), mm, dtype=np.uint16)


def _integrate(m: LayeredMap, depth: np.ndarray):
    return m.integrate_depth(depth, F, F, CX, CY, POSE, 8.0)


def _logodds(m: LayeredMap, keys) -> np.ndarray:
    return m.values("O", np.asarray(keys, dtype=np.int64))


def _known(m: LayeredMap, keys) -> np.ndarray:
    return m.known(np.asarray(keys, dtype=np.int64))


def test_axis_voxels_by_hand():
    m = _map()
    wall_x = 3.0 + ORIGIN[0]  # the wall's x: the image's depth is along the optical axis
    proj = m.depth_projection(_wall(), F, F, CX, CY, POSE, 8.0, m.depth_rays(_wall(), F, F, CX, CY, POSE, 8.0)[0])
    by_projection = set()
    for key, mask in zip(proj.keys, proj.masks):
        bx, by, bz = (int(key) >> 42) - (1 << 20), ((int(key) >> 21) & ((1 << 21) - 1)) - (1 << 20), \
            (int(key) & ((1 << 21) - 1)) - (1 << 20)  # fmt: skip
        for off in range(512):
            if int(mask[off >> 6]) >> (off & 63) & 1:
                by_projection.add((bx * 8 + (off >> 6), by * 8 + ((off >> 3) & 7), bz * 8 + (off & 7)))
    near = (20, 0, 20)  # x in [1.00, 1.05): 1 m out, far in front of the band
    in_band = (int(np.floor((wall_x - 0.1) / 0.05)), 0, 20)  # 0.1 m before the wall: within the 0.2 m band
    assert near in by_projection
    assert in_band not in by_projection  # centre 2.925 m > 3.0 - 0.2 along its pixel's ray
    _integrate(m, _wall())
    wall = (int(np.floor(wall_x / 0.05)), 0, 20)
    behind = (wall[0] + 3, 0, 20)
    lo = _logodds(m, [near, in_band, wall])
    assert lo[0] == pytest.approx(m.cfg.sensor.miss_logodds, abs=1e-6)  # one miss
    assert lo[1] == pytest.approx(m.cfg.sensor.miss_logodds, abs=1e-6)  # by the exact tail of its ray
    assert lo[2] == pytest.approx(m.cfg.sensor.hit_logodds, abs=1e-6)
    assert not _known(m, [behind])[0]


def test_projective_frees_what_exact_frees_on_a_wall():
    """One frame of a wall: the two modes' misses nearly coincide; projective frees no voxel
    behind the wall or outside the camera's frustum."""
    a, b = _map("projective"), _map("exact")
    _integrate(a, _wall())
    _integrate(b, _wall())
    fa = {tuple(k) for k in a.O.voxels_where(a.O.channel("logodds") < 0)}
    fb = {tuple(k) for k in b.O.voxels_where(b.O.channel("logodds") < 0)}
    assert len(fa & fb) / len(fa | fb) > 0.97
    keys = np.array(sorted(fa))
    centres = (keys + 0.5) * 0.05 - ORIGIN
    assert (centres[:, 0] < 3.0 + 0.05).all()  # nothing behind the wall
    # inside the frustum, up to the angle the voxel's half diagonal subtends
    slack = np.arcsin(np.minimum(1.0, 0.5 * np.sqrt(3.0) * 0.05 / np.linalg.norm(centres, axis=1)))
    assert (np.abs(np.arctan2(centres[:, 1], centres[:, 0])) < np.arctan((W / 2) / F) + slack).all()
    assert (np.abs(np.arctan2(centres[:, 2], centres[:, 0])) < np.arctan((H / 2) / F) + slack).all()


def test_voxel_seen_past_an_occluding_edge_is_a_miss():
    """A box face 1.5 m away fills the image's left half; the wall at 3 m the right half. A voxel
    2 m out whose centre projects 2 pixels left of the edge (onto the box) is partly seen past it:
    the exact rays to the wall pass through it, and so must the projection's rim test."""
    depth = _wall()
    edge = W // 2
    depth[:, :edge] = 1500
    # the voxel 2 m out whose centre projects closest to 2 px left of the edge, on the axis's row
    z = 2.0
    u = edge - 2
    y_world = -(u - CX) / F * z + ORIGIN[1]  # optical x = -world y
    key = (int(np.floor((ORIGIN[0] + z) / 0.05)), int(np.floor(y_world / 0.05)), 20)
    cz = (key[0] + 0.5) * 0.05 - ORIGIN[0]
    cy = (key[1] + 0.5) * 0.05 - ORIGIN[1]
    u_centre = F * (-cy) / cz + CX
    assert edge - 4 < u_centre < edge - 0.5  # on the box's side of the edge: the centre test alone fails
    exact, projective = _map("exact"), _map("projective")
    _integrate(exact, depth)
    _integrate(projective, depth)
    assert _logodds(exact, [key])[0] < 0  # the exact rays to the wall clear it
    assert _logodds(projective, [key])[0] < 0


def test_removed_box_is_forgotten_as_with_exact_rays():
    """A box 1.5 m away in the middle of the image for 10 frames, then gone (the wall behind it
    seen) for 12: its face voxels turn from occupied to free in both modes, frame for frame."""
    with_box = _wall()
    with_box[40:80, 60:100] = 1500
    face = None
    history = {}
    for mode in ("exact", "projective"):
        m = _map(mode)
        for _ in range(10):
            _integrate(m, with_box)
        occ = m.O.voxels_where(m.O.channel("logodds") > 0)
        face = occ[np.abs((occ[:, 0] + 0.5) * 0.05 - ORIGIN[0] - 1.5) < 0.06]
        assert len(face) > 100
        seen = []
        for _ in range(12):
            _integrate(m, _wall())
            seen.append(int((_logodds(m, face) > 0).sum()))
        history[mode] = (len(face), seen)
    n_exact, seen_exact = history["exact"]
    n_proj, seen_proj = history["projective"]
    assert n_proj == n_exact
    assert seen_proj[-1] == 0 and seen_exact[-1] == 0
    # frame by frame, the projective map forgets at least as fast
    assert all(p <= e for p, e in zip(seen_proj, seen_exact))


def test_quiet_blocks_take_no_projective_miss():
    m = _map()
    for _ in range(8):  # misses clamp the free space in front of the wall: its blocks are quiet
        _integrate(m, _wall())
    q = m._quiet
    assert q.quiet[: m.O.n_blocks].sum() > 10
    stamp = m.O.channel("stamp").copy()
    quiet = q.quiet[: m.O.n_blocks].astype(bool)
    # and the quiet quarters (4 x 4 x 4) of the blocks that are not quiet: the wall's blocks
    off = np.arange(512)
    quarter = 4 * (off >> 6 >= 4) + 2 * ((off >> 3) % 8 >= 4) + (off % 8 >= 4)
    in_quiet_q = (q.qquiet[: m.O.n_blocks, None].astype(np.int64) >> quarter[None, :]) & 1 == 1
    partial = ~quiet & in_quiet_q.any(axis=1)
    assert partial.sum() > 5 and in_quiet_q[partial].sum() > 1000
    lo = m.O.channel("logodds").copy()
    _integrate(m, _wall())
    assert (m.O.channel("stamp")[quiet] == stamp[quiet]).all()
    assert (m.O.channel("stamp")[in_quiet_q] == stamp[in_quiet_q]).all()
    assert (m.O.channel("stamp")[~quiet] != stamp[~quiet]).any()
    # the other voxels of those blocks: the clamped-free ones (no ST or LT: nothing seen there)
    # are still, and take no miss either; the wall's voxels take their hits
    lo_min = np.float32(m.cfg.sensor.clamp_min_logodds)
    still = ~in_quiet_q & partial[:, None] & (lo == lo_min)
    assert still.sum() > 1000 and (m.O.channel("stamp")[still] == stamp[still]).all()
    wall = partial[:, None] & (lo > 0)
    assert wall.sum() > 100 and (m.O.channel("stamp")[wall] != stamp[wall]).all()


def _still_bits(m: LayeredMap) -> tuple[np.ndarray, np.ndarray]:
    """(O's still bits as bools (blocks, 512), the still voxels by the map's values: clamped
    free, no ST or LT)."""
    o, q = m.O, m._quiet_sync()
    n = o.n_blocks
    bits = np.unpackbits(q.still[:n].view(np.uint8), axis=1, bitorder="little").astype(bool)
    off = np.arange(512)
    local = np.stack([off >> 6, (off >> 3) & 7, off & 7], axis=1)
    keys = (o.block_coords[:n, None, :].astype(np.int64) << 3) + local[None]
    keys = keys.reshape(-1, 3)
    lo_min = np.float32(m.cfg.sensor.clamp_min_logodds)
    truth = (o.data["logodds"][:n].reshape(-1) == lo_min) & (m.D.get("st", keys) == 0) & (m.D.get("lt", keys) == 0)
    return bits, truth.reshape(n, 512)


def _slow_st_map() -> LayeredMap:
    """A map whose ST rises in 0.4 s and falls in 60 s: a box seen for a few ticks gets ST and
    LT, and keeps them after its voxels are clamped free again."""
    cfg = MapConfig()
    cfg.layers.st_rise_s, cfg.layers.st_fall_s = 0.4, 60.0
    return LayeredMap(cfg)


def test_still_bits_are_set_only_on_still_voxels():
    """The map's still bits (``_QuietBlocks.still``: what the workers' projection leaves out)
    are set only on voxels clamped free with no ST or LT, after every frame: a wall's free space
    clamped (every still voxel has its bit), a box put in it for the tick rules to give ST and
    LT and taken away (its voxels freed again with ST, no bit), LT seeded onto still voxels
    (their bits cleared)."""
    m = _slow_st_map()
    box = _wall()
    box[40:80, 60:100] = 1500
    for t, depth in enumerate([_wall()] * 8 + [box] * 12 + [_wall()] * 16):
        _integrate(m, depth)
        if t % 2:
            m.end_tick()
        bits, truth = _still_bits(m)
        assert not (bits & ~truth).any(), t
        if t == 7:  # no ST or LT yet: every still voxel has its bit
            assert truth.sum() > 10_000 and np.array_equal(bits, truth)
    lo_min = np.float32(m.cfg.sensor.clamp_min_logodds)
    freed = (m.O.data["logodds"][: m.O.n_blocks] == lo_min) & ~truth  # the box's voxels, free with ST or LT
    assert freed.sum() > 100
    assert bits.sum() > 0.95 * truth.sum()
    # LT seeded onto still voxels: their bits go at the next frame's start
    b, off = np.nonzero(bits)
    pick = slice(0, None, 97)
    keys = (m.O.block_coords[b[pick]].astype(np.int64) << 3) + np.stack([off[pick] >> 6, (off[pick] >> 3) & 7,
                                                                         off[pick] & 7], axis=1)  # fmt: skip
    m.seed_long_term(keys, 0.8)
    bits, truth = _still_bits(m)
    assert len(keys) > 50 and not (bits & ~truth).any()
    assert not bits[b[pick], off[pick]].any()


def _seen_as(how: str, real_seen, past: list, rng):
    """A ``LayeredMap._map_seen`` that gives the map as it was three frames before (``past``:
    what it gave after each frame), nothing, every quarter quiet and voxel still, or random
    ones."""

    def seen():
        if how == "late":
            return past[-3] if len(past) >= 3 else real_seen()
        keys, vals, qquiet, still = real_seen()
        if how == "never":
            return keys[:0], vals[:0], qquiet[:0], still[:0]
        if how == "all":
            return keys, vals, np.full_like(qquiet, 255), np.full_like(still, ~np.uint64(0))
        return (keys, vals, rng.integers(0, 256, qquiet.shape).astype(qquiet.dtype),
                rng.integers(0, 2**63, still.shape, dtype=np.uint64) << np.uint64(1))  # fmt: skip

    return seen


def test_what_the_workers_read_of_the_map_changes_nothing_however_old(monkeypatch):
    """The projection leaves out the quiet quarters and the still voxels it reads of the map
    (``LayeredMap._map_seen``) while the map thread is on earlier frames; the map thread fills
    in the voxels of those that are quiet or still no more (``projective_refill``). A wall seen
    until its free space is quiet, a box appearing in that space (its blocks un-quiet, ST and LT
    from the tick rules) and taken away: the same O (log-odds, stamps, block order) and D with
    the map read as it is, read three frames late, not read, read as all quiet and still, and
    read as random quarters and voxels; and fills happen only in the last three."""
    import ltmap_cli.core.layers as layers_mod

    box = _wall()
    box[40:80, 60:100] = 1500
    seq = [_wall()] * 8 + [box] * 10 + [_wall()] * 16
    fills = {"n": 0, "skipped": 0, "still": 0}
    real_fill, real_project = layers_mod.projective_refill, LayeredMap.depth_projection

    def counting_fill(*a):
        keys, masks, n = real_fill(*a)
        fills["n"] += n
        return keys, masks, n

    def counting_project(self, *a):
        p = real_project(self, *a)
        if p.skipped is not None:
            fills["skipped"] += len(p.skipped)
            fills["still"] += int(np.unpackbits(p.skipped_still.view(np.uint8)).sum())
        return p

    monkeypatch.setattr(layers_mod, "projective_refill", counting_fill)
    monkeypatch.setattr(LayeredMap, "depth_projection", counting_project)
    out, counts = {}, {}
    rng = np.random.default_rng(17)
    for how in ("fresh", "late", "never", "all", "random"):
        fills.update(n=0, skipped=0, still=0)
        m = _slow_st_map()
        real_seen = m._map_seen
        past: list[tuple] = []
        if how != "fresh":
            m._map_seen = _seen_as(how, real_seen, past, rng)
        for t, depth in enumerate(seq):
            _integrate(m, depth)
            if t % 3 == 2:
                m.end_tick()
            past.append(tuple(a.copy() for a in real_seen()))
        o, d = m.O, m.D
        out[how] = [o.block_coords[: o.n_blocks], o.channel("logodds"), o.channel("stamp"),
                    d.block_coords[: d.n_blocks], d.channel("st"), d.channel("lt")]
        counts[how] = dict(fills)
    assert out["fresh"][4].max() > 0 and out["fresh"][5].max() > 0  # (the box had ST and LT)
    for how in ("late", "never", "all", "random"):
        assert all(np.array_equal(a, b) for a, b in zip(out[how], out["fresh"])), how
    assert counts["fresh"]["skipped"] > 1000 and counts["fresh"]["still"] > 50_000, counts
    assert counts["never"]["skipped"] == 0
    assert counts["late"]["n"] > 5 and counts["all"]["n"] > 10 and counts["random"]["n"] > 10, counts
    assert counts["fresh"]["n"] == 0, counts  # (serial: what it reads is never stale)


def test_exact_mode_is_the_whole_ray_path():
    """``depth_integration: exact`` casts whole rays, as ``integrate`` does with the same rays."""
    a, b = _map("exact"), _map("exact")
    depth = _wall()
    depth[40:80, 60:100] = 1500
    _integrate(a, depth)
    ends, kind = b.depth_rays(depth, F, F, CX, CY, POSE, 8.0)
    b.integrate_rays(ORIGIN, ends, kind)
    for name in ("logodds", "stamp"):
        assert np.array_equal(a.O.channel(name), b.O.channel(name))


def test_projective_band_config_is_checked():
    cfg = MapConfig()
    cfg.sensor.depth_integration = "fast"
    cfg.sensor.projective_band = -1.0
    problems = cfg.validate()
    assert any("depth_integration" in p for p in problems)
    assert any("projective_band" in p for p in problems)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    sa, sb = set(map(tuple, a)), set(map(tuple, b))
    return len(sa & sb) / max(1, len(sa | sb))


@pytest.mark.skipif(not HOUSE.exists(), reason="house sample missing")
def test_house_sample_agrees_with_exact_rays(tmp_path):
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest

    maps = {}
    for mode in ("exact", "projective"):
        cfg = Config()
        cfg.replay.plots = False
        cfg.map.sensor.depth_integration = mode
        run = Replay(cfg, ReplayRequest([HOUSE], tmp_path / mode))
        run.run()
        lm = run.lmap
        p = project(lm)
        maps[mode] = (lm.O.voxels_where(lm.O.channel("logodds") > 0), lm.D.voxels_where(lm.D.channel("lt") > 0),
                      np.argwhere(p.data == 100) + [p.i0, p.j0])  # fmt: skip
    for what, a, b in zip(("O", "LT", "P"), maps["exact"], maps["projective"]):
        assert _iou(a, b) >= 0.99, what


def test_projection_listed_in_chunks_is_the_same(monkeypatch):
    """The blocks with misses are listed in chunks (memory follows the frustum's free space, not
    the frame's box, which holds millions of blocks at 0.01 m): chunks of 7 blocks give the same
    projection as one."""
    import ltmap_cli.core.layers as layers

    depth = _wall()
    depth[40:80, 60:100] = 1500
    m = _map()
    ends, _ = m.depth_rays(depth, F, F, CX, CY, POSE, 8.0)
    whole = m.depth_projection(depth, F, F, CX, CY, POSE, 8.0, ends)
    monkeypatch.setattr(layers, "PROJECTIVE_CHUNK_BLOCKS", 7)
    chunked = m.depth_projection(depth, F, F, CX, CY, POSE, 8.0, ends)
    assert len(whole.keys) > 7 * 3
    assert np.array_equal(whole.keys, chunked.keys) and np.array_equal(whole.masks, chunked.masks)
    # and with every other block read as quiet, or some of its quarters, and voxels read as
    # still: the skipped blocks' list fills its chunks too, and a block's quiet quarters and
    # still voxels are left out of its mask
    full = dict(zip(whole.keys.tolist(), whole.masks))
    _integrate(m, depth)
    keys_t, vals_t, qquiet, still = m._map_seen()
    rng = np.random.default_rng(5)
    qquiet = np.zeros_like(qquiet)
    listed = m.O.lookup(np.stack(_unpacked(whole.keys[::2]), axis=1) << 3)[0]
    assert (listed >= 0).all()
    qquiet[listed] = np.resize(np.array([255, 0x0F, 0xF0, 0x5A, 0x81, 0], dtype=np.uint8), len(listed))
    still = rng.integers(0, 2**63, still.shape, dtype=np.uint64) & rng.integers(0, 2**63, still.shape, dtype=np.uint64)
    m._map_seen = lambda: (keys_t, vals_t, qquiet, still)
    chunked = m.depth_projection(depth, F, F, CX, CY, POSE, 8.0, ends)
    monkeypatch.setattr(layers, "PROJECTIVE_CHUNK_BLOCKS", 1 << 14)
    whole2 = m.depth_projection(depth, F, F, CX, CY, POSE, 8.0, ends)
    assert len(whole2.skipped) > 7 * 2
    assert np.array_equal(whole2.keys, chunked.keys) and np.array_equal(whole2.masks, chunked.masks)
    assert np.array_equal(whole2.skipped, chunked.skipped)
    assert np.array_equal(whole2.skipped_still, chunked.skipped_still)
    got = dict(zip(whole2.keys.tolist(), whole2.masks))
    for key, mask in full.items():  # by hand: the full mask without the quiet quarters' and still voxels
        ob = m.O.lookup(np.stack(_unpacked(np.array([key])), axis=1) << 3)[0][0]
        qq = int(qquiet[ob]) if ob >= 0 else 0
        st = [int(x) for x in still[ob]] if ob >= 0 else [0] * 8
        want = [int(mask[w]) & ~st[w] & ~sum(0xF << (y * 8 + (q & 1) * 4) for q in range(8)
                                               if qq >> q & 1 and q >> 2 == w >> 2
                                               for y in range((q >> 1 & 1) * 4, (q >> 1 & 1) * 4 + 4)) for w in range(8)]
        assert ([int(x) for x in got[key]] if key in got else [0] * 8) == want, (key, qq)
    skipped = {int(b[0]) >> 8: (int(b[0]) & 255, [int(x) for x in w]) for b, w in zip(whole2.skipped, whole2.skipped_still)}
    assert sum(qq == 255 for qq, _ in skipped.values()) > 3 and all(any(w) for qq, w in skipped.values() if qq == 0)


def _unpacked(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``grid.pack_block``'s keys back to block coordinates."""
    keys = np.asarray(keys, dtype=np.int64)
    m = (1 << 21) - 1
    return (keys >> 42) - (1 << 20), ((keys >> 21) & m) - (1 << 20), (keys & m) - (1 << 20)


def _encoded(depth_mm: np.ndarray, float32: bool) -> np.ndarray:
    """Millimetres (0: no return) as a 16UC1 image, or as 32FC1 metres with NaN holes."""
    if not float32:
        return depth_mm.astype(np.uint16)
    img = (depth_mm / 1000.0).astype(np.float32)
    img[img == 0] = np.nan
    return img


def _random_pose(rng: np.random.Generator, max_pitch: float) -> np.ndarray:
    """The camera looking level-ish (pitch within +-max_pitch rad) in a random direction from a
    random point near (0, 0, 1.5): optical frame -> fixed frame."""
    yaw, pitch = rng.uniform(-np.pi, np.pi), rng.uniform(-max_pitch, max_pitch)
    cy_, sy_, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    R_world = np.array([[cy_, -sy_, 0], [sy_, cy_, 0], [0, 0, 1]]) @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    pose = np.eye(4)
    pose[:3, :3] = R_world @ POSE[:3, :3]
    pose[:3, 3] = rng.uniform(-2, 2, 3) + [0, 0, 1.5]
    return pose


@pytest.mark.parametrize("seed", [0, 1, *(pytest.param(s, marks=pytest.mark.slow) for s in range(2, 6))])  # (4 in the slow tier)
def test_random_depth_images_hit_the_same_voxels(seed):
    """Seeded random depth images (a wall, boxes at random depths, holes, pixels beyond max range,
    both encodings) from random poses: one frame into an empty map marks the same occupied voxels
    in both modes (hits go first and a miss never clears a voxel the frame hit), projective frees
    nothing beyond the 8 m range, and it frees at least 90 % of what exact frees."""
    rng = np.random.default_rng(seed)
    depth = rng.normal(4000, 30, (H, W)).clip(1, 65535)
    for _ in range(rng.integers(1, 6)):
        v0, u0 = rng.integers(0, H - 10), rng.integers(0, W - 10)
        depth[v0:v0 + rng.integers(5, 60), u0:u0 + rng.integers(5, 80)] = rng.uniform(300, 9500)
    depth[rng.random((H, W)) < 0.05] = 0  # holes
    img = _encoded(depth, float32=bool(seed % 2))
    pose = _random_pose(rng, 0.4)
    maps = {}
    for mode in ("exact", "projective"):
        m = _map(mode)
        m.integrate_depth(img, F, F, CX, CY, pose, 8.0)
        maps[mode] = m
    occ = {mode: {tuple(k) for k in m.O.voxels_where(m.O.channel("logodds") > 0)} for mode, m in maps.items()}
    assert occ["exact"] == occ["projective"] and len(occ["exact"]) > 100
    free = {mode: {tuple(k) for k in m.O.voxels_where(m.O.channel("logodds") < 0)} for mode, m in maps.items()}
    keys = np.array(sorted(free["projective"]))
    dist = np.linalg.norm((keys + 0.5) * 0.05 - pose[:3, 3], axis=1)
    assert dist.max() < 8.0 + 0.1
    assert len(free["exact"] & free["projective"]) / len(free["exact"]) > 0.9


@pytest.mark.parametrize("shape", [(120, 160), (37, 61), (5, 3)])
@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_range_image_and_tiles_against_numpy(shape, encoding):
    """``depth_range_image``: per pixel the range along its ray cut at max_range, minus the band
    (-1 - band where invalid), and per 8 x 8 tile (the last row and column of tiles partial when
    the image is not a multiple of 8) the least and greatest range, and up the pyramid, 2 x 2
    tiles of the level below."""
    from ltmap_cli.core.layers import _depth_view
    from ltmap_cli.core.projective import TILE, depth_range_image, pixel_range_factors

    h, w = shape
    rng = np.random.default_rng(h * w)
    z = rng.uniform(0.3, 12.0, size=shape)
    holes = rng.random(shape) < 0.1
    if encoding == "16UC1":
        raw = np.round(z * 1000).astype(np.uint16)
        raw[holes] = 0
        zf = raw.astype(np.float32) * np.float32(0.001)
    else:
        raw = z.astype(np.float32)
        raw[holes] = np.nan
        raw[0, 0] = -1.0  # <= 0: invalid
        zf = raw
    valid = np.isfinite(zf) & (zf > 0)
    f, cx, cy, band = 90.0, (w - 1) / 2 + 0.3, (h - 1) / 2 - 0.2, 0.2
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    r = np.minimum(zf.astype(np.float64) * np.sqrt(1 + ((u - cx) / f) ** 2 + ((v - cy) / f) ** 2), 8.0)
    r = np.where(valid, r.astype(np.float32), np.float32(-1.0)).astype(np.float32)
    depth, unit_mm = _depth_view(raw)
    reach, tmin, tmax, _ = depth_range_image(depth, unit_mm, pixel_range_factors(*depth.shape, f, f, cx, cy), 8.0, band)
    np.testing.assert_allclose(reach, r - np.float32(band), rtol=1e-6, atol=1e-6)
    th, tw = -(-h // TILE), -(-w // TILE)
    lo, hi = r.copy(), r.copy()
    for lv in range(tmin.shape[0]):
        want_lo = np.array([[lo[a * (TILE << lv):(a + 1) * (TILE << lv), b * (TILE << lv):(b + 1) * (TILE << lv)].min()
                             for b in range(tw)] for a in range(th)])  # fmt: skip
        want_hi = np.array([[hi[a * (TILE << lv):(a + 1) * (TILE << lv), b * (TILE << lv):(b + 1) * (TILE << lv)].max()
                             for b in range(tw)] for a in range(th)])  # fmt: skip
        np.testing.assert_allclose(tmin[lv, :th, :tw], want_lo, rtol=1e-6)
        np.testing.assert_allclose(tmax[lv, :th, :tw], want_hi, rtol=1e-6)
        th, tw = -(-th // 2), -(-tw // 2)


@pytest.mark.parametrize("mode, band, z", [("hi", 0.2, 65.0), ("hi", 0.1, 40.0), ("hi", 0.2, 7.9), ("lo", 0.15, 40.0),
                                           ("lo", 0.15, 33.3), ("lo", 0.2, 40.0)])  # fmt: skip
def test_quarter_bounds_are_exactly_the_voxel_tests(mode, band, z):
    """A voxel whose centre's distance lies between its pixel's reach as computed (float32 range
    - float32 band) and range - band in float64 (a micrometre apart at 40 m): it is a miss
    exactly when the reach is beyond it, as the per-voxel test says, whatever bounds its quarter
    takes (found by review: bounds with a fixed 1e-6 m margin got it wrong beyond 16 m). "hi":
    only its pixel reaches that far; "lo": every pixel's depth is the same (beyond 25 m, where
    the voxel's rim lies within its pixel: the pixels around have longer ranges)."""
    from ltmap_cli.core.grid import pack_block, voxel_offset
    from ltmap_cli.core.projective import depth_range_image, pixel_range_factors, projective_blocks

    res, f, k0 = 0.05, 500.0, 1000
    z32 = np.float32(z)
    reach = np.float64(np.float32(z32 - np.float32(band)))
    exact = np.float64(z32) - band
    assert (reach > exact) == (mode == "hi")
    dist = 0.5 * (reach + exact)  # the voxel centre's distance from the camera
    depth = np.full((15, 15), z32 if mode == "lo" else np.float32(z * 0.5), dtype=np.float32)
    depth[7, 7] = z32  # the pixel the voxel (0, 0, k0) projects onto: its centre is on the optical axis
    t = np.array([0.5 * res, 0.5 * res, (k0 + 0.5) * res - dist])
    Tinv = np.ascontiguousarray(np.hstack([np.eye(3), -t[:, None]]))
    img, tmin, tmax, dil = depth_range_image(depth, False, pixel_range_factors(*depth.shape, f, f, 7.0, 7.0), 0.0, band)
    assert np.float64(img[7, 7]) == reach
    box = np.array([-8, -8, k0 - 8, 8, 8, k0 + 8], dtype=np.int64)
    keys, masks = np.empty(64, dtype=np.int64), np.zeros((64, 8), dtype=np.uint64)
    skipped = np.empty((64, 2), dtype=np.int64)
    n, ns, nxt = projective_blocks(img, tmin, tmax, dil, f, f, 7.0, 7.0, Tinv, box, res, band, keys, masks, 0,
                                   *_NOT_SEEN, skipped, np.empty((64, 8), dtype=np.uint64), 0)  # fmt: skip
    assert nxt == -1 and ns == 0
    blocks = {int(keys[q]): masks[q] for q in range(n)}
    off = voxel_offset(0, 0, k0)
    word = blocks.get(pack_block(0, 0, k0 >> 3), np.zeros(8, dtype=np.uint64))[off >> 6]
    assert bool((int(word) >> (off & 63)) & 1) == (mode == "hi")


def _reference_misses(reach: np.ndarray, fx, fy, cx, cy, Tinv: np.ndarray, box: np.ndarray, res: float) -> set:
    """The voxels of ``box`` (inclusive voxel keys) the projection makes misses, by the rule
    ``projective_blocks`` states, voxel by voxel with numpy (no block or quarter bounds, no
    tiles): the voxel's centre in the optical frame, as the kernel computes it (block origin +
    offsets times a voxel step), with z > 0, is nearer than the reach of its pixel or of one of
    the 8 pixels at the rim of its projection (centre +- ``RIM`` voxel sizes, projected)."""
    h, w = reach.shape
    ii, jj, kk = np.meshgrid(*(np.arange(box[a], box[3 + a] + 1) for a in range(3)), indexing="ij")
    ii, jj, kk = ii.ravel(), jj.ravel(), kk.ravel()
    c0 = [((v >> 3) * 8 + 0.5) * res for v in (ii, jj, kk)]  # the block's voxel (0, 0, 0)
    off = [v & 7 for v in (ii, jj, kk)]
    p = [Tinv[r, 0] * c0[0] + Tinv[r, 1] * c0[1] + Tinv[r, 2] * c0[2] + Tinv[r, 3] for r in range(3)]
    x, y, z = (p[r] + off[0] * (Tinv[r, 0] * res) + off[1] * (Tinv[r, 1] * res) + off[2] * (Tinv[r, 2] * res)
               for r in range(3))  # fmt: skip
    d2 = x * x + y * y + z * z
    with np.errstate(divide="ignore", invalid="ignore"):
        iz = 1.0 / z
        uf, vf = fx * x * iz + cx + 0.5, fy * y * iz + cy + 0.5
        su, sv = RIM * res * fx * iz, RIM * res * fy * iz
        free = np.zeros(len(d2), dtype=bool)
        for du, dv in [(0, 0), (-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)]:
            ug, vg = uf + su * du, vf + sv * dv
            inside = (z > 0) & (ug >= 0) & (ug < w) & (vg >= 0) & (vg < h)
            r = np.full(len(d2), -1.0)
            r[inside] = reach[vg[inside].astype(np.int64), ug[inside].astype(np.int64)].astype(np.float64)
            free |= inside & (r > 0) & (r * r > d2)
    return set(zip(ii[free].tolist(), jj[free].tolist(), kk[free].tolist()))


def _random_frame(seed: int) -> tuple:
    """(image, f, cx, cy, pose, max_range): a seeded depth image (a wall, boxes at random depths
    whose edges occlude, holes, pixels beyond max range, 16UC1 for even seeds, 32FC1 for odd),
    random intrinsics and a random pose."""
    rng = np.random.default_rng(100 + seed)
    h, w = int(rng.integers(40, 90)), int(rng.integers(50, 120))
    f = float(rng.uniform(40, 120))
    depth = rng.normal(rng.uniform(1500, 3500), 20, (h, w)).clip(1, 65535)
    for _ in range(rng.integers(2, 7)):
        v0, u0 = rng.integers(0, h - 5), rng.integers(0, w - 5)
        depth[v0:v0 + rng.integers(3, 40), u0:u0 + rng.integers(3, 50)] = rng.uniform(250, 4500)
    depth[rng.random((h, w)) < 0.05] = 0  # holes
    depth[rng.random((h, w)) < 0.01] = 9000  # beyond max range: clear up to it
    max_range = 4.0
    img = _encoded(depth, float32=bool(seed % 2))
    pose = _random_pose(rng, 0.5)
    cx, cy = (w - 1) / 2 + rng.uniform(-3, 3), (h - 1) / 2 + rng.uniform(-3, 3)
    return img, f, cx, cy, pose, max_range


@pytest.mark.parametrize("seed", [0, 1, 5, *(pytest.param(s, marks=pytest.mark.slow) for s in (2, 3, 4, 6, 7))])
def test_projection_is_the_per_voxel_rule(seed):  # (5: misses by the rule in the box's blocks beyond it)
    """Seeded depth images (``_random_frame``) from random poses: the blocks' masks
    ``depth_projection`` lists are exactly the misses of the rule applied voxel by voxel
    (``_reference_misses``) within the frame's voxel box: the block and quarter bounds, the tiles
    and the kernel's passes only save work."""
    _assert_projection_is_the_rule(*_random_frame(seed))


@pytest.mark.parametrize("seed", [5, 0, 1])  # (5: 39 voxels of the box's blocks beyond it are misses by the rule)
def test_voxels_read_as_still_and_filled_in_by_the_map_thread_are_the_rule(seed):
    """A worker that read every voxel of the frame's box as still tests none and leaves each
    block to the map thread's fill (``projective_refill``), which tests those not still by then
    (here all): the masks are then exactly the rule's within the frame's voxel box
    (``_reference_misses``), as when nothing is read as still; the voxels of the box's blocks
    beyond it (no ray passes them) are left out by the fill as by the worker."""
    from ltmap_cli.core.grid import BLOCK_BITS, unpack_block
    from ltmap_cli.core.projective import depth_range_image, ends_box, pixel_range_factors, projective_refill

    img, f, cx, cy, pose, max_range = _random_frame(seed)
    m = _map()
    ends, _ = m.depth_rays(img, f, f, cx, cy, pose, max_range)
    box = ends_box(np.ascontiguousarray(pose[:3, 3]), ends, 1.0 / m.resolution)
    blocks = np.stack(np.meshgrid(*(np.arange(box[a] >> BLOCK_BITS, (box[3 + a] >> BLOCK_BITS) + 1) for a in range(3)),
                      indexing="ij"), axis=-1).reshape(-1, 3) << BLOCK_BITS  # fmt: skip
    o = m.O
    o.allocate(blocks)  # every block of the box in O, so the worker reads its still voxels
    qquiet = np.zeros(o.max_blocks, dtype=np.uint8)
    still = np.full((o.max_blocks, 8), ~np.uint64(0))
    m._map_seen = lambda: (o.table_keys, o.table_vals, qquiet, still)
    proj = m.depth_projection(img, f, f, cx, cy, pose, max_range, ends)
    assert len(proj.keys) == 0 and len(proj.skipped) > 100
    keys, masks, n = projective_refill(*proj.fill, proj.skipped, proj.skipped_still, o.block_coords, o.n_blocks,
                                       np.zeros_like(qquiet), np.zeros_like(still), proj.keys, proj.masks)  # fmt: skip
    assert n == len(proj.skipped)
    got = set()
    for key, mask in zip(keys, masks):
        b = np.array(unpack_block(int(key))) * 8
        bits = np.nonzero(np.unpackbits(mask.view(np.uint8), bitorder="little"))[0]
        got.update(zip((b[0] + (bits >> 6)).tolist(), (b[1] + ((bits >> 3) & 7)).tolist(), (b[2] + (bits & 7)).tolist()))
    R, t = pose[:3, :3], pose[:3, 3]
    reach = depth_range_image(img, img.dtype == np.uint16, pixel_range_factors(*img.shape, f, f, cx, cy), max_range,
                              m.cfg.sensor.projective_band)[0]  # fmt: skip
    want = _reference_misses(reach, f, f, cx, cy, np.hstack([R.T, (-R.T @ t)[:, None]]), box, m.resolution)
    assert len(want) > 1000
    assert got == want, f"{len(got - want)} filled in but not misses, {len(want - got)} misses not filled in"


def _assert_projection_is_the_rule(img, f, cx, cy, pose, max_range) -> None:
    """The voxels ``depth_projection``'s block masks hold are exactly ``_reference_misses``'
    (the rule applied voxel by voxel), and they are many."""
    from ltmap_cli.core.grid import unpack_block
    from ltmap_cli.core.projective import depth_range_image, pixel_range_factors

    m = _map()
    ends, _ = m.depth_rays(img, f, f, cx, cy, pose, max_range)
    proj = m.depth_projection(img, f, f, cx, cy, pose, max_range, ends)
    got = set()
    for key, mask in zip(proj.keys, proj.masks):
        b = np.array(unpack_block(int(key))) * 8
        bits = np.nonzero(np.unpackbits(mask.view(np.uint8), bitorder="little"))[0]
        got.update(zip((b[0] + (bits >> 6)).tolist(), (b[1] + ((bits >> 3) & 7)).tolist(), (b[2] + (bits & 7)).tolist()))
    R, t = pose[:3, :3], pose[:3, 3]
    Tinv = np.hstack([R.T, (-R.T @ t)[:, None]])
    reach = depth_range_image(img, img.dtype == np.uint16, pixel_range_factors(*img.shape, f, f, cx, cy), max_range,
                              m.cfg.sensor.projective_band)[0]  # fmt: skip
    want = _reference_misses(reach, f, f, cx, cy, Tinv, proj.box, m.resolution)
    assert len(want) > 1000
    assert got == want, f"{len(got - want)} listed but not misses, {len(want - got)} misses not listed"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rim_pixels_in_the_middle_tiles_count(seed):
    """Voxels 0.25 to 0.45 m from the camera, whose rim (4 to 8 pixels a side here) crosses
    three tiles, in front of a near background with far patches of one tile each: a voxel whose
    centre pixel and the rim's corner tiles are near but one of its rim pixels lies in a far
    middle tile is a miss, as the rule says (``_reference_misses``). The tile bound of the
    corners alone left such voxels out on each of thirty such frames."""
    rng = np.random.default_rng(seed)
    h, w, f = 80, 96, 100.0
    depth = np.full((h, w), 420.0)
    for _ in range(6):  # far patches, each one tile (8 x 8 pixels, on the tiles' grid)
        a, b = rng.integers(0, h // 8), rng.integers(0, w // 8)
        depth[8 * a : 8 * a + 8, 8 * b : 8 * b + 8] = 3000
    _assert_projection_is_the_rule(_encoded(depth, float32=False), f, (w - 1) / 2, (h - 1) / 2, _random_pose(rng, 0.05),
                                   4.0)  # fmt: skip


@pytest.mark.parametrize("far_from, miss", [(22, True), (23, False)])
def test_rim_pixels_stand_for_rays_through_the_voxel(far_from, miss):
    """A voxel 1 m out face on (0.05 m: 5 pixels at f = 100), its centre on pixel 20's ray, in
    front of a near occluder that covers pixels up to ``far_from`` - 1; beyond, the background.
    Pixel 22's ray passes through the voxel (0.02 m off its centre line at 1 m, within its
    0.025 m half width): a ray seen past the occluder crosses it, so it is a miss. Pixel 23's
    passes outside it (0.029 to 0.031 m off over its depth): no ray to the background crosses
    it, and it is not (the rim at +-0.5 voxel, rounded to a pixel, took pixel 23: a voxel under
    a table top's far edge was cleared so)."""
    from ltmap_cli.core.grid import pack_block, voxel_offset
    from ltmap_cli.core.projective import depth_range_image, pixel_range_factors, projective_blocks

    res, f, band, k0 = 0.05, 100.0, 0.2, 1000
    depth = np.full((41, 41), 600, dtype=np.uint16)  # the occluder, 0.6 m out
    depth[:, far_from:] = 3000  # the background
    t = np.array([0.5 * res, 0.5 * res, (k0 + 0.5) * res - 1.0])  # voxel (0, 0, k0)'s centre at (0, 0, 1)
    Tinv = np.ascontiguousarray(np.hstack([np.eye(3), -t[:, None]]))
    img, tmin, tmax, dil = depth_range_image(depth, True, pixel_range_factors(*depth.shape, f, f, 20.0, 20.0), 8.0, band)
    box = np.array([-8, -8, k0 - 8, 8, 8, k0 + 8], dtype=np.int64)
    keys, masks = np.empty(64, dtype=np.int64), np.zeros((64, 8), dtype=np.uint64)
    skipped = np.empty((64, 2), dtype=np.int64)
    n, _, _ = projective_blocks(img, tmin, tmax, dil, f, f, 20.0, 20.0, Tinv, box, res, band, keys, masks, 0,
                                *_NOT_SEEN, skipped, np.empty((64, 8), dtype=np.uint64), 0)  # fmt: skip
    blocks = {int(keys[q]): masks[q] for q in range(n)}
    off = voxel_offset(0, 0, k0)
    word = blocks.get(pack_block(0, 0, k0 >> 3), np.zeros(8, dtype=np.uint64))[off >> 6]
    assert bool((int(word) >> (off & 63)) & 1) == miss


def _mask_voxels(keys, masks) -> set:
    """The voxel keys (i, j, k) a list of blocks' masks holds, decoded here by hand."""
    out = set()
    for key, mask in zip(keys, masks):
        bx, by, bz = (int(key) >> 42) - (1 << 20), ((int(key) >> 21) & ((1 << 21) - 1)) - (1 << 20), \
            (int(key) & ((1 << 21) - 1)) - (1 << 20)  # fmt: skip
        for off in range(512):
            if int(mask[off >> 6]) >> (off & 63) & 1:
                out.add((bx * 8 + (off >> 6), by * 8 + ((off >> 3) & 7), bz * 8 + (off & 7)))
    return out


def same_by_coords(a: LayeredMap, b: LayeredMap, channels=None) -> None:
    """O's and D's channels (``channels``, or all) the same voxel by voxel, blocks matched by
    their coordinates (the order blocks are made in follows the order voxels are updated in)."""
    for layer in ("O", "D"):
        ga, gb = getattr(a, layer), getattr(b, layer)
        ia = {tuple(c): i for i, c in enumerate(ga.block_coords[: ga.n_blocks])}
        ib = {tuple(c): i for i, c in enumerate(gb.block_coords[: gb.n_blocks])}
        assert ia.keys() == ib.keys() and len(ia) > 0
        for ch in ga.data:
            if channels is not None and ch not in channels:
                continue
            for c, i in ia.items():
                assert np.array_equal(ga.data[ch][i], gb.data[ch][ib[c]]), (layer, ch)


def _unpack_voxels(keys) -> list:
    """Packed voxel keys (``grid.pack_block``'s packing) as (i, j, k) tuples."""
    from ltmap_cli.core.grid import unpack_block

    return [tuple(int(c) for c in unpack_block(int(key))) for key in keys]


@pytest.mark.parametrize("bitmap", [True, False])
def test_tail_masks_by_hand(bitmap):
    """``tail_masks`` at 1 m voxels: each ray's last ``tail`` metres walked into the
    projection's masks (the end voxel not walked; a ray shorter than the tail walked from the
    origin's voxel; a dropped ray nothing), the hit rays' end voxels into masks of their own,
    keys ascending, new blocks added in key order; a voxel outside the frame's box refuses (the
    caller lists the frame's voxels instead). The tails' misses set in a bitmap of the box's
    blocks and, in a box over ``bitmap_max_blocks``, in rows found voxel by voxel: the same."""
    from ltmap_cli.core.grid import pack_blocks
    from ltmap_cli.core.projective import LISTED_VOXELS_MAX_BLOCKS as LIMIT
    from ltmap_cli.core.projective import tail_masks as masks_of
    from ltmap_cli.core.raycast import RAY_CLEAR, RAY_HIT, RAY_SKIP

    def tail_masks(*a):
        return masks_of(*a, 1 << 16 if bitmap else 0)

    box = np.array([-16, 0, 0, 23, 15, 7], dtype=np.int64)  # blocks x -2..2, y 0..1, z 0
    pkeys = np.sort(pack_blocks(np.array([[-1, 0, 0], [1, 1, 0]], dtype=np.int64)))
    pmasks = np.zeros((2, 8), dtype=np.uint64)
    pmasks[0, 0], pmasks[1, 7] = 1, 1 << 63
    before = _mask_voxels(pkeys, pmasks)  # (-8, 0, 0) and (15, 15, 7)
    origin = np.array([0.5, 0.5, 0.5])
    ends = np.array([
        [10.5, 0.5, 0.5],  # a hit 10 m along x: tail from x = 7.5
        [0.5, 12.5, 0.5],  # a clear ray along y: its tail from y = 9.5, no hit
        [-13.5, 0.5, 0.5],  # dropped
        [0.5, 0.5, 2.5],  # a hit 2 m away, shorter than the tail: from the origin's voxel
        [0.9, 0.1, 0.5],  # a hit in the origin's voxel: nothing walked
    ])  # fmt: skip
    kind = np.array([RAY_HIT, RAY_CLEAR, RAY_SKIP, RAY_HIT, RAY_HIT], dtype=np.int8)
    keys, masks, hkeys, hmasks, ok = tail_masks(origin, ends, kind, 1.0, 1.0, 3.0, pkeys, pmasks, box, LIMIT)
    assert ok
    # blocks (-1,0,0) and (1,1,0), and new: (0,0,0), (1,0,0) (x 8, 9) and (0,1,0) (y 9 to 11)
    assert np.all(np.diff(keys) > 0) and len(keys) == 5
    assert _mask_voxels(keys, masks) == before | {(7, 0, 0), (8, 0, 0), (9, 0, 0), (0, 9, 0), (0, 10, 0), (0, 11, 0),
                                                  (0, 0, 0), (0, 0, 1)}  # fmt: skip
    assert np.all(np.diff(hkeys) > 0) and len(hkeys) == 2  # blocks (0,0,0) and (1,0,0) only
    assert _mask_voxels(hkeys, hmasks) == {(10, 0, 0), (0, 0, 2), (0, 0, 0)}
    # a tail of 1.5 m: from x = 9, y = 11, z = 1
    keys, masks, _, _, ok = tail_masks(origin, ends, kind, 1.0, 1.0, 1.5, pkeys[:0], pmasks[:0], box, LIMIT)
    assert ok and _mask_voxels(keys, masks) == {(9, 0, 0), (0, 11, 0), (0, 0, 1)}
    small = np.array([-16, 0, 0, 7, 15, 7], dtype=np.int64)  # the first ray's tail and hit are beyond it
    assert not tail_masks(origin, ends, kind, 1.0, 1.0, 3.0, pkeys, pmasks, small, LIMIT)[4]
    narrow = np.array([-16, 0, 0, 23, 7, 7], dtype=np.int64)  # the clear ray's tail (y 10, 11) is beyond it
    assert not tail_masks(origin, ends[1:2], kind[1:2], 1.0, 1.0, 3.0, pkeys[:0], pmasks[:0], narrow, LIMIT)[4]
    assert tail_masks(origin, ends[3:], kind[3:], 1.0, 1.0, 3.0, pkeys[:0], pmasks[:0], narrow, LIMIT)[4]
    # no tail (0): whole rays, from the origin's voxel (``LayeredMap.ray_voxels``: scans, clouds)
    keys, masks, hkeys, hmasks, ok = tail_masks(origin, ends, kind, 1.0, 1.0, 0.0, pkeys[:0], pmasks[:0], box, LIMIT)
    assert ok and _mask_voxels(hkeys, hmasks) == {(10, 0, 0), (0, 0, 2), (0, 0, 0)}
    assert _mask_voxels(keys, masks) == ({(x, 0, 0) for x in range(10)} | {(0, y, 0) for y in range(12)}
                                         | {(0, 0, 0), (0, 0, 1)})  # fmt: skip
    # a box of more blocks than the limit refuses (``box`` holds 10)
    assert tail_masks(origin, ends[3:], kind[3:], 1.0, 1.0, 3.0, pkeys[:0], pmasks[:0], box, 9)[4] is False
    assert tail_masks(origin, ends[3:], kind[3:], 1.0, 1.0, 3.0, pkeys[:0], pmasks[:0], box, 10)[4] is True


def _scalar_walk(af, ai, q):
    """Ray ``q`` of a ``ray_starts`` chunk walked a step at a time by ``ray_step`` (the walk of
    ``frame_voxels`` and of whole rays in ``tail_masks``): the voxels it records, in order."""
    from ltmap_cli.core.raycast import ray_state, ray_step

    walk, ei, ej, ek, ci, cj, ck, si, sj, sk, tmx, tmy, tmz, tdx, tdy, tdz, length, max_steps = ray_state(af, ai, q)
    steps, out = 0, []
    while walk:
        out.append((int(ci), int(cj), int(ck)))
        _, ci, cj, ck, tmx, tmy, tmz, steps, walk = ray_step(ci, cj, ck, tmx, tmy, tmz, si, sj, sk, tdx, tdy, tdz,
                                                             ei, ej, ek, length, steps, max_steps)  # fmt: skip
    return out


def test_tail_walks_in_lockstep_are_the_walks_of_ray_step():
    """``_tail_walks`` (a chunk's tails walked in lockstep, with selects) records for each ray
    the voxels ``ray_step`` walks, in order: on rays whose crossings tie (diagonals from a voxel's
    centre, where ``ray_step``'s strict < picks the axis), rays ending on a voxel face (the walk
    stops when its next crossing is past the ray's length, not at it), rays cut to a tail, and
    rays whose end voxel is off their path (the walk stops after ``max_steps`` steps)."""
    from ltmap_cli.core.grid import BLOCK_BITS
    from ltmap_cli.core.projective import NOT_WALKED, _tail_walks
    from ltmap_cli.core.raycast import RAY_CHUNK, RS_EI, RS_EK, RS_LENGTH, ray_start_buffers, ray_starts

    rng = np.random.default_rng(17)
    o = np.array([0.5, 0.5, 0.5])  # a voxel's centre (1 m voxels)
    ties = [o + np.array(d, dtype=float) for d in
            [(3, 3, 0), (-4, 4, 0), (2, 0, 2), (0, -3, -3), (3, 3, 3), (-2, -2, 2), (5, 5, 1)]]  # fmt: skip
    faces = [np.array(e) for e in [(3.0, 0.5, 0.5), (0.5, -2.0, 0.5), (3.0, 3.0, 0.5), (0.5, 0.5, 4.0)]]
    rand = list(o + rng.uniform(-6.0, 6.0, size=(40, 3)))
    ends = np.array(ties + faces + rand)
    n = len(ends)
    box_blocks = np.array([-2, -2, -2, 4, 4, 4], dtype=np.int64)  # voxels -16 to 15 on each axis

    def lockstep(af, ai, max_it=64):
        rec = np.empty(max_it * RAY_CHUNK, dtype=np.int64)
        iters, outside = _tail_walks(af, ai, n, box_blocks, rec, np.empty(RAY_CHUNK, dtype=np.int32), max_it)
        assert iters > 0 and not outside
        walks = []
        for q in range(n):
            out = []
            for it in range(iters):
                code = int(rec[it * RAY_CHUNK + q])
                if code == NOT_WALKED:
                    break
                b, off = code >> (3 * BLOCK_BITS), code & 511
                bi, bj, bk = b // 16 - 2, (b // 4) % 4 - 2, b % 4 - 2
                out.append((bi * 8 + (off >> 6), bj * 8 + ((off >> 3) & 7), bk * 8 + (off & 7)))
            walks.append(out)
        return walks

    for tail in (50.0, 2.5):  # longer than every ray (walked from the origin's voxel); cut
        af, ai = ray_start_buffers()
        ray_starts(ends, 0, n, o[0], o[1], o[2], 0, 0, 0, 1.0, 1.0, tail, af, ai)
        if tail > 10.0:  # the end voxel moved off the path, the length unbounded: max_steps stops it
            ai[RS_EI * RAY_CHUNK + 0] += 1
            ai[RS_EK * RAY_CHUNK + 0] += 2
            af[RS_LENGTH * RAY_CHUNK + 0] = 1e9
        want = [_scalar_walk(af, ai, q) for q in range(n)]
        assert lockstep(af.copy(), ai.copy()) == want
        if tail > 10.0:
            assert len(want[0]) == 1 + (4 + 3 + 2 + 3)  # its first voxel and max_steps: |4| + |3| + |2| + 3
            assert want[1][:3] == [(0, 0, 0), (0, 1, 0), (-1, 1, 0)]  # a tie: y before x (strict <)
            assert want[len(ties)] == [(0, 0, 0), (1, 0, 0), (2, 0, 0)]  # ends at x = 3.0: voxel 2 walked


def test_ends_box_is_the_voxel_box_of_the_origin_and_the_ends():
    """``ends_box``: floor(min) and floor(max) of the origin and the ends, in voxel keys, by
    hand (negative coordinates floor down; the origin counts when it lies outside the ends;
    an end on a voxel face belongs to the voxel above it), and against numpy on random ends."""
    from ltmap_cli.core.projective import ends_box

    ends = np.array([[0.26, -0.01, 1.0], [-0.051, 0.3, 0.05], [0.1, 0.2, -0.3]])
    box = ends_box(np.array([0.5, 0.0, 0.0]), ends, 20.0)
    assert box.tolist() == [-2, -1, -6, 10, 6, 20]
    rng = np.random.default_rng(7)
    for n in (0, 1, 5, 1000):
        e = rng.uniform(-3, 3, (n, 3))
        o = rng.uniform(-1, 1, 3)
        pts = np.vstack([o[None], e])
        want = np.concatenate([np.floor(pts.min(axis=0) * 20.0), np.floor(pts.max(axis=0) * 20.0)]).astype(np.int64)
        assert ends_box(o, e, 20.0).tolist() == want.tolist()


def test_tail_masks_are_the_listed_tails():
    """On frames of a tilted camera over a wall, a box and a floor, from several poses: the
    misses ``tail_masks`` sets beside the projection's are the tails' misses ``frame_voxels``
    lists, bar the voxels the frame hits (left to the map thread: a voxel updated once a
    frame, hits first), and its hits are ``frame_voxels``' hits."""
    from ltmap_cli.core.projective import LISTED_VOXELS_MAX_BLOCKS, ends_box, tail_masks

    m = _map()
    scene = _wall(4200)
    scene[30:90, 40:100] = 1700  # a box in front of the wall
    scene[100:, :] = 0  # no return: the rows below
    scene[5:9, 150:] = 9000  # beyond max_range: cut there, no hit
    tail = m.projective_tail()
    for yaw in (0.0, 0.3, -0.7, 1.1):
        c, s_ = np.cos(yaw), np.sin(yaw)
        T = np.array([[c, -s_, 0, 0.13], [s_, c, 0, -0.21], [0, 0, 1, 0.0], [0, 0, 0, 1.0]]) @ POSE
        T[:3, :3] = T[:3, :3] @ np.array([[1, 0, 0], [0, np.cos(0.2), -np.sin(0.2)], [0, np.sin(0.2), np.cos(0.2)]])
        T = np.ascontiguousarray(T)
        ends, kind = m.depth_rays(scene, F, F, CX, CY, T, 8.0)
        hits, misses = m.frame_voxels(T[:3, 3], ends, kind, tail)
        empty_keys, empty_masks = np.empty(0, dtype=np.int64), np.empty((0, 8), dtype=np.uint64)
        box = ends_box(np.ascontiguousarray(T[:3, 3]), ends, 1.0 / m.resolution)
        hit_set = set(_unpack_voxels(hits))
        for bitmap_max in (LISTED_VOXELS_MAX_BLOCKS, 0):  # the tails' misses in a bitmap, in rows
            keys, masks, hkeys, hmasks, ok = tail_masks(np.ascontiguousarray(T[:3, 3]), ends, kind,
                                                        1.0 / m.resolution, m.resolution, tail, empty_keys,
                                                        empty_masks, box, LISTED_VOXELS_MAX_BLOCKS, bitmap_max)  # fmt: skip
            assert ok and len(misses) > 500 and len(hits) > 100
            assert _mask_voxels(hkeys, hmasks) == hit_set
            assert _mask_voxels(keys, masks) - hit_set == set(_unpack_voxels(misses))


def test_tail_misses_as_masks_leave_the_map_of_the_listed_tails(monkeypatch):
    """The rays' tails' misses applied block by block with the projection's masks, and the hits
    by masks of their own, give the map of applying them as lists: O's log-odds and stamps, D's voxels (by their blocks'
    coordinates: voxels are updated, and so blocks made and voxels put in the tick buffer, in
    another order) and the same events, over a wall, a box coming and going, and ticks."""
    import ltmap_cli.core.layers as layers_mod

    box = _wall()
    box[40:80, 60:100] = 1500
    seq = [_wall()] * 6 + [box] * 8 + [_wall()] * 10
    out = {}
    for how in ("masks", "list"):
        monkeypatch.setattr(layers_mod, "LISTED_VOXELS_MAX_BLOCKS", 1 << 18 if how == "masks" else 0)
        m = _map()
        listed = 0
        for f, depth in enumerate(seq):
            T = np.ascontiguousarray(POSE)
            ends, kind = m.depth_rays(depth, F, F, CX, CY, T, 8.0)
            hits, misses, p = m.depth_voxels(depth, F, F, CX, CY, T, 8.0, ends, kind)
            listed += len(misses) + len(hits)
            m.apply_voxels(hits, misses, int((kind > 0).sum()), p)
            if f % 3 == 2:
                m.end_tick()
        out[how] = (m, listed)
    (a, na), (b, nb) = out["masks"], out["list"]
    assert na == 0 and nb > 1000  # the tails' misses and the hits: none listed, then all
    same_by_coords(a, b)
    assert a.D.channel("st").max() > 0  # the box's obstacle reached ST
    ta, tb = a.events.transitions, b.events.transitions
    assert len(ta) == len(tb)


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_range_factors_give_the_ranges_bit_for_bit(encoding):
    """``pixel_range_factors`` (a pixel's ray length per metre of depth, made once per camera)
    times the depth is the range ``depth_range_image`` computed per frame before (z * sqrt(1 +
    x^2 + y^2) in float64, x = (u - cx) / fx, y = (v - cy) / fy, then float32): every bit, for
    random calibrations and images, so the projection's decisions are the same."""
    from ltmap_cli.core.layers import _depth_view
    from ltmap_cli.core.projective import depth_range_image, pixel_range_factors

    rng = np.random.default_rng(17)
    for _ in range(4):
        h, w = int(rng.integers(5, 90)), int(rng.integers(5, 130))
        fx, fy = rng.uniform(40.0, 900.0, 2)
        cx, cy = rng.uniform(-5.0, w + 5.0), rng.uniform(-5.0, h + 5.0)
        z = rng.uniform(0.05, 20.0, (h, w))
        if encoding == "16UC1":
            raw = np.round(z * 1000).astype(np.uint16)
            zf = (raw.astype(np.float32) * np.float32(0.001)).astype(np.float64)
        else:
            raw = z.astype(np.float32)
            zf = raw.astype(np.float64)
        xx = 1.0 + ((np.arange(w, dtype=np.float64) - cx) / fx) ** 2
        yy = ((np.arange(h, dtype=np.float64) - cy) / fy) ** 2
        want = np.minimum(zf * np.sqrt(xx[None, :] + yy[:, None]), 9.0).astype(np.float32) - np.float32(0.2)
        depth, unit_mm = _depth_view(raw)
        fac = pixel_range_factors(h, w, fx, fy, cx, cy)
        assert fac.shape == (h, w) and fac.dtype == np.float64
        reach = depth_range_image(depth, unit_mm, fac, 9.0, 0.2)[0]
        assert np.array_equal(reach, want)


def test_a_map_keeps_each_cameras_range_factors():
    """``LayeredMap._range_factors``: made once per calibration and image size and kept (the same
    array for the next frame), another camera's beside it, the oldest let go beyond
    ``RANGE_FACTORS_KEPT``."""
    from ltmap_cli.core.layers import RANGE_FACTORS_KEPT, LayeredMap

    m = LayeredMap()
    a = m._range_factors((48, 64), 50.0, 50.0, 31.5, 23.5)
    assert m._range_factors((48, 64), 50.0, 50.0, 31.5, 23.5) is a
    b = m._range_factors((48, 64), 50.0, 50.0, 30.0, 23.5)
    assert b is not a and not np.array_equal(a, b)
    for k in range(RANGE_FACTORS_KEPT):
        m._range_factors((10, 10 + k), 9.0, 9.0, 5.0, 5.0)
    assert len(m._range_factors_kept) == RANGE_FACTORS_KEPT
    assert m._range_factors((48, 64), 50.0, 50.0, 31.5, 23.5) is not a  # (let go, made again)
