"""Occupied voxels as a coloured point cloud (binary PLY), for MeshLab, CloudCompare or Open3D.

Each voxel is one point at its centre, coloured with viridis (perceptually uniform, readable in
grey and by colour-blind people), computed here with numpy from every 5th entry of matplotlib's 256-entry table
(linear interpolation between them is within 1/255 of every entry of the full table).

The file is what open3d's ``o3d.io.write_point_cloud`` writes (binary little endian: double x,
y, z and uchar red, green, blue, each colour ``round(clip(c, 0, 1) * 255)`` with halves away from
zero), written here with numpy: importing open3d took about a second of every replay's end. No
voxels (the first snapshot of a run) writes a valid PLY with 0 vertices, which open3d reads back
as an empty cloud (open3d itself refuses to write one).
"""

from __future__ import annotations

import math
import os

import numpy as np

from ltmap_cli.io.atomic import write_bytes_atomic

# matplotlib's viridis table (256 entries), every 5th entry: t = 0, 5/255, ..., 1
_VIRIDIS = np.array(
    [
        (0.267004, 0.004874, 0.329415),
        (0.273809, 0.031497, 0.358853),
        (0.278791, 0.062145, 0.386592),
        (0.281924, 0.089666, 0.412415),
        (0.283197, 0.115680, 0.436115),
        (0.282623, 0.140926, 0.457517),
        (0.280255, 0.165693, 0.476498),
        (0.276194, 0.190074, 0.493001),
        (0.270595, 0.214069, 0.507052),
        (0.263663, 0.237631, 0.518762),
        (0.255645, 0.260703, 0.528312),
        (0.246811, 0.283237, 0.535941),
        (0.237441, 0.305202, 0.541921),
        (0.227802, 0.326594, 0.546532),
        (0.218130, 0.347432, 0.550038),
        (0.208623, 0.367752, 0.552675),
        (0.199430, 0.387607, 0.554642),
        (0.190631, 0.407061, 0.556089),
        (0.182256, 0.426184, 0.557120),
        (0.174274, 0.445044, 0.557792),
        (0.166617, 0.463708, 0.558119),
        (0.159194, 0.482237, 0.558073),
        (0.151918, 0.500685, 0.557587),
        (0.144759, 0.519093, 0.556572),
        (0.137770, 0.537492, 0.554906),
        (0.131172, 0.555899, 0.552459),
        (0.125394, 0.574318, 0.549086),
        (0.121148, 0.592739, 0.544641),
        (0.119423, 0.611141, 0.538982),
        (0.121380, 0.629492, 0.531973),
        (0.128087, 0.647749, 0.523491),
        (0.140210, 0.665859, 0.513427),
        (0.157851, 0.683765, 0.501686),
        (0.180653, 0.701402, 0.488189),
        (0.208030, 0.718701, 0.472873),
        (0.239374, 0.735588, 0.455688),
        (0.274149, 0.751988, 0.436601),
        (0.311925, 0.767822, 0.415586),
        (0.352360, 0.783011, 0.392636),
        (0.395174, 0.797475, 0.367757),
        (0.440137, 0.811138, 0.340967),
        (0.487026, 0.823929, 0.312321),
        (0.535621, 0.835785, 0.281908),
        (0.585678, 0.846661, 0.249897),
        (0.636902, 0.856542, 0.216620),
        (0.688944, 0.865448, 0.182725),
        (0.741388, 0.873449, 0.149561),
        (0.793760, 0.880678, 0.120005),
        (0.845561, 0.887322, 0.099702),
        (0.896320, 0.893616, 0.096335),
        (0.945636, 0.899815, 0.112838),
        (0.993248, 0.906157, 0.143936),
    ]
)

COLOR_BY = ("height", "value")

_HEADER = (
    "ply\nformat binary_little_endian 1.0\ncomment Created by ltmap\nelement vertex {n}\n"
    "property double x\nproperty double y\nproperty double z\n"
    "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
)
_VERTEX = np.dtype([("xyz", "<f8", 3), ("rgb", "u1", 3)])  # packed: 27 bytes a vertex


def viridis(t: np.ndarray) -> np.ndarray:
    """RGB in [0, 1], shape (N, 3), for ``t`` in [0, 1] (clipped; NaN -> 0)."""
    t = np.nan_to_num(np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0), nan=0.0)
    x = t * (len(_VIRIDIS) - 1)
    i = np.minimum(np.floor(x).astype(np.int64), len(_VIRIDIS) - 2)
    f = (x - i)[:, None]
    return _VIRIDIS[i] * (1.0 - f) + _VIRIDIS[i + 1] * f


def voxel_colors(
    centers: np.ndarray, values: np.ndarray | None, resolution: float, color_by: str = "height"
) -> np.ndarray:
    """Colours (N, 3) in [0, 1]. ``height``: viridis over the voxels' z extent, from the bottom
    of the lowest voxel to the top of the highest (one layer of voxels is mid-scale).
    ``value``: viridis over [min, max] of ``values`` (all equal: mid-scale)."""
    if color_by == "height":
        z = centers[:, 2]
        low = z.min() - resolution / 2.0
        span = z.max() - z.min() + resolution
        return viridis((z - low) / span)
    if values is None:
        raise ValueError("write_voxels_ply: color_by='value' needs values")
    lo, hi = float(values.min()), float(values.max())
    t = np.full(len(values), 0.5) if hi <= lo else (values - lo) / (hi - lo)
    return viridis(t)


def write_voxels_ply(
    path: str | os.PathLike,
    centers: np.ndarray,
    values: np.ndarray | None,
    resolution: float,
    color_by: str = "height",
) -> None:
    """Write voxel ``centers`` (N, 3) as a binary PLY point cloud coloured by ``color_by``
    (``height`` or ``value``), atomically. ``values`` (N,) is only used for ``color_by='value'``.
    No voxels writes a valid empty PLY. Raises ValueError for bad arrays or options, OSError if
    the file cannot be written."""
    centers = np.asarray(centers, dtype=np.float64)
    if centers.ndim != 2 or centers.shape[1] != 3:
        raise ValueError(f"write_voxels_ply: centers must be (N, 3), got {centers.shape}")
    if color_by not in COLOR_BY:
        raise ValueError(f"write_voxels_ply: color_by must be one of {', '.join(COLOR_BY)}, got {color_by!r}")
    resolution = float(resolution)
    if not (math.isfinite(resolution) and resolution > 0.0):
        raise ValueError(f"write_voxels_ply: resolution must be > 0, got {resolution}")
    if values is not None:
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (centers.shape[0],):
            raise ValueError(f"write_voxels_ply: values must have shape ({centers.shape[0]},), got {values.shape}")
    if not np.all(np.isfinite(centers)):
        raise ValueError("write_voxels_ply: centers must be finite")

    vertices = np.empty(centers.shape[0], dtype=_VERTEX)
    vertices["xyz"] = centers
    if centers.shape[0]:
        vertices["rgb"] = _to_uint8(voxel_colors(centers, values, resolution, color_by))
    write_bytes_atomic(path, _HEADER.format(n=len(vertices)).encode("ascii") + vertices.tobytes())


def _to_uint8(colors: np.ndarray) -> np.ndarray:
    """Colours in [0, 1] as open3d writes them: ``std::round(clip(c, 0, 1) * 255)``."""
    v = np.clip(colors, 0.0, 1.0) * 255.0
    r = np.floor(v)
    return (r + (v - r >= 0.5)).astype(np.uint8)
