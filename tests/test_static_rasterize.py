"""The plan rasterizer: cell-centre rule (closed), supercover of segments, thin parts."""

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon, box

from ltmap_cli.static.rasterize import Lattice, polygon_mask, segments_mask, thin_parts


def test_lattice_covers_on_multiples_of_r():
    lat = Lattice.covering((-0.12, 0.31, 1.0, 1.06), 0.05)
    assert (lat.x0, lat.y0) == (-0.15, 0.30)
    assert lat.shape == (16, 23)  # y 0.30..1.10, x -0.15..1.00


def test_box_centre_rule_hand_computed():
    lat = Lattice(0.0, 0.0, 0.1, 10, 10)
    # centres at 0.05, 0.15, ...: x in [0.12, 0.58] holds 0.15..0.55 -> cols 1..5; y in [0.31, 0.49] -> rows 3, 4
    m = polygon_mask(box(0.12, 0.31, 0.58, 0.49), lat)
    expect = np.zeros((10, 10), bool)
    expect[3:5, 1:6] = True
    assert (m == expect).all()


def test_centre_on_the_boundary_counts_as_inside():
    lat = Lattice(0.0, 0.0, 0.1, 10, 10)
    # edges exactly on centres 0.15 and 0.35 (x) and 0.25, 0.45 (y): closed -> cols 1..3, rows 2..4
    m = polygon_mask(box(0.15, 0.25, 0.35, 0.45), lat)
    expect = np.zeros((10, 10), bool)
    expect[2:5, 1:4] = True
    assert (m == expect).all()


def test_polygon_with_hole_and_multipolygon_match_shapely():
    rng = np.random.default_rng(1)
    lat = Lattice.covering((-1, -1, 11, 11), 0.05)
    xs, ys = lat.centres()
    X, Y = np.meshgrid(xs, ys)
    for _ in range(5):
        g = shapely.union_all([Point(rng.uniform(0, 10, 2)).buffer(rng.uniform(0.3, 2.5)) for _ in range(6)])
        g = g.difference(Point(5, 5).buffer(1.1))
        m = polygon_mask(g, lat)
        ref = shapely.contains_xy(g, X, Y)
        near = shapely.distance(g.boundary, shapely.points(X, Y)) < 1e-6
        assert (m == ref)[~near].all()


def test_segments_supercover_axis_and_diagonal():
    lat = Lattice(0.0, 0.0, 1.0, 6, 6)
    m = segments_mask(np.array([[0.5, 0.5, 4.5, 0.5]]), lat)
    assert m[0, 0:5].all() and m.sum() == 5
    # a diagonal through lattice corners (1,1), (2,2): 4-connected, so the corner neighbours are marked
    m = segments_mask(np.array([[0.5, 0.5, 2.5, 2.5]]), lat)
    for i in range(3):
        assert m[i, i]
    assert m[0, 1] and m[1, 0] and m[1, 2] and m[2, 1]
    # a shallow segment: every cell it passes through, nothing else
    m = segments_mask(np.array([[0.2, 0.2, 3.8, 1.6]]), lat)
    xs = np.linspace(0.2, 3.8, 10001)
    ys = 0.2 + (xs - 0.2) * (1.4 / 3.6)
    expect = np.zeros((6, 6), bool)
    expect[np.floor(ys).astype(int), np.floor(xs).astype(int)] = True
    assert (m == expect).all()


def test_thin_parts_only_where_thinner_than_a_cell_diagonal():
    r = 0.05
    thick = box(0, 0, 2, 0.2)
    assert thin_parts(thick, r) is None
    thin = box(0, 0.5, 2, 0.52)
    parts = thin_parts(shapely.union_all([thick, thin]), r)
    assert parts is not None and abs(parts.area - thin.area) < 1e-9


def test_large_lattice_is_fast_enough():
    import time

    lat = Lattice.covering((0, 0, 100, 100), 0.05)  # 4e6 cells
    walls = shapely.union_all([LineString([(x, 0), (x, 100)]).buffer(0.1, cap_style="flat") for x in range(0, 101, 5)]
                              + [Polygon([(0, 0), (100, 0), (100, 100)]).exterior.buffer(0.1)])
    t = time.perf_counter()
    m = polygon_mask(walls, lat)
    assert time.perf_counter() - t < 5.0
    assert m.any()
