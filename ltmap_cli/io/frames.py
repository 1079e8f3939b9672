"""Plain typed frames: what the log readers produce and the pipeline consumes.

Stamps are integer nanoseconds (ROS time). Arrays are numpy; nothing here knows ROS message
classes, so the core and the pipeline never see a deserialized message.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ScanFrame:
    """A sensor_msgs/LaserScan in its own frame."""

    stamp_ns: int
    frame_id: str
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray  # float32 (N,), raw values: NaN / inf kept as recorded
    topic: str = ""
    angle_max_off: bool = False  # the message's angle_max disagrees with its ranges (angles ignore it)
    log: int = 0  # index of the log it comes from, when several are replayed as one stream

    @property
    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(len(self.ranges), dtype=np.float64)


@dataclass(frozen=True)
class CameraIntrinsics:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


@dataclass(frozen=True)
class DepthFrame:
    """A depth image in metres (float32, NaN where invalid) in the optical frame (z forward)."""

    stamp_ns: int
    frame_id: str
    depth_m: np.ndarray  # float32 (H, W); invalid pixels are NaN
    intrinsics: CameraIntrinsics
    topic: str = ""
    log: int = 0  # index of the log it comes from


@dataclass(frozen=True)
class CloudFrame:
    """A point cloud in its own frame; invalid points already removed."""

    stamp_ns: int
    frame_id: str
    points: np.ndarray  # float32 (N, 3)
    topic: str = ""
    log: int = 0  # index of the log it comes from


@dataclass(frozen=True)
class TfSample:
    """One transform parent -> child at a stamp; ``static`` for /tf_static (timeless)."""

    stamp_ns: int
    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation_xyzw: tuple[float, float, float, float]
    static: bool = False


@dataclass(frozen=True)
class OdometrySample:
    stamp_ns: int
    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation_xyzw: tuple[float, float, float, float]


@dataclass
class ReadStats:
    """What a reader saw: messages per topic, and where it stopped if it stopped early."""

    messages_per_topic: dict[str, int] = field(default_factory=dict)
    stopped_at: str | None = None


def frame_nbytes(frame) -> int:
    """The bytes a frame holds in arrays (its numpy fields: an image's pixels, a cloud's points, a
    scan's ranges); 0 for anything else. What the pipeline's buffers count against their bounds."""
    fields = getattr(frame, "__dict__", None)
    if not fields:
        return 0
    return sum(v.nbytes for v in fields.values() if isinstance(v, np.ndarray))
