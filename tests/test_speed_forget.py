"""ST forgetting from a due-tick queue (issue 7: tick cost must not grow with the map) forgets
exactly what the full scan of every D block (``_forget_kernel``) forgets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numba import njit

from ltmap_cli.config import Config
from ltmap_cli.core.grid import BLOCK, BLOCK_MASK, band_k_range
from ltmap_cli.core.layers import LayeredMap, _record_history
from ltmap_cli.pipeline.replay import Replay, ReplayRequest

HOUSE = Path(__file__).resolve().parent.parent / "sample_logs" / "scenarios" / "06_house" / "log.mcap"


@njit(cache=False)
def _forget_kernel(n_blocks, d_coords, st, lt, last_obs, obst_since, tick_index, forget_ticks, k_lo, k_hi,
                   hist_i, hist_v, hist_p, hist_meta):  # fmt: skip
    """ST falls to 0 where no obstacle was seen for ``forget_ticks``. Returns the number forgotten,
    or -1 when the history buffer must grow first (nothing changed)."""
    n = 0
    for b in range(n_blocks):
        bz0 = np.int64(d_coords[b, 2]) * BLOCK
        for o in range(st.shape[1]):
            if st[b, o] > 0.0 and tick_index - last_obs[b, o] >= forget_ticks:
                k = bz0 + (o & BLOCK_MASK)
                if k_lo <= k <= k_hi:
                    if hist_meta[0] >= hist_i.shape[0]:
                        return -1
                    _record_history(hist_i, hist_v, hist_p, hist_meta, tick_index, b * 512 + o, 0.0, lt[b, o], False)
                st[b, o] = 0.0
                obst_since[b, o] = -1
                n += 1
    return n



def _check_nothing_left(lmap: LayeredMap) -> int:
    """Run the full-scan rule after a tick: it must find nothing more to forget."""
    lay = lmap.cfg.layers
    forget_ticks = max(1, int(round(lay.st_forget_s / lay.tick)))
    k_lo, k_hi = band_k_range(lmap.cfg.projection.z_min, lmap.cfg.projection.z_max, lmap.resolution)
    d = lmap.D
    st = d.data["st"].copy()
    obst = d.data["obst_since"].copy()
    hist_i = np.zeros((1 << 20, 2), np.int32)
    hist_v = np.zeros((1 << 20, 2), np.float32)
    hist_p = np.zeros(1 << 20, np.uint8)
    meta = np.zeros(1, np.int64)
    n = _forget_kernel(d.n_blocks, d.block_coords, st, d.data["lt"], d.data["last_obs"], obst, lmap.tick_index - 1,
                       forget_ticks, k_lo, k_hi, hist_i, hist_v, hist_p, meta)  # fmt: skip
    assert n == 0, f"tick {lmap.tick_index - 1}: the queue missed {n} voxels to forget"
    return int((d.channel("st") > 0).sum())


def _forget_run(queue_slots: int = 0) -> tuple[int, LayeredMap]:
    """60 ticks of random frames with a spot seen 3 ticks in 7 (ST forgotten 5 ticks after),
    each tick checked against the full scan; (voxels forgotten, the map). ``queue_slots``: the
    forget queue starts that small."""
    rng = np.random.default_rng(5)
    cfg = Config().map
    cfg.layers.st_forget_s = 1.0  # 5 ticks
    lmap = LayeredMap(cfg)
    if queue_slots:
        lmap._fq_vid, lmap._fq_due = lmap._fq_vid[:queue_slots].copy(), lmap._fq_due[:queue_slots].copy()
    forgotten = 0
    for tick in range(60):
        for _ in range(2):
            origin = np.array([0.0, 0.0, 0.5])
            pts = rng.uniform([-2, -2, 0.1], [2, 2, 1.4], size=(200, 3))
            if tick % 7 < 3:  # a block of ticks seen, then unseen
                pts[:50] = [1.02, 1.03, 0.77] + rng.normal(0, 0.02, size=(50, 3))
            lmap.integrate(origin, pts)
        r = lmap.end_tick()
        forgotten += r.st_forgotten
        _check_nothing_left(lmap)
    return forgotten, lmap


def test_queue_forgets_what_the_full_scan_forgets():
    forgotten, _ = _forget_run()
    assert forgotten > 0


def test_a_full_forget_queue_grows_within_a_tick():
    """A queue of 4 slots: the tick kernel appends a tick's obstacles itself, stops when the queue
    is full and goes on after it grew; the same voxels are forgotten, ST and LT the same."""
    n_default, a = _forget_run()
    n_small, b = _forget_run(queue_slots=4)
    assert len(b._fq_vid) > 4
    assert n_small == n_default
    for ch in ("st", "lt", "last_obs", "obst_since"):
        assert np.array_equal(a.D.channel(ch), b.D.channel(ch)), ch


def test_queue_survives_state_reload():
    rng = np.random.default_rng(6)
    cfg = Config().map
    cfg.layers.st_forget_s = 0.6
    a = LayeredMap(cfg)
    for _ in range(4):
        a.integrate([0, 0, 0.5], rng.uniform([-1, -1, 0.2], [1, 1, 1.0], size=(300, 3)))
        a.end_tick()
    b = LayeredMap(cfg)
    b.load_state_arrays(a.state_arrays())
    assert (b.D.channel("st") > 0).any()
    for _ in range(6):
        b.end_tick()
        _check_nothing_left(b)
    assert not (b.D.channel("st") > 0).any()


def test_replay_with_fast_forgetting_checked_every_tick(tmp_path):
    if not HOUSE.exists():
        pytest.skip("house sample missing")
    cfg = Config()
    cfg.replay.plots = False
    cfg.map.layers.st_forget_s = 2.0
    run = Replay(cfg, ReplayRequest([HOUSE], tmp_path))
    checked = []
    real_run = run.run

    def patched():
        lmap_cls_end_tick = LayeredMap.end_tick

        def end_tick(self):
            r = lmap_cls_end_tick(self)
            _check_nothing_left(self)
            checked.append(r.st_forgotten)
            return r

        LayeredMap.end_tick = end_tick
        try:
            return real_run()
        finally:
            LayeredMap.end_tick = lmap_cls_end_tick

    patched()
    assert len(checked) > 100 and sum(checked) > 0


def test_queue_holds_an_obstacle_once_however_often_it_is_seen():
    """A spot seen in each of 40 ticks (ST forgotten 60 s after): the queue holds one entry per
    voxel with ST > 0, not one per sighting (a room seen for 60 s queued 7.5 M); seen no more,
    each is forgotten at its due tick all the same (checked against the full scan every tick)."""
    rng = np.random.default_rng(8)
    cfg = Config().map
    cfg.layers.st_forget_s = 2.0  # 10 ticks
    lmap = LayeredMap(cfg)
    spot = [1.02, 1.03, 0.77] + rng.normal(0, 0.03, size=(300, 3))
    for _ in range(40):
        lmap.integrate(np.array([0.0, 0.0, 0.5]), spot)
        lmap.end_tick()
        _check_nothing_left(lmap)
    with_st = int((lmap.D.channel("st") > 0).sum())
    assert with_st > 10
    assert int(lmap._fq_meta[0]) == with_st  # (40 sightings each)
    forgotten = 0
    for _ in range(12):
        forgotten += lmap.end_tick().st_forgotten
        _check_nothing_left(lmap)
    assert forgotten == with_st and int(lmap._fq_meta[0]) == 0
