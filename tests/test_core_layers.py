"""Tick rules of ST and LT (SPEC 2.2), with the spec's defaults.

tick 0.2 s, st_rise_s 15 s (75 ticks), st_fall_s 1 s (5 ticks), lt_fall_s 3 s (15 ticks),
st_forget_s 60 s (300 ticks); occupied threshold 0.65.
"""

import numpy as np
import pytest

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap, StaticGrid

R = 0.05
ORIGIN = [0.025, 0.025, 0.525]  # centre of voxel (0, 0, 10)
TARGET = (20, 0, 10)  # 1 m ahead of the sensor
BEYOND = [(40 + 0.5) * R, 0.025, 0.525]  # a ray through TARGET to 2 m


def target_point():
    return [(TARGET[0] + 0.5) * R, (TARGET[1] + 0.5) * R, (TARGET[2] + 0.5) * R]


def val(m, layer, key=TARGET):
    return float(m.values(layer, np.array([key]))[0])


def see_obstacle(m):
    m.integrate(ORIGIN, [target_point()])
    return m.end_tick()


def see_free(m, frames=10):
    """One tick in which the target is seen through (several frames, so O turns free)."""
    for _ in range(frames):
        m.integrate(ORIGIN, [BEYOND])
    return m.end_tick()


def test_continuous_sight_enters_lt_after_st_rise_s():
    m = LayeredMap(MapConfig())
    ticks = 0
    while val(m, "LT") < 1.0:
        see_obstacle(m)
        ticks += 1
        assert ticks < 200
    # 15 s / 0.2 s = 75 ticks, within one tick
    assert abs(ticks * 0.2 - 15.0) <= 0.2 + 1e-9
    assert val(m, "ST") == 1.0


def test_a_four_second_sighting_never_reaches_lt():
    m = LayeredMap(MapConfig())
    for _ in range(20):  # 4 s
        see_obstacle(m)
    assert val(m, "ST") == pytest.approx(20 / 75, abs=1e-5)
    for _ in range(400):  # 80 s unobserved: ST forgotten after 60 s, never LT
        m.end_tick()
    assert val(m, "LT") == 0.0
    assert val(m, "ST") == 0.0


def test_st_forgets_after_st_forget_s_without_sight():
    m = LayeredMap(MapConfig())
    for _ in range(10):
        see_obstacle(m)
    last_seen = m.tick_index - 1
    while val(m, "ST") > 0:
        m.end_tick()
    # forgotten at the first tick that is st_forget_s (300 ticks) after the last sighting
    assert m.tick_index - 1 - last_seen == 300


def test_seeded_lt_seen_free_falls_to_zero_within_lt_fall_s_plus_one_tick():
    m = LayeredMap(MapConfig())
    m.seed_long_term(np.array([TARGET]), 1.0)  # e.g. --resume: LT = 1, ST = 0
    ticks = 0
    while val(m, "LT") > 0:
        see_free(m)
        ticks += 1
        assert ticks < 100
    assert ticks * 0.2 <= 3.0 + 0.2 + 1e-9
    assert ticks == 15


def test_removed_object_leaves_projection_within_lt_fall_s_plus_two_ticks():
    m = LayeredMap(MapConfig())
    while val(m, "LT") < 1.0:
        see_obstacle(m)
    for _ in range(25):  # it stays a while
        see_obstacle(m)
    # removed: seen free from now on. ST falls 1 -> 0 in 5 ticks, then LT 1 -> < 0.65 in 6
    ticks = 0
    while val(m, "LT") >= 0.65:
        see_free(m)
        ticks += 1
    assert ticks == 10
    assert ticks * 0.2 <= 3.0 + 0.4
    while val(m, "LT") > 0:
        see_free(m)
        ticks += 1
    assert ticks == 4 + 15  # LT starts falling in the tick ST reaches 0 (the 5th)


def test_unobserved_lt_keeps_its_value_for_an_hour():
    m = LayeredMap(MapConfig())
    m.seed_long_term(np.array([TARGET]), 0.8)
    for _ in range(18000):  # one hour of 0.2 s ticks, looking elsewhere
        m.end_tick()
    assert val(m, "LT") == pytest.approx(0.8)


def test_a_person_passing_by_never_enters_lt():
    m = LayeredMap(MapConfig())
    for _ in range(3):
        for _ in range(15):  # 3 s in view
            see_obstacle(m)
        for _ in range(10):  # walks away: seen free for 2 s
            see_free(m)
        assert val(m, "ST") == 0.0
    assert val(m, "LT") == 0.0


def test_static_walls_never_enter_st_but_an_obstacle_beside_them_does():
    # a static wall along x = 1.0 .. 1.05 (column i = 20), 2.5 m high
    occ = np.zeros((40, 80), dtype=np.int8)
    height = np.zeros((40, 80), dtype=np.float32)
    occ[:, 20] = 100
    height[:, 20] = 2.5
    static = StaticGrid.from_height_map(occ, height, R, (0.0, -1.0, 0.0), R)
    m = LayeredMap(MapConfig(), static=static)
    wall_hit = [1.07, 0.025, 0.525]  # voxel i = 21: within the one-voxel margin of the wall
    box_hit = [0.6 + 0.025, 0.025, 0.525]  # voxel i = 12: 0.4 m in front of the wall
    for _ in range(100):
        m.integrate(ORIGIN, [wall_hit, box_hit])
        m.end_tick()
    assert val(m, "ST", (21, 0, 10)) == 0.0
    assert val(m, "LT", (21, 0, 10)) == 0.0
    assert val(m, "LT", (12, 0, 10)) == 1.0
    assert val(m, "S", (20, 0, 10)) == 1.0 and val(m, "F", (20, 0, 10)) == 1.0


def test_static_grid_resampling_keeps_thin_walls_and_heights():
    # a 0.03 m map with a one-cell wall resampled onto a 0.05 m lattice
    occ = np.zeros((100, 100), dtype=np.int8)
    occ[:, 50] = 100  # x in [1.50, 1.53)
    height = np.where(occ == 100, 2.5, 0).astype(np.float32)
    s = StaticGrid.from_height_map(occ, height, 0.03, (0.0, 0.0, 0.0), 0.05)
    cols = np.nonzero((s.occ == 100).any(axis=0))[0] + s.i0
    assert set(cols.tolist()) == {30}  # x 1.50 .. 1.55
    assert (s.occ[:, 30 - s.i0] == 100).all()
    assert s.top_k.max() == 49  # 2.5 m / 0.05 m - 1
    assert s.is_occupied(np.array([[30, 10, 0], [30, 10, 49], [30, 10, 50], [29, 10, 0]])).tolist() == [
        True,
        True,
        False,
        False,
    ]


def test_exact_state_round_trip_continues_identically():
    a = LayeredMap(MapConfig())
    for _ in range(30):
        see_obstacle(a)
    b = LayeredMap(MapConfig())
    b.load_state_arrays(a.state_arrays())
    for m in (a, b):
        for _ in range(50):
            see_obstacle(m)
        see_free(m)
    assert val(a, "LT") == val(b, "LT") == 1.0
    assert val(a, "ST") == val(b, "ST")
    assert np.array_equal(a.occupied_keys("O"), b.occupied_keys("O"))
    c = LayeredMap(MapConfig())
    c.load_state_arrays(a.state_arrays(), long_term_only=True)
    assert val(c, "LT") == 1.0 and val(c, "ST") == 0.0 and len(c.occupied_keys("O")) == 0


@pytest.mark.parametrize("every", [1, 2, 5])
def test_entry_and_removal_do_not_depend_on_the_sensor_rate(every):
    """A camera that observes every 2nd or 5th tick (2.5 Hz, 1 Hz) gives the same timing as one
    that observes every tick: the gap since the last observation counts (up to max_gap_s)."""
    m = LayeredMap(MapConfig())
    tick = 0
    while val(m, "LT") < 1.0:
        if tick % every == 0:
            see_obstacle(m)
        else:
            m.end_tick()
        tick += 1
        assert tick < 400
    # entered at tick 74 (75 ticks = st_rise_s) with any rate that divides it, else at the
    # first observation after
    assert 74 <= tick - 1 <= 74 + every - 1
    for _ in range(20):
        m.end_tick() if tick % every else see_obstacle(m)
        tick += 1
    gone = 0
    while val(m, "LT") >= 0.65:
        if tick % every == 0:
            see_free(m)
        else:
            m.end_tick()
        tick += 1
        gone += 1
        assert gone < 100
    assert gone * 0.2 <= 2.0 + every * 0.2 + 1e-9  # 10 ticks at every rate, up to one period more
