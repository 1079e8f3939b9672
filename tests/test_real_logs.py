"""Replay of logs recorded by real robots, by other people (../shared/real_logs/).

Skipped, with the reason, when the folder is absent. See docs/real_logs.md for what each log
needs and for the documented alignment of the comprobo22 log with the published map.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from ltmap_cli.cli import cli
from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.io.mapfile import read_map_yaml
from ltmap_cli.io.state import read_state

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real_logs"
PIONEER = REAL / "ist_pioneer3dx_test1.bag"
COMPROBO = REAL / "comprobo22_macfirst_floor_take_2"
COMPROBO_MAP = REAL / "comprobo22_maps" / "mac_1st_floor_final.yaml"
# map -> odom for the comprobo22 log, found by a rotation search with FFT correlation and a local
# refinement (docs/real_logs.md); the log itself has no map frame.
COMPROBO_MAP_ODOM = (-0.345, -0.017, math.radians(4.9))

pytestmark = [
    pytest.mark.skipif(not REAL.is_dir(), reason=f"real logs not present at {REAL}"),
    pytest.mark.slow,
]


def replay(*args) -> tuple[int, str]:
    r = CliRunner().invoke(cli, ["replay", *map(str, args), "-q"], catch_exceptions=False)
    return r.exit_code, r.output


def o_map(out: Path) -> LayeredMap:
    arrays, _ = read_state(out / "snapshots" / "state_final.npz")
    m = LayeredMap(MapConfig())
    m.load_state_arrays(arrays)
    return m


@pytest.fixture(scope="module")
def pioneer_out(tmp_path_factory):
    out = tmp_path_factory.mktemp("pioneer")
    code, output = replay(PIONEER, "-o", out, "--tf", "base_link:laser=0.1,0,0.3,0,0,0",
                          "--set", "map.layers.st_rise_s=5")  # fmt: skip
    assert code == 0, output
    return out


def test_pioneer_without_its_laser_mount_fails_with_the_fix(tmp_path):
    code, output = replay(PIONEER, "-o", tmp_path / "o")
    assert code == 2
    assert "every sensor frame was skipped (311 x)" in output
    assert "--tf base_link:laser=x,y,z,roll,pitch,yaw" in output
    assert not (tmp_path / "o" / "map.yaml").exists()


def test_pioneer_replays_every_scan(pioneer_out):
    report = json.loads((pioneer_out / "report.json").read_text())
    assert report["frames_used"] == {"/scan": 311}
    assert report["frames_skipped"] == {}
    assert report["fixed_frame"] == "odom"
    assert report["messages_per_topic"]["/scan"] == 311


def test_pioneer_map_has_walls_and_keeps_the_driven_path_free(pioneer_out):
    m = o_map(pioneer_out)
    occ = m.occupied_keys("O")
    cells = {(int(i), int(j)) for i, j in occ[:, :2]}
    assert len(cells) > 1000
    # the robot drove from (-2.74, -9.00) to (-0.18, -13.99) in odom: nothing occupied on that path
    a, b = np.array([-2.74, -9.00]), np.array([-0.18, -13.99])
    centres = (occ[:, :2] + 0.5) * 0.05
    t = np.clip(((centres - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
    dist = np.linalg.norm(centres - (a + t[:, None] * (b - a)), axis=1)
    assert dist.min() > 0.3
    # with st_rise_s = 5 s the corridor walls seen for 5 s enter the long-term map
    lt = read_map_yaml(pioneer_out / "long_term.yaml")
    rows, cols = np.nonzero(lt.data == 100)
    i0, j0 = round(lt.origin[0] / 0.05), round(lt.origin[1] / 0.05)
    lt_cells = {(int(c) + i0, int(r) + j0) for r, c in zip(rows, cols)}
    assert len(lt_cells) > 150  # measured 297 (docs/real_logs.md)
    # every long-term cell is on a wall the sensor map saw (within one cell)
    near = {(i + di, j + dj) for i, j in cells for di in (-1, 0, 1) for dj in (-1, 0, 1)}
    assert lt_cells <= near


@pytest.fixture(scope="module")
def comprobo_aligned(tmp_path_factory):
    out = tmp_path_factory.mktemp("comprobo")
    x, y, yaw = COMPROBO_MAP_ODOM
    code, output = replay(COMPROBO, "-o", out, "--static", COMPROBO_MAP, "--fixed-frame", "map",
                          "--tf", f"map:odom={x},{y},0,0,0,{yaw}")  # fmt: skip
    assert code == 0, output
    return out


def test_comprobo_replays_all_but_the_scan_after_the_last_tf(comprobo_aligned):
    report = json.loads((comprobo_aligned / "report.json").read_text())
    assert report["frames_used"] == {"/scan": 356}
    assert report["frames_skipped"] == {
        "transform odom -> base_link not available (stamp after its last sample; no extrapolation)": 1
    }
    assert report["messages_per_topic"]["/scan"] == 357
    assert report["static"]["source_resolution"] == pytest.approx(0.03)


def _fraction_on_walls(points_xy: np.ndarray, grid, tol_cells: int = 2) -> float:
    occ = grid.data == 100
    near = occ.copy()
    for dy in range(-tol_cells, tol_cells + 1):
        for dx in range(-tol_cells, tol_cells + 1):
            near |= np.roll(np.roll(occ, dy, 0), dx, 1)
    j = np.floor((points_xy - np.array(grid.origin[:2])) / grid.resolution).astype(int)
    ok = (j[:, 0] >= 0) & (j[:, 0] < occ.shape[1]) & (j[:, 1] >= 0) & (j[:, 1] < occ.shape[0])
    return float(near[j[ok, 1], j[ok, 0]].sum()) / len(points_xy)


def test_comprobo_map_overlaps_the_published_map_of_that_floor(comprobo_aligned):
    grid = read_map_yaml(COMPROBO_MAP)
    occ = o_map(comprobo_aligned).occupied_keys("O")
    pts = np.unique((occ[:, :2] + 0.5) * 0.05, axis=0)
    assert len(pts) > 1500
    right = _fraction_on_walls(pts, grid)
    c, s = math.cos(math.radians(10)), math.sin(math.radians(10))
    wrong = _fraction_on_walls(pts @ np.array([[c, s], [-s, c]]), grid)
    assert right >= 0.6, right  # measured 0.67: the rest are people, furniture, doors, drift
    assert wrong < right / 3, (right, wrong)


def test_comprobo_walls_of_the_static_map_stay_out_of_the_long_term_layer(comprobo_aligned, tmp_path):
    with_static = json.loads((comprobo_aligned / "report.json").read_text())["voxels"]["long_term_occupied"]
    code, output = replay(COMPROBO, "-o", tmp_path / "plain")
    assert code == 0, output
    without = json.loads((tmp_path / "plain" / "report.json").read_text())["voxels"]["long_term_occupied"]
    assert without > 0
    assert with_static < without
    static_map = read_map_yaml(comprobo_aligned / "static.yaml")
    assert (static_map.data == 100).sum() > 5000  # 9077 cells at 0.05 m
