"""Voxel PLY snapshots: written with numpy as open3d writes them, read back with open3d."""

from __future__ import annotations

import matplotlib
import numpy as np
import open3d as o3d
import pytest

from ltmap_cli.io.ply import viridis, write_voxels_ply

MPL_VIRIDIS = matplotlib.colormaps["viridis"]


def test_points_and_height_colours(tmp_path):
    # three voxels at 0.05 m, stacked: the z extent is [0, 0.15], so t = 1/6, 1/2, 5/6
    centers = np.array([[1.025, -2.475, 0.025], [1.025, -2.475, 0.075], [3.525, 0.025, 0.125]])
    path = tmp_path / "snap.ply"
    write_voxels_ply(path, centers, None, 0.05)
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian")
    cloud = o3d.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(np.asarray(cloud.points), centers)
    colors = np.asarray(cloud.colors)
    assert colors.shape == (3, 3) and colors.min() >= 0.0 and colors.max() <= 1.0
    expected = np.array([MPL_VIRIDIS(t)[:3] for t in (1 / 6, 1 / 2, 5 / 6)])
    np.testing.assert_allclose(colors, expected, atol=2 / 255)
    assert [p.name for p in tmp_path.iterdir()] == ["snap.ply"]  # no temporary file left


def test_colour_by_value(tmp_path):
    centers = np.zeros((3, 3)) + [[0, 0, 0], [1, 0, 0], [2, 0, 0]]
    write_voxels_ply(tmp_path / "v.ply", centers, np.array([3.5, 0.0, 1.75]), 0.1, color_by="value")
    colors = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "v.ply")).colors)
    expected = np.array([MPL_VIRIDIS(t)[:3] for t in (1.0, 0.0, 0.5)])
    np.testing.assert_allclose(colors, expected, atol=1 / 255)


def test_viridis_matches_matplotlib():
    t = np.arange(256) / 255.0  # the centres of matplotlib's 256 table entries
    np.testing.assert_allclose(viridis(t), MPL_VIRIDIS(t)[:, :3], atol=1 / 255)
    # outside [0, 1] is clipped to the ends
    np.testing.assert_allclose(viridis(np.array([-1.0, 2.0])), MPL_VIRIDIS(np.array([0.0, 1.0]))[:, :3])


def test_single_layer_is_mid_scale(tmp_path):
    centers = np.array([[0.05, 0.05, 0.45], [0.15, 0.05, 0.45]])
    write_voxels_ply(tmp_path / "flat.ply", centers, None, 0.1)
    colors = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "flat.ply")).colors)
    np.testing.assert_allclose(colors, [MPL_VIRIDIS(0.5)[:3]] * 2, atol=1 / 255)


def test_empty_writes_valid_empty_cloud(tmp_path):
    path = tmp_path / "empty.ply"
    write_voxels_ply(path, np.zeros((0, 3)), None, 0.05)
    assert b"element vertex 0\n" in path.read_bytes()
    cloud = o3d.io.read_point_cloud(str(path))
    assert len(cloud.points) == 0


def test_bad_input(tmp_path):
    with pytest.raises(ValueError, match=r"centers must be \(N, 3\)"):
        write_voxels_ply(tmp_path / "a.ply", np.zeros((4, 2)), None, 0.05)
    with pytest.raises(ValueError, match="color_by='value' needs values"):
        write_voxels_ply(tmp_path / "a.ply", np.zeros((1, 3)), None, 0.05, color_by="value")
    with pytest.raises(ValueError, match="color_by must be one of height, value"):
        write_voxels_ply(tmp_path / "a.ply", np.zeros((1, 3)), None, 0.05, color_by="rainbow")
    assert list(tmp_path.iterdir()) == []


def test_same_vertices_as_open3d_writes(tmp_path):
    # the file open3d's writer makes, but for the header's comment (colours rounded as it rounds
    # them: halves away from zero)
    from ltmap_cli.io.ply import voxel_colors

    rng = np.random.default_rng(3)
    centers = np.round(rng.normal(size=(500, 3)) * 40) * 0.05 + 0.025
    values = rng.random(500)
    values[:2] = [0.0, 1.0]
    for color_by in ("height", "value"):
        write_voxels_ply(tmp_path / "ours.ply", centers, values, 0.05, color_by=color_by)
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(centers))
        cloud.colors = o3d.utility.Vector3dVector(voxel_colors(centers, values, 0.05, color_by))
        assert o3d.io.write_point_cloud(str(tmp_path / "o3d.ply"), cloud, write_ascii=False, compressed=False)
        ours, theirs = (tmp_path / "ours.ply").read_bytes(), (tmp_path / "o3d.ply").read_bytes()
        assert ours.replace(b"comment Created by ltmap\n", b"comment Created by Open3D\n") == theirs
