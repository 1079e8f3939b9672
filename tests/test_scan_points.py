"""LaserScan ranges to end points (core.sensors.scan_to_points), expectations computed by hand.

Beam i is at angle angle_min + i * angle_increment in the laser frame (REP 117); a return at range
r and angle a ends at (r cos a, r sin a, 0). +inf and ranges above range_max are no-return beams
(cleared to range_max, marking nothing) or dropped; NaN, -inf and ranges below range_min are
always dropped.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ltmap_cli.core.sensors import scan_to_points

S2 = math.sqrt(2.0) / 2.0  # cos 45 deg = sin 45 deg
HALF_PI = math.pi / 2.0


def _close(actual, expected):
    np.testing.assert_allclose(np.asarray(actual), np.asarray(expected, dtype=np.float64), rtol=0, atol=1e-12)


def test_returns_on_the_axes_and_diagonals():
    # angle_min -90 deg, step 45 deg: -90, -45, 0, 45, 90 deg
    ranges = [1.0, 2.0, 3.0, 2.0, 0.5]
    pts, ret = scan_to_points(ranges, -HALF_PI, math.pi / 4.0, 0.1, 10.0)
    _close(pts, [[0.0, -1.0, 0.0],          # 1 m straight right (-y)
                 [2 * S2, -2 * S2, 0.0],    # 2 m at -45 deg: (1.41421, -1.41421)
                 [3.0, 0.0, 0.0],           # 3 m straight ahead
                 [2 * S2, 2 * S2, 0.0],     # 2 m at +45 deg
                 [0.0, 0.5, 0.0]])  # fmt: skip
    assert pts.shape == (5, 3) and pts.dtype == np.float64
    assert ret.dtype == bool and ret.tolist() == [True] * 5
    assert (pts[:, 2] == 0.0).all()


def test_arbitrary_angle():
    # one beam, 30 deg: (r cos 30, r sin 30) = (4 * 0.8660254, 4 * 0.5)
    pts, ret = scan_to_points(np.array([4.0]), math.radians(30.0), 0.01, 0.0, 30.0)
    _close(pts, [[4.0 * math.sqrt(3.0) / 2.0, 2.0, 0.0]])
    assert ret.tolist() == [True]


def test_behind_the_sensor():
    # angles 180 and 270 deg (angle_min pi, step pi/2): (-2, 0) and (0, -1.5)
    pts, ret = scan_to_points([2.0, 1.5], math.pi, HALF_PI, 0.1, 5.0)
    _close(pts, [[-2.0, 0.0, 0.0], [0.0, -1.5, 0.0]])
    assert ret.tolist() == [True, True]


def test_no_return_beams_clear_to_range_max_and_mark_nothing():
    # range_max 5: +inf at 0 deg and 7.5 (> range_max) at 90 deg both become 5 m no-return rays
    pts, ret = scan_to_points([np.inf, 7.5, 4.0], 0.0, HALF_PI, 0.1, 5.0, clear_no_return=True)
    _close(pts, [[5.0, 0.0, 0.0], [0.0, 5.0, 0.0], [-4.0, 0.0, 0.0]])
    assert ret.tolist() == [False, False, True]


def test_no_return_beams_dropped_when_clearing_is_off():
    pts, ret = scan_to_points([np.inf, 7.5, 4.0], 0.0, HALF_PI, 0.1, 5.0, clear_no_return=False)
    # only the 4 m return at 180 deg is left, at its own angle
    _close(pts, [[-4.0, 0.0, 0.0]])
    assert ret.tolist() == [True]


@pytest.mark.parametrize("clear", [True, False])
def test_nan_minus_inf_and_short_ranges_dropped(clear):
    # range_min 0.2: 0.1 and 0.0 are too short; NaN and -inf are invalid
    pts, ret = scan_to_points([np.nan, 0.1, 0.0, -np.inf], 0.0, 0.1, 0.2, 5.0, clear_no_return=clear)
    assert pts.shape == (0, 3) and ret.shape == (0,)


def test_range_limits_are_inclusive():
    # exactly range_min and exactly range_max are returns (REP 117: valid is [min, max])
    pts, ret = scan_to_points([0.2, 5.0], 0.0, HALF_PI, 0.2, 5.0)
    _close(pts, [[0.2, 0.0, 0.0], [0.0, 5.0, 0.0]])
    assert ret.tolist() == [True, True]


def test_dropped_beams_do_not_shift_the_angles_of_the_others():
    # angle_min 0, step 90 deg; beam 0 NaN (dropped), 1 below range_min (dropped), 2 at 180 deg,
    # 3 +inf at 270 deg (no return, 6 m), 4 at 360 deg
    ranges = np.array([np.nan, 0.05, 2.0, np.inf, 1.0], dtype=np.float32)
    pts, ret = scan_to_points(ranges, 0.0, HALF_PI, 0.1, 6.0)
    _close(pts, [[-2.0, 0.0, 0.0], [0.0, -6.0, 0.0], [1.0, 0.0, 0.0]])
    assert ret.tolist() == [True, False, True]


def test_empty_scan():
    pts, ret = scan_to_points(np.zeros(0), 0.0, 0.1, 0.1, 5.0)
    assert pts.shape == (0, 3) and ret.shape == (0,)


def test_no_return_ray_clears_but_marks_nothing_in_the_map():
    # sensor at the centre of voxel (0, 0, 10) at 0.05 m; a no-return beam straight ahead with
    # range_max 1 m, against a return at 1 m: the same ray, but only the return is a hit
    from ltmap_cli.core.config import MapConfig
    from ltmap_cli.core.layers import LayeredMap

    origin = np.array([0.025, 0.025, 0.525])
    for ranges, hits in (([np.inf], 0), ([1.0], 1)):
        pts, ret = scan_to_points(ranges, 0.0, 0.1, 0.1, 1.0)
        m = LayeredMap(MapConfig())
        res = m.integrate(origin, pts + origin, ret, max_range=2.0)
        assert res.hits == hits
        # voxels x = 0..19 lie between the sensor and the 1 m end point (voxel x = 20)
        assert res.misses == 20
        occupied = m.occupied_keys("O").tolist()
        assert occupied == ([] if hits == 0 else [[20, 0, 10]])
