"""The fast paths of issue 7 give exactly what the plain serial path gives.

- ``depth_image_rays`` (one fused kernel) == depth_metres -> depth_to_points -> transform_points
  -> classify_rays -> dedupe_endpoints, bit for bit;
- the direct CDR parsers give the same frames as the generic deserializers;
- a replay with the fast decoding, fused kernel, reader thread and rays worker leaves the same O
  (log-odds and stamps, block for block), the same D (ST, LT, ...) and the same events as the
  serial path;
- ``map.sensor.depth_max_rate`` drops depth frames before decoding, as documented.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from ltmap_cli.config import Config
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.core.raycast import transform_points_kernel
from ltmap_cli.core.sensors import depth_to_points, transform_points, transform_points_numpy
from ltmap_cli.io.decode import RawDepthFrame
from ltmap_cli.io.frames import DepthFrame
from ltmap_cli.io.logs import open_logs
from ltmap_cli.pipeline.replay import Replay, ReplayRequest

ROOT = Path(__file__).resolve().parent.parent
HOUSE = ROOT / "sample_logs" / "scenarios" / "06_house" / "log.mcap"
SCEN = ROOT / "sample_logs" / "scenarios"


def _pose(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    T = np.eye(4)
    T[:3, :3] = q
    T[:3, 3] = rng.normal(size=3) * 3 + [0, 0, 1.0]
    return T


def test_transform_points_numpy_equals_kernel():
    rng = np.random.default_rng(3)
    for _ in range(4):
        T = _pose(rng)
        p = rng.normal(size=(5000, 3)) * 7
        assert np.array_equal(transform_points_numpy(T, p), transform_points_kernel(T, p))
        assert np.array_equal(transform_points(T, p), transform_points_kernel(T, p))


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
@pytest.mark.parametrize("dedupe", [True, False])
@pytest.mark.parametrize("max_range", [3.0, 8.0])
def test_fused_depth_kernel_equals_serial_steps(encoding, dedupe, max_range):
    rng = np.random.default_rng(7)
    h, w = 120, 160
    raw16 = rng.uniform(100, 9000, size=(h, w)).astype(np.uint16)
    raw16[rng.random((h, w)) < 0.1] = 0
    if encoding == "16UC1":
        raw = raw16
        depth = raw16.astype(np.float32) * np.float32(0.001)
        depth[raw16 == 0] = np.nan
    else:
        raw = raw16.astype(np.float32) * np.float32(0.00137)
        raw[raw16 == 0] = np.nan
        raw[:3, :5] = -1.0
        raw[5, 5] = np.inf
        depth = raw.copy()
        depth[~(depth > 0) | ~np.isfinite(depth)] = np.nan
    for trial in range(3):
        T = _pose(rng)
        robot = T.copy() if trial else None
        lmap = LayeredMap()
        lmap.cfg.sensor.ground_tolerance = 0.3  # so that the ground rule fires on some points
        lmap.cfg.robot.footprint_min = [-3.0, -3.0, -1.0]  # and the footprint rule on others
        lmap.cfg.robot.footprint_max = [3.0, 3.0, 2.0]
        pts = depth_to_points(depth, 130.0, 131.0, 79.5, 59.5)
        e1, k1 = lmap.rays(T[:3, 3], transform_points(T, pts), None, max_range, robot, dedupe)
        e2, k2 = lmap.depth_rays(raw, 130.0, 131.0, 79.5, 59.5, T, max_range, robot, dedupe)
        keep = k1 > 0
        assert np.array_equal(e1[keep], e2) and np.array_equal(k1[keep], k2)
        assert set(np.unique(k2)) >= {2}
        if robot is not None:
            plain = LayeredMap()
            plain.cfg.sensor.ground_tolerance = 0.3
            _, k0 = plain.depth_rays(raw, 130.0, 131.0, 79.5, 59.5, T, max_range, robot, dedupe)
            assert (k0 == 2).sum() > (k2 == 2).sum() or not dedupe  # the footprint took some hits
        # and the same map once integrated
        m1, m2 = LayeredMap(), LayeredMap()
        r1 = m1.integrate_rays(T[:3, 3], e1, k1)
        r2 = m2.integrate_rays(T[:3, 3], e2, k2)
        assert (r1.rays, r1.hits, r1.misses) == (r2.rays, r2.hits, r2.misses)
        assert np.array_equal(m1.O.channel("logodds"), m2.O.channel("logodds"))


FW_F, FW_CX, FW_CY = 300.0, 63.5, 47.5  # _floor_and_wall's camera (96 x 128 pixels)


def _floor_and_wall(encoding, rng):
    """A camera's view of a floor (y = 0.4 m in the optical frame, y down) and a wall (z = 3 m),
    2 mm noise, 5 % holes: (raw pixels of ``encoding``, their metres as float32, NaN for holes)."""
    h, w = 96, 128
    v, _ = np.mgrid[0:h, 0:w].astype(np.float64)
    ray_y = (v - FW_CY) / FW_F
    z = np.where(ray_y > 0.4 / 3.0, 0.4 / np.maximum(ray_y, 1e-9), 3.0)
    z = z + rng.normal(0.0, 0.002, size=z.shape)
    holes = rng.random((h, w)) < 0.05
    if encoding == "16UC1":
        raw = np.round(z * 1000).astype(np.uint16)
        raw[holes] = 0
        depth = raw.astype(np.float32) * np.float32(0.001)
        depth[holes] = np.nan
    else:
        raw = z.astype(np.float32)
        raw[holes] = np.nan
        depth = raw.copy()
    return raw, depth


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
@pytest.mark.parametrize("dedupe", [True, False])
@pytest.mark.parametrize("max_range", [1.6, 4.0, 0.0])
def test_fused_depth_kernel_equals_serial_steps_on_smooth_surfaces(encoding, dedupe, max_range):
    """A camera's view of a floor and a wall (2 mm noise, holes): neighbouring pixels end in the
    same voxel, so the kernel's shortcuts (the pixels before and above) carry most pixels, and
    with max_range 1.6 m most of the wall is cut. Still bit for bit the serial steps' rays."""
    raw, depth = _floor_and_wall(encoding, np.random.default_rng(5))
    h, w = raw.shape
    f, cx, cy = FW_F, FW_CX, FW_CY
    for trial in range(3):
        T = np.eye(4)  # optical frame (z forward, y down) -> fixed frame (z up), then a small turn
        T[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
        a = 0.3 * trial
        T[:3, :3] = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]]) @ T[:3, :3]
        T[:3, 3] = [0.37 * trial, -0.21, 0.4]
        robot = np.eye(4)
        robot[:3, 3] = [0.37 * trial, -0.21, 0.0]
        lmap = LayeredMap()
        lmap.cfg.sensor.ground_tolerance = 0.05
        pts = depth_to_points(depth, f, f, cx, cy)
        e1, k1 = lmap.rays(T[:3, 3], transform_points(T, pts), None, max_range, robot, dedupe)
        e2, k2 = lmap.depth_rays(raw, f, f, cx, cy, T, max_range, robot, dedupe)
        keep = k1 > 0
        assert np.array_equal(e1[keep], e2) and np.array_equal(k1[keep], k2)
        kinds = set(np.unique(k2).tolist())  # floor returns clear (ground rule), wall returns hit
        assert kinds == ({1} if max_range == 1.6 else {1, 2})  # at 1.6 m the wall is cut: no hit
        if dedupe:
            assert len(k2) < 0.2 * h * w  # mostly repeats: the shortcuts had work to do



@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_fused_depth_kernel_footprint_box_in_view_and_around_the_camera(encoding):
    """The kernel tests the robot's footprint box only on rows with a pixel no deeper than the
    distance from the camera to the box's farthest corner. Boxes around the camera (its near
    floor inside), around a patch of the wall 3 m ahead (the camera outside it, rows above and
    below without a pixel in it), and one whose farthest corner lies just beyond the wall: the
    serial steps' rays bit for bit, and the box takes hits in each."""
    raw, depth = _floor_and_wall(encoding, np.random.default_rng(23))
    h, w = raw.shape
    f, cx, cy = FW_F, FW_CX, FW_CY
    T = np.eye(4)  # optical frame (z forward, y down) -> fixed frame (z up): the camera 0.4 m up
    T[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    T[:3, 3] = [0.0, 0.0, 0.4]
    pts = transform_points(T, depth_to_points(depth, f, f, cx, cy))
    pix_row = np.nonzero(np.isfinite(depth))[0]  # (the points are the valid pixels', row by row)
    assert len(pix_row) == len(pts)
    boxes = [  # (robot position, footprint_min, footprint_max)
        ([0.0, 0.0, 0.0], [-0.3, -0.3, -0.1], [2.7, 0.3, 0.6]),  # the camera and the floor ahead of it
        ([2.8, 0.1, 0.5], [-0.3, -0.2, -0.15], [0.3, 0.25, 0.1]),  # a patch of the wall (x = 3 m)
        ([3.0, -0.1, 0.6], [-0.5, -0.2, -0.1], [0.0 + 1e-4, 0.2, 0.1]),  # its far side 0.1 mm behind the wall
    ]
    for pos, lo, hi in boxes:
        robot = np.eye(4)
        robot[:3, 3] = pos
        for dedupe in (False, True):
            lmap = LayeredMap()
            lmap.cfg.sensor.ground_tolerance = -1.0  # (the floor's returns hit, so the box takes some)
            lmap.cfg.robot.footprint_min, lmap.cfg.robot.footprint_max = lo, hi
            e1, k1 = lmap.rays(T[:3, 3], pts, None, 8.0, robot, dedupe)
            e2, k2 = lmap.depth_rays(raw, f, f, cx, cy, T, 8.0, robot, dedupe)
            keep = k1 > 0
            assert np.array_equal(e1[keep], e2) and np.array_equal(k1[keep], k2)
            if not dedupe:
                _, k0 = lmap.rays(T[:3, 3], pts, None, 8.0, None, False)  # (a ray per pixel)
                taken = (k0 == 2) & (k1 == 1)  # hits the box made clear
                rows = np.unique(pix_row[taken])
                assert 0 < len(rows) < h and taken.sum() >= 10, (pos, len(rows), taken.sum())

@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_fused_depth_kernel_pixels_at_max_range(encoding):
    """The kernel skips the max-range cut's square root on rows whose rays all stay below
    (1 - 1e-9) max_range and cuts beyond max_range exactly as classify_rays does. max_range set to the exact length of chosen
    pixels' rays (as classify_rays computes it): those are not cut (still hits); set a hair
    (5e-10) short of it: they are; bit for bit the serial steps' rays, with and without dedupe."""
    rng = np.random.default_rng(11)
    h, w = 60, 80
    raw16 = rng.uniform(500, 6000, size=(h, w)).astype(np.uint16)
    if encoding == "16UC1":
        raw = raw16
        depth = raw16.astype(np.float32) * np.float32(0.001)
    else:
        raw = raw16.astype(np.float32) * np.float32(0.00113)
        depth = raw.copy()
    T = _pose(rng)
    pts = transform_points(T, depth_to_points(depth, 70.0, 71.0, 39.5, 29.5))
    length = np.sqrt(((pts - T[:3, 3]) ** 2).sum(axis=1))
    order = np.argsort(length)
    for at, eps in itertools.product((len(order) // 3, len(order) // 2, (9 * len(order)) // 10), (0.0, 5e-10)):
        # eps 0: exactly this pixel's length, not cut; 5e-10: the pixel a hair beyond, cut
        max_range = float(length[order[at]]) * (1.0 - eps)
        n_cut = int((length > max_range).sum())
        assert 0 < n_cut < len(length)
        for dedupe in (False, True):
            lmap = LayeredMap()
            lmap.cfg.sensor.ground_tolerance = -1.0
            e1, k1 = lmap.rays(T[:3, 3], pts, None, max_range, None, dedupe)
            e2, k2 = lmap.depth_rays(raw, 70.0, 71.0, 39.5, 29.5, T, max_range, None, dedupe)
            keep = k1 > 0
            assert np.array_equal(e1[keep], e2) and np.array_equal(k1[keep], k2)
            if not dedupe:  # every pixel a ray: those beyond max_range are cut (clear), the rest hit
                assert k2[order[at]] == (2 if eps == 0.0 else 1)
                assert (k2 == 1).sum() == n_cut
                cut = length > max_range
                reach = np.sqrt(((e2[cut] - T[:3, 3]) ** 2).sum(axis=1))
                assert np.allclose(reach, max_range, rtol=1e-12, atol=0)


def test_fused_depth_kernel_cuts_a_lone_far_pixel_of_a_row():
    """The kernel does the max-range cut only on rows with a pixel that may reach beyond
    max_range: a row whose one far pixel is its first, its middle or its last, among rows that
    all stay within it, and an image all beyond it, give the serial steps' rays bit for bit,
    exactly those pixels cut."""
    rng = np.random.default_rng(5)
    h, w = 24, 40
    T = _pose(rng)
    for far_at in ((7, 0), (11, w // 2), (23, w - 1), None):
        raw = rng.uniform(1000, 2500, size=(h, w)).astype(np.uint16)  # 1 to 2.5 m: within 4 m
        if far_at is None:
            raw[:] = 6000  # every pixel beyond
        else:
            raw[far_at] = 6000
        depth = raw.astype(np.float32) * np.float32(0.001)
        pts = transform_points(T, depth_to_points(depth, 40.0, 41.0, 19.5, 11.5))
        lmap = LayeredMap()
        lmap.cfg.sensor.ground_tolerance = -1.0
        e1, k1 = lmap.rays(T[:3, 3], pts, None, 4.0, None, False)
        e2, k2 = lmap.depth_rays(raw, 40.0, 41.0, 19.5, 11.5, T, 4.0, None, False)
        assert np.array_equal(e1, e2) and np.array_equal(k1, k2)
        cut = (k2 == 1).reshape(h, w)  # RAY_CLEAR: cut at max_range
        assert cut.all() if far_at is None else (cut.sum() == 1 and cut[far_at])
    # the lone pixel a hair (5e-10) beyond max_range, at a row's end and the image's corners,
    # where pass 1's bound on a pixel's range from its depth is tightest (cx off centre: the
    # row's first pixel is the farthest from the axis)
    for far_at in ((0, 0), (0, w - 1), (h - 1, 0), (h - 1, w - 1), (12, 0), (12, w - 1)):
        raw = rng.uniform(1000, 2500, size=(h, w)).astype(np.uint16)
        raw[far_at] = 3000
        depth = raw.astype(np.float32) * np.float32(0.001)
        pts = transform_points(T, depth_to_points(depth, 40.0, 41.0, 27.5, 11.5))
        length = np.sqrt(((pts - T[:3, 3]) ** 2).sum(axis=1))
        lmap = LayeredMap()
        lmap.cfg.sensor.ground_tolerance = -1.0
        max_range = float(length[far_at[0] * w + far_at[1]]) * (1.0 - 5e-10)
        e1, k1 = lmap.rays(T[:3, 3], pts, None, max_range, None, False)
        e2, k2 = lmap.depth_rays(raw, 40.0, 41.0, 27.5, 11.5, T, max_range, None, False)
        assert np.array_equal(e1, e2) and np.array_equal(k1, k2)
        cut = (k2 == 1).reshape(h, w)
        assert cut.sum() == 1 and cut[far_at], far_at


def test_fused_depth_kernel_equals_serial_steps_on_narrow_images():
    """Images 1 to 7 pixels wide (every pixel near a row's end, where the kernel looks at fewer
    neighbours), of a smooth wall: still the serial steps' rays."""
    rng = np.random.default_rng(9)
    for w in range(1, 8):
        h = 40
        z = 2.0 + 0.002 * np.arange(h)[:, None] + rng.normal(0, 0.001, (h, w))
        raw = np.round(z * 1000).astype(np.uint16)
        raw[rng.random((h, w)) < 0.1] = 0
        depth = raw.astype(np.float32) * np.float32(0.001)
        depth[raw == 0] = np.nan
        T = _pose(rng)
        lmap = LayeredMap()
        pts = depth_to_points(depth, 200.0, 200.0, (w - 1) / 2, 19.5)
        e1, k1 = lmap.rays(T[:3, 3], transform_points(T, pts), None, 8.0, None, True)
        e2, k2 = lmap.depth_rays(raw, 200.0, 200.0, (w - 1) / 2, 19.5, T, 8.0, None, True)
        keep = k1 > 0
        assert np.array_equal(e1[keep], e2) and np.array_equal(k1[keep], k2)
        assert 0 < len(k2) < (raw > 0).sum()


def test_fused_depth_kernel_dedupe_set_with_every_ray_in_its_own_block():
    """The dedupe set keeps a row of bits per end block, or, for a frame spread over more blocks
    than it has rows for, the voxels' keys. An image whose 128 end voxels each lie in a block of
    their own (as many rows as rays), each seen again two and four rows further down (repeats
    that only the set finds: the neighbour test compares the row above alone), gives the serial
    steps' rays either way, hits and clear rays apart."""
    from ltmap_cli.core.grid import BLOCK
    from ltmap_cli.core.raycast import (
        DEDUPE_BLOCKS,
        DEDUPE_DONE,
        DEDUPE_FULL,
        RAY_CLEAR,
        RAY_HIT,
        _depth_rays_pass,
    )

    h, w = 6, 64
    u = np.arange(w)
    a = 3000 + 37 * u  # mm: neighbours' points 0.75 m apart and more (fx 4), blocks 0.4 m
    raw = np.empty((h, w), dtype=np.uint16)
    raw[0::2] = a
    raw[1::2] = a + 1000  # rows 1, 3, 5: other blocks again
    raw[4, ::3] = 0  # holes: invalid pixels among the repeats
    fx, fy, cx, cy = 4.0, 1e6, (w - 1) / 2, (h - 1) / 2  # every row looks the same way (y within 1e-5 m)
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.025, 0.0]  # y in the middle of a voxel
    lmap = LayeredMap()
    lmap.cfg.sensor.ground_tolerance = -1.0  # (no ground: z is the depth here)
    depth = raw.astype(np.float32) * np.float32(0.001)
    depth[raw == 0] = np.nan
    e1, k1 = lmap.rays(T[:3, 3], transform_points(T, depth_to_points(depth, fx, fy, cx, cy)), None, 100.0, None, True)
    keep = k1 > 0
    e2, k2 = lmap.depth_rays(raw, fx, fy, cx, cy, T, 100.0, None, True)
    assert np.array_equal(e1[keep], e2) and np.array_equal(k1[keep], k2)
    assert len(k2) == 2 * w
    blocks = np.floor(e2 / (lmap.resolution * BLOCK)).astype(np.int64)
    assert len(np.unique(blocks, axis=0)) == len(k2)  # every kept ray its own block
    none = np.zeros(3)
    args = (raw, True, fx, fy, cx, cy, T, 100.0, -1.0, np.eye(4), none, none, False, True, 1.0 / lmap.resolution)
    # by block: rows for cap / 16 blocks, so 2048 slots hold the 128 (128 rows: all used), 1024
    # do not (the frame is done again by voxel); by voxel: 256 slots, half full with the 128,
    # start again, and 512 do not
    for cap, by_block, status in ((2048, True, DEDUPE_DONE), (1024, True, DEDUPE_BLOCKS),
                                  (256, False, DEDUPE_FULL), (512, False, DEDUPE_DONE)):  # fmt: skip
        e3, k3, st = _depth_rays_pass(*args, np.int64(cap), by_block)
        assert st == status, (cap, by_block)
        if st == DEDUPE_DONE:
            assert np.array_equal(e3, e2) and np.array_equal(k3, k2)
        else:
            assert len(k3) == 0
    # a clear ray and a hit ending in the same voxel (z in [3.00, 3.05) m, the ground's tolerance
    # 3.02 m between them) are two rays, each kept once: the bits are two a voxel
    col = np.array([[3010], [3040], [3010], [3040], [3010]], dtype=np.uint16)
    lmap.cfg.sensor.ground_tolerance = 3.02
    e6, k6 = lmap.depth_rays(col, 4.0, 1e6, 0.0, 2.0, T, 100.0, None, True)
    assert k6.tolist() == [RAY_CLEAR, RAY_HIT] and np.allclose(e6[:, 2], [3.01, 3.04])


def test_fused_depth_kernel_dedupe_set_sized_by_the_previous_frame():
    """The dedupe set starts at the size the thread's previous frame needed: a frame with far
    more end voxels than that is done again with a bigger set, one with far fewer uses a set
    bigger than it needs; either way the rays are the serial steps'."""
    from ltmap_cli.core.raycast import DEPTH_CAP_MIN, depth_rays_cap

    assert depth_rays_cap(0, 640 * 480) == DEPTH_CAP_MIN and depth_rays_cap(24_488, 640 * 480) == 1 << 17
    # every pixel its own voxel: no bigger than the whole image needs (2 (pixels + 1) slots)
    assert depth_rays_cap(640 * 480, 640 * 480) == 1 << 20 and depth_rays_cap(3000, 3000) == 1 << 15
    rng = np.random.default_rng(13)
    h, w = 240, 320
    lmap = LayeredMap()
    for scale in (1.0, 0.02, 1.0, 1.0):  # noise over 9 m (tens of thousands of end voxels), then a flat few
        raw = (2000 + scale * rng.uniform(0, 7000, size=(h, w))).astype(np.uint16)
        depth = raw.astype(np.float32) * np.float32(0.001)
        T = _pose(rng)
        pts = depth_to_points(depth, 250.0, 250.0, 159.5, 119.5)
        e1, k1 = lmap.rays(T[:3, 3], transform_points(T, pts), None, 10.0, None, True)
        cap = getattr(lmap._scratch, "depth_cap", DEPTH_CAP_MIN)
        e2, k2 = lmap.depth_rays(raw, 250.0, 250.0, 159.5, 119.5, T, 10.0, None, True)
        keep = k1 > 0
        assert np.array_equal(e1[keep], e2) and np.array_equal(k1[keep], k2)
        assert lmap._scratch.depth_cap == depth_rays_cap(len(k2), h * w)
        if scale == 1.0 and cap == DEPTH_CAP_MIN:
            assert 2 * len(k2) > cap  # this frame overflowed the first set: the second pass ran
        if scale == 0.02:
            assert 4 * len(k2) < cap  # and this one ran in a set sized for the frame before
    # without the dedupe every pixel is a ray: the set is not used, and its size stays the least
    lmap2 = LayeredMap()
    e3, k3 = lmap2.depth_rays(raw, 250.0, 250.0, 159.5, 119.5, T, 10.0, None, False)
    assert len(k3) == h * w and getattr(lmap2._scratch, "depth_cap", DEPTH_CAP_MIN) == DEPTH_CAP_MIN


def test_fused_depth_kernel_big_endian_and_strided():
    rng = np.random.default_rng(11)
    raw = rng.uniform(300, 5000, size=(40, 60)).astype(np.uint16)
    T = _pose(rng)
    lmap = LayeredMap()
    ref = lmap.depth_rays(raw, 50.0, 50.0, 29.5, 19.5, T, 8.0)
    big = raw.astype(">u2")
    assert all(np.array_equal(a, b) for a, b in zip(ref, lmap.depth_rays(big, 50.0, 50.0, 29.5, 19.5, T, 8.0)))
    wide = np.zeros((40, 64), np.uint16)
    wide[:, :60] = raw
    view = wide[:, :60]
    assert all(np.array_equal(a, b) for a, b in zip(ref, lmap.depth_rays(view, 50.0, 50.0, 29.5, 19.5, T, 8.0)))


def _fields(item) -> dict:
    out = {}
    for f in ("stamp_ns", "frame_id", "topic", "intrinsics", "angle_min", "angle_increment", "range_min",
              "range_max", "parent", "child", "translation", "rotation_xyzw", "static"):
        if hasattr(item, f):
            out[f] = getattr(item, f)
    return out


@pytest.mark.parametrize("log", [HOUSE, SCEN / "01_static_object" / "log.mcap"])
def test_fast_decoding_gives_the_same_frames(log):
    if not log.exists():
        pytest.skip(f"{log} missing")
    with open_logs(log) as logs:
        slow = list(logs.messages())
    with open_logs(log) as logs:
        fast = list(logs.messages(fast=True))
    assert len(slow) == len(fast)
    n_depth = 0
    for (ta, na, a), (tb, nb, b) in zip(slow, fast):
        assert (ta, na) == (tb, nb)
        assert _fields(a) == _fields(b)
        if hasattr(a, "ranges"):
            assert a.ranges.dtype == b.ranges.dtype
            assert np.array_equal(a.ranges, b.ranges, equal_nan=True)
        if isinstance(a, DepthFrame):
            assert isinstance(b, RawDepthFrame)
            assert np.array_equal(a.depth_m, b.depth_m, equal_nan=True)
            n_depth += 1
    assert n_depth > 0 or log != HOUSE


def test_fast_decoding_ros1_and_ros2_bags_fall_back():
    """ROS 1 bags have no fast path and ROS 2 bags go through it: both still give the frames."""
    for log in [SCEN / "01_static_object" / "log.bag", SCEN / "01_static_object" / "log_ros2"]:
        if not log.exists():
            continue
        with open_logs(log) as logs:
            slow = [(t, n, _fields(i)) for t, n, i in logs.messages()]
        with open_logs(log) as logs:
            fast = [(t, n, _fields(i)) for t, n, i in logs.messages(fast=True)]
        assert slow == fast


def _replay(log: Path, out: Path, fast: bool, threads: bool, workers: int = 0, **sensor) -> tuple[Replay, dict]:
    cfg = Config()
    cfg.replay.plots = False
    cfg.replay.workers = workers
    for k, v in sensor.items():
        setattr(cfg.map.sensor, k, v)
    r = Replay(cfg, ReplayRequest([log], out))
    r.fast = fast
    r.threads = threads
    return r, r.run()


def _same_maps(a: LayeredMap, b: LayeredMap) -> None:
    assert a.O.n_blocks == b.O.n_blocks and a.D.n_blocks == b.D.n_blocks
    assert np.array_equal(a.O.block_coords[: a.O.n_blocks], b.O.block_coords[: b.O.n_blocks])
    for c in ("logodds", "stamp"):
        x, y = a.O.channel(c), b.O.channel(c)
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), c  # bit for bit
    assert np.array_equal(a.D.block_coords[: a.D.n_blocks], b.D.block_coords[: b.D.n_blocks])
    for c in ("st", "lt", "last_obs", "last_seen", "obst_since", "free_since"):
        assert a.D.channel(c).tobytes() == b.D.channel(c).tobytes(), c
    assert np.array_equal(a.events.transitions, b.events.transitions)
    for x, y in zip(a.events.history, b.events.history):
        assert np.array_equal(x, y)


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
def test_fast_threaded_replay_equals_serial_replay(tmp_path):
    if not HOUSE.exists():
        pytest.skip("house sample missing")
    serial, rep_s = _replay(HOUSE, tmp_path / "serial", fast=False, threads=False)
    fast, rep_f = _replay(HOUSE, tmp_path / "fast", fast=True, threads=True)
    _same_maps(serial.lmap, fast.lmap)
    assert rep_s["frames_used"] == rep_f["frames_used"]
    assert rep_s["rays"] == rep_f["rays"]
    assert rep_s["events"]["list"] == rep_f["events"]["list"]
    assert (tmp_path / "serial" / "map.pgm").read_bytes() == (tmp_path / "fast" / "map.pgm").read_bytes()
    assert set(rep_f["stage_s"]) >= {"warmup", "read", "tf", "rays", "integrate", "ticks", "output"}
    # the kernels' first calls happen in the warm-up, not in the first frames (that nothing is
    # compiled or loaded after it: test_warmup's subprocess checks, not a timed bound on the
    # first frames here, which a loaded machine broke)
    assert rep_s["stage_s"]["warmup"] > 0


def test_any_number_of_ray_workers_gives_the_serial_map(tmp_path):
    """replay.workers (0: one per usable core) changes how many frames are cast at once, never
    the map: 5 workers (more than this machine's cores, so frames finish out of order) and 1."""
    if not HOUSE.exists():
        pytest.skip("house sample missing")
    serial, rep_s = _replay(HOUSE, tmp_path / "serial", fast=True, threads=False)
    assert rep_s["ray_workers"] == 0
    cpu = rep_s["thread_cpu_s"]  # serial: everything on the main thread
    assert cpu["ray_workers"] == 0 and cpu["reader"] == 0 and 0 < cpu["main"] <= cpu["process"] + 0.01
    for n in (5, 1):
        run, rep = _replay(HOUSE, tmp_path / f"w{n}", fast=True, threads=True, workers=n)
        assert rep["ray_workers"] == n
        cpu = rep["thread_cpu_s"]
        assert min(cpu.values()) > 0 and cpu["main"] + cpu["reader"] + cpu["ray_workers"] <= cpu["process"] + 0.05
        _same_maps(serial.lmap, run.lmap)
        assert rep["events"]["list"] == rep_s["events"]["list"]


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
def test_fast_serial_replay_equals_serial_replay(tmp_path):
    if not HOUSE.exists():
        pytest.skip("house sample missing")
    a, _ = _replay(HOUSE, tmp_path / "a", fast=False, threads=True)
    b, _ = _replay(HOUSE, tmp_path / "b", fast=True, threads=False)
    _same_maps(a.lmap, b.lmap)


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
def test_depth_max_rate_drops_frames_before_integration(tmp_path):
    if not HOUSE.exists():
        pytest.skip("house sample missing")
    _, full = _replay(HOUSE, tmp_path / "full", fast=True, threads=True)
    _, capped = _replay(HOUSE, tmp_path / "capped", fast=True, threads=True, depth_max_rate=1.0)
    topic = "/camera/depth/image_raw"
    n_full, n_cap = full["frames_used"][topic], capped["frames_used"][topic]
    skipped = capped["frames_over_depth_max_rate"][topic]
    assert n_cap + skipped == n_full
    assert n_cap == -(-n_full // 3)  # a 2.5 Hz camera with at most one frame per 0.9 s: every 3rd
    assert capped["frames_used"]["/scan"] == full["frames_used"]["/scan"]
    # the slow path drops the same frames
    _, capped_slow = _replay(HOUSE, tmp_path / "capped_slow", fast=False, threads=False, depth_max_rate=1.0)
    assert capped_slow["frames_used"] == capped["frames_used"]


def test_depth_max_rate_is_validated():
    cfg = Config()
    cfg.map.sensor.depth_max_rate = -1
    assert any("depth_max_rate" in p for p in cfg.map.validate())
