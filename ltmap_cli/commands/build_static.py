"""`ltmap build-static PLAN`: the static map S from an SVG floor plan or an existing map."""

from __future__ import annotations

import math
import time
from pathlib import Path

import click

from ..io.mapfile import read_map_yaml
from ..outputs.folder import OutputFolder, listing
from ..static.build import DEFAULT_MAX_CELLS, build_from_map, build_from_plan, write_static
from ..static.svgplan import parse_plan
from . import nonempty_output

HELP = """Build the static map S from an architect's plan (SVG) or an existing map_server map.

\b
SVG conventions (see docs/plans.md):
  scale, first that applies: --scale METRES_PER_UNIT; the root <svg> width/height in
    mm, cm, m, in, pt or pc against its viewBox; a line with id="scale" and
    data-length-m="<its length in metres>".
  layers: a <g> whose id or inkscape:label is walls, doors, windows or furniture.
    No named layer: every shape is a wall. With named layers, other shapes are ignored.
    Doors stay free (they carve their cells out of the walls) and are counted.
    Windows are walls. Furniture is left out unless --furniture static|long-term.
  geometry: strokes are walls as wide as the stroke after transforms (hairlines and
    strokes without a width: --wall-thickness); filled closed shapes are solid.
    A wall thinner than a cell still gives an unbroken line of cells.
  frame: the canvas' (viewBox') lower-left corner is map (0, 0), x right, y up,
    unless --origin x,y,yaw places it elsewhere.

\b
Writes into OUTPUT (replaced as a whole when the build completes; a folder
ltmap did not write is refused unless --force): static.pgm + static.yaml (walls occupied, inside the plan's
outline free, outside unknown), static.png, and static_layer.npz (the 3D layer:
walls extruded to --wall-height) that `ltmap replay --static OUTPUT` loads.
A map YAML as PLAN is normalized to the same outputs (at its own resolution
unless --resolution is given).
"""


def _origin(ctx, param, value):
    if value is None:
        return None
    try:
        parts = [float(v) for v in value.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 3 or not all(math.isfinite(v) for v in parts):
        raise click.BadParameter(f"{value!r}: give x,y,yaw (metres, metres, radians), e.g. 2.5,-1,0")
    return tuple(parts)


def _positive(ctx, param, value):
    if value is not None and not (math.isfinite(value) and value > 0):
        raise click.BadParameter(f"must be a positive number, got {value}")
    return value


@click.command("build-static", help=HELP, short_help="Build the static map from a plan.")
@click.argument("plan", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("static_out"),
    show_default=True,
    help="Output folder.",
    callback=nonempty_output,
)
@click.option("--force", is_flag=True, help="Replace the output folder even if ltmap did not write it.")
@click.option(
    "--resolution",
    type=float,
    default=None,
    callback=_positive,
    help="Cell size in metres [default: 0.05 for a plan; a map's own].",
)
@click.option(
    "--scale",
    type=float,
    default=None,
    callback=_positive,
    metavar="METRES_PER_UNIT",
    help="Metres per SVG user unit (overrides width/height and the scale element).",
)
@click.option(
    "--wall-height",
    type=float,
    default=2.5,
    show_default=True,
    callback=_positive,
    help="Height (m) the walls are extruded to.",
)
@click.option(
    "--wall-thickness",
    type=float,
    default=0.10,
    show_default=True,
    callback=_positive,
    help="Thickness (m) of hairline walls and strokes without a width.",
)
@click.option(
    "--origin",
    type=str,
    default=None,
    callback=_origin,
    metavar="X,Y,YAW",
    help="Map pose of the plan's lower-left corner [default: 0,0,0].",
)
@click.option(
    "--furniture",
    type=click.Choice(["none", "static", "long-term"]),
    default="none",
    show_default=True,
    help="static: furniture is part of S (to its data-height-m, else the wall height); "
    "long-term: it seeds the initial long-term layer.",
)
@click.option(
    "--max-cells",
    type=int,
    default=None,
    help="Refuse maps with more cells than this, before allocating them [default: 6.4e7, about 1 GB].",
)
def build_static(
    plan: Path, output: Path, force: bool, resolution, scale, wall_height, wall_thickness, origin, furniture, max_cells
) -> None:

    t0 = time.perf_counter()
    max_cells = DEFAULT_MAX_CELLS if max_cells is None else max_cells
    if plan.suffix.lower() in (".yaml", ".yml"):
        layer, stats = build_from_map(
            read_map_yaml(plan, max_cells), resolution, wall_height, origin, max_cells, str(plan)
        )
        what = "map"
    else:
        parsed = parse_plan(plan, scale, wall_thickness, origin or (0.0, 0.0, 0.0))
        layer, stats = build_from_plan(parsed, resolution or 0.05, wall_height, furniture, max_cells)
        what = f"plan (scale from {stats.scale_source})"
    # everything is computed before the first file is written, into a staging folder swapped in whole
    with OutputFolder(output, command="build-static", force=force) as out:
        out.refuse_inputs_inside([plan], "PLAN")
        write_static(out.staging, layer)
        manifest = out.commit({"plan": str(plan)})
    g = layer.grid
    extra = []
    if stats.furniture:
        extra.append(f"{stats.furniture} furniture shapes " + {
            "none": "left out (--furniture none)", "static": "in S", "long-term": "seeding LT"}[stats.furniture_mode])
    if stats.ignored_shapes:
        extra.append(f"{stats.ignored_shapes} shapes outside the named layers ignored")
    click.echo(
        f"{output}/: {what}: walls {stats.wall_length_m:.1f} m long (half the wall outline's perimeter), "
        f"{stats.wall_area_m2:.2f} m^2, {stats.wall_cells} wall cells; {stats.doors} doors; "
        f"{g.width} x {g.height} cells = {g.width * g.resolution:.2f} x {g.height * g.resolution:.2f} m "
        f"at {g.resolution:g} m, origin ({g.origin[0]:g}, {g.origin[1]:g}); "
        + ("; ".join(extra) + "; " if extra else "")
        + f"wrote {listing(manifest)} in {time.perf_counter() - t0:.2f} s"
    )
