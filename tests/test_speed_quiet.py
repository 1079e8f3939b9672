"""Quiet quarters and blocks (issue 17): a 4 x 4 x 4 quarter of an O block whose 64 voxels are
all clamped free and which has no ST or LT (no D block, or one whose ST and LT are all 0 there
again) takes no miss updates (they would change nothing); a block of eight such quarters is quiet
(the workers' projection skips it).

- the map is the one of updating every voxel (``quiet_blocks = False``): O log-odds, D, events,
  block order bit for bit; only the stamps of voxels in quiet blocks differ (they keep the frame
  that clamped them), and a voxel is known (stamp > 0) exactly when it is there;
- it is decided in ``apply_voxels``, in frame order: frames cast several frames ahead of being
  applied (as the replay's worker threads cast them) give the same map bit for bit, stamps too;
- the per-quarter counts stay those of the map, also after a loaded state and new LT seeds;
- the replay of a sample log gives the same map on the serial path and the threaded one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ltmap_cli.config import Config
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.pipeline.replay import Replay, ReplayRequest

ROOT = Path(__file__).resolve().parent.parent
HOUSE = ROOT / "sample_logs" / "scenarios" / "06_house" / "log.mcap"


def _by_quarter(a: np.ndarray) -> np.ndarray:
    """(n, 512) per voxel of O blocks -> (n, 8, 64): each quarter's 64 voxels (quarter 4 * x half +
    2 * y half + z half, as core.projective's block loop numbers them), computed here from the
    offsets (x * 64 + y * 8 + z), not from the kernels' helper."""
    off = np.arange(512)
    quarter = 4 * (off >> 6 >= 4) + 2 * ((off >> 3) % 8 >= 4) + (off % 8 >= 4)
    return a[:, np.argsort(quarter, kind="stable")].reshape(len(a), 8, 64)


def _quiet_rule(m: LayeredMap) -> tuple[np.ndarray, np.ndarray]:
    """What the quiet record should say of the map as it is: per O block and quarter the count
    of voxels clamped free, and the quiet quarters (64 clamped free, no ST or LT) as bits."""
    n = m.O.n_blocks
    free = _by_quarter(m.O.data["logodds"][:n] == np.float32(m.cfg.sensor.clamp_min_logodds))
    st_lt = np.zeros((n, 8, 64), dtype=bool)
    for b in range(n):
        db = _d_block(m, b)
        if db >= 0:
            st_lt[b] = _by_quarter(((m.D.data["st"][db] != 0) | (m.D.data["lt"][db] != 0))[None])[0]
    quiet = free.all(axis=2) & ~st_lt.any(axis=2)
    return free.sum(axis=2), (quiet * (1 << np.arange(8))).sum(axis=1)


def _frames(n: int, seed: int):
    """Depth-camera-like fans of rays in a 4 x 3 x 2.5 m room from near one point, with stray
    hits in the free space now and then (noise, a person walking through) that un-quiet blocks."""
    rng = np.random.default_rng(seed)
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([4.0, 3.0, 2.5])
    frames = []
    for f in range(n):
        origin = np.array([0.52, 1.47, 1.03]) + rng.normal(0, 0.01, 3)
        yaw = 0.3 * np.sin(f / 7.0)
        u = np.linspace(-0.5, 0.5, 48)[None, :] + rng.normal(0, 0.002, (36, 48))
        v = np.linspace(-0.4, 0.4, 36)[:, None] + rng.normal(0, 0.002, (36, 48))
        d = np.stack([np.cos(yaw + u) * np.cos(v), np.sin(yaw + u) * np.cos(v), np.sin(v)], -1).reshape(-1, 3)
        # distance to the room's walls along each ray
        t = np.full(len(d), np.inf)
        for ax in range(3):
            with np.errstate(divide="ignore"):
                for wall in (lo[ax], hi[ax]):
                    tw = (wall - origin[ax]) / d[:, ax]
                    t = np.where((tw > 0) & (tw < t), tw, t)
        t = t * (1 + rng.normal(0, 0.002, len(t)))
        if f % 9 == 5:  # stray returns in the free space
            stray = rng.random(len(t)) < 0.01
            t[stray] *= rng.uniform(0.2, 0.9, stray.sum())
        ends = origin + d * t[:, None]
        kind = np.where(rng.random(len(t)) < 0.02, 1, 2).astype(np.int8)  # a few clear-only rays
        frames.append((origin, ends, kind))
    return frames


def _run(frames, quiet: bool, mode: str, ahead: int = 0):
    """mode: 'integrate' (cast and apply each frame), 'ahead' (cast ``ahead`` frames before applying
    them, as the worker threads do)."""
    m = LayeredMap()
    m.quiet_blocks = quiet
    ticks = []
    pending = []
    for f, (origin, ends, kind) in enumerate(frames):
        if mode == "integrate":
            m.integrate_rays(origin, ends, kind)
        else:
            hits, misses, masks = m.ray_voxels(origin, ends, kind)
            pending.append((hits, misses, int((kind > 0).sum()), masks))
            if len(pending) > ahead:
                m.apply_voxels(*pending.pop(0))
        if f % 6 == 5:
            while pending:  # a tick: applied in order first (the replay does the same)
                m.apply_voxels(*pending.pop(0))
            ticks.append(m.end_tick())
    return m, ticks


def _same_map(a: LayeredMap, b: LayeredMap, stamps: bool) -> None:
    n = a.O.n_blocks
    assert b.O.n_blocks == n
    assert np.array_equal(a.O.block_coords[:n], b.O.block_coords[:n])
    assert np.array_equal(a.O.data["logodds"][:n], b.O.data["logodds"][:n])
    assert np.array_equal(a.O.data["stamp"][:n] > 0, b.O.data["stamp"][:n] > 0)
    if stamps:
        assert np.array_equal(a.O.data["stamp"][:n], b.O.data["stamp"][:n])
    nd = a.D.n_blocks
    assert b.D.n_blocks == nd
    assert np.array_equal(a.D.block_coords[:nd], b.D.block_coords[:nd])
    for ch in a.D.data:
        assert np.array_equal(a.D.data[ch][:nd], b.D.data[ch][:nd]), ch
    assert np.array_equal(a.events.transitions, b.events.transitions)
    # the history's rows, by tick and voxel: a voxel whose miss was skipped (still), then hit in
    # the same tick, enters the tick buffer later, so its rows of that tick come later
    (ia, va), (ib, vb) = a.events.history, b.events.history
    oa, ob = np.lexsort(ia.T[::-1]), np.lexsort(ib.T[::-1])
    assert np.array_equal(ia[oa], ib[ob]) and np.array_equal(va[oa], vb[ob])


def test_quiet_blocks_leave_the_map_of_every_update():
    frames = _frames(90, seed=1)
    full, _ = _run(frames, quiet=False, mode="integrate")
    quiet, ticks = _run(frames, quiet=True, mode="integrate")
    _same_map(full, quiet, stamps=False)
    q = quiet._quiet
    n = quiet.O.n_blocks
    assert q.quiet[:n].sum() > 20  # the lever is exercised: blocks became quiet
    # stamps differ only in voxels clamped free, where the quiet map's is older
    lo = quiet.O.data["logodds"][:n]
    sa, sb = full.O.data["stamp"][:n], quiet.O.data["stamp"][:n]
    differ = sa != sb
    assert differ.any()
    assert (lo[differ] == np.float32(quiet.cfg.sensor.clamp_min_logodds)).all()
    assert (sb[differ] < sa[differ]).all()
    # the counts are the quiet state of the map: recomputed from scratch, the same
    q = quiet._quiet_sync()
    nfree, qquiet = _quiet_rule(quiet)
    assert np.array_equal(q.nfree[:n], nfree)
    # quiet quarters: all clamped free, and no ST or LT there (no D block, or the stray hits' D
    # blocks once their ST fell back to 0), as of the last tick; a block is quiet when all are
    assert np.array_equal(q.qquiet[:n], qquiet)
    assert np.array_equal(q.quiet[:n].astype(bool), qquiet == 255)
    d_block = np.array([_d_block(quiet, b) for b in range(n)])
    assert (q.quiet[:n].astype(bool) & (d_block >= 0)).any()  # quiet with a D block: a stray hit's
    # quiet quarters in blocks that are not quiet (a wall's blocks, the stray hits' quarters)
    assert ((qquiet > 0) & (qquiet < 255)).sum() > 20
    assert all(t.observed > 0 for t in ticks)


# where the box's face was (x 1.5 m: voxel 30), in one block that has a D block from its hits
_SEEDS = np.array([[29 + i, j, 20] for i in range(3) for j in range(3)], dtype=np.int64)


def _o_block(m: LayeredMap, c) -> int:
    from ltmap_cli.core.grid import find_block

    return int(find_block(m.O.table_keys, m.O.table_vals, int(c[0]), int(c[1]), int(c[2])))


def _depth_run(quiet: bool, seed_at: int | None = None):
    """A depth camera 1 m up facing a wall 3 m away, as the replay integrates it (projective),
    a tick every 3 frames: the wall alone (its free space clamps), a box 1.5 m away in part of
    the image for 6 frames (hits: its blocks get D blocks with ST), then the wall alone for 60
    frames (the box's space turns free again, its ST falls back to 0). ``seed_at``: LT seeded
    before that frame at the box's space, as --resume or furniture drawn as long-term do."""
    from ltmap_cli.core.config import MapConfig

    cfg = MapConfig()
    cfg.sensor.depth_integration = "projective"
    m = LayeredMap(cfg)
    m.quiet_blocks = quiet
    pose = np.eye(4)
    pose[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]  # optical frame looking along +x
    pose[:3, 3] = [0.01, 0.01, 1.01]
    wall = np.full((60, 80), 3000, dtype=np.uint16)
    box = wall.copy()
    box[20:40, 30:50] = 1500
    for f, depth in enumerate([wall] * 12 + [box] * 6 + [wall] * 60):
        if f == seed_at:
            m.seed_long_term(_SEEDS, 0.9)
        m.integrate_depth(depth, 50.0, 50.0, 39.5, 29.5, pose, 8.0)
        if f % 3 == 2:
            m.end_tick()
    m._quiet_sync()
    return m


def test_blocks_whose_st_and_lt_fell_back_to_0_are_quiet_again():
    """The D block of something seen once stays (a person walking through): once its ST and LT
    are 0 again and its O voxels clamped free, the block is quiet like one that never had a D
    block (the office bench scene: 40 such blocks in each frame's frustum, 22 % of the
    projection's misses, were never quiet). The map stays that of updating every voxel, and LT
    seeded there makes the block take misses again until it has fallen back to 0."""
    for seed_at in (None, 30, 75):
        full, quiet = _depth_run(False, seed_at), _depth_run(True, seed_at)
        _same_map(full, quiet, stamps=False)
        q, n = quiet._quiet, quiet.O.n_blocks
        d_block = np.array([_d_block(quiet, b) for b in range(n)])
        with_d = q.quiet[:n].astype(bool) & (d_block >= 0)
        lt = quiet.D.channel("lt")
        assert with_d.sum() >= 2  # the box's blocks, ST and LT 0 again (the wall's ST rises), are quiet
        seeded = np.unique(np.array([_o_block(quiet, k >> 3) for k in _SEEDS]))
        assert len(seeded) == 1 and seeded[0] >= 0 and _d_block(quiet, seeded[0]) >= 0
        if seed_at == 75:  # LT seeded 3 frames ago: those blocks take misses again, LT falls
            assert lt.max() > 0 and not q.quiet[seeded].any()
        else:  # (seeded 48 frames ago: fallen back to 0, quiet again)
            assert lt.max() == 0 and (seed_at is None or q.quiet[seeded].all())
        nfree, qquiet = _quiet_rule(quiet)
        assert np.array_equal(q.nfree[:n], nfree) and np.array_equal(q.qquiet[:n], qquiet)
        assert ((qquiet > 0) & (qquiet < 255)).sum() >= 10  # the wall's blocks: quarters in front of it


def _d_block(m: LayeredMap, b: int) -> int:
    from ltmap_cli.core.grid import find_block

    c = m.O.block_coords[b]
    return int(find_block(m.D.table_keys, m.D.table_vals, int(c[0]), int(c[1]), int(c[2])))


def test_frames_cast_ahead_give_the_same_map_bit_for_bit():
    frames = _frames(90, seed=2)
    ref, _ = _run(frames, quiet=True, mode="integrate")
    assert ref._quiet.quiet[: ref.O.n_blocks].sum() > 20
    for ahead in (3, 8):
        late, _ = _run(frames, quiet=True, mode="ahead", ahead=ahead)
        _same_map(ref, late, stamps=True)


def test_quiet_blocks_follow_a_loaded_state_and_new_long_term_seeds():
    frames = _frames(60, seed=3)
    ref, _ = _run(frames, quiet=False, mode="integrate")
    m, _ = _run(frames[:30], quiet=True, mode="integrate")
    # a copy through the exact state: the quiet record is rebuilt from its O and D
    m2 = LayeredMap()
    m2.load_state_arrays({k: np.array(v) for k, v in m.state_arrays().items()})
    # LT seeded inside what is quiet free space now: those blocks stop being quiet
    q = m._quiet
    qb = np.nonzero(q.quiet[: m.O.n_blocks])[0][:3]
    keys = m.O.block_coords[qb].astype(np.int64) * 8 + 3
    for x in (m, m2, ref):
        x.seed_long_term(keys, 0.9)
    for x in (m, m2):
        for f, (origin, ends, kind) in enumerate(frames[30:], start=30):
            x.integrate_rays(origin, ends, kind)
            if f % 6 == 5:
                x.end_tick()
    ref2 = LayeredMap()
    ref2.quiet_blocks = False
    for f, (origin, ends, kind) in enumerate(frames):
        ref2.integrate_rays(origin, ends, kind)
        if f % 6 == 5:
            ref2.end_tick()
        if f == 29:
            ref2.seed_long_term(keys, 0.9)
    for x in (m, m2):
        n = x.O.n_blocks
        assert np.array_equal(x.O.data["logodds"][:n], ref2.O.data["logodds"][:n])
        nd = x.D.n_blocks
        for ch in x.D.data:
            assert np.array_equal(x.D.data[ch][:nd], ref2.D.data[ch][:nd]), ch
        assert not x._quiet.quiet[qb].any()
        x._quiet_sync()
        nfree, qquiet = _quiet_rule(x)
        assert np.array_equal(x._quiet.nfree[:n], nfree) and np.array_equal(x._quiet.qquiet[:n], qquiet)
    assert ref.frame_id == 60


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
def test_replay_serial_and_threaded_same_map_with_quiet_blocks(tmp_path):
    outs = {}
    for name, (fast, threads) in {"serial": (False, False), "threads": (True, True)}.items():
        cfg = Config()
        cfg.replay.plots = False
        run = Replay(cfg, ReplayRequest([HOUSE], tmp_path / name))
        run.fast, run.threads = fast, threads
        run.run()
        outs[name] = run.lmap
    a, b = outs["serial"], outs["threads"]
    _same_map(a, b, stamps=True)
    assert a._quiet.quiet.sum() > 0



def test_quiet_counts_survive_storage_growing_mid_frame():
    """O's pool, the tick buffer and the list of changed blocks all full at the start: each grows
    in the middle of frames, and the map and the per-block counts are those of a roomy map."""
    from ltmap_cli.core.grid import VoxelGrid
    from ltmap_cli.core.layers import O_CHANNELS

    frames = _frames(40, seed=5)
    ref, _ = _run(frames, quiet=True, mode="integrate")
    tight = LayeredMap()
    tight.O = VoxelGrid(tight.resolution, O_CHANNELS, initial_blocks=1)
    tight._tb_block, tight._tb_off = tight._tb_block[:2].copy(), tight._tb_off[:2].copy()
    q = tight._quiet_sync()
    q.changed = q.changed[:1].copy()
    for f, (origin, ends, kind) in enumerate(frames):
        tight.integrate_rays(origin, ends, kind)
        if f % 6 == 5:
            tight.end_tick()
    _same_map(ref, tight, stamps=True)
    n = tight.O.n_blocks
    tight._quiet_sync()
    nfree, qquiet = _quiet_rule(tight)
    assert np.array_equal(tight._quiet.nfree[:n], nfree)
    assert np.array_equal(tight._quiet.qquiet[:n], qquiet)
    assert np.array_equal(tight._quiet.quiet[:n], ref._quiet.quiet[:n])
    assert len(tight._quiet.changed) > 1 and tight._quiet.quiet[:n].sum() > 0


def test_a_full_list_of_changed_blocks_puts_no_voxel_twice_in_the_tick_buffer():
    """The kernel stops for a longer list of changed blocks before it writes anything of the
    voxel it is at, so the voxel is not put in the tick buffer a second time when it resumes."""
    frames = _frames(6, seed=7)
    ref, tight = LayeredMap(), LayeredMap()
    q = tight._quiet_sync()
    q.changed = q.changed[:1].copy()
    for origin, ends, kind in frames:
        ref.end_tick()  # each frame in a tick of its own: every voxel it updates enters the buffer
        tight.end_tick()
        ref.integrate_rays(origin, ends, kind)
        tight.integrate_rays(origin, ends, kind)
        n_ref, n = int(ref._tb_meta[0]), int(tight._tb_meta[0])
        keys = tight._tb_block[:n].astype(np.int64) * 512 + tight._tb_off[:n]
        assert n == n_ref and len(np.unique(keys)) == n
    assert len(tight._quiet.changed) > 1  # it grew in the middle of frames
