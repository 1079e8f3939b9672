"""Ray casting into O, checked against hand-computed voxels and OctoMap's rules."""

import math

import numpy as np
import pytest

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.grid import pos_to_coord
from ltmap_cli.core.layers import LayeredMap

HIT = math.log(0.7 / 0.3)
MISS = math.log(0.4 / 0.6)
R = 0.05


def centre(i, j, k, r=R):
    return [(i + 0.5) * r, (j + 0.5) * r, (k + 0.5) * r]


def new_map(**sensor):
    cfg = MapConfig(resolution=R)
    cfg.sensor.ground_tolerance = -1.0  # off unless a test turns it on
    for k, v in sensor.items():
        setattr(cfg.sensor, k, v)
    return LayeredMap(cfg)


def updated(m):
    """{key: log-odds} of every voxel ever updated."""
    keys = m.O.voxels_where(m.O.channel("stamp") > 0)
    vals = m.O.get("logodds", keys)
    return {tuple(int(v) for v in k): float(x) for k, x in zip(keys, vals)}


def test_ray_along_x_marks_free_voxels_and_one_hit():
    m = new_map()
    res = m.integrate(centre(0, 0, 0), [centre(10, 0, 0)])
    u = updated(m)
    assert set(u) == {(i, 0, 0) for i in range(11)}
    for i in range(10):
        assert u[(i, 0, 0)] == pytest.approx(MISS, abs=1e-6)
    assert u[(10, 0, 0)] == pytest.approx(HIT, abs=1e-6)
    assert (res.hits, res.misses) == (1, 10)


def test_ray_along_negative_y_and_down_z_with_negative_keys():
    m = new_map()
    m.integrate(centre(-1, -1, 3), [centre(-1, -11, 3)])
    u = updated(m)
    assert set(u) == {(-1, j, 3) for j in range(-11, 0)}
    assert u[(-1, -11, 3)] > 0 and all(u[(-1, j, 3)] < 0 for j in range(-10, 0))
    m2 = new_map()
    m2.integrate(centre(2, 2, 0), [centre(2, 2, -7)])
    assert set(updated(m2)) == {(2, 2, k) for k in range(-7, 1)}


def test_exact_diagonal_follows_octomap_tie_rule():
    # tMax ties go to the later axis (OctoMap's strict '<'): y first, then x, alternating.
    m = new_map()
    m.integrate(centre(0, 0, 0), [centre(5, 5, 0)])
    free = {k for k, v in updated(m).items() if v < 0}
    expected = {(0, 0, 0)}
    i = j = 0
    while (i, j) != (4, 5):
        if i == j:
            j += 1
        else:
            i += 1
        expected.add((i, j, 0))
    assert free == expected and len(free) == 10


def test_ray_across_block_boundaries_is_contiguous():
    # blocks are 8 voxels wide: keys -12..11 cross the boundaries at -8, 0 and 8
    m = new_map()
    m.integrate(centre(-12, 5, 1), [centre(11, 5, 1)])
    u = updated(m)
    assert set(u) == {(i, 5, 1) for i in range(-12, 12)}
    assert m.O.n_blocks == 4  # blocks -2, -1, 0, 1 (8 voxels each)


def test_hit_in_a_frame_is_not_also_cleared_and_each_voxel_updated_once():
    m = new_map()
    # ray A ends in (5,0,0); ray B passes through it to (9,0,0); ray C duplicates B
    m.integrate(centre(0, 0, 0), [centre(5, 0, 0), centre(9, 0, 0), centre(9, 0, 0)])
    u = updated(m)
    assert u[(5, 0, 0)] == pytest.approx(HIT, abs=1e-6)
    assert u[(9, 0, 0)] == pytest.approx(HIT, abs=1e-6)
    assert u[(3, 0, 0)] == pytest.approx(MISS, abs=1e-6)  # once, although three rays cross it
    assert u[(7, 0, 0)] == pytest.approx(MISS, abs=1e-6)


def test_clamping_to_configured_bounds():
    m = new_map()
    for _ in range(10):
        m.integrate(centre(0, 0, 0), [centre(6, 0, 0)])
    u = updated(m)
    assert u[(6, 0, 0)] == pytest.approx(3.5, abs=1e-6)
    assert u[(2, 0, 0)] == pytest.approx(-2.0, abs=1e-6)
    # from the clamp, 9 misses are needed to make the voxel free (3.5 / 0.405 = 8.6)
    for n in range(1, 10):
        m.integrate(centre(0, 0, 0), [centre(12, 0, 0)])
        lo = updated(m)[(6, 0, 0)]
        assert (lo > 0) == (n < 9)


def test_max_range_cuts_the_ray_and_marks_nothing_at_the_cut():
    m = new_map()
    m.integrate(centre(0, 0, 0), [centre(60, 0, 0)], max_range=1.0)
    u = updated(m)
    # the cut point is at x = 0.025 + 1.0 = 1.025 -> voxel 20, excluded; 0..19 free
    assert set(u) == {(i, 0, 0) for i in range(20)}
    assert all(v < 0 for v in u.values())


def test_no_return_ray_clears_and_marks_nothing():
    m = new_map()
    m.integrate(centre(0, 0, 0), [centre(8, 0, 0)], returns=[False])
    u = updated(m)
    assert set(u) == {(i, 0, 0) for i in range(8)} and all(v < 0 for v in u.values())


def test_nan_points_are_dropped():
    m = new_map()
    r = m.integrate(centre(0, 0, 0), [[np.nan, 0.0, 0.0], centre(3, 0, 0)])
    assert r.rays == 1 and set(updated(m)) == {(i, 0, 0) for i in range(4)}


def test_ground_returns_clear_but_do_not_mark():
    m = new_map(ground_tolerance=0.05)
    origin = [0.025, 0.025, 1.0]
    m.integrate(origin, [[2.0, 0.025, 0.03], [0.025, 2.0, 0.10]])
    u = updated(m)
    assert (40, 0, 0) not in u  # the floor end voxel is neither hit nor cleared
    assert all(v < 0 for k, v in u.items() if k[2] <= 1 and k[1] == 0)
    assert u[(0, 40, 2)] == pytest.approx(HIT, abs=1e-6)  # z = 0.10 is above the tolerance
    assert sum(v > 0 for v in u.values()) == 1


def test_footprint_box_is_never_marked():
    m = new_map()
    yaw = math.pi / 2
    pose = np.eye(4)
    pose[:3, :3] = [[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]]
    pose[:3, 3] = [1.0, 1.0, 0.0]
    inside = [1.1, 1.2, 0.5]  # robot frame (0.2, -0.1, 0.5): inside the default 0.25 box
    outside = [1.0, 1.4, 0.5]  # robot frame (0.4, 0, 0.5): outside
    m.integrate([1.0, 1.0, 0.5], [inside, outside], robot_pose=pose)
    occ = {tuple(k) for k in m.occupied_keys("O").tolist()}
    assert occ == {(20, 28, 10)}


def test_storage_grows_while_integrating_many_blocks():
    m = new_map()
    rng = np.random.default_rng(1)
    ang = rng.uniform(-np.pi, np.pi, 3000)
    pts = np.stack([20 * np.cos(ang), 20 * np.sin(ang), np.full_like(ang, 0.3)], axis=1)
    r = m.integrate([0.0, 0.0, 0.3], pts)
    expected = {tuple(k) for k in pos_to_coord(pts, R).tolist()}
    assert r.hits == len(expected)
    assert m.O.n_blocks > 1024  # beyond the initial pool: grown mid-frame and resumed
    occ = {tuple(k) for k in m.occupied_keys("O").tolist()}
    assert occ == expected


def test_dedupe_casts_one_ray_per_end_voxel_with_the_same_result_for_hits():
    rng = np.random.default_rng(5)
    pts = np.repeat(np.array([centre(30, 4, 6), centre(-20, 9, 2), centre(3, -25, 8)]), 40, axis=0)
    pts += rng.uniform(-0.02, 0.02, pts.shape)  # 40 points per end voxel, all inside it
    a, b = new_map(), new_map()
    ra = a.integrate(centre(0, 0, 5), pts)
    rb = b.integrate(centre(0, 0, 5), pts, dedupe=True)
    assert ra.rays == 120 and ra.hits == rb.hits == 3
    assert {tuple(k) for k in a.occupied_keys("O").tolist()} == {tuple(k) for k in b.occupied_keys("O").tolist()}
    assert rb.misses <= ra.misses and rb.misses > 0


def test_far_coordinates_are_refused_not_silently_merged():
    """Voxel keys are packed with 21 bits per axis: beyond +-2^20 voxels (52 km at 0.05 m) two
    voxels would share a key. Within it a ray is exact; beyond, the frame is refused."""
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap
    from ltmap_cli.errors import CoreError

    m = LayeredMap(MapConfig())
    x0 = 40_000.01  # 40 km east: a ray of 1 m along +x, 20 voxels (19 misses, 1 hit)
    r = m.integrate([x0, 0.01, 1.01], [[x0 + 0.99, 0.01, 1.01]], dedupe=True)
    assert (r.hits, r.misses) == (1, 19)
    assert len(m.occupied_keys("O")) == 1
    for origin in ([60_000.0, 0.0, 1.0], [0.0, -60_000.0, 1.0]):
        with pytest.raises(CoreError, match=r"beyond \+-52\.4 km"):
            m.integrate(origin, [[origin[0] + 1.0, origin[1], 1.0]], dedupe=True)
    with pytest.raises(CoreError, match="not finite"):
        m.integrate([np.nan, 0.0, 1.0], [[1.0, 0.0, 1.0]])
    with pytest.raises(CoreError, match="long-term voxel"):
        m.seed_long_term(np.array([[10_000_000, 0, 20]]), 1.0)
    # a max-range cut bounds the reach: a point 100 km away with max_range 4 m is fine near the origin
    m.integrate([0.01, 0.01, 1.01], [[100_000.0, 0.01, 1.01]], max_range=4.0)


def test_infinite_or_huge_range_max_is_not_refused():
    """pointcloud_to_laserscan publishes range_max = inf: the reach is the farthest point, not inf."""
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap

    m = LayeredMap(MapConfig())
    pts = np.array([[1.0, 0.0, 0.3], [2.0, 0.5, 0.3], [np.inf, 0.0, 0.3]])
    for max_range in (np.inf, 1e6):
        r = m.integrate([0.0, 0.0, 0.3], pts, [True, True, True], max_range=max_range)
        assert r.hits == 2


def _room_frames(m, n=6):
    """Rays of a few depth frames (a floor and a wall, 2 mm noise) and laser scans of a box room
    from poses across the room: what a replay integrates."""
    rng = np.random.default_rng(12)
    h, w, f = 60, 80, 60.0
    v, _ = np.mgrid[0:h, 0:w].astype(np.float64)
    ray_y = (v - 29.5) / f
    z = np.where(ray_y > 0.5 / 2.5, 0.5 / np.maximum(ray_y, 1e-9), 2.5) + rng.normal(0, 0.002, (h, w))
    raw = np.round(z * 1000).astype(np.uint16)
    frames = []
    for t in range(n):
        a = 0.4 * t
        T = np.eye(4)
        T[:3, :3] = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]]) @ np.array(
            [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
        )
        T[:3, 3] = [0.11 * t, -0.07 * t, 0.5]
        frames.append((T[:3, 3].copy(), *m.depth_rays(raw, f, f, 39.5, 29.5, T, 4.0)))
        ang = np.linspace(-np.pi, np.pi, 360, endpoint=False)
        rng_m = 2.0 + rng.uniform(0, 1.5, ang.size)
        o = np.array([0.11 * t, -0.07 * t, 0.3])
        pts = o + np.stack([rng_m * np.cos(ang), rng_m * np.sin(ang), np.zeros_like(ang)], axis=1)
        frames.append((o, *m.rays(o, pts, None, 3.0)))
    return frames


def test_updated_voxel_bitmap_gives_the_same_map_as_the_stamps_alone():
    """frame_voxels drops the voxels a frame has updated already through a bitmap over the
    frame's box; without it apply_voxels drops them by their stamps, and decides the same. With
    the bitmap off, and with storage that runs out in the middle of frames (blocks, tick buffer,
    the bitmap and the miss buffer), the map, its block order and the tick buffer are those of
    the default map, and each voxel is updated once."""
    from ltmap_cli.core.grid import VoxelGrid
    from ltmap_cli.core.layers import O_CHANNELS, _sparse_bitmap

    ref, off, tight, tight_off = new_map(), new_map(), new_map(), new_map()
    off.seen_max_words = 0  # no frame gets the dense bitmap: the sparse one takes every voxel
    tight_off.seen_max_words = 0
    tight_off.O = VoxelGrid(R, O_CHANNELS, initial_blocks=1)
    tight_off._scratch.seen = np.empty(0, dtype=np.uint64)
    tight_off._scratch.meta = np.zeros(12, dtype=np.int64)
    tight_off._scratch.misses = np.empty(3, dtype=np.int64)
    tight_off._scratch.sparse = _sparse_bitmap(2)  # full at once: grown in the middle of frames
    tight.O = VoxelGrid(R, O_CHANNELS, initial_blocks=1)
    tight._tb_block, tight._tb_off = tight._tb_block[:3].copy(), tight._tb_off[:3].copy()
    tight._scratch.seen = np.empty(1, dtype=np.uint64)  # and frame_voxels' bitmap and miss buffer
    tight._scratch.meta = np.zeros(12, dtype=np.int64)
    tight._scratch.sparse = _sparse_bitmap(2)
    tight._scratch.misses = np.empty(3, dtype=np.int64)
    frames = _room_frames(ref)
    counts = []
    for origin, ends, kind in frames:
        # either bitmap lists each voxel once: no repeats for apply_voxels to drop
        for m in (ref, off):
            hits, misses = m.frame_voxels(origin, ends, kind)
            assert len(np.unique(misses)) == len(misses) and not np.isin(misses, hits).any()
        r = [m.integrate_rays(origin, ends, kind) for m in (ref, off, tight, tight_off)]
        assert r[0] == r[1] == r[2] == r[3]
        counts.append(r[0].hits + r[0].misses)
    assert ref._scratch.meta[0] == 1 and off._scratch.meta[0] == 0  # the bitmap was used, and was not
    n = ref.O.meta[0]
    assert n > 50 and sum(counts) > 10000
    for m in (off, tight, tight_off):
        assert m.O.meta[0] == n
        assert np.array_equal(m.O.block_coords[:n], ref.O.block_coords[:n])
        for ch in ("logodds", "stamp"):
            assert np.array_equal(m.O.data[ch][:n], ref.O.data[ch][:n])
        k = int(ref._tb_meta[0])
        assert int(m._tb_meta[0]) == k
        assert np.array_equal(m._tb_block[:k], ref._tb_block[:k]) and np.array_equal(m._tb_off[:k], ref._tb_off[:k])
    # each frame's updates are the distinct voxels it touched: the last frame's stamp count
    assert int((ref.O.data["stamp"][:n] == ref.frame_id).sum()) == counts[-1]


def test_frame_boxes_beyond_a_dense_bitmap_and_voxel_keys_beyond_their_extent():
    """Rays to opposite corners of the key extent: the frame's box (2^21 voxels a side, 2^63
    voxels) is far too big for a dense bitmap, and computing its size must not overflow (it
    wrapped negative and passed as small: writes outside the bitmap). Such a frame goes to the
    sparse bitmap (the bitmap test above checks it lists each voxel once). Rays whose voxels lie
    beyond the keys' extent are refused, not wrapped into other keys."""
    from ltmap_cli.core.layers import KEY_LIMIT
    from ltmap_cli.core.raycast import _seen_setup
    from ltmap_cli.errors import CoreError

    far = (KEY_LIMIT - 2) * R
    ends = np.array([[far, far, far], [-far, -far, -far]])
    meta = np.zeros(12, dtype=np.int64)
    meta[8] = 1 << 21
    assert _seen_setup(np.zeros(3), ends, np.array([1, 1], dtype=np.int8), 1 / R, np.empty(8, np.uint64), meta)
    assert meta[0] == 0 and (meta[4:7] >= 2 * (KEY_LIMIT - 2) + 9).all()  # dense off; the box recorded

    fine = new_map()
    fine.cfg.resolution = 0.01
    fine.resolution = 0.01
    x = (KEY_LIMIT - 50) * 0.01
    with pytest.raises(CoreError, match="beyond"):
        fine.integrate_rays([x, 0.0, 0.0], np.array([[x + 1.0, 0.0, 0.0]]), np.array([2], dtype=np.int8))


def _start_by_hand(o, e, res, tail):
    """The DDA's start of one ray, scalar Python floats, written out from OctoMap's
    computeRayKeys (the first crossing (c + 0.5) res + s res / 2 - r over d, the step res / |d|),
    with projective depth integration's tail: (walk, end voxel, first voxel, steps, first
    crossings, crossing steps, length, max_steps)."""
    far = 1e300
    o, e = [float(x) for x in o], [float(x) for x in e]
    ki = tuple(math.floor(c * (1.0 / res)) for c in o)
    ei = tuple(math.floor(c * (1.0 / res)) for c in e)
    d = [e[a] - o[a] for a in range(3)]
    length = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    if ei == ki:
        return False, ei
    d = [x / length for x in d]
    r, ci = list(o), ki
    if tail > 0.0 and length > tail:
        r = [e[a] - d[a] * tail for a in range(3)]
        ci = tuple(math.floor(x * (1.0 / res)) for x in r)
        length = tail
        if ci == ei:
            return False, ei
    s = tuple((x > 0) - (x < 0) for x in d)
    tm = tuple(((ci[a] + 0.5) * res + s[a] * res * 0.5 - r[a]) / d[a] if s[a] else far for a in range(3))
    td = tuple(res / abs(d[a]) if s[a] else far for a in range(3))
    steps = sum(abs(ei[a] - ci[a]) for a in range(3)) + 3
    return True, ei, ci, s, tm, td, length, steps


@pytest.mark.parametrize("tail", [0.0, 0.04, 0.3])  # (0.04: under a voxel, tails that start in the end voxel)
def test_ray_starts_on_vectors_are_the_scalar_arithmetic(tail):
    """``ray_starts`` computes a chunk of rays' DDA starts on vectors, with no branches: every
    value equals the scalar arithmetic's, bit for bit (rays along the axes, ends in the origin's
    voxel, tails starting in the end voxel, negative keys, a chunk that starts mid-array and is
    not full), as ``ray_state`` reads it back."""
    from ltmap_cli.core.raycast import RAY_CHUNK, ray_start_buffers, ray_starts, ray_state

    rng = np.random.default_rng(7)
    o = np.array([0.013, -1.27, 0.61])
    ends = o + rng.normal(size=(3 * RAY_CHUNK, 3)) * rng.choice([0.02, 0.2, 3.0], size=(3 * RAY_CHUNK, 1))
    ends[:40, 1:] = o[1:]  # along x (either way), along y, along z, the other two axes still
    ends[40:80, [0, 2]] = o[[0, 2]]
    ends[80:120, :2] = o[:2]
    ends[120:140] = o + 0.01  # in the origin's voxel
    ends[140:160] = o + np.array([0.2, 0.1, 0.0]) + 0.004  # a tail that may start in the end voxel
    ends[160:170] = o + [[-2.5, -3.1, -0.6]]  # negative keys
    res = 0.05
    ki = [np.int64(math.floor(c * (1.0 / res))) for c in o]
    af, ai = ray_start_buffers()
    checked = {True: 0, False: 0}
    for r0, n in ((0, RAY_CHUNK), (RAY_CHUNK + 17, RAY_CHUNK), (2 * RAY_CHUNK + 50, 100)):
        ray_starts(ends, np.int64(r0), np.int64(n), o[0], o[1], o[2], *ki, 1.0 / res, res, tail, af, ai)
        for q in range(n):
            want = _start_by_hand(tuple(o), tuple(ends[r0 + q]), res, tail)
            got = ray_state(af, ai, np.int64(q))
            assert got[0] == want[0], (r0 + q, got, want)
            checked[want[0]] += 1
            if not want[0]:
                assert tuple(got[1:4]) == want[1]
                continue
            _, ei, ci, s, tm, td, length, steps = want
            assert tuple(got[1:4]) == ei and tuple(got[4:7]) == ci and tuple(got[7:10]) == s
            assert tuple(got[10:13]) == tm and tuple(got[13:16]) == td  # (floats, compared exactly)
            assert got[16] == length and got[17] == steps
    assert checked[True] > 400 and checked[False] >= 20  # both kinds were met
