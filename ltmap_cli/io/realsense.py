"""The RealSense SDK's own bag layout (RealSense Viewer, rs-record, ``rs2::recorder``).

A stream's topics hang under ``/device_<d>/sensor_<s>/<Stream>_<i>/``: images on
``.../image/data`` (depth as ``mono16``), the stream's CameraInfo on ``.../info/camera_info``
(not beside the image), its extrinsics on ``.../tf/<i>`` (a geometry_msgs/Transform), and the
sensor's options as ``std_msgs/Float32`` topics ``/device_<d>/sensor_<s>/option/<Name>/value``,
among them ``Depth Units``: metres per depth unit (0.001 by default, other values on request).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
FLOAT32 = "std_msgs/msg/Float32"
DEPTH_UNITS_OPTION = "Depth Units"

_STREAM_IMAGE = re.compile(r"^(?P<sensor>.*/sensor_\d+)/(?P<stream>[^/]+)/image/data$")


def _sensor_topic(image_topic: str, topics: Mapping[str, Any], path: str, msgtype: str) -> str | None:
    """``<sensor>/<path>`` (``{stream}`` filled in) of the RealSense SDK image topic when the log
    has it with ``msgtype``; None when ``image_topic`` is not laid out that way or it is absent."""
    m = _STREAM_IMAGE.match(image_topic)
    if m is None:
        return None
    name = f"{m['sensor']}/{path.format(stream=m['stream'])}"
    t = topics.get(name)
    return name if t is not None and getattr(t, "msgtype", None) == msgtype else None


def camera_info_topic(image_topic: str, topics: Mapping[str, Any]) -> str | None:
    """The CameraInfo topic of a RealSense SDK image topic (``.../<Stream>/info/camera_info``)."""
    return _sensor_topic(image_topic, topics, "{stream}/info/camera_info", CAMERA_INFO)


def depth_units_topic(image_topic: str, topics: Mapping[str, Any]) -> str | None:
    """The ``Depth Units`` option topic of the sensor that records ``image_topic``."""
    return _sensor_topic(image_topic, topics, f"option/{DEPTH_UNITS_OPTION}/value", FLOAT32)


def depth_units(msg: Any) -> float | None:
    """Metres per depth unit from a ``Depth Units`` Float32 message; None when not a usable
    value (then the default applies)."""
    try:
        v = float(msg.data)
    except (AttributeError, TypeError, ValueError):
        return None
    return v if 1e-7 <= v <= 1.0 else None
