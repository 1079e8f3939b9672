"""OctoMap (the C++ library through pyoctomap) as the oracle of sensor integration."""

import math

import numpy as np
import pytest

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap

pyoctomap = pytest.importorskip("pyoctomap", reason="pyoctomap (OctoMap) is the oracle; pip install pyoctomap")


def room_points(rng, origin, n):
    """Rays from origin to the walls of a 6 x 5 x 2.5 m box, with a 0.6 m cube inside."""
    az = rng.uniform(-np.pi, np.pi, n)
    el = rng.uniform(-0.6, 0.6, n)
    d = np.stack([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)], axis=1)
    lo, hi = np.array([-3.0, -2.5, 0.0]), np.array([3.0, 2.5, 2.5])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - origin) / d, (hi - origin) / d
        t_wall = np.nanmin(np.where(np.maximum(t1, t2) > 0, np.maximum(t1, t2), np.inf), axis=1)
        clo, chi = np.array([1.0, 0.5, 0.0]), np.array([1.6, 1.1, 0.6])
        a, b = (clo - origin) / d, (chi - origin) / d
        tn = np.nanmax(np.minimum(a, b), axis=1)
        tf = np.nanmin(np.maximum(a, b), axis=1)
    t_cube = np.where((tn <= tf) & (tn > 0), tn, np.inf)
    t = np.minimum(t_wall, t_cube) * 0.9995
    return origin + d * t[:, None]


def octomap_sets(tree, res):
    occ, free = set(), set()
    for it in tree.begin_leafs():
        c = np.asarray(it.getCoordinate(), dtype=float)
        size = it.getSize()
        n = max(1, int(round(size / res)))
        base = np.floor((c - size / 2) / res + 0.5).astype(int)
        target = occ if tree.isNodeOccupied(it) else free
        for dx in range(n):
            for dy in range(n):
                for dz in range(n):
                    target.add((base[0] + dx, base[1] + dy, base[2] + dz))
    return occ, free


@pytest.mark.parametrize("res,max_range", [(0.1, -1.0), (0.05, -1.0), (0.05, 2.0)])
def test_same_occupied_and_free_voxels_as_octomap(res, max_range):
    rng = np.random.default_rng(7)
    cfg = MapConfig(resolution=res)
    cfg.sensor.ground_tolerance = -1.0
    m = LayeredMap(cfg)
    tree = pyoctomap.OcTree(res)
    tree.setClampingThresMin(1 / (1 + math.exp(2.0)))
    tree.setClampingThresMax(1 / (1 + math.exp(-3.5)))
    for _ in range(4):
        origin = np.array([0.0, 0.0, 1.0]) + rng.normal(0, 0.4, 3) * [1, 1, 0.2]
        pts = room_points(rng, origin, 4000)
        m.integrate(origin, pts, max_range=max(max_range, 0.0))
        tree.insertPointCloud(pts, origin, max_range)
    ours_occ = {tuple(k) for k in m.occupied_keys("O").tolist()}
    keys = m.O.voxels_where(m.O.channel("stamp") > 0)
    lo = m.O.get("logodds", keys)
    ours_free = {tuple(k) for k in keys[lo < 0].tolist()}
    occ, free = octomap_sets(tree, res)
    assert len(occ) > 500
    iou_occ = len(ours_occ & occ) / len(ours_occ | occ)
    iou_free = len(ours_free & free) / len(ours_free | free)
    assert iou_occ >= 0.99, (iou_occ, len(ours_occ), len(occ))
    assert iou_free >= 0.99, iou_free
