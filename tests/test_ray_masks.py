"""Whole rays (laser scans, point clouds, exact depth) handed to the map thread as block masks
(``LayeredMap.ray_voxels``, ``core.projective.tail_masks`` with no tail), as a depth frame's
tails and hits are: the voxels are those ``frame_voxels`` lists, and the map is the one the
lists give (O and D by coordinates, the same events), with nothing listed.

A laser-only robot log (comprobo22 of ``../shared/real_logs``) was replayed 1.5x faster so:
the map thread looked each voxel up (about 22 ns a voxel), it now looks each block up."""

from __future__ import annotations

import numpy as np
import pytest
from test_projective import _mask_voxels, _unpack_voxels, same_by_coords

import ltmap_cli.core.layers as layers_mod
from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import TR_APPEAR, TR_DISAPPEAR, LayeredMap
from ltmap_cli.core.sensors import scan_to_points, transform_points

BEAMS = 360
ROOM = (-3.0, 5.0, -2.5, 3.5)  # x0, x1, y0, y1 of the walls (m)


def _ranges(x: float, y: float, yaw: float, box: bool, rng) -> np.ndarray:
    """A 2D scan from (x, y, yaw) of the room's walls and, with ``box``, a 0.6 m square pillar
    at (1.5, 0.5): ranges by hand (ray against the walls' and the pillar's lines), some noise,
    a few beams with no return (inf) and a few invalid (NaN)."""
    a = yaw + np.linspace(-np.pi, np.pi, BEAMS, endpoint=False)
    dx, dy = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(dx > 0, (ROOM[1] - x) / dx, (ROOM[0] - x) / dx)
        ty = np.where(dy > 0, (ROOM[3] - y) / dy, (ROOM[2] - y) / dy)
        r = np.minimum(tx, ty)
        if box:
            lo, hi = np.array([1.2, 0.2]), np.array([1.8, 0.8])
            t1 = (lo[0] - x) / dx, (lo[1] - y) / dy
            t2 = (hi[0] - x) / dx, (hi[1] - y) / dy
            tn = np.maximum(np.minimum(t1[0], t2[0]), np.minimum(t1[1], t2[1]))
            tf = np.minimum(np.maximum(t1[0], t2[0]), np.maximum(t1[1], t2[1]))
            r = np.where((tn <= tf) & (tn > 0), np.minimum(r, tn), r)
    r = r + rng.normal(0.0, 0.01, BEAMS)
    r[rng.random(BEAMS) < 0.03] = np.inf
    r[rng.random(BEAMS) < 0.02] = np.nan
    return r


def _scan_rays(m: LayeredMap, pose, ranges):
    x, y, yaw = pose
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:3, 3] = (x, y, 0.3)
    pts, rets = scan_to_points(ranges, -np.pi, 2 * np.pi / BEAMS, 0.1, 6.0)
    return T[:3, 3], *m.rays(T[:3, 3], transform_points(T, pts), rets, max_range=6.0)


POSES = [(0.0, 0.0, 0.0), (0.37, -0.21, 0.4), (-1.1, 1.3, -2.0), (3.2, 2.9, 3.0)]


@pytest.mark.parametrize("what", ["scan", "cloud", "depth"])
def test_ray_voxels_are_the_listed_voxels(what):
    """Scans (hits, no-return beams cleared up to the range, dropped beams), a cloud of
    scattered 3D points, and a depth image cast whole (exact mode): the masks' hits are
    ``frame_voxels``' hits, their misses its misses (bar the voxels the frame hits: a voxel is
    updated once a frame, hits first)."""
    rng = np.random.default_rng(7)
    cfg = MapConfig()
    cfg.sensor.depth_integration = "exact"
    m = LayeredMap(cfg)
    for pose in POSES:
        if what == "scan":
            origin, ends, kind = _scan_rays(m, pose, _ranges(*pose, box=True, rng=rng))
        elif what == "cloud":
            origin = np.array([pose[0], pose[1], 0.8])
            pts = origin + rng.normal(0.0, 1.5, (3000, 3))
            ends, kind = m.rays(origin, pts, None, max_range=3.0, dedupe=True)
        else:
            from test_projective import CX, CY, POSE, F, _wall

            depth = _wall(2500 + int(300 * pose[0]))
            depth[30:70, 50:90] = 1200
            depth[:5] = 0
            T = POSE.copy()
            T[:3, 3] += (pose[0], pose[1], 0.0)
            origin = T[:3, 3]
            ends, kind = m.depth_rays(depth, F, F, CX, CY, T, 8.0)
        hits, misses = m.frame_voxels(origin, ends, kind)
        no_hits, no_misses, masks = m.ray_voxels(origin, ends, kind)
        assert masks is not None and len(no_hits) == 0 and len(no_misses) == 0
        assert masks.box is None and masks.skipped is None  # (no projection: nothing for the workers' quiet list)
        hit_set = set(_unpack_voxels(hits))
        assert len(hit_set) > 20 and len(misses) > 300
        assert _mask_voxels(*masks.hits) == hit_set
        assert _mask_voxels(masks.keys, masks.masks) - hit_set == set(_unpack_voxels(misses))


def _scanned(monkeypatch, how: str, quiet: bool = True):
    """A robot scanning the room for 60 frames (ticks every 2) while a pillar stands there from
    frame 10 to 40: (map, voxels listed, misses applied)."""
    monkeypatch.setattr(layers_mod, "LISTED_VOXELS_MAX_BLOCKS", 1 << 18 if how == "masks" else 0)
    cfg = MapConfig()
    cfg.layers.st_rise_s, cfg.layers.lt_fall_s = 1.0, 1.0  # 5 ticks: the pillar enters LT and leaves it
    m = LayeredMap(cfg)
    m.quiet_blocks = quiet
    rng = np.random.default_rng(3)
    listed = applied = 0
    for f in range(60):
        pose = (0.1 * np.sin(f / 7.0), 0.05 * f / 60.0, 0.3 * np.sin(f / 11.0))
        origin, ends, kind = _scan_rays(m, pose, _ranges(*pose, box=10 <= f < 40, rng=rng))
        hits, misses, masks = m.ray_voxels(origin, ends, kind)
        listed += len(hits) + len(misses)
        applied += m.apply_voxels(hits, misses, int((kind > 0).sum()), masks).misses
        if f % 2 == 1:
            m.end_tick()
    return m, listed, applied


def _transitions(m: LayeredMap) -> list:
    """The transitions as (kind, tick, streak start), sorted: their D block and offset depend on
    the order blocks were made in."""
    return sorted(map(tuple, np.asarray(m.events.transitions)[:, [0, 3, 4]].tolist()))


def test_still_voxels_take_no_miss_and_leave_the_map_of_every_update(monkeypatch):
    """A 2D scan fills one voxel layer of a quarter's four, so its quarters are never quiet; a
    miss on a still voxel (clamped free, no ST or LT) is skipped a voxel at a time instead, in
    both kernels: O's log-odds, D's values and the transitions are those of updating every
    voxel (``quiet_blocks`` off), where the pillar stood too (missed after it left: its ST and
    LT fall, it leaves LT), with most misses skipped."""
    every, _, n_every = _scanned(monkeypatch, "masks", quiet=False)
    for how in ("masks", "lists"):
        m, _, n = _scanned(monkeypatch, how)
        assert int(m._quiet.quiet[: m.O.n_blocks].sum()) == 0  # no quiet block: the lever is the still voxels
        assert n < 0.5 * n_every
        same_by_coords(m, every, channels={"logodds", "st", "lt", "last_obs", "last_seen", "obst_since", "free_since"})
        assert _transitions(m) == _transitions(every)


def test_scans_as_masks_leave_the_map_of_the_lists(monkeypatch):
    """A robot scanning the room while a pillar comes and goes, masks against lists (a frame box
    over ``LISTED_VOXELS_MAX_BLOCKS``, 0 here, keeps the lists): O's log-odds and stamps and D's
    values by block coordinates, the pillar's transitions into LT and out of it, the same; nothing listed with masks."""
    (a, na, _), (b, nb, _) = _scanned(monkeypatch, "masks"), _scanned(monkeypatch, "lists")
    assert na == 0 and nb > 10_000
    same_by_coords(a, b)
    assert a.D.channel("st").max() > 0  # the pillar reached ST
    kinds = {t[0] for t in _transitions(a)}
    assert kinds == {TR_APPEAR, TR_DISAPPEAR} and _transitions(a) == _transitions(b)
