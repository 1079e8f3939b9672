"""A depth camera's intrinsics from a file, for logs recorded without its CameraInfo
(``--camera-info [TOPIC=]FILE``): only the image topic was recorded, or its CameraInfo is wrong.

Two YAML forms, both what ROS users have at hand:

- the calibration file of ``camera_calibration`` / ``camera_info_manager``
  (``~/.ros/camera_info/NAME.yaml``): ``image_width``, ``image_height``, ``camera_matrix``
  (``rows``, ``cols``, ``data``: K row by row), ``distortion_model``,
  ``distortion_coefficients`` (``data``);
- a CameraInfo message as ``ros2 topic echo --once .../camera_info`` prints it: ``width``,
  ``height``, ``k`` (or ROS 1's ``K``), ``distortion_model``, ``d``, ``binning_x``, ``binning_y``,
  ``roi``.

``load_camera_info`` returns an object with a CameraInfo's fields (``width``, ``height``, ``k``,
``d``, ``distortion_model``, ``binning_x``, ``binning_y``, ``roi``), which the readers take as
they take a logged CameraInfo (``decode.intrinsics``, ``rectify.distortion``).
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from ..errors import InputError
from .safe_yaml import load_file

OPTION = "--camera-info"
MAX_CAMERA_FILE_BYTES = 1 << 20  # a calibration file is a few hundred bytes


def parse_spec(spec: str) -> tuple[str, Path]:
    """``[TOPIC=]FILE`` -> (the depth topic it is for, "" for every depth topic without a
    CameraInfo; the file)."""
    topic, sep, path = spec.partition("=")
    if not sep or Path(spec).is_file():  # (a file whose name holds "=")
        topic, path = "", spec
    topic = topic.strip()
    if topic and not topic.startswith("/"):  # (topics are read with their leading slash)
        topic = "/" + topic
    if not path.strip():
        raise InputError(f"{OPTION} {spec}: no file given; give a camera calibration YAML, as "
                         f"{OPTION} FILE or {OPTION} /camera/depth/image_raw=FILE")  # fmt: skip
    return topic, Path(path.strip())


def _numbers(value: Any, n: int | None, what: str, where: str) -> list[float]:
    if isinstance(value, dict):
        value = value.get("data")
    if not isinstance(value, (list, tuple)) or (n is not None and len(value) != n):
        want = f"{n} numbers" if n is not None else "a list of numbers"
        raise InputError(f"{where}: {what} must be {want}, got {str(value)[:80]!r}; see docs/real_logs.md")
    try:
        out = [float(x) for x in value]
    except (TypeError, ValueError):
        raise InputError(f"{where}: {what} must be numbers, got {str(value)[:80]!r}") from None
    if not all(math.isfinite(x) for x in out):
        raise InputError(f"{where}: {what} holds a value that is not finite: {out}")
    return out


def _count(value: Any, what: str, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 1 << 20:
        raise InputError(f"{where}: {what} must be a whole number of pixels from 0, got {str(value)[:40]!r}")
    return value


def load_camera_info(path: Path, spec: str) -> SimpleNamespace:
    """The CameraInfo a calibration or echoed-CameraInfo YAML file holds (see the module doc).
    ``InputError`` (one line: the option, the file, the fault, what to give) otherwise."""
    where = f"{OPTION} {spec}"
    doc = load_file(path, f"camera calibration ({OPTION})", InputError, max_bytes=MAX_CAMERA_FILE_BYTES,
                    trailing_separator=True)  # fmt: skip
    if not isinstance(doc, dict):
        raise InputError(f"{where}: not a camera calibration (a YAML mapping with camera_matrix, or a "
                         f"CameraInfo as `ros2 topic echo --once .../camera_info` prints it)")  # fmt: skip
    if "camera_matrix" in doc:  # camera_calibration_parsers' file
        k = _numbers(doc["camera_matrix"], 9, "camera_matrix", where)
        d = _numbers(doc.get("distortion_coefficients", []), None, "distortion_coefficients", where)
        width = _count(doc.get("image_width", 0), "image_width", where)
        height = _count(doc.get("image_height", 0), "image_height", where)
        binning, roi = (0, 0), (0, 0, 0, 0)
    elif "k" in doc or "K" in doc:  # a CameraInfo message
        k = _numbers(doc.get("k", doc.get("K")), 9, "k", where)
        d = _numbers(doc.get("d", doc.get("D", [])) or [], None, "d", where)
        width = _count(doc.get("width", 0), "width", where)
        height = _count(doc.get("height", 0), "height", where)
        binning = (_count(doc.get("binning_x", 0), "binning_x", where),
                   _count(doc.get("binning_y", 0), "binning_y", where))  # fmt: skip
        r = doc.get("roi") or {}
        if not isinstance(r, dict):
            raise InputError(f"{where}: roi must be a mapping of x_offset, y_offset, width, height")
        roi = tuple(_count(r.get(f, 0), f"roi.{f}", where) for f in ("x_offset", "y_offset", "width", "height"))
    else:
        raise InputError(f"{where}: no camera_matrix (a calibration file) nor k (a CameraInfo) in it; give "
                         f"the camera's calibration YAML or `ros2 topic echo --once .../camera_info` saved to a file")  # fmt: skip
    if not (k[0] > 0 and k[4] > 0):
        raise InputError(f"{where}: focal lengths fx={k[0]}, fy={k[4]} (camera_matrix / k [0] and [4]) must "
                         f"be above 0: the camera is uncalibrated")  # fmt: skip
    model = doc.get("distortion_model") or "plumb_bob"
    return SimpleNamespace(width=width, height=height, k=k, d=d, distortion_model=str(model)[:40],
                           binning_x=binning[0], binning_y=binning[1],
                           roi=SimpleNamespace(x_offset=roi[0], y_offset=roi[1], width=roi[2], height=roi[3]),
                           source=str(path))  # fmt: skip


def load_camera_infos(specs) -> dict[str, SimpleNamespace]:
    """``--camera-info`` specs -> {depth topic ("" for any without a CameraInfo): its CameraInfo};
    one file per topic."""
    out: dict[str, SimpleNamespace] = {}
    for spec in specs:
        topic, path = parse_spec(spec)
        if topic in out:
            raise InputError(f"{OPTION} {spec}: {'the topic ' + topic if topic else 'a file for every topic'} "
                             f"is given twice; give one file per depth topic")  # fmt: skip
        out[topic] = load_camera_info(path, spec)
    return out


__all__ = ["OPTION", "parse_spec", "load_camera_info", "load_camera_infos"]
