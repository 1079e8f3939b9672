"""Merged rays (``map.sensor.ray_merge``, issue 17): dense frames' rays walked back from their ends
stop where they merge into rays walked before, except through the bricks next to the frame's
hits. Checked against the exact traversal (``ray_merge = 0``) voxel by voxel on a frame, and map
against map on replays of the samples."""

from pathlib import Path

import numpy as np
import pytest

from ltmap_cli.config import Config
from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.grid import _PACK_BITS, _PACK_OFFSET
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.core.projection import OCCUPIED, project
from ltmap_cli.pipeline.replay import Replay, ReplayRequest

SAMPLES = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios"
FX = FY = 262.5
W, H = 320, 240


def room_frame(yaw: float, seed: int = 0):
    """A depth frame (uint16 mm) of an 8 x 5 x 2.6 m room with a 0.4 m box standing at
    (3.5, 1.2), seen from about (0.6, 2.5, 1.1) looking along +x turned by ``yaw``, 2 mm noise; and its
    camera pose (optical frame -> room)."""
    u = (np.arange(W) - (W - 1) / 2) / FX
    v = (np.arange(H) - (H - 1) / 2) / FY
    U, V = np.meshgrid(u, v)
    f = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    r = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    d = np.array([0.0, 0.0, -1.0])
    D = f + U[..., None] * r + V[..., None] * d  # a ray per pixel, unit depth along f
    o = np.array([0.613, 2.4937, 1.1071])  # off the lattice: no ray runs along voxel faces
    with np.errstate(divide="ignore", invalid="ignore"):
        walls = np.where(D > 0, (np.array([8.0, 5.0, 2.6]) - o) / D, np.where(D < 0, -o / D, np.inf)).min(axis=-1)
        lo, hi = np.array([3.3, 1.0, 0.0]), np.array([3.7, 1.4, 0.6])  # the box, slab test
        t1, t2 = (lo - o) / D, (hi - o) / D
        tn = np.nanmax(np.minimum(t1, t2), axis=-1)
        tf = np.nanmin(np.maximum(t1, t2), axis=-1)
    z = np.where((tn <= tf) & (tn > 0), np.minimum(walls, tn), walls)
    z = z + np.random.default_rng(seed).normal(0.0, 0.002, z.shape)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = r, d, f, o
    return np.round(z * 1000).astype(np.uint16), T


def voxels(keys: np.ndarray) -> set:
    return set(keys.tolist())


@pytest.mark.parametrize("yaw", [0.0, 0.45, -0.9])
def test_merged_rays_list_the_exact_hits_and_near_them_every_exact_miss(yaw):
    m = LayeredMap(MapConfig(resolution=0.05))
    depth, T = room_frame(yaw)
    ends, kind = m.depth_rays(depth, FX, FY, (W - 1) / 2, (H - 1) / 2, T, 8.0, None, dedupe=True)
    exact_hits, exact_misses = m.frame_voxels(T[:3, 3], ends, kind, 0)
    ex = voxels(exact_misses)
    assert len(exact_misses) == len(ex) > 50_000
    listed = {}
    for merge in (1, 2, 4):
        hits, misses = m.frame_voxels(T[:3, 3], ends, kind, merge)
        assert np.array_equal(hits, exact_hits)  # hits are never merged
        got = voxels(misses)
        assert len(got) == len(misses) and not got & voxels(hits)  # each voxel once, a hit is no miss
        # what merging lists is what the exact traversal lists (the backward DDA may break a tie
        # the other way now and then)
        assert len(got - ex) <= 0.001 * len(ex)
        listed[merge] = got
    # merging leaves out voxels of free space (that is the saving) ...
    assert len(listed[1]) < 0.9 * len(ex)
    assert len(listed[1]) <= len(listed[2]) <= len(listed[4])
    # ... but not the ones next to a surface of this frame: every exact miss within one voxel of a
    # hit voxel is listed (these decide what a surface keeps: noise in front of it, edges rays graze)
    hit_ijk = _unpack(exact_hits)
    near = set()
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            for dk in (-1, 0, 1):
                near |= set(_pack(hit_ijk + np.array([di, dj, dk])).tolist())
    near_exact = ex & near
    assert len(near_exact) > 5_000
    for merge, got in listed.items():
        assert not near_exact - got, merge


def _unpack(keys: np.ndarray) -> np.ndarray:
    """Voxel keys (M, 3) of frame_voxels' packed keys (core.grid.pack_block's layout)."""
    mask = (1 << _PACK_BITS) - 1
    k = keys.astype(np.int64)
    return np.stack([(k >> (2 * _PACK_BITS)) & mask, (k >> _PACK_BITS) & mask, k & mask], axis=1) - _PACK_OFFSET


def _pack(ijk: np.ndarray) -> np.ndarray:
    k = ijk.astype(np.int64) + _PACK_OFFSET
    return (k[:, 0] << (2 * _PACK_BITS)) | (k[:, 1] << _PACK_BITS) | k[:, 2]


def test_merged_rays_survive_buffers_that_grow_in_the_middle_of_a_frame():
    """The bitmaps (seen, walked, bricks) and the miss buffer start too small: frame_voxels
    grows them and goes on, and lists what a roomy call lists, in the same order."""
    from ltmap_cli.core.layers import _sparse_bitmap

    depth, T = room_frame(0.3, seed=4)
    roomy, tight = LayeredMap(), LayeredMap()
    ends, kind = roomy.depth_rays(depth, FX, FY, (W - 1) / 2, (H - 1) / 2, T, 8.0, None, dedupe=True)
    ref = roomy.frame_voxels(T[:3, 3], ends, kind, 2)
    tight.frame_voxels(T[:3, 3], ends[:1], kind[:1], 2)  # makes the thread's scratch
    tight._scratch.seen = np.empty(1, dtype=np.uint64)
    tight._scratch.misses = np.empty(3, dtype=np.int64)
    tight._scratch.sparse = _sparse_bitmap(2)
    got = tight.frame_voxels(T[:3, 3], ends, kind, 2)
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])


def test_ray_merge_is_validated():
    cfg = MapConfig()
    cfg.sensor.ray_merge = -1
    assert any("ray_merge" in p for p in cfg.validate())
    cfg.sensor.ray_merge = 0
    assert cfg.validate() == []


def _replay(log: Path, out: Path, merge: int) -> LayeredMap:
    cfg = Config()
    cfg.replay.plots = False
    cfg.map.sensor.ray_merge = merge
    run = Replay(cfg, ReplayRequest([log], out))
    run.run()
    return run.lmap


def _occupied(lmap: LayeredMap) -> set:
    return set(map(tuple, lmap.O.voxels_where(lmap.O.channel("logodds") > 0).tolist()))


def _p_occupied(lmap: LayeredMap) -> set:
    p = project(lmap)
    rows, cols = np.nonzero(p.data == OCCUPIED)
    return set(zip((cols + p.i0).tolist(), (rows + p.j0).tolist()))


def _iou(a: set, b: set) -> float:
    return len(a & b) / len(a | b)


def test_replays_with_merged_rays_keep_the_exact_maps(tmp_path):
    """The default (ray_merge 2) against the exact traversal (ray_merge 0) on a sample with a
    depth camera: O's occupied voxels and P's occupied cells agree at IoU >= 0.99 (issue 17's
    bound for an approximate default), yet the maps are not the same (merging did something);
    laser scans are never merged: a laser-only sample gives the same O either way."""
    assert Config().map.sensor.ray_merge == 2
    exact = _replay(SAMPLES / "02_table" / "log.mcap", tmp_path / "exact", 0)
    merged = _replay(SAMPLES / "02_table" / "log.mcap", tmp_path / "merged", 2)
    assert exact.O.n_blocks == merged.O.n_blocks
    assert not np.array_equal(exact.O.channel("logodds"), merged.O.channel("logodds"))
    assert _iou(_occupied(exact), _occupied(merged)) >= 0.99
    assert _iou(_p_occupied(exact), _p_occupied(merged)) >= 0.99
    laser = [_replay(SAMPLES / "01_static_object" / "log.mcap", tmp_path / f"laser{m}", m) for m in (0, 2)]
    n = laser[0].O.n_blocks
    assert n == laser[1].O.n_blocks > 0
    assert np.array_equal(laser[0].O.channel("logodds"), laser[1].O.channel("logodds"))
