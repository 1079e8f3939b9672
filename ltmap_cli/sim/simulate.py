"""Turn a scenario into a log: timeline, rendering with noise, messages, ground truth.

Topics: ``/tf`` (map -> odom and odom -> base_link at ``robot.tf_rate``), ``/tf_static``
(base_link -> sensor frames, camera_link -> optical frame; once at t = 0), ``/odom``
(nav_msgs/Odometry at ``robot.odom_rate``), and per sensor ``/scan`` (LaserScan),
``/camera/depth/image_raw`` + ``/camera/depth/camera_info`` (Image + CameraInfo),
``/points`` (PointCloud2); every message's header stamp equals its log time.

Odometry drift ``(vx, vy, wz)`` makes odom -> base_link drift linearly from the truth: odom ->
base_link = D(t) * truth with D(t) the planar motion (vx t, vy t, wz t); map -> odom = D(t)^-1
corrects it, so map -> base_link is always the true pose.

Noise comes from numpy generators seeded with (seed, sensor index): the same scenario and seed give
a byte-identical log.
"""

from __future__ import annotations

import contextlib
import heapq
import json
import math
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.atomic import atomic_path
from ..outputs.folder import OutputFolder, locked_file
from .logwriter import LogWriter
from .scenario import Scenario
from .scene import World, active, door_leaf, door_motion, person_at, robot_pose
from .sensors import (
    R_LINK_OPTICAL,
    depth_edges,
    laser_angles,
    mount_matrix,
    pixel_rays,
    points_rays,
    quat_from_matrix,
    render_depth,
    render_points,
    render_scan,
    yaw_quat,
)

NS = 1_000_000_000
FIXED, ODOM, BASE = "map", "odom", "base_link"
TF = "tf2_msgs/msg/TFMessage"


def _times(rate: float, duration: float, inclusive: bool = False) -> np.ndarray:
    """k / rate for k = 0, 1, ... up to ``duration`` (included only with ``inclusive``)."""
    t = np.arange(int(math.floor(duration * rate + 1e-9)) + 1) / rate
    return t if inclusive else t[t < duration - 1e-9]


def _stamp(sc: Scenario, t: float) -> int:
    return int(round(sc.start_time * NS)) + int(round(t * NS))


def _tf_entry(stamp: int, parent: str, child: str, xyz, q) -> dict:
    return {
        "header": {"stamp": stamp, "frame_id": parent},
        "child_frame_id": child,
        "transform": {
            "translation": dict(zip("xyz", map(float, xyz))),
            "rotation": dict(zip("xyzw", map(float, q))),
        },
    }


def _compose(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """Planar a * b."""
    ax, ay, at = a
    bx, by, bt = b
    return ax + math.cos(at) * bx - math.sin(at) * by, ay + math.sin(at) * bx + math.cos(at) * by, at + bt


def _inverse(a: tuple[float, float, float]) -> tuple[float, float, float]:
    x, y, t = a
    return -math.cos(t) * x - math.sin(t) * y, math.sin(t) * x - math.cos(t) * y, -t


class Simulator:
    def __init__(self, sc: Scenario):
        self.sc = sc
        self.world = World(sc)

    def drift(self, t: float) -> tuple[float, float, float]:
        vx, vy, wz = self.sc.robot.odometry_drift
        return vx * t, vy * t, math.radians(wz) * t

    def odom_pose(self, t: float) -> tuple[float, float, float]:
        return _compose(self.drift(t), robot_pose(self.sc, t))

    # -- the message stream ---------------------------------------------------------------
    def messages(self) -> Iterator[tuple[str, str, int, dict]]:
        """(topic, msgtype, log_time_ns, fields) in log-time order."""
        sc = self.sc
        streams: list[Iterator] = [self._tf_static(), self._tf(), self._odom()]
        if sc.laser is not None:
            streams.append(self._scans())
        if sc.depth is not None:
            streams.append(self._depth())
        if sc.points is not None:
            streams.append(self._points())
        # (time, stream priority, sequence) orders tf before the sensor frames of the same instant
        tagged = [((m[2], prio, i, m) for i, m in enumerate(s)) for prio, s in enumerate(streams)]
        for *_, m in heapq.merge(*tagged, key=lambda x: x[:3]):
            yield m

    def _tf_static(self):
        sc = self.sc
        s0 = _stamp(sc, 0.0)
        out = []
        if sc.laser is not None:
            T = mount_matrix(sc.laser.mount)
            out.append(_tf_entry(s0, BASE, sc.laser.frame, T[:3, 3], quat_from_matrix(T[:3, :3])))
        if sc.depth is not None:
            D = sc.depth
            T = mount_matrix(D.mount, D.pitch_deg)
            out.append(_tf_entry(s0, BASE, D.frame, T[:3, 3], quat_from_matrix(T[:3, :3])))
            out.append(_tf_entry(s0, D.frame, D.optical_frame, (0, 0, 0), quat_from_matrix(R_LINK_OPTICAL)))
        if sc.points is not None:
            T = mount_matrix(sc.points.mount)
            out.append(_tf_entry(s0, BASE, sc.points.frame, T[:3, 3], quat_from_matrix(T[:3, :3])))
        yield "/tf_static", TF, s0, {"transforms": out}

    def _tf(self):
        sc = self.sc
        for t in _times(sc.robot.tf_rate, sc.duration, inclusive=True):
            s = _stamp(sc, t)
            mo = _inverse(self.drift(t))
            ob = self.odom_pose(t)
            yield (
                "/tf",
                TF,
                s,
                {
                    "transforms": [
                        _tf_entry(s, FIXED, ODOM, (mo[0], mo[1], 0.0), yaw_quat(mo[2])),
                        _tf_entry(s, ODOM, BASE, (ob[0], ob[1], 0.0), yaw_quat(ob[2])),
                    ]
                },
            )

    def _odom(self):
        sc = self.sc
        if sc.robot.odom_rate <= 0:
            return
        dt = 1e-3
        for t in _times(sc.robot.odom_rate, sc.duration, inclusive=True):
            s = _stamp(sc, t)
            x, y, a = self.odom_pose(t)
            x1, y1, a1 = self.odom_pose(t + dt)
            vx_w, vy_w = (x1 - x) / dt, (y1 - y) / dt
            yield (
                "/odom",
                "nav_msgs/msg/Odometry",
                s,
                {
                    "header": {"stamp": s, "frame_id": ODOM},
                    "child_frame_id": BASE,
                    "pose": {
                        "pose": {
                            "position": {"x": x, "y": y, "z": 0.0},
                            "orientation": dict(zip("xyzw", yaw_quat(a))),
                        }
                    },
                    "twist": {
                        "twist": {
                            "linear": {
                                "x": math.cos(a) * vx_w + math.sin(a) * vy_w,
                                "y": -math.sin(a) * vx_w + math.cos(a) * vy_w,
                                "z": 0.0,
                            },
                            "angular": {"x": 0.0, "y": 0.0, "z": (a1 - a) / dt},
                        }
                    },
                },
            )

    def _scans(self):
        sc, L = self.sc, self.sc.laser
        rng = np.random.default_rng([sc.seed, 1])
        amin, inc, _ = laser_angles(L)
        for t in _times(L.rate, sc.duration):
            r = render_scan(self.world.at(t), L, robot_pose(sc, t))
            if L.noise > 0:
                r = r + rng.normal(0.0, L.noise, r.shape)
            if L.dropout > 0:
                r[rng.random(r.shape) < L.dropout] = np.inf
            r[~(r <= L.range_max)] = np.inf
            s = _stamp(sc, t)
            yield (
                L.topic,
                "sensor_msgs/msg/LaserScan",
                s,
                {
                    "header": {"stamp": s, "frame_id": L.frame},
                    "angle_min": amin,
                    "angle_max": amin + inc * (L.beams - 1),
                    "angle_increment": inc,
                    "time_increment": 0.0,
                    "scan_time": 1.0 / L.rate,
                    "range_min": L.range_min,
                    "range_max": L.range_max,
                    "ranges": r.astype(np.float32),
                    "intensities": np.zeros(0, np.float32),
                },
            )

    def _depth(self):
        sc, D = self.sc, self.sc.depth
        rng = np.random.default_rng([sc.seed, 2])
        holes = np.random.default_rng([sc.seed, 4])  # (a stream of its own: the noise is drawn as before)
        rays = pixel_rays(D)
        info = {
            "height": D.height,
            "width": D.width,
            "distortion_model": "plumb_bob",
            "d": [0.0] * 5,
            "k": [D.fx, 0.0, D.cx, 0.0, D.fy, D.cy, 0.0, 0.0, 1.0],
            "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            "p": [D.fx, 0.0, D.cx, 0.0, 0.0, D.fy, D.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        }
        for t in _times(D.rate, sc.duration):
            z = render_depth(self.world.at(t), D, robot_pose(sc, t), rays)
            if D.noise > 0:
                z = z + rng.normal(0.0, D.noise, z.shape)
            if D.quantization > 0:
                with np.errstate(invalid="ignore"):
                    step = D.quantization * z * z
                    z = np.where(np.isfinite(z), np.round(z / step) * step, z)
            if D.edge_dropout > 0:
                z = np.where(depth_edges(z, D.edge_dropout), np.nan, z)
            if D.dropout > 0:
                z = np.where(holes.random(z.shape) < D.dropout, np.nan, z)
            bad = ~((z >= D.range_min) & (z <= D.range_max))
            s = _stamp(sc, t)
            header = {"stamp": s, "frame_id": D.optical_frame}
            yield D.info_topic, "sensor_msgs/msg/CameraInfo", s, {"header": header, **info}
            if D.encoding == "16UC1":
                img = np.clip(np.round(z * 1000.0), 0, 65535)
                img[bad] = 0
                data = img.astype("<u2")
                step = 2 * D.width
            else:
                img = z.astype(np.float32)
                img[bad] = np.nan
                data = img.astype("<f4")
                step = 4 * D.width
            yield (
                D.topic,
                "sensor_msgs/msg/Image",
                s,
                {
                    "header": header,
                    "height": D.height,
                    "width": D.width,
                    "encoding": D.encoding,
                    "is_bigendian": 0,
                    "step": step,
                    "data": np.frombuffer(data.tobytes(), np.uint8),
                },
            )

    def _points(self):
        sc, P = self.sc, self.sc.points
        rng = np.random.default_rng([sc.seed, 3])
        rays = points_rays(P)
        fields = [{"name": n, "offset": 4 * i, "datatype": 7, "count": 1} for i, n in enumerate("xyz")]
        for t in _times(P.rate, sc.duration):
            r, dirs = render_points(self.world.at(t), P, robot_pose(sc, t), rays)
            if P.noise > 0:
                r = r + rng.normal(0.0, P.noise, r.shape)
            ok = (r >= P.range_min) & (r <= P.range_max)
            pts = (dirs[ok] * r[ok, None]).astype("<f4")
            s = _stamp(sc, t)
            yield (
                P.topic,
                "sensor_msgs/msg/PointCloud2",
                s,
                {
                    "header": {"stamp": s, "frame_id": P.frame},
                    "height": 1,
                    "width": len(pts),
                    "fields": fields,
                    "is_bigendian": False,
                    "point_step": 12,
                    "row_step": 12 * len(pts),
                    "data": np.frombuffer(pts.tobytes(), np.uint8),
                    "is_dense": True,
                },
            )

    # -- ground truth ---------------------------------------------------------------------
    def ground_truth(self) -> dict:
        sc = self.sc
        objects = []
        for o in sc.objects:
            objects.append(
                {
                    "id": o.id,
                    "kind": o.label,
                    "shape": o.kind,
                    "category": "object",
                    "pose": {"x": o.x, "y": o.y, "z": o.z, "yaw_deg": o.yaw_deg},
                    "parts": self.world.object_parts[o.id],
                    "present": [list(p) for p in o.present],
                }
            )
        for d in sc.doors:
            entry = {
                "id": d.id,
                "kind": "door",
                "shape": d.kind,  # box | hinged | sliding
                "category": "door",
                "from": list(d.p1),
                "to": list(d.p2),
                "parts": [self.world.door_parts[d.id]],  # the closed leaf
                "present": [list(p) for p in d.closed],  # fully closed
            }
            if d.kind != "box":  # a moving leaf (box doors keep the entry they always had)
                entry["motion_s"] = d.motion_s
                if d.kind == "hinged":
                    entry["hinge"] = list(d.p1)
                    entry["open_angle_deg"] = d.open_angle_deg
                    entry["swing"] = "left" if d.swing > 0 else "right"
                entry["moving"] = door_motion(d, sc.duration)
                entry["open_parts"] = [door_leaf(d, 1.0)]
            objects.append(entry)
        for p in sc.people:
            objects.append(
                {
                    "id": p.id,
                    "kind": "person",
                    "shape": "cylinder",
                    "category": "person",
                    "radius": p.radius,
                    "height": p.height,
                    "path": [{"t": t, "x": x, "y": y} for t, x, y in p.path],
                    "present": [[p.path[0][0], p.path[-1][0]]],
                }
            )
        step = 0.1
        ts = np.round(np.arange(0.0, sc.duration + 1e-9, step), 6)
        path = [
            {
                "t": float(t),
                **dict(
                    zip(
                        ("x", "y", "yaw_deg"),
                        (round(v, 6) for v in (*robot_pose(sc, t)[:2], math.degrees(robot_pose(sc, t)[2]))),
                    )
                ),
            }
            for t in ts
        ]
        sensors = {}
        if sc.laser is not None:
            L = sc.laser
            sensors["laser"] = {
                "topic": L.topic,
                "frame": L.frame,
                "mount": {"xyz": list(L.mount.xyz), "rpy_deg": list(L.mount.rpy_deg)},
                "rate": L.rate,
                "beams": L.beams,
            }
        if sc.depth is not None:
            D = sc.depth
            sensors["depth"] = {
                "topic": D.topic,
                "frame": D.optical_frame,
                "mount": {"xyz": list(D.mount.xyz), "rpy_deg": list(D.mount.rpy_deg)},
                "pitch_deg": D.pitch_deg,
                "rate": D.rate,
                "width": D.width,
                "height": D.height,
            }
        if sc.points is not None:
            sensors["points"] = {"topic": sc.points.topic, "frame": sc.points.frame, "rate": sc.points.rate}
        walls = None
        if self.world.wall_geometry is not None:
            walls = self.world.wall_geometry.wkt
        return {
            "scenario": sc.name,
            "plan": sc.plan.name if sc.plan is not None else None,
            "start_time_ns": _stamp(sc, 0.0),
            "duration_s": sc.duration,
            "seed": sc.seed,
            "frames": {"fixed": FIXED, "odom": ODOM, "base": BASE},
            "wall_height": sc.wall_height,
            "walls_wkt": walls,
            "robot": {"radius": sc.robot.radius, "path_step_s": step, "path": path},
            "sensors": sensors,
            "objects": objects,
        }


def _check_outputs(out: Path, gt: Path, given: bool) -> None:
    """Refuse, before simulating, a log or ground-truth path that cannot be written."""
    gt_label = f"--ground-truth {gt}" if given else f"{gt} (the ground truth beside -o {out})"
    todo = "choose another path" if given else "give --ground-truth another path"
    for label, path, fix in ((f"-o {out}", out, "choose another path"), (gt_label, gt, todo)):
        for parent in path.parents:
            if parent.exists():
                if not parent.is_dir():
                    raise InputError(f"{label}: {parent} is a file, not a folder; {fix}")
                if not os.access(parent, os.W_OK | os.X_OK):
                    raise InputError(f"{label}: cannot write in {parent} (permission denied); {fix}")
                break
    g, o = gt.resolve(), out.resolve()
    if g in o.parents:
        raise InputError(f"{gt_label}: is the folder of the log -o {out}; give a file name such as "
                         f"{gt / 'ground_truth.json'}")  # fmt: skip
    if gt.is_dir():
        fix = f"give a file name such as {gt / 'ground_truth.json'}" if given else todo
        raise InputError(f"{gt_label}: is a folder; {fix}")
    if g == o or o in g.parents:
        raise InputError(f"{gt_label}: is the log -o {out} or inside it; give another file name")


def _lift(inner: Path, folder: Path) -> None:
    """Move the bag rosbags wrote into ``inner`` up into ``folder`` (its metadata.yaml names its
    files relative to it, so the bag stays whole)."""
    for p in inner.iterdir():
        os.rename(p, folder / p.name)
    inner.rmdir()


def _write_ground_truth(path: Path, sim: Simulator) -> None:
    path.write_bytes((json.dumps(sim.ground_truth(), indent=1) + "\n").encode())


def simulate(
    sc: Scenario, out: str | Path, fmt: str = "mcap", ground_truth: str | Path | None = None, progress=None,
    force: bool = False,
) -> dict:
    """Write the log of ``sc`` to ``out`` (``fmt``: mcap, ros1, ros2) and its ground truth; return
    a summary (messages per topic, files). A file is written under a temporary name and renamed; a
    ROS 2 bag folder is an ``OutputFolder`` (replaced as a whole; one ltmap did not write is
    refused unless ``force``)."""
    out = Path(out)
    gt_path = Path(ground_truth) if ground_truth is not None else out.parent / "ground_truth.json"
    _check_outputs(out, gt_path, ground_truth is not None)
    sim = Simulator(sc)
    # the ground truth is staged before the log is renamed into place and renamed after it, so
    # that a failure writing either leaves both targets as they were
    folder = OutputFolder(out, command="simulate", force=force) if fmt == "ros2" else contextlib.nullcontext()
    log_lock = contextlib.nullcontext() if fmt == "ros2" else locked_file(out, "simulate")
    gt_label = "--ground-truth" if ground_truth is not None else "the ground truth"
    with locked_file(gt_path, "simulate", gt_label), log_lock, atomic_path(gt_path) as gt_tmp, folder:
        with LogWriter(folder.staging / out.name if fmt == "ros2" else out, fmt) as w:
            for topic, msgtype, t_ns, fields in sim.messages():
                w.write(topic, msgtype, t_ns, fields, latching=topic == "/tf_static")
                if progress is not None:
                    progress((t_ns - _stamp(sc, 0.0)) / NS, sc.duration)
            counts = dict(w.counts)
            try:
                _write_ground_truth(gt_tmp, sim)
            except OSError as err:  # name the file the user asked for, not the temporary one
                raise OSError(err.errno, err.strerror, str(gt_path)) from None
        if fmt == "ros2":
            _lift(folder.staging / out.name, folder.staging)
            folder.commit({"format": fmt, "seed": sc.seed})
    return {
        "log": str(out),
        "format": fmt,
        "ground_truth": str(gt_path),
        "messages": counts,
        "duration_s": sc.duration,
    }


__all__ = ["Simulator", "simulate", "active", "person_at"]
