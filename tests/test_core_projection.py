"""Projection P over the z band, and the virtual scan (SPEC 2.3)."""

import numpy as np
import pytest

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.grid import band_k_range
from ltmap_cli.core.layers import LayeredMap, StaticGrid
from ltmap_cli.core.projection import project, virtual_scan

R = 0.05


def test_band_includes_voxels_overlapping_it_with_positive_length():
    assert band_k_range(0.05, 1.5, 0.05) == (1, 29)
    assert band_k_range(0.04, 1.51, 0.05) == (0, 30)
    assert band_k_range(0.05, 1.5, 0.1) == (0, 14)


def test_projection_takes_lt_in_the_band_only_and_reads_thresholds():
    m = LayeredMap(MapConfig())
    m.seed_long_term(np.array([[0, 0, 0], [1, 0, 1], [2, 0, 29], [3, 0, 30], [4, 0, 5], [5, 0, 5]]),
                     [1.0, 1.0, 1.0, 1.0, 0.64, 0.65])  # fmt: skip
    p = project(m)
    row = p.data[0 - p.j0]
    got = {i: int(row[i - p.i0]) for i in range(6)}
    # k=0 (floor clearance) and k=30 (above 1.5 m) do not count; 0.64 < 0.65 is not occupied
    assert got == {0: -1, 1: 100, 2: 100, 3: -1, 4: -1, 5: 100}
    assert p.value[0 - p.j0, 4 - p.i0] == pytest.approx(0.64)


def test_free_comes_from_o_seen_free_in_band_and_from_static_free():
    m = LayeredMap(MapConfig())
    m.integrate([0.025, 0.025, 0.525], [[1.025, 0.025, 0.525]])  # free x-voxels 0..19 at k=10
    m.integrate([0.025, 1.025, 0.025], [[1.025, 1.025, 0.025]])  # free at k=0: below the band
    p = project(m)
    r0 = 0 - p.j0
    r20 = 20 - p.j0
    assert (p.data[r0, 0 - p.i0 : 20 - p.i0] == 0).all()
    assert p.data[r20, 5 - p.i0] == -1
    occ = np.array([[0, 100], [-1, 0]], dtype=np.int8)
    s = StaticGrid.from_height_map(occ, np.where(occ == 100, 2.5, 0.0), R, (-1.0, -1.0, 0.0), R)
    m2 = LayeredMap(MapConfig(), static=s)
    p2 = project(m2)
    assert p2.data.tolist() == [[0, 100], [-1, 0]]
    assert p2.origin == pytest.approx((-1.0, -1.0, 0.0))


def test_virtual_scan_sees_projection_and_current_obstacles_in_o():
    m = LayeredMap(MapConfig())
    # P: a long-term wall cell at x 2.00..2.05 (i = 40), y 0 .. 0.05, k = 10
    m.seed_long_term(np.array([[40, 0, 10]]), 1.0)
    p = project(m)
    angles = np.array([0.0, np.pi / 2])
    ranges = virtual_scan(m, p, (0.025, 0.025, 0.0), angles, 0.05, 5.0)
    assert ranges[0] == pytest.approx(2.0 - 0.025, abs=1e-6)
    assert np.isinf(ranges[1])
    # a table top at 0.75 m, 1 m ahead, occupied in O now (not yet in LT)
    m.integrate([0.025, 0.025, 1.2], [[1.025, 0.025, 0.775]])
    ranges = virtual_scan(m, p, (0.025, 0.025, 0.0), angles, 0.05, 5.0)
    assert ranges[0] == pytest.approx(1.0 - 0.025, abs=1e-6)
    assert virtual_scan(m, p, (0.025, 0.025, 0.0), angles, 0.05, 5.0, include_o=False)[0] == pytest.approx(1.975)


def test_virtual_scan_forgets_o_obstacles_not_updated_since_the_window():
    """An obstacle a person left in O where no sensor looks again is not a current obstacle: with
    ``o_since_frame`` after the frame that marked it, the scan sees through it to the wall."""
    m = LayeredMap(MapConfig())
    m.seed_long_term(np.array([[40, 0, 10]]), 1.0)  # the wall at 2 m, in LT
    p = project(m)
    m.integrate([0.025, 0.025, 1.2], [[1.025, 0.025, 0.775]])  # frame 1 marks a voxel 1 m ahead
    marked = m.frame_id
    m.integrate([0.025, 0.025, 1.2], [[0.025, 3.025, 0.775]])  # frame 2 looks elsewhere (+y)
    angles = np.array([0.0])
    pose = (0.025, 0.025, 0.0)
    assert virtual_scan(m, p, pose, angles, 0.05, 5.0, o_since_frame=marked)[0] == pytest.approx(0.975, abs=1e-6)
    assert virtual_scan(m, p, pose, angles, 0.05, 5.0, o_since_frame=marked + 1)[0] == pytest.approx(1.975, abs=1e-6)
    # seen again (frame 3): current again
    m.integrate([0.025, 0.025, 1.2], [[1.025, 0.025, 0.775]])
    assert virtual_scan(m, p, pose, angles, 0.05, 5.0, o_since_frame=marked + 1)[0] == pytest.approx(0.975, abs=1e-6)
