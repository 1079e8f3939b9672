"""Quiet blocks (issue 17): an O block whose 512 voxels are all clamped free and which has no D
block takes no miss updates (they would change nothing), and rays skip it.

- the map is the one of updating every voxel (``quiet_blocks = False``): O log-odds, D, events,
  block order bit for bit; only the stamps of voxels in quiet blocks differ (they keep the frame
  that clamped them), and a voxel is known (stamp > 0) exactly when it is there;
- it is the same whether the rays skip quiet blocks or not, and whether the frames are cast
  with the quiet table of the moment or one several frames old (as the replay's worker threads
  cast ahead of the frames being applied): a block that stopped being quiet since is caught and
  the frame cast again;
- the replay of a sample log gives the same map on the serial path and the threaded one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ltmap_cli.config import Config
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.pipeline.replay import Replay, ReplayRequest

ROOT = Path(__file__).resolve().parent.parent
HOUSE = ROOT / "sample_logs" / "scenarios" / "06_house" / "log.mcap"


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
    them, as the worker threads do), 'noskip' (rays list every voxel; the apply rule alone)."""
    m = LayeredMap()
    m.quiet_blocks = quiet
    ticks = []
    pending = []
    for f, (origin, ends, kind) in enumerate(frames):
        if mode == "integrate":
            m.integrate_rays(origin, ends, kind)
        else:
            pending.append(m.frame_voxels(origin, ends, kind, quiet=(mode == "ahead")))
            if len(pending) > ahead:
                fv = pending.pop(0)
                m.apply_voxels(fv.hits, fv.misses, 0, fv)
        if f % 6 == 5:
            while pending:  # a tick: applied in order first (the replay does the same)
                fv = pending.pop(0)
                m.apply_voxels(fv.hits, fv.misses, 0, fv)
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
    for x, y in zip(a.events.history, b.events.history):
        assert np.array_equal(x, y)


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
    lo_min = np.float32(quiet.cfg.sensor.clamp_min_logodds)
    assert np.array_equal(q.nfree[:n], (lo == lo_min).sum(axis=1))
    no_d = np.array([quiet.D.get("lt", (quiet.O.block_coords[b:b + 1].astype(np.int64) * 8)).size >= 0
                     and _d_block(quiet, b) < 0 for b in range(n)])
    assert np.array_equal(q.quiet[:n].astype(bool), (q.nfree[:n] == 512) & no_d)
    assert all(t.observed > 0 for t in ticks)


def _d_block(m: LayeredMap, b: int) -> int:
    from ltmap_cli.core.grid import find_block

    c = m.O.block_coords[b]
    return int(find_block(m.D.table_keys, m.D.table_vals, int(c[0]), int(c[1]), int(c[2])))


def test_skipping_rays_cast_ahead_give_the_same_map_bit_for_bit():
    frames = _frames(90, seed=2)
    ref, _ = _run(frames, quiet=True, mode="noskip")
    now, _ = _run(frames, quiet=True, mode="integrate")
    _same_map(ref, now, stamps=True)
    for ahead in (3, 8):
        late, _ = _run(frames, quiet=True, mode="ahead", ahead=ahead)
        _same_map(ref, late, stamps=True)
        assert late.quiet_recasts > 0  # stray hits made blocks skipped by frames in flight noisy
    # the skipping frames listed fewer voxels
    m = LayeredMap()
    for origin, ends, kind in frames[:40]:
        m.integrate_rays(origin, ends, kind)
    a = m.frame_voxels(*frames[40], quiet=True)
    b = m.frame_voxels(*frames[40], quiet=False)
    assert len(a.passed) > 0 and len(a.misses) < len(b.misses)
    assert np.array_equal(a.hits, b.hits)


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
    assert ref.frame_id == 60


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


def _tricky_rays(rng, n: int, res: float):
    """Random rays, plus axis-aligned ones, exact diagonals from voxel centres (ties between axes
    at every step) and ends on voxel and block faces."""
    origin = (np.floor(rng.uniform(-1, 1, 3) / res) + 0.5) * res
    if rng.random() < 0.5:
        origin = origin + rng.uniform(-0.5, 0.5, 3) * res
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    ends = origin + d * rng.uniform(0.05, 4.0, (n, 1))
    m = n // 8
    axis = rng.integers(0, 3, m)
    steps = rng.integers(1, 60, m) * rng.choice([-1, 1], m)
    ends[:m] = origin
    ends[np.arange(m), axis] += steps * res  # axis-aligned
    diag = rng.integers(-40, 40, (m, 3))
    ends[m : 2 * m] = origin + diag * res  # exact multiples: ties
    ends[2 * m : 3 * m] = np.floor(ends[2 * m : 3 * m] / (8 * res)) * 8 * res  # on block corners
    kind = np.where(rng.random(n) < 0.8, 2, 1).astype(np.int8)
    kind[rng.random(n) < 0.02] = 0
    return origin, ends, kind


def test_rays_skip_exactly_the_quiet_blocks_voxels():
    """frame_voxels with a quiet table lists the voxels of the full listing outside quiet blocks,
    in the same order (hits unchanged), whatever the rays: the fast steps through quiet blocks
    stop where stepping voxel by voxel stops."""
    from ltmap_cli.core.grid import pack_block
    from ltmap_cli.core.raycast import KEY_MASK, KEY_OFFSET, quiet_table_rehash

    rng = np.random.default_rng(11)
    m = LayeredMap()
    res = m.resolution
    for trial in range(12):
        origin, ends, kind = _tricky_rays(rng, 3000, res)
        full = m.frame_voxels(origin, ends, kind, quiet=False)
        keys = full.misses
        bx = ((keys >> 42) - KEY_OFFSET) >> 3
        by = (((keys >> 21) & KEY_MASK) - KEY_OFFSET) >> 3
        bz = ((keys & KEY_MASK) - KEY_OFFSET) >> 3
        blocks = np.unique(np.stack([bx, by, bz], 1), axis=0)
        share = [0.3, 0.7, 1.0][trial % 3]
        chosen = blocks[rng.random(len(blocks)) < share]
        packed = np.array([pack_block(*map(int, b)) for b in chosen], dtype=np.int64)
        slots = 16
        while slots < 4 * max(len(packed), 1):
            slots *= 2
        qk, qo, _ = quiet_table_rehash(np.full(1, -1, dtype=np.int64), np.zeros(1, dtype=np.uint8), slots)
        for p in packed:
            qk2 = np.concatenate([qk, np.array([p])])  # (simple insert through the table's own rehash)
            qo2 = np.concatenate([qo, np.array([1], dtype=np.uint8)])
            qk, qo, _ = quiet_table_rehash(qk2, qo2, slots)
        m._qtable = (qk, qo)
        part = m.frame_voxels(origin, ends, kind, quiet=True)
        qset = set(packed.tolist())
        keep = np.array([pack_block(int(a), int(b), int(c)) not in qset for a, b, c in zip(bx, by, bz)], dtype=bool)
        assert np.array_equal(part.hits, full.hits)
        assert np.array_equal(part.misses, keys[keep])
        assert set(part.passed.tolist()) <= qset and len(part.passed) > 0
