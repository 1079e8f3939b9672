"""Turn a plan (or an existing 2D map) into the static layer S and its 2D map.

The 2D map:

- *occupied*: wall cells (walls and windows; furniture too with ``--furniture static``), by the
  two rules of ``rasterize`` (cell centre inside a wall polygon; cells crossed by the spine of a
  wall thinner than ``sqrt(2)`` cells);
- *free*: every other cell inside the plan's outline. The outline is the union of walls, windows
  and doors, closed over gaps up to ``2 * OUTLINE_CLOSE_M`` wide (a doorway without a door shape,
  a gap between two wall lines that do not quite meet), with its holes filled: the building's
  footprint, courtyards included;
- *unknown*: outside the outline (the grid covers the SVG canvas and the drawing).

Door shapes carve their cells out of the walls (an architect's door symbol often covers the wall
line). The 3D layer gives each occupied cell its top z: ``wall_height`` for walls and windows,
a piece's ``data-height-m`` (else ``wall_height``) for static furniture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import PlanError
from ..errors import human as _human
from ..io.mapfile import DEFAULT_MAX_CELLS, GridMap, write_map
from ..io.static_layer import MAP_YAML, StaticLayer, layer_from_grid, trinary, write_static_layer
from .memory import BUILD_BYTES_PER_CELL as BYTES_PER_CELL
from .rasterize import Lattice, lines_to_segments, outline_lines, polygon_mask, segments_mask, thin_parts
from .svgplan import Plan, PlanShape

OUTLINE_CLOSE_M = 1.0
GRID_M = 1e-6  # precision of the geometry unions (m)


@dataclass
class BuildStats:
    """What the command reports."""

    wall_length_m: float  # half the perimeter of the wall outline (walls + windows, doors carved)
    wall_area_m2: float
    wall_cells: int  # walls and windows (not furniture)
    free_cells: int
    doors: int
    furniture: int
    furniture_mode: str
    ignored_shapes: int
    scale_source: str


def check_size(lat: Lattice, max_cells: int, source: str) -> None:
    cells = lat.height * lat.width
    if cells > max_cells:
        need = cells * BYTES_PER_CELL
        raise PlanError(
            f"{source}: the map would be {lat.width} x {lat.height} = {cells:.3g} cells "
            f"({lat.width * lat.r:.6g} x {lat.height * lat.r:.6g} m at {lat.r:g} m), needing about "
            f"{_human(need)} of memory, over --max-cells {max_cells:.3g}; check the plan's scale, use a "
            "coarser --resolution, or raise --max-cells")


def shapes_mask(shapes: list[PlanShape], lat: Lattice, thin_rule: bool = True):
    """(mask, region): the cells of a group of shapes (centre rule, and the thin rule unless
    ``thin_rule`` is False), and their union polygon."""
    import shapely

    regions = [s.region for s in shapes if s.region is not None and not s.region.is_empty]
    # snapped to 1 um: coincident edges (a window inside its wall band) merge without slivers
    region = shapely.union_all(regions, grid_size=GRID_M) if regions else None
    mask = polygon_mask(region, lat)
    if not thin_rule:
        return mask, region
    thin = math.sqrt(2.0) * lat.r
    spines = [st.line if not st.closed else np.vstack([st.line, st.line[:1]])
              for s in shapes for st in s.strokes if st.width < thin]
    fills = [s.fill for s in shapes if s.fill is not None and not s.fill.is_empty]
    if fills:
        spines.extend(outline_lines(thin_parts(shapely.union_all(fills), lat.r)))
    if spines:
        mask |= segments_mask(lines_to_segments(spines), lat)
    return mask, region


def write_static(folder, layer: StaticLayer) -> None:
    """What ``ltmap build-static`` writes into its (staging) folder: the map_server map
    (static.yaml, .pgm, .png) and the 3D static layer beside it."""
    write_map(folder / MAP_YAML, layer.grid, png=True)
    write_static_layer(folder, layer)


def build_from_plan(
    plan: Plan,
    resolution: float = 0.05,
    wall_height: float = 2.5,
    furniture: str = "none",
    max_cells: int = DEFAULT_MAX_CELLS,
) -> tuple[StaticLayer, BuildStats]:
    import shapely

    walls = plan.of("walls", "windows")
    doors = plan.of("doors")
    pieces = plan.of("furniture")
    bounds = [s.region.bounds for s in plan.shapes if s.region is not None and not s.region.is_empty]
    bounds += [(*st.line.min(axis=0), *st.line.max(axis=0)) for s in plan.shapes for st in s.strokes]
    if plan.canvas is not None:
        bounds.append(plan.canvas)
    b = np.array(bounds, dtype=np.float64)
    lat = Lattice.covering((b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()), resolution)
    check_size(lat, max_cells, plan.source)

    wall_mask, wall_region = shapes_mask(walls, lat)
    # doors carve the cells whose centre they cover (no thin rule: a door's outline drawn in thin
    # lines must not cut notches into the jambs it touches)
    door_mask, door_region = shapes_mask(doors, lat, thin_rule=False) if doors else (None, None)
    if door_mask is not None:
        wall_mask &= ~door_mask
    n_wall_cells = int(wall_mask.sum())
    if n_wall_cells == 0:
        raise PlanError(f"{plan.source}: the wall shapes cover no cell of the {resolution:g} m grid (are they "
                        "collapsed, e.g. by a scale(0) transform, or all inside doors?); check the drawing")

    height = np.where(wall_mask, np.float32(wall_height), np.float32(0)).astype(np.float32)
    seed = None
    if furniture in ("static", "long-term") and pieces:
        target = height if furniture == "static" else np.zeros(lat.shape, dtype=np.float32)
        for piece in pieces:
            m, _ = shapes_mask([piece], lat)
            h = np.float32(piece.height_m if piece.height_m is not None else wall_height)
            np.maximum(target, np.where(m, h, np.float32(0)), out=target)
        if furniture == "long-term":
            seed = target
    occupied = height > 0

    # free: inside the outline (walls, windows and doors closed over small gaps, holes filled)
    outline_parts = [g for g in (wall_region, door_region) if g is not None and not g.is_empty]
    outline = shapely.union_all(outline_parts)
    d = OUTLINE_CLOSE_M
    closed = outline.buffer(d, join_style="mitre").buffer(-d, join_style="mitre")
    filled = shapely.union_all([shapely.Polygon(p.exterior) for p in shapely.get_parts(closed)
                                if p.geom_type == "Polygon"] + [outline])
    inside = polygon_mask(filled, lat)

    data = np.full(lat.shape, -1, dtype=np.int8)
    data[inside] = 0
    data[occupied] = 100
    grid = GridMap(data, float(resolution), (lat.x0, lat.y0, 0.0))

    wall_geom = wall_region
    if wall_geom is not None and door_region is not None:
        wall_geom = wall_geom.difference(door_region)
    n_doors = len(shapely.get_parts(door_region)) if door_region is not None and not door_region.is_empty else 0
    layer = StaticLayer(grid, height, seed, float(wall_height), n_doors)
    stats = BuildStats(
        wall_length_m=float(wall_geom.length / 2) if wall_geom is not None else 0.0,
        wall_area_m2=float(wall_geom.area) if wall_geom is not None else 0.0,
        wall_cells=n_wall_cells,
        free_cells=int((data == 0).sum()),
        doors=n_doors,
        furniture=len(pieces),
        furniture_mode=furniture,
        ignored_shapes=plan.ignored,
        scale_source=plan.scale_source,
    )
    return layer, stats


def resample_grid(grid: GridMap, resolution: float, max_cells: int = DEFAULT_MAX_CELLS,
                  source: str = "") -> GridMap:
    """A trinary grid at another resolution, same origin corner. A new cell is occupied when
    the centre of an occupied source cell lies in it or the source cell under its centre is
    occupied (thin walls survive coarsening), else free likewise, else unknown."""
    data = trinary(grid.data)
    H, W = data.shape
    r0, r = float(grid.resolution), float(resolution)
    nw, nh = max(math.ceil(W * r0 / r - 1e-9), 1), max(math.ceil(H * r0 / r - 1e-9), 1)
    check_size(Lattice(0.0, 0.0, r, nh, nw), max_cells, source)
    rank_src = np.where(data == 100, 2, np.where(data == 0, 1, 0)).astype(np.int8)
    # (a) the source cell under each new centre
    cols = np.minimum(((np.arange(nw) + 0.5) * r / r0).astype(np.int64), W - 1)
    rows = np.minimum(((np.arange(nh) + 0.5) * r / r0).astype(np.int64), H - 1)
    rank = rank_src[np.ix_(rows, cols)].copy()
    # (b) every source centre marks the new cell it falls in
    sc = np.minimum(((np.arange(W) + 0.5) * r0 / r).astype(np.int64), nw - 1)
    sr = np.minimum(((np.arange(H) + 0.5) * r0 / r).astype(np.int64), nh - 1)
    np.maximum.at(rank, (sr[:, None].repeat(W, 1), sc[None, :].repeat(H, 0)), rank_src)
    out = np.where(rank == 2, 100, np.where(rank == 1, 0, -1)).astype(np.int8)
    return GridMap(out, r, tuple(grid.origin))


def build_from_map(
    grid: GridMap,
    resolution: float | None = None,
    wall_height: float = 2.5,
    origin: tuple[float, float, float] | None = None,
    max_cells: int = DEFAULT_MAX_CELLS,
    source: str = "",
) -> tuple[StaticLayer, BuildStats]:
    """Normalize an existing map_server map into a static layer (trinary; occupied cells are
    walls of ``wall_height``), resampled when ``resolution`` differs from the map's."""
    g = GridMap(trinary(grid.data), float(grid.resolution), tuple(grid.origin))
    if resolution is not None and abs(resolution - g.resolution) > 1e-9 * g.resolution:
        g = resample_grid(g, resolution, max_cells, source)
    if origin is not None:
        g = GridMap(g.data, g.resolution, tuple(float(v) for v in origin))
    layer = layer_from_grid(g, wall_height)
    occ = layer.grid.data == 100
    area = float(occ.sum()) * g.resolution ** 2
    stats = BuildStats(
        wall_length_m=_cell_wall_length(occ, g.resolution),
        wall_area_m2=area,
        wall_cells=int(occ.sum()),
        free_cells=int((layer.grid.data == 0).sum()),
        doors=0,
        furniture=0,
        furniture_mode="none",
        ignored_shapes=0,
        scale_source="map",
    )
    return layer, stats


def _cell_wall_length(occ: np.ndarray, r: float) -> float:
    """Half the perimeter of the occupied cells (cell edges between occupied and not)."""
    pad = np.pad(occ, 1)
    edges = np.count_nonzero(pad[1:, :] != pad[:-1, :]) + np.count_nonzero(pad[:, 1:] != pad[:, :-1])
    return edges * r / 2
