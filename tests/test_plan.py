"""`ltmap plan` and the A* library: optimal lengths on hand-made maps, inflation, doors,
unknown cells, exit statuses, PNG/JSON output."""

from __future__ import annotations

import heapq
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from mapfactory import write_trinary

from ltmap_cli.analysis import cell_to_world
from ltmap_cli.analysis.planner import blocked_grid, inflate, plan_on_grid, plan_path
from ltmap_cli.cli import cli
from ltmap_cli.errors import InputError, NoPathError
from ltmap_cli.io.mapfile import GridMap
from ltmap_cli.outputs.folder import OutputFolder

S2 = math.sqrt(2.0)
RES = 0.05


def xy(row: int, col: int, origin=(0.0, 0.0), res: float = RES) -> str:
    """The command-line point at the centre of a cell."""
    return f"{origin[0] + (col + 0.5) * res!r},{origin[1] + (row + 0.5) * res!r}"


def run(*args):
    return CliRunner().invoke(cli, ["plan", *map(str, args)])


def dijkstra(blocked: np.ndarray, start, goal) -> float:
    """Reference: plain Dijkstra with the same moves (8-connected, no corner cutting)."""
    h, w = blocked.shape
    dist = {start: 0.0}
    pq = [(0.0, start)]
    done = set()
    while pq:
        d, (r, c) = heapq.heappop(pq)
        if (r, c) in done:
            continue
        done.add((r, c))
        if (r, c) == goal:
            return d
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if not dr and not dc:
                    continue
                nr, nc = r + dr, c + dc
                if not (0 <= nr < h and 0 <= nc < w) or blocked[nr, nc]:
                    continue
                if dr and dc and (blocked[r, nc] or blocked[nr, c]):
                    continue
                nd = d + (S2 if dr and dc else 1.0)
                if nd < dist.get((nr, nc), math.inf):
                    dist[(nr, nc)] = nd
                    heapq.heappush(pq, (nd, (nr, nc)))
    return math.inf


# ---------------------------------------------------------------------------------------------
# library: plan_path, inflate


def test_straight_line_is_exact():
    b = np.zeros((10, 30), bool)
    res = plan_path(b, (5, 2), (5, 27))
    assert res.length_cells == 25.0
    assert len(res.path_rc) == 26
    assert (res.path_rc[:, 0] == 5).all()
    assert res.path_rc[0].tolist() == [5, 2] and res.path_rc[-1].tolist() == [5, 27]
    # a good tie-break goes straight for the goal: only the cells on the line are expanded
    assert res.expanded == 26


def test_diagonal_is_k_sqrt2():
    b = np.zeros((20, 20), bool)
    res = plan_path(b, (1, 2), (13, 14))
    assert res.length_cells == pytest.approx(12 * S2, abs=1e-12)
    # octile: 7 diagonal + 5 straight
    assert plan_path(b, (0, 0), (7, 12)).length_cells == pytest.approx(7 * S2 + 5, abs=1e-12)


def test_around_a_wall_hand_computed():
    # wall on col 10, rows 0..7, in a 10 x 20 grid; from (0, 0) to (0, 19).
    # No corner cutting: reach (8, 9) [8 diagonal + 1 straight], step to (8, 10) and (8, 11)
    # [2 straight], then down to (0, 19) [8 diagonal]: 16 sqrt(2) + 3.
    b = np.zeros((10, 20), bool)
    b[0:8, 10] = True
    res = plan_path(b, (0, 0), (0, 19))
    assert res.length_cells == pytest.approx(16 * S2 + 3, abs=1e-12)
    assert not b[res.path_rc[:, 0], res.path_rc[:, 1]].any()
    steps = np.abs(np.diff(res.path_rc, axis=0))
    assert (steps.max(axis=1) == 1).all()  # 8-connected, one cell per step
    # the path's own length adds up to the reported one
    assert (np.where(steps.sum(axis=1) == 2, S2, 1.0)).sum() == pytest.approx(res.length_cells)


def test_no_squeezing_between_corner_touching_cells():
    b = np.zeros((3, 3), bool)
    b[0, 1] = b[1, 0] = True  # a diagonal wall
    assert plan_path(b, (0, 0), (2, 2)) is None
    b[1, 0] = False
    assert plan_path(b, (0, 0), (1, 1)).length_cells == 2.0  # around the corner, not across it


def test_matches_dijkstra_on_random_maps():
    rng = np.random.default_rng(7)
    for _ in range(25):
        b = rng.random((25, 30)) < 0.3
        free = np.argwhere(~b)
        s, g = free[rng.choice(len(free), 2, replace=False)]
        s, g = tuple(int(v) for v in s), tuple(int(v) for v in g)
        ref = dijkstra(b, s, g)
        res = plan_path(b, s, g)
        if math.isinf(ref):
            assert res is None
        else:
            assert res is not None and res.length_cells == pytest.approx(ref, abs=1e-9)


def test_long_searches_reachable_and_unreachable():
    # 400 x 400: long enough that A* runs its one-off connectivity check (after 65536
    # expansions) before finishing.
    # Reachable: a wall on col 200, rows 0..398, open only at row 399; (0, 0) -> (0, 399):
    # to (399, 199) [199 diagonal + 200 straight], two steps along row 399 to col 201, then to
    # (0, 399) [198 diagonal + 201 straight]: 397 sqrt(2) + 403.
    b = np.zeros((400, 400), bool)
    b[0:399, 200] = True
    res = plan_path(b, (0, 0), (0, 399))
    assert res.expanded > 65536
    assert res.length_cells == pytest.approx(397 * S2 + 403, abs=1e-9)
    # Unreachable: the goal is enclosed by a ring; the start's side is large
    b = np.zeros((400, 400), bool)
    b[300, 300:311] = b[310, 300:311] = b[300:311, 300] = b[300:311, 310] = True
    assert plan_path(b, (0, 0), (305, 305)) is None
    # ... and the start is enclosed instead
    assert plan_path(b, (305, 305), (0, 0)) is None
    # a ring closed only at a corner-touching diagonal is still closed (no corner cutting)
    b[310, 310] = False
    b[311, 311] = True
    assert plan_path(b, (0, 0), (305, 305)) is None


def test_blocked_endpoints_and_bounds():
    b = np.zeros((5, 5), bool)
    b[2, 2] = True
    assert plan_path(b, (2, 2), (0, 0)) is None
    assert plan_path(b, (0, 0), (2, 2)) is None
    assert plan_path(b, (0, 0), (0, 0)).length_cells == 0.0
    with pytest.raises(ValueError, match="goal"):
        plan_path(b, (0, 0), (5, 0))


def test_inflate_disk():
    occ = np.zeros((11, 11), bool)
    occ[5, 5] = True
    assert inflate(occ, 0).sum() == 1
    assert inflate(occ, 0.99).sum() == 1
    assert inflate(occ, 1).sum() == 5  # centre + 4 neighbours
    assert inflate(occ, 1.5).sum() == 9  # + diagonals (sqrt 2 <= 1.5)
    assert inflate(occ, 2).sum() == 13
    # radius 4: integer points with dx^2 + dy^2 <= 16: 49
    big = np.zeros((21, 21), bool)
    big[10, 10] = True
    assert inflate(big, 4).sum() == 49
    assert inflate(big, 0.2 / 0.05).sum() == 49  # 0.2 / 0.05 is exactly 4 cells
    assert inflate(big, 0.3 / 0.1).sum() == 29  # 0.3 / 0.1 = 2.9999999999999996: still 3 cells
    # the border and a brute-force check
    rng = np.random.default_rng(3)
    occ = rng.random((30, 40)) < 0.02
    occ[0, 0] = occ[-1, -1] = True
    r = 3.5
    pts = np.argwhere(occ)
    rr, cc = np.mgrid[0:30, 0:40]
    ref = np.zeros_like(occ)
    for pr, pc in pts:
        ref |= (rr - pr) ** 2 + (cc - pc) ** 2 <= r * r
    np.testing.assert_array_equal(inflate(occ, r), ref)


def test_gap_narrower_than_robot_diameter_is_blocked():
    # two walls with a gap of g free cells between them, at 0.05 m; robot radius 0.2 m = 4 cells.
    # A cell in the gap is blocked when it is <= 4 cells from a wall cell: the middle of a g-cell
    # gap is floor((g + 1) / 2) cells from the walls, so g = 9 (0.45 m) passes and g = 8
    # (0.40 m = 2 x radius) does not.
    def corridor(gap):
        d = np.zeros((40, 40), np.int8)
        d[20, :] = 100
        d[20, 10 : 10 + gap] = 0
        return GridMap(d, RES)

    start, goal = (14.5 * RES, 5.5 * RES), (14.5 * RES, 35.5 * RES)  # cells (5, 14) and (35, 14)
    ok = plan_on_grid(corridor(9), start, goal)
    assert ok.length_cells == pytest.approx(30.0) and ok.length_m == pytest.approx(1.5)
    with pytest.raises(NoPathError, match="no path"):
        plan_on_grid(corridor(8), start, goal)
    # with a smaller robot (3 cells) the 8-cell gap opens
    assert plan_on_grid(corridor(8), start, goal, robot_radius=0.15).length_cells == pytest.approx(30.0)


def test_blocked_grid_unknown():
    d = np.zeros((5, 5), np.int8)
    d[0, 0] = -1
    d[4, 4] = 100
    g = GridMap(d, 1.0)
    assert blocked_grid(g, 0.0).sum() == 2
    assert blocked_grid(g, 0.0, allow_unknown=True).sum() == 1
    assert blocked_grid(g, 1.0, allow_unknown=True).sum() == 3


def test_plan_on_grid_with_yaw():
    # a 1 x 10 corridor stored with yaw pi/2: it runs along world y
    g = GridMap(np.zeros((1, 10), np.int8), 1.0, (0.0, 0.0, math.pi / 2))
    res = plan_on_grid(g, (-0.5, 0.5), (-0.5, 9.5), robot_radius=0.0)
    assert res.length_cells == 9.0 and res.start_rc == (0, 0) and res.goal_rc == (0, 9)
    assert res.path_xy[-1] == pytest.approx(cell_to_world(g, 0, 9))


# ---------------------------------------------------------------------------------------------
# door maps and the command line


def door_map(door_open: bool, second_door: bool = False) -> np.ndarray:
    """60 x 60 cells: a horizontal wall on row 30 with a 12-cell door at cols 24..35
    (and optionally a second one at cols 46..57)."""
    d = np.zeros((60, 60), np.int8)
    d[30, :] = 100
    if door_open:
        d[30, 24:36] = 0
    if second_door:
        d[30, 46:58] = 0
    return d


def test_cli_door_open_then_closed(tmp_path):
    with OutputFolder(tmp_path / "open", command="replay") as out:  # a folder as a completed replay leaves it
        write_trinary(out.staging / "map.yaml", door_map(True))
        out.commit()
    b = write_trinary(tmp_path / "closed.yaml", door_map(False))
    start, goal = xy(10, 30), xy(50, 30)
    r = run(tmp_path / "open", "--start", start, "--goal", goal)
    assert r.exit_code == 0, r.output
    assert "path length:  2.000 m (40.00 cells" in r.output  # straight through the door
    r = run(b, "--start", start, "--goal", goal)
    assert r.exit_code == 1
    assert r.output.startswith("ltmap: error: no path from start") and len(r.output.splitlines()) == 1


def test_cli_closed_door_longer_detour(tmp_path):
    a = write_trinary(tmp_path / "a.yaml", door_map(True, second_door=True))
    b = write_trinary(tmp_path / "b.yaml", door_map(False, second_door=True))
    start, goal = xy(10, 30), xy(50, 30)
    ra = json.loads(run(a, "--start", start, "--goal", goal, "--json").output)
    assert ra["length_cells"] == pytest.approx(40.0)
    # a point robot through the second door (cols 46..57): no corner cutting, so from (10, 30)
    # to (29, 46) [16 diagonal + 3 straight], (29, 46) -> (31, 46) [2], (31, 46) -> (50, 30)
    # [16 diagonal + 3 straight]: 32 sqrt(2) + 8
    rb = json.loads(run(b, "--start", start, "--goal", goal, "--json", "--robot-radius", "0").output)
    assert rb["length_cells"] == pytest.approx(32 * S2 + 8, abs=1e-9)
    assert rb["length_m"] == pytest.approx((32 * S2 + 8) * RES)
    assert rb["path"][0] == pytest.approx([30.5 * RES, 10.5 * RES])
    # with the default 0.2 m radius the detour is longer still, and optimal
    rr = json.loads(run(b, "--start", start, "--goal", goal, "--json").output)
    blocked = blocked_grid(GridMap(door_map(False, second_door=True), RES), 0.2)
    assert rr["length_cells"] == pytest.approx(dijkstra(blocked, (10, 30), (50, 30)), abs=1e-9)
    assert rr["length_cells"] > rb["length_cells"]


def test_cli_unknown_cells(tmp_path):
    d = np.zeros((30, 30), np.int8)
    d[15, :] = -1  # an unknown band across the map
    p = write_trinary(tmp_path / "m.yaml", d)
    start, goal = xy(5, 15), xy(25, 15)
    r = run(p, "--start", start, "--goal", goal)
    assert r.exit_code == 1 and "--allow-unknown" in r.output
    r = run(p, "--start", start, "--goal", goal, "--allow-unknown")
    assert r.exit_code == 0 and "unknown cells allowed" in r.output
    r = run(p, "--start", xy(15, 3), "--goal", goal)
    assert r.exit_code == 2 and "start" in r.output and "unknown" in r.output


def test_cli_bad_start_and_goal(tmp_path):
    d = door_map(True)
    p = write_trinary(tmp_path / "m.yaml", d, origin=(-1.0, -1.0, 0.0))
    o = (-1.0, -1.0)
    good = xy(10, 10, o)
    r = run(p, "--start", xy(30, 5, o), "--goal", good)
    assert r.exit_code == 2
    assert r.output.startswith("ltmap: error: start (") and "inside an obstacle" in r.output
    assert "row 30, col 5" in r.output and len(r.output.splitlines()) == 1
    r = run(p, "--start", good, "--goal", xy(32, 5, o))
    assert r.exit_code == 2 and "goal" in r.output and "robot radius" in r.output
    r = run(p, "--start", good, "--goal", "10,0.5")
    assert r.exit_code == 2 and "goal (10, 0.5) is off the map" in r.output
    r = run(p, "--start", good, "--goal", good, "--robot-radius", "nan")
    assert r.exit_code == 2 and "--robot-radius nan is not a radius" in r.output and "Traceback" not in r.output
    r = run(p, "--start", "abc", "--goal", good)
    assert r.exit_code == 2 and "x,y" in r.output
    r = run(tmp_path / "nothere", "--start", good, "--goal", good)
    assert r.exit_code == 2 and "nothere" in r.output


def test_cli_png_and_json(tmp_path):
    p = write_trinary(tmp_path / "m.yaml", door_map(True))
    png = tmp_path / "plan.png"
    r = run(p, "--start", xy(10, 30), "--goal", xy(50, 30), "--png", png, "--json")
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    assert rep["expanded"] >= 41 and rep["robot_radius"] == 0.2 and rep["allow_unknown"] is False
    assert len(rep["path"]) == 41 and rep["start_cell"] == [10, 30] and rep["goal_cell"] == [50, 30]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from PIL import Image

    with Image.open(png) as im:
        im.verify()
        assert im.size[0] > 300


def test_library_errors_are_ltmap_errors():
    g = GridMap(door_map(False), RES)
    with pytest.raises(InputError, match="goal"):
        plan_on_grid(g, (0.5, 0.5), (50.0, 0.5))
    with pytest.raises(NoPathError):
        plan_on_grid(g, (0.5, 0.5), (0.5, 2.5))


def test_search_time_leaves_out_the_kernels_compiling(monkeypatch):
    """plan_on_grid's ``seconds`` (the CLI's "expanded ... in N ms") is the search alone: its
    kernel is compiled, or loaded from the cache, before the clock starts, with the very
    specialization the search then calls (a first run reported 4.5 s of compiling as the
    search's time)."""
    from ltmap_cli.analysis import planner

    astar, search = planner._astar, planner.plan_path
    calls = []
    monkeypatch.setattr(planner, "_astar", lambda *a: calls.append("kernel") or astar(*a))
    monkeypatch.setattr(planner, "plan_path", lambda *a: calls.append("timed search") or search(*a))
    grid = GridMap(np.zeros((40, 60), dtype=np.int8), RES, (0.0, 0.0, 0.0))
    res = planner.plan_on_grid(grid, (0.3, 0.3), (2.7, 1.7), robot_radius=0.1)
    assert res.length_cells > 0 and res.seconds >= 0
    assert calls == ["kernel", "timed search", "kernel"]  # the kernel called once before the clock
    assert len(astar.signatures) == 1  # the warm-up call and the search: one compiled specialization
