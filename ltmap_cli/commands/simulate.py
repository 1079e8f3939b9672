"""`ltmap simulate SCENARIO.yaml -o LOG`: a synthetic log from a plan and a timeline."""

from __future__ import annotations

import time
from pathlib import Path

import click

from ..errors import ConfigError
from ..sim.scenario import load_scenario
from ..sim.simulate import simulate as run
from . import nonempty_output

HELP = """Write a simulated robot log from a scenario file, and its ground truth.

\b
The scenario (YAML; schema in docs/scenarios.md; angles in degrees, times in s):
  plan (SVG, relative to the scenario; walls and windows extruded to wall_height,
  doors are openings) or walls (polylines with a thickness), duration, seed,
  robot (radius, path: timed waypoints or standing still with a yaw sweep,
  odometry_drift), sensors (laser, depth, points), objects (box, cylinder,
  sphere, table, chair with presence intervals), doors (box, hinged or sliding, with closed intervals),
  people (cylinders walking along a timed path).

\b
Rendered by exact ray casting; noise is drawn from the seed, so the same
scenario and seed give a byte-identical log. Topics: /tf (map -> odom ->
base_link), /tf_static, /odom, /scan, /camera/depth/image_raw and
/camera/depth/camera_info, /points. The ground truth (every object with its
geometry, pose, presence intervals and kind; the robot's path) is written
beside the log as ground_truth.json unless --ground-truth says where. A log
file is written under a temporary name and renamed; a ROS 2 bag folder is
replaced as a whole (a folder ltmap did not write is refused unless --force).
"""


@click.command("simulate", help=HELP, short_help="Write a simulated log from a scenario.")
@click.argument("scenario", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(path_type=Path),
    help="The log to write: a .mcap file, a .bag file, or a ROS 2 bag folder.",
    callback=nonempty_output,
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["mcap", "ros1", "ros2"]),
    default=None,
    help="Log format (default: from the output name: .bag -> ros1, .mcap -> mcap, "
    "no suffix -> ros2; else mcap).",
)
@click.option(
    "--ground-truth",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Where to write the ground truth (default: ground_truth.json beside the log).",
)
@click.option("--seed", type=int, help="Override the scenario's seed.")
@click.option("--force", is_flag=True, help="Replace a ROS 2 bag folder ltmap did not write.")
@click.option("-q", "--quiet", is_flag=True, help="No summary on stdout.")
def simulate(
    scenario: Path, output: Path, fmt: str | None, ground_truth: Path | None, seed: int | None, force: bool, quiet: bool
) -> None:

    if fmt is None:
        fmt = {".bag": "ros1", ".mcap": "mcap", "": "ros2"}.get(output.suffix.lower(), "mcap")
    sc = load_scenario(scenario)
    if seed is not None:
        if seed < 0:
            raise ConfigError(f"--seed {seed}: must be a non-negative integer")
        sc.seed = seed
    t0 = time.perf_counter()
    summary = run(sc, output, fmt, ground_truth, force=force)
    if not quiet:
        n = sum(summary["messages"].values())
        click.echo(
            f"wrote {output} ({fmt}, {sc.duration:g} s, {n} messages: "
            + ", ".join(f"{k} {v}" for k, v in sorted(summary["messages"].items()))
            + f") and {summary['ground_truth']} in {time.perf_counter() - t0:.1f} s"
        )
