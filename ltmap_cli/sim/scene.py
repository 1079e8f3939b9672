"""The simulated world at a time t, as primitives, and exact ray casting against it.

Primitives (all in the map frame, metres):

- wall faces: vertical rectangles over a 2D segment ``(x1, y1, x2, y2, z0, z1)``; a wall polygon
  extruded from 0 to ``wall_height`` is the set of its boundary edges (a ray can only enter a
  closed extruded polygon through a side face while it stays below the top);
- boxes: centre, half sizes, yaw (slab method in the box frame); a door leaf is one, turned about
  its hinge (hinged) or shifted along the door line (sliding) as the door opens;
- vertical cylinders: centre x, y, radius, z0, z1 (side and both caps);
- spheres: centre, radius;
- the floor plane z = 0 and an optional ceiling plane.

``cast`` returns, for each ray ``o + t d`` (``d`` need not be unit length), the smallest ``t > 0``
at which it meets a primitive, or +inf. With unit ``d`` that is the range; with a camera ray
``d = ((u - cx) / fx, (v - cy) / fy, 1)`` in the optical frame it is the z-depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..jit import njit
from .scenario import Door, Obj, Person, Scenario

EPS = 1e-9


@njit(cache=True, inline="always")
def _slab(lo, ld, h, tn, tf):  # pragma: no cover - compiled
    """Clip the interval (tn, tf) of a ray to the slab |x| <= h along one axis."""
    if abs(ld) < 1e-15:
        return tn, tf, -h <= lo <= h
    t1 = (-h - lo) / ld
    t2 = (h - lo) / ld
    if t1 > t2:
        t1, t2 = t2, t1
    tn = max(tn, t1)
    tf = min(tf, t2)
    return tn, tf, tn <= tf


@njit(cache=True)
def _cast_kernel(o, d, segs, boxes, cyls, sphs, floor, ceiling, out):  # pragma: no cover - compiled
    n = o.shape[0]
    for i in range(n):
        ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        best = np.inf
        if floor and dz < 0.0:
            t = -oz / dz
            if t > EPS:
                best = t
        if ceiling > 0.0 and dz > 0.0:
            t = (ceiling - oz) / dz
            if EPS < t < best:
                best = t
        # vertical wall faces
        for k in range(segs.shape[0]):
            x1, y1 = segs[k, 0], segs[k, 1]
            ex, ey = segs[k, 2] - x1, segs[k, 3] - y1
            den = dx * ey - dy * ex
            if abs(den) < 1e-15:
                continue
            wx, wy = x1 - ox, y1 - oy
            t = (wx * ey - wy * ex) / den
            if t <= EPS or t >= best:
                continue
            s = (wx * dy - wy * dx) / den
            if s < 0.0 or s > 1.0:
                continue
            z = oz + t * dz
            if segs[k, 4] <= z <= segs[k, 5]:
                best = t
        # oriented boxes: cx, cy, cz, hx, hy, hz, cos(yaw), sin(yaw)
        for k in range(boxes.shape[0]):
            c, sn = boxes[k, 6], boxes[k, 7]
            px, py, pz = ox - boxes[k, 0], oy - boxes[k, 1], oz - boxes[k, 2]
            lx = c * px + sn * py
            ly = -sn * px + c * py
            ldx = c * dx + sn * dy
            ldy = -sn * dx + c * dy
            tn, tf, hit = _slab(lx, ldx, boxes[k, 3], -np.inf, np.inf)
            if hit:
                tn, tf, hit = _slab(ly, ldy, boxes[k, 4], tn, tf)
            if hit:
                tn, tf, hit = _slab(pz, dz, boxes[k, 5], tn, tf)
            if hit and EPS < tn < best:
                best = tn
        # vertical cylinders: cx, cy, r, z0, z1
        for k in range(cyls.shape[0]):
            px, py = ox - cyls[k, 0], oy - cyls[k, 1]
            r, z0, z1 = cyls[k, 2], cyls[k, 3], cyls[k, 4]
            a = dx * dx + dy * dy
            if a > 1e-20:
                b = px * dx + py * dy
                cc = px * px + py * py - r * r
                disc = b * b - a * cc
                if disc >= 0.0:
                    t = (-b - math.sqrt(disc)) / a
                    if EPS < t < best:
                        z = oz + t * dz
                        if z0 <= z <= z1:
                            best = t
            for zc in (z0, z1):
                if abs(dz) > 1e-15:
                    t = (zc - oz) / dz
                    if EPS < t < best:
                        qx, qy = px + t * dx, py + t * dy
                        if qx * qx + qy * qy <= r * r:
                            best = t
        # spheres: cx, cy, cz, r
        for k in range(sphs.shape[0]):
            px, py, pz = ox - sphs[k, 0], oy - sphs[k, 1], oz - sphs[k, 2]
            r = sphs[k, 3]
            a = dx * dx + dy * dy + dz * dz
            b = px * dx + py * dy + pz * dz
            cc = px * px + py * py + pz * pz - r * r
            disc = b * b - a * cc
            if disc >= 0.0:
                t = (-b - math.sqrt(disc)) / a
                if EPS < t < best:
                    best = t
        out[i] = best


@dataclass
class Primitives:
    """What rays can hit at one instant."""

    segs: np.ndarray  # (S, 6)
    boxes: np.ndarray  # (B, 8)
    cyls: np.ndarray  # (C, 5)
    sphs: np.ndarray  # (K, 4)
    floor: bool = True
    ceiling: float = 0.0  # 0: none

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        o = np.ascontiguousarray(np.broadcast_to(np.asarray(origins, np.float64), np.shape(dirs)))
        d = np.ascontiguousarray(dirs, dtype=np.float64)
        out = np.empty(len(d), dtype=np.float64)
        _cast_kernel(
            o.reshape(-1, 3),
            d.reshape(-1, 3),
            self.segs,
            self.boxes,
            self.cyls,
            self.sphs,
            self.floor,
            float(self.ceiling),
            out,
        )
        return out


def box_row(cx, cy, cz, sx, sy, sz, yaw_rad) -> list[float]:
    return [cx, cy, cz, sx / 2, sy / 2, sz / 2, math.cos(yaw_rad), math.sin(yaw_rad)]


# ----------------------------------------------------------------------------- object geometry


def object_parts(o: Obj) -> list[dict]:
    """The primitives of an object in the map frame, as ground-truth dicts:
    ``{"type": "box", "center": [x, y, z], "size": [sx, sy, sz], "yaw_deg": a}``,
    ``{"type": "cylinder", "center": [x, y], "radius": r, "z": [z0, z1]}``,
    ``{"type": "sphere", "center": [x, y, z], "radius": r}``."""
    yaw = math.radians(o.yaw_deg)
    c, s = math.cos(yaw), math.sin(yaw)

    def world(lx: float, ly: float) -> tuple[float, float]:
        return o.x + c * lx - s * ly, o.y + s * lx + c * ly

    def box(lx, ly, z0, sx, sy, sz) -> dict:
        wx, wy = world(lx, ly)
        return {"type": "box", "center": [wx, wy, z0 + sz / 2], "size": [sx, sy, sz], "yaw_deg": o.yaw_deg}

    if o.kind == "box":
        return [box(0.0, 0.0, o.z, *o.size)]
    if o.kind == "cylinder":
        return [{"type": "cylinder", "center": [o.x, o.y], "radius": o.radius, "z": [o.z, o.z + o.height]}]
    if o.kind == "sphere":
        return [{"type": "sphere", "center": [o.x, o.y, o.z], "radius": o.radius}]
    sx, sy, h = o.size
    leg, top = o.leg, o.top_thickness
    parts = [box(0.0, 0.0, o.z + h - top, sx, sy, top)]  # table top / chair seat
    for ix in (-1, 1):
        for iy in (-1, 1):
            parts.append(box(ix * (sx - leg) / 2, iy * (sy - leg) / 2, o.z, leg, leg, h - top))
    if o.kind == "chair":  # backrest on the local -x side
        parts.append(box(-(sx - leg) / 2, 0.0, o.z + h, leg, sy, o.back_height - h))
    return parts


def door_part(d: Door) -> dict:
    """The closed leaf: a box filling the opening from ``p1`` to ``p2``."""
    return door_leaf(d, 0.0)


def door_leaf(d: Door, f: float) -> dict:
    """The leaf of a door open by the fraction ``f`` (0: closed, 1: open), as a ground-truth box.

    hinged: turned about the hinge at ``p1`` by ``f * open_angle_deg`` to the ``swing`` side;
    sliding: shifted along the door line toward ``p1`` by ``f`` times the width; box: closed."""
    (x1, y1), (x2, y2) = d.p1, d.p2
    length = math.hypot(x2 - x1, y2 - y1)
    yaw = math.atan2(y2 - y1, x2 - x1)
    cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
    if f > 0.0 and d.kind == "hinged":
        yaw += d.swing * math.radians(f * d.open_angle_deg)
        cx, cy = x1 + length / 2 * math.cos(yaw), y1 + length / 2 * math.sin(yaw)
    elif f > 0.0 and d.kind == "sliding":
        cx, cy = cx - f * (x2 - x1), cy - f * (y2 - y1)
    return {
        "type": "box",
        "center": [cx, cy, d.height / 2],
        "size": [length, d.thickness, d.height],
        "yaw_deg": math.degrees(yaw),
    }


def door_open_fraction(d: Door, t: float) -> float:
    """How far a door is open at time t: 0 during its ``closed`` intervals, 1 well outside them,
    linear over the ``motion_s`` before each ``t_on`` (closing) and after each ``t_off`` (opening).
    With intervals closer than ``2 * motion_s`` the door does not open fully in between."""
    f = 1.0
    m = d.motion_s if d.kind != "box" else 0.0
    for on, off in d.closed:
        if on <= t < off:
            return 0.0
        if m > 0.0 and on - m < t < on:
            f = min(f, (on - t) / m)
        elif m > 0.0 and off <= t < off + m:
            f = min(f, (t - off) / m)
    return f


def door_motion(d: Door, duration: float) -> list[list[float]]:
    """The intervals (within the log) during which a hinged or sliding door moves."""
    if d.kind == "box" or d.motion_s <= 0.0:
        return []
    out: list[list[float]] = []
    bounds = [0.0] + [x for iv in d.closed for x in iv] + [duration]
    for i, (on, off) in enumerate(d.closed):
        # closing after the previous interval's end, opening until the next one's start
        for a, b in (
            (max(on - d.motion_s, bounds[2 * i]), on),
            (off, min(off + d.motion_s, bounds[2 * i + 3])),
        ):
            if b > a:
                if out and a <= out[-1][1]:
                    out[-1][1] = max(out[-1][1], b)
                else:
                    out.append([a, b])
    return out


def door_at(d: Door, t: float) -> dict | None:
    """The door's leaf at time t, or None when there is none (an open ``box`` door)."""
    if d.kind == "box":
        return door_part(d) if active(d.closed, t) else None
    return door_leaf(d, door_open_fraction(d, t))


def active(intervals: list[tuple[float, float]], t: float) -> bool:
    return any(on <= t < off for on, off in intervals)


def person_at(p: Person, t: float) -> tuple[float, float] | None:
    ts = [q[0] for q in p.path]
    if t < ts[0] or t > ts[-1]:
        return None
    return float(np.interp(t, ts, [q[1] for q in p.path])), float(np.interp(t, ts, [q[2] for q in p.path]))


# ----------------------------------------------------------------------------- the world


class World:
    """A scenario's geometry: static walls once, then the primitives at any time."""

    def __init__(self, sc: Scenario):
        self.sc = sc
        self.wall_geometry = wall_geometry(sc)
        self.segs = wall_segments(self.wall_geometry, sc.wall_height)
        self.object_parts = {o.id: object_parts(o) for o in sc.objects}
        self.door_parts = {d.id: door_part(d) for d in sc.doors}

    def at(self, t: float) -> Primitives:
        boxes: list[list[float]] = []
        cyls: list[list[float]] = []
        sphs: list[list[float]] = []
        parts = [p for o in self.sc.objects if active(o.present, t) for p in self.object_parts[o.id]]
        parts += [leaf for d in self.sc.doors if (leaf := door_at(d, t)) is not None]
        for p in parts:
            if p["type"] == "box":
                boxes.append(box_row(*p["center"], *p["size"], math.radians(p["yaw_deg"])))
            elif p["type"] == "cylinder":
                cyls.append([p["center"][0], p["center"][1], p["radius"], p["z"][0], p["z"][1]])
            else:
                sphs.append([*p["center"], p["radius"]])
        for person in self.sc.people:
            xy = person_at(person, t)
            if xy is not None:
                cyls.append([xy[0], xy[1], person.radius, 0.0, person.height])
        return Primitives(
            self.segs,
            np.array(boxes, dtype=np.float64).reshape(-1, 8),
            np.array(cyls, dtype=np.float64).reshape(-1, 5),
            np.array(sphs, dtype=np.float64).reshape(-1, 4),
            True,
            self.sc.ceiling or 0.0,
        )


def wall_geometry(sc: Scenario):
    """The union of the plan's walls and windows (doors are openings) and the scenario's wall
    lines, as a shapely geometry in metres (None when there are no walls)."""
    import shapely

    polys = []
    if sc.plan is not None:
        from ..static.svgplan import parse_plan

        plan = parse_plan(sc.plan, scale=sc.plan_scale)
        polys += [
            s.region for s in plan.of("walls", "windows") if s.region is not None and not s.region.is_empty
        ]
    for w in sc.walls:
        line = shapely.LineString(w.points)
        polys.append(line.buffer(w.thickness / 2, cap_style="flat", join_style="mitre"))
    if not polys:
        return None
    return shapely.union_all(polys)


def wall_segments(geom, height: float) -> np.ndarray:
    """Boundary edges of a (multi)polygon as vertical faces from 0 to ``height``."""
    import shapely

    rows: list[list[float]] = []
    if geom is not None:
        for poly in shapely.get_parts(geom):
            if poly.geom_type != "Polygon":
                continue
            for ring in (poly.exterior, *poly.interiors):
                xy = np.asarray(ring.coords)
                for a, b in zip(xy[:-1], xy[1:]):
                    if np.hypot(*(b - a)) > 1e-9:
                        rows.append([a[0], a[1], b[0], b[1], 0.0, height])
    return np.array(rows, dtype=np.float64).reshape(-1, 6)


# ----------------------------------------------------------------------------- the robot


def robot_pose(sc: Scenario, t: float) -> tuple[float, float, float]:
    """True pose (x, y, yaw in radians) of base_link in the map frame at time t."""
    r = sc.robot
    if len(r.waypoints) == 1:
        _, x, y, yaw = r.waypoints[0]
        if r.sweep_deg:
            yaw = yaw + r.sweep_deg / 2 * math.sin(2 * math.pi * t / r.sweep_period)
        return x, y, math.radians(yaw)
    ts = [w[0] for w in r.waypoints]
    return (
        float(np.interp(t, ts, [w[1] for w in r.waypoints])),
        float(np.interp(t, ts, [w[2] for w in r.waypoints])),
        math.radians(float(np.interp(t, ts, [w[3] for w in r.waypoints]))),
    )
