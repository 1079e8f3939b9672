"""Planner latency (SPEC 6): when does the robot's A* path change because of an event?

During a replay with ``--plan-goal``, ``PlanTracker.update`` plans on P from the robot's current
position to the goal at every planning tick and records the path, and which cells of the previous
path are blocked now. After the run, ``attribute`` gives each event its planner latency:

- appear: a planning tick at which a cell of the previous path is blocked within the event's
  footprint (its xy extent grown by the robot radius): the path had to change because of it;
- disappear: a planning tick at which the new path runs through the event's own cells (its xy
  extent), which the previous path, planned while they were occupied, did not.

The change is credited to the event only while the event is changing P: at a planning tick from
the first to the last tick at which its voxels changed P (``t_in_map_s`` .. ``t_in_map_last_s``),
or the first planning tick after that. A path that changes later (the robot drove elsewhere, and
a shorter route now happens to cross the cells) was not changed by the event; an event that
never changed P changed no path.

Latency = that tick's time - the event's ``t_start_s``. Paths are kept in world coordinates (the
grid grows during a replay).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..io.mapfile import GridMap
from . import cell_to_world, world_to_cell
from .planner import blocked_grid, plan_path


@dataclass
class PlanRecord:
    t_s: float
    path_xy: np.ndarray | None  # (K, 2) cell centres, None when no path
    newly_blocked_xy: np.ndarray  # (M, 2) cells of the previous path blocked now
    length_m: float | None
    status: str = "path"  # or why there is none: "no path", "goal off the map", "robot off the map"


@dataclass
class PlanTracker:
    goal_xy: tuple[float, float]
    robot_radius: float = 0.2
    allow_unknown: bool = True
    records: list[PlanRecord] = field(default_factory=list)

    def update(self, t_s: float, grid: GridMap, robot_xy: tuple[float, float]) -> PlanRecord:
        blocked = blocked_grid(grid, self.robot_radius, allow_unknown=self.allow_unknown)
        H, W = blocked.shape
        prev = self.records[-1].path_xy if self.records else None
        newly = np.zeros((0, 2))
        if prev is not None and len(prev):
            r, c = world_to_cell(grid, prev[:, 0], prev[:, 1])
            r, c = np.asarray(r), np.asarray(c)
            inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
            hit = np.zeros(len(prev), dtype=bool)
            hit[inside] = blocked[r[inside], c[inside]]
            newly = prev[hit]
        path_xy, length = None, None
        sr, sc = (int(v) for v in world_to_cell(grid, robot_xy[0], robot_xy[1]))
        gr, gc = (int(v) for v in world_to_cell(grid, self.goal_xy[0], self.goal_xy[1]))
        if not (0 <= gr < H and 0 <= gc < W):
            status = "goal off the map"
        elif not (0 <= sr < H and 0 <= sc < W):
            status = "robot off the map"
        else:
            res = plan_path(blocked, (sr, sc), (gr, gc))
            status = "no path"
            if res is not None:
                x, y = cell_to_world(grid, res.path_rc[:, 0], res.path_rc[:, 1])
                path_xy = np.stack([np.asarray(x, dtype=float), np.asarray(y, dtype=float)], axis=1)
                length = float(res.length_cells * grid.resolution)
                status = "path"
        rec = PlanRecord(t_s, path_xy, newly, length, status)
        self.records.append(rec)
        return rec

    def summary(self) -> dict:
        """Plans by outcome, and a warning when no tick found a path (no planner latency then)."""
        by: dict[str, int] = {}
        for rec in self.records:
            by[rec.status] = by.get(rec.status, 0) + 1
        final = self.records[-1] if self.records else None
        out = {"goal": list(self.goal_xy), "plans": len(self.records), "plans_by_outcome": by,
               "final_length_m": final.length_m if final else None}  # fmt: skip
        if not by.get("path"):
            why = max((k for k in by), key=lambda k: by[k]) if by else "no tick was planned"
            out["warning"] = (f"--plan-goal {self.goal_xy[0]:g},{self.goal_xy[1]:g}: no path at any of "
                              f"{len(self.records)} ticks ({why}), so no planner latency; choose a goal "
                              f"on free space of the map")  # fmt: skip
        return out

    @property
    def final_path_xy(self) -> np.ndarray | None:
        return self.records[-1].path_xy if self.records else None

    def _footprint(self, e: dict, margin: float) -> tuple[np.ndarray, np.ndarray]:
        lo = np.array(e["extent_min"][:2]) - margin
        hi = np.array(e["extent_max"][:2]) + margin
        return lo, hi

    @staticmethod
    def _any_inside(xy: np.ndarray | None, lo: np.ndarray, hi: np.ndarray) -> bool:
        if xy is None or not len(xy):
            return False
        return bool((((xy >= lo) & (xy <= hi)).all(axis=1)).any())

    def attribute(self, events: list[dict], resolution: float) -> None:
        """Set ``planner_latency_s`` (and ``t_plan_change_s``) of each event, or leave None."""
        eps = 1e-9
        for e in events:
            t_p0, t_p1 = e.get("t_in_map_s"), e.get("t_in_map_last_s", e.get("t_in_map_s"))
            if t_p0 is None:
                continue  # P never showed it: no path could change because of it
            start = e["t_start_s"] if e["t_start_s"] is not None else t_p0
            if e["kind"] == "appear":  # cells the inflated event blocks
                lo, hi = self._footprint(e, self.robot_radius + resolution)
            else:  # the event's own cells (path cell centres lie within half a cell of them)
                lo, hi = self._footprint(e, 0.0)
            prev_path = None
            for rec in self.records:
                if rec.t_s < t_p0 - eps:
                    prev_path = rec.path_xy
                    continue
                if e["kind"] == "appear":
                    changed = self._any_inside(rec.newly_blocked_xy, lo, hi)
                else:
                    changed = self._any_inside(rec.path_xy, lo, hi) and not self._any_inside(prev_path, lo, hi)
                if changed:
                    e["planner_latency_s"] = float(rec.t_s - start)
                    e["t_plan_change_s"] = float(rec.t_s)
                    break
                if rec.t_s > t_p1 + eps:
                    break  # the first planning tick after the event's last P change: too late
                prev_path = rec.path_xy
