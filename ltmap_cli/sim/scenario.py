"""The scenario file of ``ltmap simulate``: a YAML description, validated into plain dataclasses.

Units: metres, seconds, and **degrees** for every angle (yaw, roll/pitch/yaw of mounts, fields of
view, camera pitch). Times are seconds from the start of the log. The schema is documented with
an example in docs/scenarios.md; every error is one ``ConfigError`` line naming the file and key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError

OBJECT_KINDS = ("box", "cylinder", "sphere", "table", "chair")
ENCODINGS = ("16UC1", "32FC1")
DOOR_KINDS = ("box", "hinged", "sliding")
SWINGS = {"left": 1, "right": -1, 1: 1, -1: -1}


@dataclass
class Mount:
    xyz: tuple[float, float, float]
    rpy_deg: tuple[float, float, float]


@dataclass
class Laser:
    topic: str = "/scan"
    frame: str = "laser"
    mount: Mount = field(default_factory=lambda: Mount((0.0, 0.0, 0.25), (0.0, 0.0, 0.0)))
    beams: int = 360
    fov_deg: float = 360.0
    range_min: float = 0.05
    range_max: float = 10.0
    rate: float = 10.0
    noise: float = 0.0
    dropout: float = 0.0


@dataclass
class Depth:
    topic: str = "/camera/depth/image_raw"
    info_topic: str = "/camera/depth/camera_info"
    frame: str = "camera_link"
    optical_frame: str = "camera_depth_optical_frame"
    mount: Mount = field(default_factory=lambda: Mount((0.1, 0.0, 1.0), (0.0, 0.0, 0.0)))
    pitch_deg: float = 0.0  # downward tilt, added to the mount's pitch
    width: int = 640
    height: int = 480
    fx: float = 525.0
    fy: float = 525.0
    cx: float = 319.5
    cy: float = 239.5
    rate: float = 2.5
    range_min: float = 0.2
    range_max: float = 8.0
    noise: float = 0.0
    quantization: float = 0.0  # disparity-like steps: depth rounded to multiples of q * z^2
    dropout: float = 0.0  # the share of pixels, drawn at random, without a return
    edge_dropout: int = 0  # pixels without a return up to this many from a depth edge (a jump of EDGE_JUMP)
    encoding: str = "16UC1"


@dataclass
class Points:
    topic: str = "/points"
    frame: str = "lidar"
    mount: Mount = field(default_factory=lambda: Mount((0.0, 0.0, 0.5), (0.0, 0.0, 0.0)))
    beams: int = 360
    channels: int = 16
    vfov_deg: tuple[float, float] = (-15.0, 15.0)
    range_min: float = 0.1
    range_max: float = 10.0
    rate: float = 5.0
    noise: float = 0.0


@dataclass
class Robot:
    radius: float = 0.25
    waypoints: list[tuple[float, float, float, float]] = field(default_factory=list)  # t, x, y, yaw_deg
    sweep_deg: float = 0.0  # standing still: yaw = yaw0 + sweep/2 * sin(2 pi t / period)
    sweep_period: float = 10.0
    odometry_drift: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m/s, m/s, deg/s
    tf_rate: float = 50.0
    odom_rate: float = 20.0


@dataclass
class Obj:
    id: str
    kind: str  # box | cylinder | sphere | table | chair
    label: str  # ground-truth kind: "static object", "table", "ball", ...
    x: float
    y: float
    z: float
    yaw_deg: float
    size: tuple[float, float, float]  # box: sx, sy, sz; table: sx, sy, height; chair: sx, sy, seat height
    radius: float  # cylinder / sphere
    height: float  # cylinder
    present: list[tuple[float, float]]
    leg: float = 0.05  # table / chair leg side
    top_thickness: float = 0.04  # table top / chair seat
    back_height: float = 0.9  # chair backrest top


@dataclass
class Door:
    """A door in the opening from ``p1`` to ``p2``, closed during the ``closed`` intervals.

    ``box``: a leaf filling the opening while closed, nothing while open. ``hinged``: a leaf
    rotating about a hinge at ``p1``, by ``open_angle_deg`` to the ``swing`` side (+1: left of the
    direction p1 -> p2, counterclockwise seen from above; -1: right) when open. ``sliding``: a leaf
    translating along the door line toward ``p1`` by the opening's width when open. Both move
    for ``motion_s`` seconds: closing ends at ``t_on``, opening starts at ``t_off``."""

    id: str
    p1: tuple[float, float]
    p2: tuple[float, float]
    thickness: float
    height: float
    closed: list[tuple[float, float]]
    kind: str = "box"  # box | hinged | sliding
    motion_s: float = 1.0
    open_angle_deg: float = 90.0
    swing: int = 1  # +1 left (counterclockwise), -1 right


@dataclass
class Person:
    id: str
    radius: float
    height: float
    path: list[tuple[float, float, float]]  # t, x, y


@dataclass
class WallLine:
    points: list[tuple[float, float]]
    thickness: float


@dataclass
class Scenario:
    source: Path
    name: str
    plan: Path | None
    plan_scale: float | None
    walls: list[WallLine]
    wall_height: float
    ceiling: float | None
    duration: float
    seed: int
    start_time: float
    robot: Robot
    laser: Laser | None
    depth: Depth | None
    points: Points | None
    objects: list[Obj]
    doors: list[Door]
    people: list[Person]


# ----------------------------------------------------------------------------- validation helpers


class _Ctx:
    def __init__(self, source: str):
        self.source = source

    def fail(self, key: str, what: str, todo: str) -> ConfigError:
        return ConfigError(f"{self.source}: {key}: {what}; {todo}")

    def mapping(self, value: Any, key: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> dict:
        if not isinstance(value, dict):
            raise self.fail(
                key, f"expected a mapping, got {_show(value)}", f"write {key} as key: value lines"
            )
        for k in value:
            if k not in allowed:
                raise self.fail(
                    f"{key}.{k}" if key else str(k),
                    "unknown key",
                    f"use one of {', '.join(allowed)} (see docs/scenarios.md)",
                )
        for k in required:
            if k not in value or value[k] is None:
                raise self.fail(f"{key}.{k}" if key else k, "missing", "add it (see docs/scenarios.md)")
        return value

    def number(
        self,
        d: dict,
        key: str,
        path: str,
        default: Any = None,
        *,
        lo: float | None = None,
        hi: float | None = None,
        lo_open: bool = False,
    ) -> float:
        v = d.get(key, default)
        full = f"{path}.{key}" if path else key
        if v is None:
            raise self.fail(full, "missing", "add a number (see docs/scenarios.md)")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.fail(full, f"expected a number, got {_show(v)}", "write a finite number")
        v = float(v)
        if lo is not None and (v <= lo if lo_open else v < lo):
            raise self.fail(full, f"{v:g} is too small", f"use a value {'>' if lo_open else '>='} {lo:g}")
        if hi is not None and v > hi:
            raise self.fail(full, f"{v:g} is too large", f"use a value <= {hi:g}")
        return v

    def vector(self, v: Any, n: int, path: str) -> tuple[float, ...]:
        if (
            not isinstance(v, (list, tuple))
            or len(v) != n
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in v)
        ):
            raise self.fail(
                path, f"expected a list of {n} numbers, got {_show(v)}", f"write [{', '.join(['0'] * n)}]"
            )
        return tuple(float(x) for x in v)

    def text(self, d: dict, key: str, path: str, default: str) -> str:
        v = d.get(key, default)
        if not isinstance(v, str) or not v:
            raise self.fail(f"{path}.{key}", f"expected a non-empty string, got {_show(v)}", "write a name")
        return v

    def intervals(self, v: Any, path: str, duration: float) -> list[tuple[float, float]]:
        if not isinstance(v, list):
            raise self.fail(
                path,
                f"expected a list of [t_on, t_off] pairs, got {_show(v)}",
                "write e.g. [[0, 10], [20, 30]] (t_off null: until the end)",
            )
        out: list[tuple[float, float]] = []
        for i, pair in enumerate(v):
            where = f"{path}[{i}]"
            if not isinstance(pair, (list, tuple)) or len(pair) != 2:
                raise self.fail(
                    where, f"expected [t_on, t_off], got {_show(pair)}", "write two times in seconds"
                )
            on, off = pair[0], pair[1] if pair[1] is not None else duration
            for x in (on, off):
                if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                    raise self.fail(
                        where, f"expected two numbers, got {_show(pair)}", "write two times in seconds"
                    )
            on, off = float(on), float(off)
            if on < 0 or off <= on:
                raise self.fail(
                    where, f"[{on:g}, {off:g}] is not an interval 0 <= t_on < t_off", "swap or fix the times"
                )
            if out and on < out[-1][1]:
                raise self.fail(
                    where,
                    f"starts at {on:g} s, before the previous interval ends ({out[-1][1]:g} s)",
                    "list intervals in time order without overlap",
                )
            out.append((on, off))
        return out


def _show(v: Any) -> str:
    from ..errors import shown

    return shown(v, 40)


def _mount(ctx: _Ctx, d: dict, path: str, default: Mount) -> Mount:
    if "mount" not in d:
        return default
    m = ctx.mapping(d["mount"], f"{path}.mount", ("xyz", "rpy"))
    xyz = ctx.vector(m.get("xyz", list(default.xyz)), 3, f"{path}.mount.xyz")
    rpy = ctx.vector(m.get("rpy", list(default.rpy_deg)), 3, f"{path}.mount.rpy")
    return Mount(xyz, rpy)  # type: ignore[arg-type]


def _topic(ctx: _Ctx, d: dict, key: str, path: str, default: str) -> str:
    t = ctx.text(d, key, path, default)
    return t if t.startswith("/") else "/" + t


# ----------------------------------------------------------------------------- sections


def _laser(ctx: _Ctx, v: Any) -> Laser:
    p = "sensors.laser"
    d = ctx.mapping(
        v,
        p,
        ("topic", "frame", "mount", "beams", "fov", "range_min", "range_max", "rate", "noise", "dropout"),
    )
    L = Laser()
    L.topic = _topic(ctx, d, "topic", p, L.topic)
    L.frame = ctx.text(d, "frame", p, L.frame)
    L.mount = _mount(ctx, d, p, L.mount)
    L.beams = int(ctx.number(d, "beams", p, L.beams, lo=1, hi=100000))
    L.fov_deg = ctx.number(d, "fov", p, L.fov_deg, lo=0, hi=360, lo_open=True)
    L.range_min = ctx.number(d, "range_min", p, L.range_min, lo=0)
    L.range_max = ctx.number(d, "range_max", p, L.range_max, lo=L.range_min, lo_open=True)
    L.rate = ctx.number(d, "rate", p, L.rate, lo=0, hi=1000, lo_open=True)
    L.noise = ctx.number(d, "noise", p, L.noise, lo=0)
    L.dropout = ctx.number(d, "dropout", p, L.dropout, lo=0, hi=1)
    return L


def _depth(ctx: _Ctx, v: Any) -> Depth:
    p = "sensors.depth"
    d = ctx.mapping(
        v,
        p,
        (
            "topic",
            "info_topic",
            "frame",
            "optical_frame",
            "mount",
            "pitch",
            "width",
            "height",
            "fx",
            "fy",
            "cx",
            "cy",
            "rate",
            "range_min",
            "range_max",
            "noise",
            "quantization",
            "dropout",
            "edge_dropout",
            "encoding",
        ),
    )
    D = Depth()
    D.topic = _topic(ctx, d, "topic", p, D.topic)
    D.info_topic = _topic(ctx, d, "info_topic", p, D.topic.rsplit("/", 1)[0] + "/camera_info")
    D.frame = ctx.text(d, "frame", p, D.frame)
    D.optical_frame = ctx.text(d, "optical_frame", p, D.optical_frame)
    D.mount = _mount(ctx, d, p, D.mount)
    D.pitch_deg = ctx.number(d, "pitch", p, 0.0, lo=-90, hi=90)
    D.width = int(ctx.number(d, "width", p, D.width, lo=1, hi=4096))
    D.height = int(ctx.number(d, "height", p, D.height, lo=1, hi=4096))
    D.fx = ctx.number(d, "fx", p, D.fx * D.width / 640.0, lo=0, lo_open=True)
    D.fy = ctx.number(d, "fy", p, D.fx, lo=0, lo_open=True)
    D.cx = ctx.number(d, "cx", p, (D.width - 1) / 2.0)
    D.cy = ctx.number(d, "cy", p, (D.height - 1) / 2.0)
    D.rate = ctx.number(d, "rate", p, D.rate, lo=0, hi=1000, lo_open=True)
    D.range_min = ctx.number(d, "range_min", p, D.range_min, lo=0)
    D.range_max = ctx.number(d, "range_max", p, D.range_max, lo=D.range_min, lo_open=True)
    D.noise = ctx.number(d, "noise", p, D.noise, lo=0)
    D.quantization = ctx.number(d, "quantization", p, D.quantization, lo=0, hi=1)
    D.dropout = ctx.number(d, "dropout", p, D.dropout, lo=0, hi=1)
    edge = ctx.number(d, "edge_dropout", p, D.edge_dropout, lo=0, hi=64)
    if edge != int(edge):
        raise ctx.fail(f"{p}.edge_dropout", f"{edge:g} is not a whole number of pixels", "use 0, 1, 2, ...")
    D.edge_dropout = int(edge)
    enc = d.get("encoding", D.encoding)
    if enc not in ENCODINGS:
        raise ctx.fail(
            f"{p}.encoding", f"unknown encoding {_show(enc)}", f"use one of {', '.join(ENCODINGS)}"
        )
    D.encoding = enc
    return D


def _points(ctx: _Ctx, v: Any) -> Points:
    p = "sensors.points"
    d = ctx.mapping(
        v,
        p,
        ("topic", "frame", "mount", "beams", "channels", "vfov", "range_min", "range_max", "rate", "noise"),
    )
    P = Points()
    P.topic = _topic(ctx, d, "topic", p, P.topic)
    P.frame = ctx.text(d, "frame", p, P.frame)
    P.mount = _mount(ctx, d, p, P.mount)
    P.beams = int(ctx.number(d, "beams", p, P.beams, lo=1, hi=100000))
    P.channels = int(ctx.number(d, "channels", p, P.channels, lo=1, hi=1024))
    vf = ctx.vector(d.get("vfov", list(P.vfov_deg)), 2, f"{p}.vfov")
    if not -90 <= vf[0] <= vf[1] <= 90:
        raise ctx.fail(f"{p}.vfov", f"{list(vf)} is not [low, high] within [-90, 90]", "write e.g. [-15, 15]")
    P.vfov_deg = vf  # type: ignore[assignment]
    P.range_min = ctx.number(d, "range_min", p, P.range_min, lo=0)
    P.range_max = ctx.number(d, "range_max", p, P.range_max, lo=P.range_min, lo_open=True)
    P.rate = ctx.number(d, "rate", p, P.rate, lo=0, hi=1000, lo_open=True)
    P.noise = ctx.number(d, "noise", p, P.noise, lo=0)
    return P


def _robot(ctx: _Ctx, v: Any, duration: float) -> Robot:
    d = ctx.mapping(v, "robot", ("radius", "path", "odometry_drift", "tf_rate", "odom_rate"), ("path",))
    R = Robot()
    R.radius = ctx.number(d, "radius", "robot", R.radius, lo=0, lo_open=True)
    R.tf_rate = ctx.number(d, "tf_rate", "robot", R.tf_rate, lo=1, hi=1000)
    R.odom_rate = ctx.number(d, "odom_rate", "robot", R.odom_rate, lo=0, hi=1000)
    if "odometry_drift" in d:
        R.odometry_drift = ctx.vector(d["odometry_drift"], 3, "robot.odometry_drift")  # type: ignore[assignment]
    path = ctx.mapping(d["path"], "robot.path", ("waypoints", "still"))
    if ("waypoints" in path) == ("still" in path):
        raise ctx.fail(
            "robot.path",
            "give exactly one of waypoints or still",
            "write waypoints: [{t, x, y, yaw}, ...] or still: {x, y, yaw, sweep, period}",
        )
    if "still" in path:
        s = ctx.mapping(path["still"], "robot.path.still", ("x", "y", "yaw", "sweep", "period"), ("x", "y"))
        x = ctx.number(s, "x", "robot.path.still")
        y = ctx.number(s, "y", "robot.path.still")
        yaw = ctx.number(s, "yaw", "robot.path.still", 0.0)
        R.sweep_deg = ctx.number(s, "sweep", "robot.path.still", 0.0, lo=0, hi=360)
        R.sweep_period = ctx.number(s, "period", "robot.path.still", 10.0, lo=0, lo_open=True)
        R.waypoints = [(0.0, x, y, yaw)]
        return R
    wps = path["waypoints"]
    if not isinstance(wps, list) or not wps:
        raise ctx.fail(
            "robot.path.waypoints",
            f"expected a non-empty list, got {_show(wps)}",
            "write [{t: 0, x: 1, y: 1, yaw: 0}, ...]",
        )
    for i, w in enumerate(wps):
        key = f"robot.path.waypoints[{i}]"
        w = ctx.mapping(w, key, ("t", "x", "y", "yaw"), ("t", "x", "y"))
        t = ctx.number(w, "t", key, lo=0)
        if R.waypoints and t <= R.waypoints[-1][0]:
            raise ctx.fail(
                f"{key}.t",
                f"{t:g} s is not after the previous waypoint ({R.waypoints[-1][0]:g} s)",
                "list waypoints in increasing time",
            )
        R.waypoints.append(
            (t, ctx.number(w, "x", key), ctx.number(w, "y", key), ctx.number(w, "yaw", key, 0.0))
        )
    return R


def _object(ctx: _Ctx, v: Any, i: int, duration: float, ids: set[str]) -> Obj:
    key = f"objects[{i}]"
    d = ctx.mapping(
        v,
        key,
        (
            "id",
            "kind",
            "label",
            "pose",
            "size",
            "radius",
            "height",
            "present",
            "leg",
            "top_thickness",
            "back_height",
        ),
        ("kind", "pose"),
    )
    kind = d["kind"]
    if kind not in OBJECT_KINDS:
        raise ctx.fail(f"{key}.kind", f"unknown kind {_show(kind)}", f"use one of {', '.join(OBJECT_KINDS)}")
    oid = ctx.text(d, "id", key, f"{kind}{i}")
    if oid in ids:
        raise ctx.fail(
            f"{key}.id", f"id {_show(oid)} is used twice", "give every object, door and person its own id"
        )
    ids.add(oid)
    pose = ctx.mapping(d["pose"], f"{key}.pose", ("x", "y", "z", "yaw"), ("x", "y"))
    radius = ctx.number(d, "radius", key, 0.1 if kind == "sphere" else 0.2, lo=0, lo_open=True)
    default_z = radius if kind == "sphere" else 0.0
    default_label = {"table": "table", "chair": "chair", "sphere": "ball"}.get(kind, "static object")
    size_default = {"box": [0.4, 0.4, 0.5], "table": [1.2, 0.8, 0.75], "chair": [0.45, 0.45, 0.45]}.get(kind)
    size = (0.0, 0.0, 0.0)
    if size_default is not None:
        size = ctx.vector(d.get("size", size_default), 3, f"{key}.size")
        if min(size) <= 0:
            raise ctx.fail(
                f"{key}.size", f"{list(size)} has a non-positive side", "give positive sizes in metres"
            )
    label = ctx.text(d, "label", key, default_label)
    leg = ctx.number(d, "leg", key, 0.05 if kind == "table" else 0.04, lo=0, lo_open=True)
    top = ctx.number(d, "top_thickness", key, 0.04, lo=0, lo_open=True)
    if kind in ("table", "chair") and (2 * leg >= min(size[0], size[1]) or top >= size[2]):
        raise ctx.fail(
            f"{key}.size",
            f"{list(size)} leaves no room for legs of {leg:g} m and a top of {top:g} m",
            "make the piece larger or its legs thinner",
        )
    return Obj(
        id=oid, kind=kind, label=label,
        x=ctx.number(pose, "x", f"{key}.pose"), y=ctx.number(pose, "y", f"{key}.pose"),
        z=ctx.number(pose, "z", f"{key}.pose", default_z), yaw_deg=ctx.number(pose, "yaw", f"{key}.pose", 0.0),
        size=size, radius=radius, height=ctx.number(d, "height", key, 0.5, lo=0, lo_open=True),
        present=ctx.intervals(d.get("present", [[0, None]]), f"{key}.present", duration),
        leg=leg, top_thickness=top,
        back_height=ctx.number(d, "back_height", key, 0.9, lo=size[2] if kind == "chair" else 0),
    )  # fmt: skip


def _door(ctx: _Ctx, v: Any, i: int, duration: float, ids: set[str]) -> Door:
    key = f"doors[{i}]"
    d = ctx.mapping(
        v,
        key,
        ("id", "kind", "from", "to", "thickness", "height", "closed", "motion_s", "open_angle_deg", "swing"),
        ("from", "to"),
    )
    kind = d.get("kind", "box")
    if kind not in DOOR_KINDS:
        raise ctx.fail(f"{key}.kind", f"unknown kind {_show(kind)}", f"use one of {', '.join(DOOR_KINDS)}")
    for k, kinds in (
        ("motion_s", ("hinged", "sliding")),
        ("open_angle_deg", ("hinged",)),
        ("swing", ("hinged",)),
    ):
        if k in d and kind not in kinds:
            raise ctx.fail(
                f"{key}.{k}",
                f"only for a {' or '.join(kinds)} door, not kind {kind}",
                f"remove it or set kind: {kinds[0]}",
            )
    did = ctx.text(d, "id", key, f"door{i}")
    if did in ids:
        raise ctx.fail(
            f"{key}.id", f"id {_show(did)} is used twice", "give every object, door and person its own id"
        )
    ids.add(did)
    p1 = ctx.vector(d["from"], 2, f"{key}.from")
    p2 = ctx.vector(d["to"], 2, f"{key}.to")
    if math.dist(p1, p2) < 1e-6:
        raise ctx.fail(f"{key}.to", "the door has zero width", "give the two ends of the opening")
    swing = d.get("swing", "left")
    if isinstance(swing, bool) or not isinstance(swing, (str, int, float)) or swing not in SWINGS:
        raise ctx.fail(
            f"{key}.swing",
            f"expected left, right, +1 or -1, got {_show(swing)}",
            "write left (counterclockwise about the hinge at from, seen from above) or right",
        )
    return Door(
        did,
        p1,  # type: ignore[arg-type]
        p2,  # type: ignore[arg-type]
        ctx.number(d, "thickness", key, 0.04, lo=0, lo_open=True),
        ctx.number(d, "height", key, 2.0, lo=0, lo_open=True),
        ctx.intervals(d.get("closed", []), f"{key}.closed", duration),
        kind=kind,
        motion_s=ctx.number(d, "motion_s", key, 1.0, lo=0),
        open_angle_deg=ctx.number(d, "open_angle_deg", key, 90.0, lo=0, hi=180, lo_open=True),
        swing=SWINGS[swing],
    )


def _person(ctx: _Ctx, v: Any, i: int, ids: set[str]) -> Person:
    key = f"people[{i}]"
    d = ctx.mapping(v, key, ("id", "radius", "height", "path"), ("path",))
    pid = ctx.text(d, "id", key, f"person{i}")
    if pid in ids:
        raise ctx.fail(
            f"{key}.id", f"id {_show(pid)} is used twice", "give every object, door and person its own id"
        )
    ids.add(pid)
    path = d["path"]
    if not isinstance(path, list) or len(path) < 2:
        raise ctx.fail(
            f"{key}.path",
            f"expected a list of at least 2 points, got {_show(path)}",
            "write [{t: 0, x: 1, y: 1}, {t: 5, x: 3, y: 1}]",
        )
    pts: list[tuple[float, float, float]] = []
    for j, w in enumerate(path):
        k = f"{key}.path[{j}]"
        w = ctx.mapping(w, k, ("t", "x", "y"), ("t", "x", "y"))
        t = ctx.number(w, "t", k, lo=0)
        if pts and t <= pts[-1][0]:
            raise ctx.fail(
                f"{k}.t",
                f"{t:g} s is not after the previous point ({pts[-1][0]:g} s)",
                "list the path in increasing time",
            )
        pts.append((t, ctx.number(w, "x", k), ctx.number(w, "y", k)))
    return Person(
        pid,
        ctx.number(d, "radius", key, 0.25, lo=0, lo_open=True),
        ctx.number(d, "height", key, 1.7, lo=0, lo_open=True),
        pts,
    )


TOP_KEYS = (
    "name",
    "plan",
    "plan_scale",
    "walls",
    "wall_height",
    "ceiling",
    "duration",
    "seed",
    "start_time",
    "robot",
    "sensors",
    "objects",
    "doors",
    "people",
)


def parse_scenario(data: Any, source: str | Path, base_dir: Path | None = None) -> Scenario:
    """Validate a loaded YAML document; ``base_dir`` resolves a relative plan path."""
    ctx = _Ctx(str(source))
    src = Path(source)
    base_dir = base_dir if base_dir is not None else src.parent
    if not isinstance(data, dict):
        what = "empty file" if data is None else f"its top level is {_show(data)}, not a mapping"
        raise ConfigError(
            f"{source}: {what}; write the scenario as key: value lines (duration, robot, sensors, ...; "
            "see docs/scenarios.md)"
        )
    d = ctx.mapping(data, "", TOP_KEYS, ("duration", "robot"))
    duration = ctx.number(d, "duration", "", lo=0, hi=24 * 3600, lo_open=True)
    seed = d.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ctx.fail("seed", f"expected a non-negative integer, got {_show(seed)}", "write e.g. seed: 1")
    plan = d.get("plan")
    plan_path = None
    if plan is not None:
        if not isinstance(plan, str) or not plan:
            raise ctx.fail(
                "plan",
                f"expected the path of an SVG plan, got {_show(plan)}",
                "write plan: ../plans/house.svg (relative to the scenario file) or leave it out",
            )
        plan_path = Path(plan) if Path(plan).is_absolute() else base_dir / plan
        if not plan_path.is_file():
            raise ctx.fail(
                "plan", f"no such file {plan_path}", "give an SVG plan relative to the scenario file"
            )
    plan_scale = None
    if d.get("plan_scale") is not None:
        plan_scale = ctx.number(d, "plan_scale", "", lo=0, lo_open=True)
    walls: list[WallLine] = []
    wl = d.get("walls", [])
    if not isinstance(wl, list):
        raise ctx.fail(
            "walls", f"expected a list, got {_show(wl)}", "write [{points: [[0,0],[4,0]], thickness: 0.1}]"
        )
    for i, w in enumerate(wl):
        key = f"walls[{i}]"
        w = ctx.mapping(w, key, ("points", "thickness"), ("points",))
        pts = w["points"]
        if not isinstance(pts, list) or len(pts) < 2:
            raise ctx.fail(
                f"{key}.points",
                f"expected at least 2 points, got {_show(pts)}",
                "write [[x, y], [x, y], ...]",
            )
        walls.append(
            WallLine(
                [ctx.vector(p, 2, f"{key}.points[{j}]") for j, p in enumerate(pts)],  # type: ignore[misc]
                ctx.number(w, "thickness", key, 0.1, lo=0, lo_open=True),
            )
        )
    sensors = ctx.mapping(d.get("sensors", {}), "sensors", ("laser", "depth", "points"))
    laser = _laser(ctx, sensors["laser"]) if sensors.get("laser") is not None else None
    depth = _depth(ctx, sensors["depth"]) if sensors.get("depth") is not None else None
    points = _points(ctx, sensors["points"]) if sensors.get("points") is not None else None
    if laser is None and depth is None and points is None:
        raise ctx.fail("sensors", "no sensor", "add sensors.laser, sensors.depth or sensors.points")
    ids: set[str] = set()
    lists = {}
    for k in ("objects", "doors", "people"):
        lists[k] = d.get(k) or []
        if not isinstance(lists[k], list):
            raise ctx.fail(
                k, f"expected a list, got {_show(lists[k])}", f"write {k}: [...] (see docs/scenarios.md)"
            )
    start = ctx.number(d, "start_time", "", 1_700_000_000.0, lo=0)
    return Scenario(
        source=src, name=str(d.get("name", src.stem)), plan=plan_path, plan_scale=plan_scale, walls=walls,
        wall_height=ctx.number(d, "wall_height", "", 2.5, lo=0, lo_open=True),
        ceiling=ctx.number(d, "ceiling", "", lo=0, lo_open=True) if d.get("ceiling") is not None else None,
        duration=duration, seed=seed, start_time=start, robot=_robot(ctx, d["robot"], duration),
        laser=laser, depth=depth, points=points,
        objects=[_object(ctx, o, i, duration, ids) for i, o in enumerate(lists["objects"])],
        doors=[_door(ctx, o, i, duration, ids) for i, o in enumerate(lists["doors"])],
        people=[_person(ctx, o, i, ids) for i, o in enumerate(lists["people"])],
    )  # fmt: skip


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file (ConfigError on any problem)."""
    from ..errors import InputError
    from ..io import safe_yaml

    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such scenario file; give a scenario YAML (see docs/scenarios.md)")
    data = safe_yaml.load_file(p, "scenario", ConfigError, max_bytes=16 * 2**20)
    return parse_scenario(data, p)
