"""The held rule of SPEC 2.2: a voxel that O still says occupied but that a tick observed only as
misses (an object just removed) keeps its ST and LT; only a hit in the tick lets ST rise.

Defaults: tick 0.2 s, st_rise_s 15 s (ST + 1/75 per tick), st_fall_s 1 s, lt_fall_s 3 s; O's
log-odds: hit +0.847, miss -0.405, clamped to [-2, 3.5], so a voxel at the top clamp needs 9
misses to turn free.
"""

import numpy as np
import pytest

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap

R = 0.05
ORIGIN = [0.025, 0.025, 0.525]  # centre of voxel (0, 0, 10)
TARGET = (20, 0, 10)  # 1 m ahead of the sensor
HIT = [(20 + 0.5) * R, 0.025, 0.525]
BEYOND = [(40 + 0.5) * R, 0.025, 0.525]  # a ray through TARGET to 2 m
RISE = 0.2 / 15.0


def val(m, layer):
    return float(m.values(layer, np.array([TARGET]))[0])


def hit_tick(m, frames=1):
    for _ in range(frames):
        m.integrate(ORIGIN, [HIT])
    return m.end_tick()


def miss_tick(m, frames=1):
    for _ in range(frames):
        m.integrate(ORIGIN, [BEYOND])
    return m.end_tick()


def test_misses_while_o_is_occupied_hold_st_and_lt():
    m = LayeredMap(MapConfig())
    for _ in range(74):  # one tick short of LT
        hit_tick(m, frames=2)
    assert val(m, "ST") == pytest.approx(74 * RISE, abs=1e-4) and val(m, "LT") == 0.0
    # the object is removed: 8 misses in 4 ticks leave O occupied (3.5 - 8 * 0.405 > 0)
    for _ in range(4):
        r = miss_tick(m, frames=2)
        assert val(m, "O") > 0.0
        assert r.held == 1  # the target; the voxel beyond is hit (an obstacle)
        assert val(m, "ST") == pytest.approx(74 * RISE, abs=1e-4)  # before the rule: rose to 1
        assert val(m, "LT") == 0.0  # ... and entered LT after the object was gone
    r = miss_tick(m, frames=2)  # O turns free: seen free, ST falls
    assert val(m, "O") < 0.0 and r.held == 0
    assert val(m, "ST") == pytest.approx(74 * RISE - 0.2, abs=1e-4)
    assert val(m, "LT") == 0.0


def test_held_keeps_lt_of_a_voxel_already_in_lt():
    m = LayeredMap(MapConfig())
    for _ in range(80):
        hit_tick(m)
    assert val(m, "LT") == 1.0 and val(m, "ST") == 1.0
    for _ in range(8):
        r = miss_tick(m)
        assert r.held == 1
        assert val(m, "LT") == 1.0 and val(m, "ST") == 1.0


def test_a_hit_in_any_frame_of_the_tick_makes_an_obstacle():
    """Within a tick, a hit then misses (O still occupied) or misses then a hit: an obstacle."""
    m = LayeredMap(MapConfig())
    hit_tick(m, frames=3)  # O at 2.54
    m.integrate(ORIGIN, [HIT])
    m.integrate(ORIGIN, [BEYOND])
    r = m.end_tick()
    assert r.held == 0
    m.integrate(ORIGIN, [BEYOND])
    m.integrate(ORIGIN, [HIT])
    r = m.end_tick()
    assert r.held == 0
    assert val(m, "ST") == pytest.approx(3 * RISE, abs=1e-5)
    # the mark is the tick's: the next tick, misses only, holds
    r = miss_tick(m)
    assert r.held == 1 and val(m, "ST") == pytest.approx(3 * RISE, abs=1e-5)


def test_a_held_tick_gives_no_gap_credit():
    """Gap credit (a voxel re-observed after unobserved ticks counts the gap) is for sensors
    slower than the tick; ticks that observed the voxel as held are not a gap."""
    m = LayeredMap(MapConfig())
    hit_tick(m, frames=3)
    miss_tick(m)
    miss_tick(m)
    hit_tick(m)
    assert val(m, "ST") == pytest.approx(2 * RISE, abs=1e-5)
    m.end_tick()  # unobserved
    m.end_tick()
    hit_tick(m)  # a real gap of 3 ticks: credited
    assert val(m, "ST") == pytest.approx(5 * RISE, abs=1e-5)


def test_a_loaded_state_starts_with_no_hit_marks():
    m = LayeredMap(MapConfig())
    hit_tick(m, frames=3)
    m.integrate(ORIGIN, [HIT])  # a tick in progress: marked
    arrays = {k: np.array(v) for k, v in m.state_arrays().items()}
    assert "O_hit" not in arrays  # the marks of a tick in progress are not state
    old = {**arrays, "O_hit": np.ones(arrays["O_logodds"].shape, dtype=np.uint8)}  # a state that wrote them
    for a in (arrays, old):
        m2 = LayeredMap(MapConfig())
        m2.load_state_arrays(a)
        assert int(m2.O.channel("hit").sum()) == 0
        r = miss_tick(m2)
        assert r.held == 1


def test_state_files_with_and_without_hit_marks_load(tmp_path):
    """A state file holds no hit marks (they belong to a tick in progress); one written while it
    did (O_hit among its arrays) passes the state checks and loads as well."""
    from ltmap_cli.io.state import read_state, write_state
    from ltmap_cli.outputs.snapshots import check_state

    m = LayeredMap(MapConfig())
    hit_tick(m, frames=3)
    arrays = {k: np.array(v) for k, v in m.state_arrays().items()}
    with_marks = {**arrays, "O_hit": np.ones(arrays["O_logodds"].shape, dtype=np.uint8)}
    for name, a in (("now.npz", arrays), ("with_marks.npz", with_marks)):
        write_state(tmp_path / name, a, {"log_time_s": 1.0})
        read, _ = read_state(tmp_path / name)
        m2 = LayeredMap(MapConfig(resolution=check_state(read, tmp_path / name)))
        m2.load_state_arrays(read)
        assert np.array_equal(m2.O.channel("logodds"), m.O.channel("logodds"))
        assert int(m2.O.channel("hit").sum()) == 0
