"""Footprint clearing (SPEC 2.3): the cells the robot's footprint covered along its path are free
in P unless something occupied is there now, so a path can be planned from where the robot was."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from ltmap_cli.cli import cli
from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.core.projection import FREE, OCCUPIED, UNKNOWN, FootprintTrace, footprint_cells, project

R = 0.05
SAMPLE = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "01_static_object"


def brute(path, radius, res=R):
    """Every cell of a wide box whose centre is within radius of a pose (poses dense enough)."""
    out = set()
    for x, y in path:
        for i in range(int(np.floor(x / res)) - 10, int(np.floor(x / res)) + 11):
            for j in range(int(np.floor(y / res)) - 10, int(np.floor(y / res)) + 11):
                if (((i + 0.5) * res - x) ** 2 + ((j + 0.5) * res - y) ** 2) <= radius**2 + 1e-12:
                    out.add((i, j))
    return out


def test_footprint_cells_of_one_pose_are_the_disc():
    x, y = 80.5 * R / 4, 160.5 * R / 4  # a quarter cell's centre: no snapping
    cells = footprint_cells([[x, y]], 0.2, R)
    assert {tuple(c) for c in cells.tolist()} == brute([(x, y)], 0.2)
    assert len(cells) == len(brute([(x, y)], 0.2)) >= 49
    assert len(footprint_cells([[1.0, 2.0]], 0.0, R)) == 0


def test_a_path_with_a_gap_is_a_band():
    """Two poses 1 m apart: the points between them are taken in (not two discs)."""
    cells = {tuple(c) for c in footprint_cells([[0.0, 0.0], [1.0, 0.0]], 0.1, R).tolist()}
    dense = [(x, 0.0) for x in np.linspace(0.0, 1.0, 401)]
    # poses are snapped to a grid of quarter cells (within 0.9 cm)
    assert brute(dense, 0.1 - 0.009) <= cells <= brute(dense, 0.1 + 0.009)
    assert len(cells) >= 0.9 * len(brute(dense, 0.1))


def test_trace_taken_in_bit_by_bit_equals_the_whole_path():
    rng = np.random.default_rng(3)
    path = np.cumsum(rng.normal(0, 0.03, (300, 2)), axis=0)
    trace = FootprintTrace(0.2, R)
    rows = []
    for k in range(0, 300, 37):
        rows.extend((float(t), float(x), float(y)) for t, (x, y) in zip(range(k, k + 37), path[k : k + 37]))
        trace.update(rows)
    np.testing.assert_array_equal(trace.cells, footprint_cells(path, 0.2, R))


def test_trace_of_the_replays_track_equals_the_whole_path():
    """The replay keeps the robot's path in a ``Track`` (24 bytes a row), which the trace reads
    by slices as the path grows."""
    from ltmap_cli.pipeline.sinks import Track

    rng = np.random.default_rng(4)
    path = np.cumsum(rng.normal(0, 0.03, (300, 2)), axis=0)
    trace, track = FootprintTrace(0.2, R), Track()
    for k, (x, y) in enumerate(path):
        track.append(0.1 * k, float(x), float(y))
        if k % 41 == 0:
            trace.update(track)
    trace.update(track)
    np.testing.assert_array_equal(trace.cells, footprint_cells(path, 0.2, R))
    assert len(track) == 300 and track[298:].tolist() == [[0.1 * 298, *path[298]], [0.1 * 299, *path[299]]]
    np.testing.assert_array_equal(track.xy(), path)


def test_footprint_is_free_unless_occupied():
    m = LayeredMap(MapConfig())
    m.seed_long_term(np.array([[22, 40, 10]]), 1.0)  # an obstacle in LT at (1.1, 2.0)
    path = np.array([[1.0, 2.0], [1.2, 2.0]])
    p0 = project(m)
    p = project(m, footprint=path)
    cells = footprint_cells(path, 0.2, R)
    val = p.data[cells[:, 1] - p.j0, cells[:, 0] - p.i0]
    occ = (cells[:, 0] == 22) & (cells[:, 1] == 40)
    assert (val[occ] == OCCUPIED).all() and (val[~occ] == FREE).all()
    assert (p0.data != FREE).all()  # without the footprint: nothing seen free
    # the cells themselves give the same P as the path
    np.testing.assert_array_equal(project(m, footprint=cells).data, p.data)
    # outside the footprint, P is as without it
    far = p.data.copy()
    far[cells[:, 1] - p.j0, cells[:, 0] - p.i0] = UNKNOWN
    assert set(np.unique(far).tolist()) <= {UNKNOWN, OCCUPIED}


def test_plan_from_the_robot_start_pose_without_flags(tmp_path):
    """01_static_object: the robot stands at (1.5, 2.5); its laser, 0.15 m ahead, never sees the
    cells under the robot, so without the footprint the start is in an unknown cell."""
    runner = CliRunner()
    out = tmp_path / "out"
    r = runner.invoke(cli, ["replay", str(SAMPLE / "log.mcap"), "-o", str(out), "-q", "--no-plots"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(cli, ["plan", str(out), "--start", "1.5,2.5", "--goal", "6.5,2.5"])
    assert r.exit_code == 0, r.output
    assert "length" in r.output
    cfg = tmp_path / "nofp.yaml"
    cfg.write_text("map:\n  projection:\n    footprint_radius: 0.0\n")
    out0 = tmp_path / "out0"
    r = runner.invoke(cli, ["replay", str(SAMPLE / "log.mcap"), "-o", str(out0), "-q", "--no-plots",
                            "--config", str(cfg)])  # fmt: skip
    assert r.exit_code == 0, r.output
    r = runner.invoke(cli, ["plan", str(out0), "--start", "1.5,2.5", "--goal", "6.5,2.5"])
    assert r.exit_code == 2 and "unknown cell" in r.output, r.output


@pytest.mark.parametrize("radius", [-0.1])
def test_a_negative_radius_is_refused(radius):
    cfg = MapConfig()
    cfg.projection.footprint_radius = radius
    assert any("footprint_radius" in p for p in cfg.validate())
