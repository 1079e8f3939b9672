"""`ltmap plan MAP --start x,y --goal x,y`: A* on a map with the robot radius inflated."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from ..analysis import KINDS, load_grid
from ..analysis.planner import plan_on_grid
from ..io.atomic import check_file_target
from ..outputs.folder import check_completed_input
from ..viz.plots import new_figure, plot_path, save_png


class PointType(click.ParamType):
    """``x,y`` in metres."""

    name = "x,y"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        parts = str(value).replace(" ", "").split(",")
        try:
            if len(parts) != 2:
                raise ValueError
            x, y = float(parts[0]), float(parts[1])
            if not (math.isfinite(x) and math.isfinite(y)):
                raise ValueError
        except ValueError:
            self.fail(f"{value!r} is not a point: give x,y in metres, e.g. 1.5,-2", param, ctx)
        return (x, y)


@click.command("plan")
@click.argument("map_path", metavar="MAP", type=click.Path(path_type=Path))
@click.option("--start", required=True, type=PointType(), help="Start x,y in metres (map frame).")
@click.option("--goal", required=True, type=PointType(), help="Goal x,y in metres (map frame).")
@click.option(
    "--robot-radius",
    type=float,
    default=0.2,
    show_default=True,
    help="Robot radius [m]: a cell is blocked when an occupied cell's centre is within it.",
)
@click.option("--allow-unknown", is_flag=True, help="Let the path cross unknown cells.")
@click.option(
    "--png", "png", type=click.Path(path_type=Path), metavar="FILE", help="Draw the map and the path to FILE."
)
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON (with the path).")
def plan(
    map_path: Path,
    start: tuple[float, float],
    goal: tuple[float, float],
    robot_radius: float,
    allow_unknown: bool,
    png: Path | None,
    as_json: bool,
) -> None:
    """Plan the shortest 8-connected path on MAP from --start to --goal (A*, octile costs).

    MAP is a map_server YAML, a replay output folder (its map.yaml), a .ot snapshot or an
    exact-state .npz snapshot (snapshots/state_*.npz: its long-term layer), these two projected
    over [0.05, 1.5] m. Occupied cells are inflated by --robot-radius; unknown cells are forbidden
    unless --allow-unknown.
    The length is measured between cell centres. Exit status: 0 path found, 1 no path, 2 error
    (e.g. start or goal off the map or inside an obstacle).
    """

    if png is not None:

        check_file_target(png, "--png", "path.png")

    check_completed_input(map_path, "MAP", f"give {KINDS} of a completed run", "replay")
    grid = load_grid(map_path, "map")
    res = plan_on_grid(grid, start, goal, robot_radius=robot_radius, allow_unknown=allow_unknown)

    if png is not None:

        fig, ax = new_figure(grid.width, grid.height, legend=True)
        plot_path(
            ax,
            grid,
            res.path_xy,
            start,
            goal,
            blocked=res.blocked,
            title=f"{map_path.name}: path {res.length_m:.2f} m, robot radius {robot_radius:g} m",
        )
        save_png(fig, png)

    if as_json:
        click.echo(
            json.dumps(
                {
                    "map": str(map_path),
                    "resolution": grid.resolution,
                    "start": list(res.start_xy),
                    "goal": list(res.goal_xy),
                    "start_cell": list(res.start_rc),
                    "goal_cell": list(res.goal_rc),
                    "robot_radius": res.robot_radius,
                    "allow_unknown": res.allow_unknown,
                    "length_m": res.length_m,
                    "length_cells": res.length_cells,
                    "expanded": res.expanded,
                    "seconds": res.seconds,
                    "path": [[round(float(x), 6), round(float(y), 6)] for x, y in res.path_xy],
                    "png": str(png) if png is not None else None,
                },
                indent=2,
            )
        )
        return
    radius_cells = robot_radius / grid.resolution
    click.echo(f"map:          {map_path} ({grid.width} x {grid.height} cells of {grid.resolution:g} m)")
    click.echo(f"start:        {start[0]:g}, {start[1]:g} (row {res.start_rc[0]}, col {res.start_rc[1]})")
    click.echo(f"goal:         {goal[0]:g}, {goal[1]:g} (row {res.goal_rc[0]}, col {res.goal_rc[1]})")
    click.echo(
        f"robot radius: {robot_radius:g} m ({radius_cells:.2f} cells); unknown cells "
        f"{'allowed' if allow_unknown else 'forbidden'}"
    )
    click.echo(
        f"path length:  {res.length_m:.3f} m ({res.length_cells:.2f} cells, {len(res.path_rc)} waypoints)"
    )
    click.echo(f"expanded:     {res.expanded} cells in {res.seconds * 1e3:.1f} ms")
    if png is not None:
        click.echo(f"image:        {png}")
