"""`ltmap diff A B`: compare two maps cell by cell (exit 0 same, 1 different, 2 error)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..analysis import KINDS, load_grid, resolve_map_path
from ..analysis.diff import diff_maps, diff_report, diff_voxels, voxel_report
from ..core.config import ProjectionConfig
from ..errors import InputError
from ..io.atomic import check_file_target
from ..outputs.folder import check_completed_input
from ..outputs.snapshots import final_state, read_snapshot_voxels
from ..viz.plots import new_figure, plot_diff, save_png


def _describe(grid) -> str:
    ox, oy, yaw = grid.origin
    yaw_s = f", yaw {yaw:g} rad" if yaw else ""
    return f"{grid.width} x {grid.height} cells of {grid.resolution:g} m, origin ({ox:g}, {oy:g}){yaw_s}"


def _table(rows: list[tuple[str, int, float]], area_digits: int) -> list[str]:
    out = [f"{'':<22}{'cells':>12}{'m^2':>14}"]
    for name, cells, m2 in rows:
        out.append(f"{name:<22}{cells:>12d}{m2:>14.{area_digits}f}")
    return out


def _area_digits(cell_area: float) -> int:
    # enough decimals to show one cell's area exactly for the usual resolutions
    for digits in range(2, 9):
        if abs(round(cell_area, digits) - cell_area) < 1e-12:
            return digits
    return 6


def _run_3d(a: Path, b: Path, tolerance: int, as_json: bool) -> int:

    def snapshot(p: Path, name: str) -> Path:
        final = Path(p) / final_state()
        if Path(p).is_dir():
            if not final.is_file():
                raise InputError(
                    f"--3d: {name} {p}: folder has no {final_state()}; give a replay output "
                    "folder, a .ot or a state .npz snapshot"
                )
            return final
        return resolve_map_path(p, name)

    pa, pb = snapshot(a, "A"), snapshot(b, "B")
    for name, p in (("A", pa), ("B", pb)):
        if p.suffix.lower() not in (".ot", ".npz"):
            raise InputError(
                f"--3d compares two long-term snapshots (.ot, state .npz or replay output folders); "
                f"{name} {p} is none of these"
            )

    ka, la, ra = read_snapshot_voxels(pa)
    kb, lb, rb = read_snapshot_voxels(pb)
    if abs(ra - rb) > 1e-9 * max(ra, rb):
        raise InputError(
            f"--3d needs equal resolutions: A {pa} has {ra:g} m voxels, B {pb} {rb:g} m; compare the "
            "projected maps without --3d (with --resample) instead"
        )
    d = diff_voxels(ka, la, kb, lb, ra, tolerance)
    rep = voxel_report(d)
    if as_json:
        rep.update(a=str(a), b=str(b))
        click.echo(json.dumps(rep, indent=2))
    else:
        c = d.counts
        vol = ra**3
        click.echo(f"A: {a} ({c['occupied_a']} occupied voxels of {ra:g} m)")
        click.echo(f"B: {b} ({c['occupied_b']} occupied voxels)")
        click.echo(f"{'':<22}{'voxels':>12}{'m^3':>14}")
        for label, key in (
            ("added", "added"),
            ("removed", "removed"),
            ("unknown-changed", "unknown_changed"),
            ("unchanged occupied", "unchanged_occupied"),
        ):
            click.echo(f"{label:<22}{c[key]:>12d}{c[key] * vol:>14.6f}")
        if tolerance:
            click.echo(
                f"within tolerance      {c['added_within_tolerance']} added, {c['removed_within_tolerance']} "
                f"removed ignored (Euclidean <= {tolerance} voxels)"
            )
        click.echo(f"IoU (occupied)        {d.iou:.4f}")
        click.echo(
            "result: same" if d.same else f"result: maps differ ({c['added']} added, {c['removed']} removed)"
        )
    return 0 if d.same else 1


@click.command("diff")
@click.argument("a", type=click.Path(path_type=Path))
@click.argument("b", type=click.Path(path_type=Path))
@click.option(
    "--tolerance",
    type=click.IntRange(min=0),
    metavar="N",
    default=0,
    show_default=True,
    help="Ignore an added (removed) cell within N cells (Euclidean, centre to centre) of a cell "
    "occupied in the other map.",
)
@click.option(
    "--resample",
    is_flag=True,
    help="Allow maps of different resolutions: resample to the finer one (nearest cell centre).",
)
@click.option(
    "--png", "png", type=click.Path(path_type=Path), metavar="FILE", help="Write an overlay image to FILE."
)
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
@click.option(
    "--3d",
    "three_d",
    is_flag=True,
    help="Compare two long-term snapshots voxel by voxel (occupied, free as the sensors saw it, unknown) (.ot, state .npz or replay output folders: their final state) in 3D (counts and IoU) instead of projected maps.",
)
@click.option(
    "--z-band",
    nargs=2,
    type=float,
    metavar="LO HI",
    default=(ProjectionConfig.z_min, ProjectionConfig.z_max),
    show_default=True,
    help="Height band [m] over which .ot and state .npz snapshots are projected to 2D.",
)
@click.pass_context
def diff(
    ctx: click.Context,
    a: Path,
    b: Path,
    tolerance: int,
    resample: bool,
    png: Path | None,
    as_json: bool,
    three_d: bool,
    z_band: tuple[float, float],
) -> None:
    """Compare map A with map B cell by cell, aligned in world coordinates.

    A and B are map_server YAMLs, replay output folders (their map.yaml), .ot snapshots or
    exact-state .npz snapshots (snapshots/state_*.npz: the long-term layer; these two projected
    over --z-band). Maps with different origins and sizes are compared on the union
    of their extents; a cell outside a map is unknown in it. Added: free or unknown in A,
    occupied in B. Removed: occupied in A, free in B. Unknown-changed: known in one map,
    unknown in the other (other than added/removed).

    Exit status: 0 same (nothing added or removed after --tolerance), 1 different, 2 error.
    """

    for name, p in (("A", a), ("B", b)):  # a folder is read only when a run completed it
        check_completed_input(p, name, f"give {KINDS} of a completed run", "replay")
    if z_band[1] <= z_band[0]:
        raise InputError(f"--z-band {z_band[0]:g} {z_band[1]:g}: the top must exceed the bottom")
    if png is not None and not three_d:

        check_file_target(png, "--png", "diff.png")
    if three_d:
        if png is not None:
            raise InputError("--png draws projected maps; drop --3d to get an overlay image")
        ctx.exit(_run_3d(a, b, tolerance, as_json))
        return


    ga = load_grid(a, "A", z_band)
    gb = load_grid(b, "B", z_band)
    d = diff_maps(ga, gb, tolerance=tolerance, resample=resample, names=(f"A {a}", f"B {b}"))
    rep = diff_report(d)

    if png is not None:

        h, w = d.aligned.a.shape
        fig, ax = new_figure(w, h, legend=True)
        plot_diff(ax, d)
        save_png(fig, png)

    if as_json:
        rep.update(a=str(a), b=str(b), png=str(png) if png is not None else None)
        click.echo(json.dumps(rep, indent=2))
    else:
        al = d.aligned
        c = d.counts()
        area = d.cell_area
        digits = _area_digits(area)
        h, w = al.a.shape
        click.echo(f"A: {a} ({_describe(ga)})")
        click.echo(f"B: {b} ({_describe(gb)})")
        ox, oy, yaw = al.origin
        yaw_s = f", yaw {yaw:g} rad" if yaw else ""
        click.echo(
            f"compared on {al.resolution:g} m cells over {w} x {h} cells "
            f"({w * al.resolution:g} m x {h * al.resolution:g} m) from ({ox:g}, {oy:g}){yaw_s}"
        )
        for note in al.notes:
            click.echo(f"note: {note}")
        click.echo("")
        for line in _table(
            [
                ("added", c["added"], c["added"] * area),
                ("removed", c["removed"], c["removed"] * area),
                ("unknown-changed", c["unknown_changed"], c["unknown_changed"] * area),
                ("unchanged occupied", c["unchanged_occupied"], c["unchanged_occupied"] * area),
            ],
            digits,
        ):
            click.echo(line)
        if tolerance:
            click.echo(
                f"within tolerance      {c['added_within_tolerance']} added, {c['removed_within_tolerance']} "
                f"removed cells ignored (Euclidean <= {tolerance} cells)"
            )
        click.echo(f"IoU (occupied)        {d.iou:.4f}  ({c['occupied_a']} in A, {c['occupied_b']} in B)")
        if png is not None:
            click.echo(f"overlay: {png}")
        click.echo(
            "result: same" if d.same else f"result: maps differ ({c['added']} added, {c['removed']} removed)"
        )
    ctx.exit(0 if d.same else 1)
