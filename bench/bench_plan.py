"""Benchmark of the A* planner and the obstacle inflation on a 2000 x 2000 office-like map.

The map (0.05 m cells, 100 m x 100 m) is a grid of rooms separated by 0.1 m walls, each wall
segment with a 1 m door at a random place, plus random furniture boxes kept clear of doors.
The planner goes from the lower-left room to the upper-right room (a long path that has to
thread doors), and also across an empty 2000 x 2000 map (the heuristic's best case).

Times are after a warm-up call (numba compiles on first use; cached on disk afterwards).
Run: python bench/bench_plan.py [--size 2000] [--repeat 5] [--seed 1]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from ltmap_cli.analysis.planner import inflate, plan_path


def office_map(
    size: int = 2000, room: int = 200, wall: int = 2, door: int = 20, boxes: int | None = None, seed: int = 1
):
    """bool (size, size) occupied grid of an office-like maze."""
    rng = np.random.default_rng(seed)
    if boxes is None:
        boxes = int(900 * (size / 2000) ** 2)  # 9 per 10 m x 10 m room
    occ = np.zeros((size, size), dtype=bool)
    occ[:wall, :] = occ[-wall:, :] = True
    occ[:, :wall] = occ[:, -wall:] = True
    doors = np.zeros_like(occ)
    lines = list(range(room, size - wall, room))
    for x in lines:  # vertical walls, one door per room-height segment
        occ[:, x : x + wall] = True
        for y0 in range(0, size, room):
            y1 = min(y0 + room, size)
            if y1 - y0 < door + 2 * wall + 2:
                continue
            d = int(rng.integers(y0 + wall + 1, y1 - door - 1))
            occ[d : d + door, x : x + wall] = False
            doors[max(d - 15, 0) : d + door + 15, max(x - 15, 0) : x + wall + 15] = True
    for y in lines:  # horizontal walls
        occ[y : y + wall, :] = True
        for x0 in range(0, size, room):
            x1 = min(x0 + room, size)
            if x1 - x0 < door + 2 * wall + 2:
                continue
            d = int(rng.integers(x0 + wall + 1, x1 - door - 1))
            occ[y : y + wall, d : d + door] = False
            doors[max(y - 15, 0) : y + wall + 15, max(d - 15, 0) : d + door + 15] = True
    # re-close the wall crossings that a door may have cut
    for x in lines:
        for y in lines:
            occ[y : y + wall, x : x + wall] = True
    for r, c in ((100, 100), (size - 100, size - 100)):  # keep the benchmark's start and goal clear
        doors[r - 15 : r + 16, c - 15 : c + 16] = True
    placed = 0
    while placed < boxes:
        h, w = (int(v) for v in rng.integers(6, 30, size=2))
        r, c = (int(v) for v in rng.integers(wall, size - wall - 30, size=2))
        if doors[r : r + h, c : c + w].any():
            continue
        occ[r : r + h, c : c + w] = True
        placed += 1
    return occ


def timed(fn, repeat: int):
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--radius-cells", type=float, default=4.0, help="inflation radius (0.2 m at 0.05 m)")
    args = ap.parse_args()

    n = args.size
    occ = office_map(n, seed=args.seed)
    print(
        f"map: {n} x {n} cells ({n * 0.05:g} m x {n * 0.05:g} m at 0.05 m), {occ.mean() * 100:.1f} % occupied"
    )

    t0 = time.perf_counter()
    inflate(occ[:50, :50], args.radius_cells)
    plan_path(np.zeros((8, 8), bool), (0, 0), (7, 7))
    print(f"warm-up (numba compile or cache load): {time.perf_counter() - t0:.2f} s")

    blocked, t_inf = timed(lambda: inflate(occ, args.radius_cells), args.repeat)
    print(
        f"inflate r={args.radius_cells:g} cells: median {statistics.median(t_inf) * 1e3:.1f} ms "
        f"(min {min(t_inf) * 1e3:.1f}, max {max(t_inf) * 1e3:.1f}) over {args.repeat} runs; "
        f"{blocked.mean() * 100:.1f} % blocked"
    )

    start, goal = (100, 100), (n - 100, n - 100)
    if n < 400:
        raise SystemExit("--size must be >= 400")
    assert not blocked[start] and not blocked[goal], "start or goal blocked: pick another seed"
    res, t_plan = timed(lambda: plan_path(blocked, start, goal), args.repeat)
    if res is None:
        print("office maze: no path (pick another seed)")
    else:
        octile = (n - 200) * np.sqrt(2)
        print(
            f"plan_path office maze {start} -> {goal}: median {statistics.median(t_plan) * 1e3:.1f} ms "
            f"(min {min(t_plan) * 1e3:.1f}, max {max(t_plan) * 1e3:.1f}); length {res.length_cells:.1f} cells "
            f"({res.length_cells / octile:.2f} x the straight diagonal), {res.expanded} cells expanded "
            f"({res.expanded / blocked.size * 100:.1f} % of the map)"
        )

    empty = np.zeros((n, n), dtype=bool)
    res_e, t_e = timed(lambda: plan_path(empty, (0, 0), (n - 1, n - 1)), args.repeat)
    print(
        f"plan_path empty map corner -> corner: median {statistics.median(t_e) * 1e3:.1f} ms; "
        f"length {res_e.length_cells:.1f} cells, {res_e.expanded} expanded"
    )

    # the goal is unreachable (enclosed): without the planner's connectivity check A* would
    # expand every cell reachable from the start before giving up
    walled = blocked.copy()
    walled[n - 200 : n - 1, n - 200] = True
    walled[n - 200, n - 200 : n - 1] = True
    walled[n - 1, :] = True
    walled[:, n - 1] = True
    res_w, t_w = timed(lambda: plan_path(walled, start, goal), args.repeat)
    print(
        f"plan_path unreachable (enclosed) goal: median {statistics.median(t_w) * 1e3:.1f} ms; "
        f"result {'none' if res_w is None else 'path'}"
    )


if __name__ == "__main__":
    main()
