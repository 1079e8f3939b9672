"""Memory a static map needs before it is allocated, so that a tiny file describing a huge map
(an SVG of 700 m x 700 m, a 14000 x 14000 PNG) is refused in one line instead of exhausting RAM.

The figures are peaks per cell of the code that builds S (measured with tracemalloc):
``BUILD_BYTES_PER_CELL`` for ``build-static`` (grid, heights, masks, scanlines), and
``LATTICE_BYTES_PER_CELL`` for ``replay --static``, which resamples S onto the voxel lattice
(``StaticGrid.from_height_map``: index grids and coordinates in 64-bit per cell of the lattice,
and of the source map when it is finer than the lattice).
"""

from __future__ import annotations

import math

BUILD_BYTES_PER_CELL = 16
LATTICE_BYTES_PER_CELL = 88  # measured peak (tracemalloc): 86 per lattice cell, 67 per lattice + source cell
DEFAULT_MAX_STATIC_MB = 2048.0  # replay.max_static_mb: S of ~ 250 m x 250 m at 0.05 m




def lattice_bytes(width: int, height: int, resolution: float, lattice_resolution: float) -> tuple[int, int]:
    """(lattice cells, bytes) of resampling a width x height map at ``resolution`` onto the
    voxel lattice at ``lattice_resolution`` (any rotation: the diagonal bounds the extent)."""
    diag = math.hypot(width, height) * resolution
    side = math.ceil(diag / lattice_resolution) + 1
    scale = resolution / lattice_resolution
    cells = min(side * side, math.ceil(width * scale + 1) * math.ceil(height * scale + 1) * 2)
    source = width * height if resolution < lattice_resolution else 0
    return cells, (cells + source) * LATTICE_BYTES_PER_CELL


__all__ = ["BUILD_BYTES_PER_CELL", "LATTICE_BYTES_PER_CELL", "DEFAULT_MAX_STATIC_MB", "lattice_bytes"]
