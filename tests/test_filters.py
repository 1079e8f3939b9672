"""The depth outlier filter: flying pixels at depth jumps go, surfaces stay."""

import numpy as np

from ltmap_cli.filters import depth_jump_mask, flying_pixel_mask

F, CX, CY = 100.0, 39.5, 29.5  # an 80 x 60 camera


def scene():
    """A wall at 3 m with a box face at 2 m in the middle; two mixed pixels on the box's edge."""
    d = np.full((60, 80), 3.0, dtype=np.float32)
    d[20:40, 30:50] = 2.0
    d[25, 30] = 2.5  # left edge of the box: halfway between box and wall
    d[33, 49] = 2.7  # right edge
    d[0, 0] = np.nan
    return d


def test_jump_mask_marks_both_sides_of_each_edge():
    m = depth_jump_mask(scene(), 0.1)
    assert m[30, 29] and m[30, 30] and m[19, 40] and m[20, 40]
    assert not m[10, 10] and not m[30, 40] and not m[0, 0]


def test_flying_pixels_go_and_the_surfaces_stay():
    d = scene()
    drop = flying_pixel_mask(d, F, F, CX, CY, radius=0.06, min_neighbors=3)
    assert drop[25, 30] and drop[33, 49]
    assert drop.sum() == 2  # nothing of the wall or the box face, edges included


def test_no_edges_no_work():
    d = np.full((60, 80), 3.0, dtype=np.float32)
    assert not flying_pixel_mask(d, F, F, CX, CY).any()
