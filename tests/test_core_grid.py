"""Sparse voxel storage: keys, blocks, growth, memory that follows the space observed."""

import numpy as np

from ltmap_cli.core.grid import VoxelGrid, coord_to_pos, pos_to_coord


def test_world_key_conversion_at_any_resolution_and_sign():
    pts = np.array([[0.0, 0.049, -0.001], [-0.05, -0.051, 1.0]])
    assert pos_to_coord(pts, 0.05).tolist() == [[0, 0, -1], [-1, -2, 20]]
    assert pos_to_coord(pts, 0.1).tolist() == [[0, 0, -1], [-1, -1, 10]]
    assert np.allclose(coord_to_pos(np.array([[-1, 0, 2]]), 0.05), [[-0.025, 0.025, 0.125]])
    keys = np.array([[-7, 3, 1000], [123456, -98765, -3]])
    assert (pos_to_coord(coord_to_pos(keys, 0.05), 0.05) == keys).all()


def test_set_get_across_growth_and_rehash():
    g = VoxelGrid(0.05, {"v": (np.float32, -1.0)}, initial_blocks=16)
    rng = np.random.default_rng(3)
    keys = np.unique(rng.integers(-5000, 5000, size=(20000, 3)), axis=0)
    vals = rng.random(len(keys)).astype(np.float32)
    g.set("v", keys, vals)
    assert g.n_blocks > 16
    assert np.array_equal(g.get("v", keys), vals)
    assert g.get("v", np.array([[99999, 0, 0]]))[0] == -1.0  # never allocated: fill value


def test_memory_grows_with_space_observed_not_bounding_box():
    g = VoxelGrid(0.05, {"v": (np.float32, 0.0)})
    far = np.array([[0, 0, 0], [20000, 20000, 0]])  # 1 km apart at 0.05 m
    g.set("v", far, 1.0)
    assert g.n_blocks == 2
    assert g.nbytes() < 2_000_000
