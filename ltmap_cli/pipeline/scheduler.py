"""The scheduler: log messages in, placed sensor frames out.

tf and odometry samples go into the tf buffer as they are read. A sensor frame is held until the
tf samples around its header stamp have had time to arrive, then placed with the transform at its
header stamp (SPEC 4) and handed on in stamp order; a frame whose pose cannot be had is a skip
with its reason, never a guess.

The wait for tf is measured in header time (SPEC 4: header stamps may differ from record times
by a constant: a bag re-recorded from playback, sim time, an unsynced clock): a frame is released
once tf has a sample stamped ``wait`` after it, or once it has been held ``wait`` of record time
(tf that stopped, or static tf only), or when too many frames, or too many bytes of them, are
held. With header stamps equal to record times, both conditions are the same. Knows nothing of
the map: testable on its own.
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..errors import TransformError
from ..io.frames import OdometrySample, TfSample, frame_nbytes
from ..io.transforms import TfBuffer, choose_base_frame, norm

MAX_PENDING = 200  # sensor frames held for tf at most (guards logs whose stamps run ahead)
MAX_PENDING_BYTES = 256 << 20  # and their arrays at most (200 large frames would be gigabytes)


@dataclass
class TfSeen:
    """A tf or odometry sample the buffer took in (replay.mcap copies it)."""

    sample: TfSample | OdometrySample
    source: str | None = None  # "localize" for the localization pre-pass's estimates


@dataclass
class Placed:
    """A sensor frame and its pose: ``T`` sensor -> fixed frame, ``robot`` base -> fixed frame (or
    None when the base frame cannot be placed: no footprint), ``lookup_s`` the lookups' seconds."""

    topic: str
    frame: object
    T: np.ndarray
    robot: np.ndarray | None
    lookup_s: float
    log_ns: int = 0  # when the frame was logged (record time)


@dataclass
class Skipped:
    topic: str
    reason: str
    frame: object = None


class FrameHold:
    """Sensor frames held for tf, released in header-stamp order (the rule of the module doc):
    ``push`` each frame, then ``release(log_ns)`` yields those whose tf has had time to
    arrive, and the earliest stamped while more than ``max_pending`` frames or ``max_bytes`` of
    their arrays (``nbytes`` at ``push``) are held; ``flush`` the rest at the end."""

    def __init__(self, wait_ns: int, max_pending: int = MAX_PENDING, max_bytes: int = MAX_PENDING_BYTES):
        self.wait_ns = wait_ns
        self.max_pending = max_pending
        self.max_bytes = max_bytes
        self.bytes = 0  # of the frames held
        self.heap: list = []
        self._seq = 0
        self.tf_high_ns: int | None = None  # newest header stamp of a dynamic tf / odometry sample

    def outdated_by(self, tf: TfBuffer, sample: TfSample | OdometrySample) -> list:
        """The frames held that ``sample`` would push out of the tf buffer's window (a sample far
        newer than them: the next of several logs, recorded long after), removed from the hold:
        place them before ``sample`` goes into tf."""
        if not self.heap or (isinstance(sample, TfSample) and sample.static):
            return []
        return list(self.flush(before_ns=sample.stamp_ns - tf.window_ns // 2))

    def took_tf(self, sample: TfSample | OdometrySample) -> None:
        """``sample`` went into tf: a dynamic one moves the header time tf has reached."""
        if not (isinstance(sample, TfSample) and sample.static):
            self.tf_high_ns = sample.stamp_ns if self.tf_high_ns is None else max(self.tf_high_ns, sample.stamp_ns)

    def __len__(self) -> int:
        return len(self.heap)

    def push(self, stamp_ns: int, log_ns: int, payload, nbytes: int = 0) -> None:
        heapq.heappush(self.heap, (stamp_ns, self._seq, log_ns, payload, nbytes))
        self._seq += 1
        self.bytes += nbytes

    def _pop(self):
        entry = heapq.heappop(self.heap)
        self.bytes -= entry[4]
        return entry[3]

    def release(self, log_ns: int) -> Iterator:
        heap, wait, tf_high_ns = self.heap, self.wait_ns, self.tf_high_ns
        while heap and (
            (tf_high_ns is not None and heap[0][0] <= tf_high_ns - wait)
            or heap[0][2] <= log_ns - wait
            or len(heap) > self.max_pending
            or self.bytes > self.max_bytes
        ):
            yield self._pop()

    def flush(self, before_ns: int | None = None) -> Iterator:
        """The frames held (those stamped before ``before_ns``, when given), in stamp order."""
        while self.heap and (before_ns is None or self.heap[0][0] < before_ns):
            yield self._pop()

    def payloads(self) -> Iterator:
        return (entry[3] for entry in self.heap)


class Scheduler:
    """``feed(topic, log_ns, item)`` for each message in log order, then ``flush()``; both yield
    ``TfSeen``, ``Placed`` and ``Skipped`` events. ``fixed_frame`` and ``base_frame`` are chosen at
    the first sensor frame placed (``fixed_frame_request``: the user's, else map, else odom)."""

    def __init__(self, tf: TfBuffer, *, wait_ns: int, fixed_frame_request: str = "", base_frame: str = "base_link",
                 timer=None, max_pending: int = MAX_PENDING, max_bytes: int = MAX_PENDING_BYTES):  # fmt: skip
        self.tf = tf
        self.request = fixed_frame_request
        self.base_request = base_frame
        self.timer = timer
        self.fixed_frame: str | None = None
        self.base_frame: str | None = None
        self.fixed_later: tuple | None = None  # (--fixed-frame, sensor frames) when tf lacked it at the start
        self.hold = FrameHold(wait_ns, max_pending, max_bytes)

    def feed(self, topic: str, log_ns: int, item) -> Iterator[TfSeen | Placed | Skipped]:
        if isinstance(item, (TfSample, OdometrySample)):
            for t, frame, at in self.hold.outdated_by(self.tf, item):
                yield self._place(t, frame, at)
            t0 = time.perf_counter()
            self.tf.add(item)
            self.hold.took_tf(item)
            self._time("tf", t0)
            yield TfSeen(item)
        else:
            self.hold.push(item.stamp_ns, log_ns, (topic, item, log_ns), frame_nbytes(item))
        for t, frame, at in self.hold.release(log_ns):
            yield self._place(t, frame, at)

    def add_localized(self, sample: TfSample) -> TfSeen:
        """A map -> odom estimate of the localization pre-pass, taken in as if recorded (its edge
        beats a recorded one)."""
        self.tf.add_localized(sample)
        return TfSeen(sample, source="localize")

    def flush(self) -> Iterator[Placed | Skipped]:
        for t, frame, at in self.hold.flush():
            yield self._place(t, frame, at)

    def _time(self, stage: str, t0: float) -> float:
        dt = time.perf_counter() - t0
        if self.timer is not None:
            self.timer.add(stage, dt)
        return dt

    def _choose_frames(self, sensor_frames: set[str]) -> None:
        """The fixed frame (``TfBuffer.fixed_frame``: a sensor's own frame may be asked for) and
        the robot's base frame, once tf has had the samples before the first frame."""
        try:
            self.fixed_frame = self.tf.fixed_frame(self.request, sensor_frames)
        except TransformError:
            if not self.request:
                raise
            # not in tf yet (a map frame that a localizer starts publishing later): frames are
            # skipped until it comes; if it never does, the run ends with choose_fixed_frame's line
            self.fixed_frame = norm(self.request)
            self.fixed_later = (self.request, sensor_frames)
        self.base_frame = choose_base_frame(self.tf.frames, self.base_request)

    def _place(self, topic: str, frame, log_ns: int) -> Placed | Skipped:
        t0 = time.perf_counter()
        if self.fixed_frame is None:
            self._choose_frames({frame.frame_id, *(f.frame_id for _, f, _ in self.hold.payloads())})
        if not frame.frame_id:
            return Skipped(topic, f"{topic}: message has an empty header.frame_id", frame)
        T, reason = self.tf.try_lookup(self.fixed_frame, frame.frame_id, frame.stamp_ns)
        if T is None:
            return Skipped(topic, reason, frame)
        robot, _ = self.tf.try_lookup(self.fixed_frame, self.base_frame, frame.stamp_ns)
        return Placed(topic, frame, T, robot, self._time("tf", t0), log_ns)
