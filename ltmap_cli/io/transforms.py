"""A tf buffer in pure numpy: the tree of frames, interpolated lookups, user mounts.

Conventions: a sample ``parent -> child`` gives the pose of ``child`` in ``parent``
(``p_parent = T @ p_child``). ``lookup(target, source, stamp_ns)`` returns the 4x4 float64 ``T``
with ``p_target = T @ p_source`` (tf2's ``lookupTransform(target, source, time)``).

- Per edge, samples are kept sorted by stamp (bisect). A lookup interpolates between the two
  bracketing samples: translation linearly, rotation by SLERP. There is no extrapolation: a stamp
  before an edge's first or after its last sample fails, unless within ``tolerance_ns`` of it
  (default 0: exact stamps only), in which case the end sample is used.
- ``/tf_static`` samples (``static=True``) and user mounts are timeless: real logs stamp
  ``/tf_static`` hours before the log.
- Frame names are normalized: ``/laser`` and ``laser`` are one frame.
- Each edge has one source. The estimate of ``replay --localize`` beats a user mount (``--tf``),
  which beats /tf and /tf_static, which beat nav_msgs/Odometry; between /tf and /tf_static the
  first wins. Samples from a weaker source are ignored (counted in ``ignored``), so odometry that
  duplicates /tf does not fight it, and a recorded map -> odom does not fight the estimate, in
  whichever order they arrive.
- Memory is bounded: samples older than ``window_ns`` before an edge's newest sample are dropped.
- A failed lookup raises ``LookupFailure`` (a ``TransformError``) whose ``reason`` names the
  missing edge and what to do, and contains no stamp, so callers can count skipped frames by it.
"""

from __future__ import annotations

import bisect
import math
import re
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, TransformError, bounded
from .frames import OdometrySample, TfSample

MOUNT_FORM = "parent:child=x,y,z,roll,pitch,yaw (metres, radians), e.g. base_link:laser=0.1,0,0.2,0,0,0"


class LookupFailure(TransformError):
    """A transform could not be had. ``reason`` is stable (no stamp) for counting."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(reason + (f" ({detail})" if detail else ""))
        self.reason = reason
        self.detail = detail


def norm(frame: str) -> str:
    """The one normalisation of frame ids (tf2's): no surrounding whitespace, no leading ``/``;
    ``/laser``, ``laser`` and ``" /laser"`` are one frame. Used by the readers, the tf buffer,
    ``--tf``, ``--fixed-frame``, ``info`` and ``replay``."""
    return frame.strip().lstrip("/").strip()


def _unit(q: np.ndarray) -> np.ndarray:
    """``q / np.linalg.norm(q)``, the same bits (norm is sqrt(q . q)), without norm's overhead
    (a few microseconds a call: 4 % of the map thread's time, in the tf lookups)."""
    return q / math.sqrt(q.dot(q))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, w = _unit(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rpy_to_quat(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """ROS fixed-axis roll, pitch, yaw (R = Rz(yaw) Ry(pitch) Rx(roll)) as (x, y, z, w)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    q0 = _unit(q0)
    q1 = _unit(q1)
    d = float(np.dot(q0, q1))
    if d < 0.0:  # shortest path
        q1, d = -q1, -d
    if d > 0.9995:
        return _unit(q0 + u * (q1 - q0))
    theta = math.acos(min(d, 1.0))
    s = math.sin(theta)
    return (math.sin((1 - u) * theta) / s) * q0 + (math.sin(u * theta) / s) * q1


def make_matrix(translation, rotation_xyzw) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = quat_to_matrix(np.asarray(rotation_xyzw, dtype=np.float64))
    m[:3, 3] = translation
    return m


def invert(m: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    r = m[:3, :3].T
    out[:3, :3] = r
    out[:3, 3] = -r @ m[:3, 3]
    return out


def parse_mount(spec: str) -> TfSample:
    """``"base_link:laser=x,y,z,roll,pitch,yaw"`` -> a static TfSample; bad text -> InputError."""
    m = re.fullmatch(r"\s*([^:=\s]+)\s*:\s*([^:=\s]+)\s*=\s*(.+?)\s*", spec or "")
    if not m:
        raise InputError(f"bad --tf {spec!r}: expected {MOUNT_FORM}")
    parent, child, nums = norm(m.group(1)), norm(m.group(2)), m.group(3).split(",")
    try:
        vals = [float(v) for v in nums]
    except ValueError:
        raise InputError(f"bad --tf {spec!r}: {m.group(3)!r} are not 6 numbers; expected {MOUNT_FORM}") from None
    if len(vals) != 6 or not all(math.isfinite(v) for v in vals):
        raise InputError(f"bad --tf {spec!r}: got {len(vals)} values, need 6 finite numbers; expected {MOUNT_FORM}")
    if not parent or not child or parent == child:
        raise InputError(f"bad --tf {spec!r}: parent and child frames must differ; expected {MOUNT_FORM}")
    return TfSample(0, parent, child, (vals[0], vals[1], vals[2]), rpy_to_quat(*vals[3:]), static=True)


# which source owns an edge that several provide: the estimate of ``replay --localize``, a user
# mount, then tf, then odometry
_PRIORITY = {"localize": 4, "mount": 3, "tf": 2, "static": 2, "odom": 1}
QUATERNION_TOLERANCE = 0.01  # tf2's QUATERNION_NORMALIZATION_TOLERANCE: |q|^2 this far from 1 is refused


@dataclass
class _Edge:
    parent: str
    source: str  # "tf" | "static" | "odom" | "mount"
    times: list[int] = field(default_factory=list)
    values: list[np.ndarray] = field(default_factory=list)  # (7,) tx ty tz qx qy qz qw
    count: int = 0  # samples this edge got from its source, including those the window dropped

    @property
    def timeless(self) -> bool:
        return self.source in ("static", "mount")


class TfBuffer:
    """See the module doc. ``window_ns`` bounds the history kept per edge (default 120 s)."""

    def __init__(self, tolerance_ns: int = 0, window_ns: int = 120 * 10**9):
        self.tolerance_ns = int(tolerance_ns)
        self.window_ns = int(window_ns)
        self.edges: dict[str, _Edge] = {}  # child -> edge to its parent
        self.ignored: Counter[str] = Counter()  # "parent -> child from <source>" -> samples ignored
        # samples with an empty frame name (an Odometry whose child_frame_id is ""), which tf2
        # refuses: "<source> parent -> child" (the empty name shown as such) -> samples
        self.unnamed: Counter[str] = Counter()
        # samples tf2 refuses too: a NaN or infinite value, or a quaternion whose squared norm is
        # off 1 by more than QUATERNION_TOLERANCE (a zeroed message): "parent -> child" -> samples
        self.invalid: Counter[str] = Counter()
        # Caches, pure speed-ups (a lookup computes the same numbers with or without them): the
        # chain of parents per frame (dropped when an edge is made or removed) and, per edge, the
        # matrix of its last lookup with its stamp (dropped when the edge gets a sample). A sensor
        # frame and the robot pose at the same stamp share their timed edges; static edges are
        # computed once.
        self._chains: dict[str, tuple[str, ...]] = {}
        # per (target, source): the edges (their children) from the source and from the target up
        # to their common frame; cleared with _chains whenever an edge is added or re-parented
        self._paths: dict[tuple[str, str], tuple[tuple[str, ...], tuple[str, ...]]] = {}
        self._edge_m: dict[str, tuple[int, np.ndarray]] = {}

    # ------------------------------------------------------------------ filling
    def add(self, sample: TfSample | OdometrySample) -> None:
        if isinstance(sample, OdometrySample):
            source = "odom"
        else:
            source = "static" if sample.static else "tf"
        parent, child = norm(sample.parent), norm(sample.child)
        if not parent or not child:
            kind = {"odom": "nav_msgs/Odometry", "tf": "/tf", "static": "/tf_static"}[source]
            self.unnamed[f"{kind} {parent or '(empty header.frame_id)'} -> {child or '(empty child_frame_id)'}"] += 1
            return
        q = sample.rotation_xyzw
        if not all(math.isfinite(v) for v in (*sample.translation, *q)) or \
                abs(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] - 1.0) > QUATERNION_TOLERANCE:  # fmt: skip
            self.invalid[f"{parent} -> {child}"] += 1
            return
        self._add(parent, child, sample.stamp_ns, sample.translation, sample.rotation_xyzw, source)

    def add_mount(self, spec: str) -> TfSample:
        """Add a user mount ``parent:child=x,y,z,roll,pitch,yaw``; it overrides the log's edge."""
        s = parse_mount(spec)
        self.edges.pop(s.child, None)
        self._chains.clear()
        self._paths.clear()
        self._edge_m.pop(s.child, None)
        self._add(s.parent, s.child, 0, s.translation, s.rotation_xyzw, "mount")
        return s

    def add_localized(self, sample: TfSample) -> None:
        """Add a sample of an edge estimated by ``replay --localize`` (``map -> odom``): it beats
        every recorded source of that edge (a recorded ``map -> odom`` is ignored)."""
        self._add(norm(sample.parent), norm(sample.child), sample.stamp_ns, sample.translation,
                  sample.rotation_xyzw, "localize")

    def _add(self, parent: str, child: str, stamp: int, t, q, source: str) -> None:
        if parent == child:
            return
        edge = self.edges.get(child)
        self._edge_m.pop(child, None)
        if edge is not None and (edge.source != source or edge.parent != parent):
            have, new = _PRIORITY[edge.source], _PRIORITY[source]
            if new < have or (new == have and edge.source != source):
                self.ignored[f"{parent} -> {child} from {source}"] += 1
                return
            if new > have:
                self.ignored[f"{edge.parent} -> {child} from {edge.source}"] += len(edge.times)
            edge = None  # a stronger source takes the edge, or the same source re-parents the child
        if edge is None:
            edge = self.edges[child] = _Edge(parent, source)
            self._chains.clear()
            self._paths.clear()
        value = np.array([*t, *q], dtype=np.float64)
        edge.count += 1
        if edge.timeless:
            edge.times, edge.values = [0], [value]
            return
        i = bisect.bisect_right(edge.times, stamp)
        if i > 0 and edge.times[i - 1] == stamp:
            edge.values[i - 1] = value
            return
        edge.times.insert(i, stamp)
        edge.values.insert(i, value)
        if len(edge.times) > 64 and edge.times[0] < edge.times[-1] - 2 * self.window_ns:
            cut = bisect.bisect_left(edge.times, edge.times[-1] - self.window_ns) - 1
            if cut > 0:
                del edge.times[:cut]
                del edge.values[:cut]

    # ------------------------------------------------------------------ queries
    @property
    def frames(self) -> set[str]:
        out = set(self.edges)
        out.update(e.parent for e in self.edges.values())
        return out

    def _chain(self, frame: str) -> tuple[str, ...]:
        cached = self._chains.get(frame)
        if cached is not None:
            return cached
        chain = [frame]
        seen = {frame}
        while chain[-1] in self.edges:
            p = self.edges[chain[-1]].parent
            if p in seen:  # a cycle in recorded tf: stop
                break
            chain.append(p)
            seen.add(p)
        self._chains[frame] = out = tuple(chain)
        return out

    def chain(self, frame: str) -> tuple[str, ...]:
        """``frame`` and its parents up to the root of its tree (a cycle in recorded tf ends it)."""
        return self._chain(norm(frame))

    def root(self, frame: str) -> str:
        return self.chain(frame)[-1]

    def _edge_matrix(self, child: str, stamp: int) -> np.ndarray:
        e = self.edges[child]
        cached = self._edge_m.get(child)
        if cached is not None and (e.timeless or cached[0] == stamp):
            return cached[1]
        m = self._compute_edge_matrix(e, child, stamp)
        m.flags.writeable = False  # shared by the lookups that hit the cache
        self._edge_m[child] = (stamp, m)
        return m

    def _compute_edge_matrix(self, e: _Edge, child: str, stamp: int) -> np.ndarray:
        name = f"{e.parent} -> {child}"
        if e.timeless:
            v = e.values[0]
        else:
            ts = e.times
            i = bisect.bisect_left(ts, stamp)
            if i < len(ts) and ts[i] == stamp:
                v = e.values[i]
            elif i == 0:
                if ts[0] - stamp > self.tolerance_ns:
                    raise LookupFailure(f"transform {name} not available yet (stamp before its first sample)",
                                        f"{(ts[0] - stamp) / 1e9:.3f} s early")
                v = e.values[0]
            elif i == len(ts):
                if stamp - ts[-1] > self.tolerance_ns:
                    raise LookupFailure(f"transform {name} not available (stamp after its last sample; "
                                        f"no extrapolation)", f"{(stamp - ts[-1]) / 1e9:.3f} s late")
                v = e.values[-1]
            else:
                t0, t1 = ts[i - 1], ts[i]
                u = (stamp - t0) / (t1 - t0)
                a, b = e.values[i - 1], e.values[i]
                v = np.concatenate([a[:3] + u * (b[:3] - a[:3]), slerp(a[3:], b[3:], u)])
        return make_matrix(v[:3], v[3:])

    def lookup(self, target_frame: str, source_frame: str, stamp_ns: int) -> np.ndarray:
        """``T`` (4x4 float64) with ``p_target = T @ p_source`` at ``stamp_ns``; LookupFailure if not."""
        target, source = norm(target_frame), norm(source_frame)
        if target == source:
            return np.eye(4)
        path_s, path_t = self._paths.get((target, source)) or self._path(target, source)
        m_source = None  # the edges' product from the source up to the common frame
        for child in path_s:
            m = self._edge_matrix(child, stamp_ns)
            m_source = m if m_source is None else m @ m_source
        m_target = None
        for child in path_t:
            m = self._edge_matrix(child, stamp_ns)
            m_target = m if m_target is None else m @ m_target
        if m_target is None:  # (the source's frame is under the target's; a copy: edge matrices are shared)
            return np.array(m_source)
        if m_source is None:
            return invert(m_target)
        return invert(m_target) @ m_source

    def _path(self, target: str, source: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """The children of the edges from ``source`` and from ``target`` up to their common frame
        (cached in ``_paths``); LookupFailure when a frame is unknown or no tf connects them."""
        frames = self.frames
        for f in (source, target):
            if f not in frames:
                raise LookupFailure(self._missing_reason(target, source, f))
        up_s, up_t = self._chain(source), self._chain(target)
        in_t = set(up_t)
        common = next((f for f in up_s if f in in_t), None)
        if common is None:
            raise LookupFailure(
                f"no transform {target} -> {source}: {source} is under {up_s[-1]} and {target} under "
                f"{up_t[-1]}, and no tf connects them; give the missing edge with "
                f"--tf {up_t[-1] if up_t[-1] != target else target}:{up_s[-1]}=x,y,z,roll,pitch,yaw")
        self._paths[(target, source)] = out = (up_s[: up_s.index(common)], up_t[: up_t.index(common)])
        return out

    def _missing_reason(self, target: str, source: str, missing: str) -> str:
        frames = self.frames
        if missing == source:
            parent = next((f for f in ("base_link", "base_footprint") if f in frames), target)
            return (f"no transform {parent} -> {source}: frame {source} is not in tf; give its mount with "
                    f"--tf {parent}:{source}=x,y,z,roll,pitch,yaw")
        known = bounded(sorted(frames))
        return (f"no transform {target} -> {source}: frame {target} is not in tf (frames: {known}); "
                f"choose another with --fixed-frame or give it with --tf")

    def connection_problem(self, target_frame: str, source_frame: str) -> str | None:
        """Why ``source`` can never be placed in ``target`` with the tree as it is (ignoring
        time), or None when a chain of edges connects them."""
        target, source = norm(target_frame), norm(source_frame)
        if target == source:
            return None
        frames = self.frames
        for f in (source, target):
            if f not in frames:
                return self._missing_reason(target, source, f)
        up_s, up_t = self._chain(source), set(self._chain(target))
        if not any(f in up_t for f in up_s):
            try:
                self.lookup(target, source, 0)
            except LookupFailure as err:
                return err.reason
        return None

    def available_until(self, target_frame: str, source_frame: str) -> int | None:
        """The latest stamp at which ``lookup(target, source, stamp)`` can succeed (the oldest
        newest-sample over the chain's timed edges; a huge number when every edge is static), or
        None when the frames are not connected. tf usually arrives after the frames it places:
        hold a frame until ``available_until`` reaches its stamp (or the log ends)."""
        target, source = norm(target_frame), norm(source_frame)
        if self.connection_problem(target, source):
            return None
        up_s, up_t = self._chain(source), self._chain(target)
        common = next(f for f in up_s if f in set(up_t))
        edges = up_s[: up_s.index(common)] + up_t[: up_t.index(common)]
        timed = [self.edges[c].times[-1] for c in edges if not self.edges[c].timeless]
        return min(timed) if timed else 2**63 - 1

    def try_lookup(self, target_frame: str, source_frame: str, stamp_ns: int) -> tuple[np.ndarray | None, str | None]:
        """``(T, None)`` or ``(None, reason)``: the reason names the missing edge, without a stamp."""
        try:
            return self.lookup(target_frame, source_frame, stamp_ns), None
        except LookupFailure as f:
            return None, f.reason

    def fixed_frame(self, requested: str = "", sensor_frames=(), frames=None) -> str:
        """``requested`` if given (a frame of tf, or one of ``sensor_frames``: the sensors' own
        frame ids), else ``map`` when tf has it, else ``odom`` (``choose_fixed_frame``).
        ``frames``: choose among these (the frames tf had at some moment) instead of all."""
        known = self.frames
        frames = known if frames is None else set(frames)
        roots = {norm(f): (self.root(f) if norm(f) in known else norm(f)) for f in sensor_frames}
        return choose_fixed_frame(frames, requested, sensor_frames, roots, [f for f in frames if f not in self.edges])

    def tree_text(self, indent: str = "  ") -> str:
        """The frames as an indented tree; each edge shows its source and how many samples it got
        (all of them, not only those still in the window)."""
        children: dict[str, list[str]] = {}
        for child, e in self.edges.items():
            children.setdefault(e.parent, []).append(child)
        roots = sorted(f for f in self.frames if f not in self.edges)
        lines: list[str] = []

        def walk(frame: str, depth: int, seen: set[str]) -> None:
            e = self.edges.get(frame)
            if e is None:
                note = ""
            elif e.timeless:
                note = f"  [{'user mount' if e.source == 'mount' else 'static'}]"
            else:
                note = f"  [{e.source}, {e.count} samples]"
            lines.append(f"{indent * depth}{frame}{note}")
            for c in sorted(children.get(frame, [])):
                if c not in seen:
                    walk(c, depth + 1, seen | {c})

        for r in roots:
            walk(r, 0, {r})
        return "\n".join(lines)


def choose_fixed_frame(frames: set[str] | list[str], requested: str = "", sensor_frames=(),
                       roots: dict[str, str] | None = None, tf_roots=()) -> str:
    """The fixed frame (as ``TfBuffer.fixed_frame``): ``requested`` if given, which must be a
    frame of tf or a sensor's own frame (a map in that frame: the sensor stands still in it),
    else ``map`` when tf has it, else ``odom``. Otherwise TransformError in one line naming
    ``--fixed-frame`` and ``--tf`` with frames that exist: ``roots`` maps each sensor frame to
    the root of its tf tree (itself when tf does not have it); ``tf_roots`` are the roots of tf."""
    names = {norm(f) for f in frames} - {""}
    sensors = sorted({norm(f) for f in sensor_frames} - {""})
    if requested:
        want = norm(requested)
        if want in names or want in sensors:
            return want
        raise TransformError(f"--fixed-frame {requested}: no frame {want} in tf (frames: "
                             f"{bounded(sorted(names))}) nor among the sensors' frames "
                             f"({bounded(sensors)}); choose one of them")
    for f in ("map", "odom"):
        if f in names:
            return f
    raise TransformError(no_fixed_frame_reason(names, sensors, roots, tf_roots))


def no_fixed_frame_reason(names: set[str], sensors: list[str], roots: dict[str, str] | None = None,
                          tf_roots=()) -> str:
    """Why no fixed frame could be chosen, and the ways out, with frames that exist: a root of
    tf or of a sensor's tree (``--fixed-frame``), or a transform from a fixed frame (``--tf``)."""
    roots = roots or {}
    have = f"tf has neither map nor odom (frames in tf: {bounded(sorted(names))})"
    placed = sorted({roots.get(f, f) for f in sensors} & names)  # tf roots above a sensor
    trees = sorted(set(tf_roots) - set(placed))
    alone = sorted(f for f in sensors if f not in names)  # sensor frames tf does not have
    ways = []
    if placed:
        ways.append(f"--fixed-frame {placed[0]} (the root of the tf above the sensor"
                    f"{'s' if len(sensors) > 1 else ''}{', or ' + bounded(placed[1:], limit=4) if placed[1:] else ''})")
    if alone:
        ways.append(f"--fixed-frame {alone[0]} (the sensor's own frame: a map with it standing still"
                    f"{', or ' + bounded(alone[1:], limit=4) if alone[1:] else ''})")
    if trees and not placed:
        ways.append(f"--fixed-frame {trees[0]} (the root of tf{', or ' + bounded(trees[1:], limit=4) if trees[1:] else ''}"
                    f"; then give the sensor's mount with --tf)")
    if not ways:
        return f"{have}; choose the fixed frame with --fixed-frame <frame>"
    # (no sensor frame known: a log cut before its first sensor message; then the root of tf)
    top = placed[0] if placed else roots.get(sensors[0], sensors[0]) if sensors else trees[0]
    mount = f"--tf odom:{top}=x,y,z,roll,pitch,yaw"
    return f"{have}: choose the fixed frame with {' or '.join(ways)}, or give the transform from a fixed frame with {mount}"


BASE_FRAMES = ("base_link", "base_footprint")  # the robot's frame when the configured one is not in tf


def choose_base_frame(frames: set[str] | list[str], preferred: str) -> str:
    """The robot's base frame: ``preferred`` (``map.robot.base_frame``) when tf has it, else
    ``base_link`` or ``base_footprint`` when tf has one, else ``preferred`` (the robot's
    footprint then cannot be placed and is counted as missing)."""
    names = {norm(f) for f in frames}
    want = norm(preferred)
    if want in names:
        return want
    return next((f for f in BASE_FRAMES if f in names), want)
