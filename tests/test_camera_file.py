"""A depth camera's intrinsics from a file (``--camera-info [TOPIC=]FILE``, ``io/camera_file.py``):
logs recorded without their CameraInfo map as the same log with it; a wrong logged CameraInfo is
replaced for the topic named; a bad file is one line, exit 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from logfactory import camera_info, image, tf, write_log

from ltmap_cli.cli import cli

S = 1_000_000_000
TOPIC = "/cam/depth/image_raw"
W, H, FX, FY, CX, CY = 32, 24, 28.8, 30.1, 15.5, 11.25

CALIBRATION = f"""\
image_width: {W}
image_height: {H}
camera_name: depth
camera_matrix:
  rows: 3
  cols: 3
  data: [{FX}, 0, {CX}, 0, {FY}, {CY}, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0, 0, 0, 0, 0]
"""

# what `ros2 topic echo --once /cam/depth/camera_info` prints (the header's stamp cut short)
ECHOED = f"""\
header:
  stamp:
    sec: 1
    nanosec: 0
  frame_id: camera_optical
height: {H}
width: {W}
distortion_model: plumb_bob
d:
- 0.0
- 0.0
- 0.0
- 0.0
- 0.0
k:
- {FX}
- 0.0
- {CX}
- 0.0
- {FY}
- {CY}
- 0.0
- 0.0
- 1.0
binning_x: 0
binning_y: 0
roi:
  x_offset: 0
  y_offset: 0
  height: 0
  width: 0
  do_rectify: false
---
"""


def _depth(i: int) -> np.ndarray:
    """A wall 3 m ahead with a box 1.5 m ahead that moves a pixel per frame (millimetres)."""
    d = np.full((H, W), 3000, dtype=np.uint16)
    d[8:16, 6 + i : 14 + i] = 1500
    d[0, :3] = 0  # no return
    return d


def _log(tmp_path: Path, name: str, fx: float | None = FX) -> Path:
    """Five depth images in 0.5 s; with their CameraInfo (focal length ``fx``) unless None."""
    msgs = [tf(S // 2, [("map", "camera_optical", (0.0, 0.0, 1.0), (0.5, -0.5, 0.5, -0.5))], static=True)]
    for i in range(5):
        t = S + i * S // 10
        if fx is not None:
            msgs.append(camera_info("/cam/depth/camera_info", t, width=W, height=H, fx=fx, fy=FY, cx=CX, cy=CY))
        msgs.append(image(TOPIC, t + 1, _depth(i)))
    return write_log(tmp_path / f"{name}.mcap", "mcap-ros2", msgs)


def _replay(tmp_path: Path, log: Path, name: str, *args: str):
    out = tmp_path / name
    r = CliRunner().invoke(cli, ["replay", str(log), "-o", str(out), "--no-plots", "-q", *args])
    return r, out


def _state(out: Path) -> dict:
    with np.load(out / "snapshots" / "state_final.npz") as z:
        return {k: z[k] for k in z.files}


def _same_map(a: Path, b: Path) -> None:
    assert (a / "map.pgm").read_bytes() == (b / "map.pgm").read_bytes()
    sa, sb = _state(a), _state(b)
    assert sa.keys() == sb.keys()
    for k in sa:
        assert np.array_equal(sa[k], sb[k]), k


def test_a_log_without_camera_info_maps_with_its_calibration_file(tmp_path):
    ref, ref_out = _replay(tmp_path, _log(tmp_path, "with_info"), "ref")
    assert ref.exit_code == 0, ref.output
    bare = _log(tmp_path, "bare", fx=None)
    # without: the one depth topic is skipped, and the line says what to give
    r, _ = _replay(tmp_path, bare, "none")
    assert r.exit_code == 2 and r.output.count("\n") == 1
    assert "depth Image without CameraInfo" in r.output and "--camera-info FILE" in r.output
    for form, text in (("calibration", CALIBRATION), ("echoed", ECHOED)):
        f = tmp_path / f"{form}.yaml"
        f.write_text(text)
        r, out = _replay(tmp_path, bare, form, "--camera-info", str(f))
        assert r.exit_code == 0, r.output
        _same_map(ref_out, out)
        lo = _state(out)["O_logodds"]
        assert (lo > 0).sum() > 100 and (lo < 0).sum() > 1000  # the wall and box seen, and the free space
    # info says where the intrinsics come from
    r = CliRunner().invoke(cli, ["info", str(bare), "--camera-info", str(tmp_path / "calibration.yaml")])
    assert r.exit_code == 0, r.output
    assert f"(CameraInfo {tmp_path / 'calibration.yaml'} (--camera-info)), 32x24 fx 28.8 fy 30.1 cx 15.5 cy 11.25" \
        in r.output  # fmt: skip


def test_info_says_the_intrinsics_of_a_binned_camera(tmp_path):
    """A 64 x 48 camera binned 2 x 2 (K halved by hand: fx 57.6 -> 28.8, cx 31 -> 15.5)."""
    msgs = [tf(S // 2, [("map", "camera_optical", (0.0, 0.0, 1.0), (0.5, -0.5, 0.5, -0.5))], static=True),
            camera_info("/cam/depth/camera_info", S, width=64, height=48, fx=57.6, fy=60.2, cx=31.0, cy=22.5,
                        binning=(2, 2)),
            image(TOPIC, S + 1, _depth(0))]  # fmt: skip
    log = write_log(tmp_path / "binned.mcap", "mcap-ros2", msgs)
    r = CliRunner().invoke(cli, ["info", str(log)])
    assert r.exit_code == 0, r.output
    assert "32x24 fx 28.8 fy 30.1 cx 15.5 cy 11.25 of 64x48 with binning 2x2" in r.output, r.output


def test_a_topic_named_takes_the_file_instead_of_its_logged_camera_info(tmp_path):
    ref, ref_out = _replay(tmp_path, _log(tmp_path, "right"), "ref")
    assert ref.exit_code == 0, ref.output
    wrong = _log(tmp_path, "wrong", fx=2 * FX)  # a CameraInfo with another camera's focal length
    calib = tmp_path / "calib.yaml"
    calib.write_text(CALIBRATION)
    r, out = _replay(tmp_path, wrong, "unqualified", "--camera-info", str(calib))
    assert r.exit_code == 0, r.output  # a file for every topic: only where the log has none
    assert not np.array_equal(_state(out)["O_logodds"], _state(ref_out)["O_logodds"])  # the log's fx
    for spec in (f"{TOPIC}={calib}", f"{TOPIC.lstrip('/')}={calib}"):  # (with or without its leading slash)
        r, out = _replay(tmp_path, wrong, f"named{len(spec)}", "--camera-info", spec)
        assert r.exit_code == 0, r.output
        _same_map(ref_out, out)


@pytest.mark.parametrize("content, spec, words", [
    (None, "{f}", ["calib.yaml: camera calibration (--camera-info) not found"]),
    ("image_width: 32\n", "{f}", ["no camera_matrix", "nor k"]),
    (CALIBRATION.replace(f"data: [{FX}, 0,", "data: [0, 0,"), "{f}", ["fx=0.0", "uncalibrated"]),
    (CALIBRATION.replace(f"data: [{FX}, 0,", "data: [oops, 0,"), "{f}", ["camera_matrix must be numbers"]),
    (CALIBRATION.replace(", 0, 0, 1]", ", 0, 1]"), "{f}", ["camera_matrix must be 9 numbers"]),
    (CALIBRATION, "/no/such/topic={f}", ["has no depth image topic /no/such/topic"]),
    (CALIBRATION, "{f} --camera-info {f}", ["is given twice"]),
    ("[1, 2", "{f}", ["not valid YAML"]),
])  # fmt: skip
def test_a_bad_camera_file_is_one_line(tmp_path, content, spec, words):
    f = tmp_path / "calib.yaml"
    if content is not None:
        f.write_text(content)
    args = spec.format(f=f).split(" --camera-info ")
    r, out = _replay(tmp_path, _log(tmp_path, "bare", fx=None), "out", *sum((["--camera-info", a] for a in args), []))
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert r.output.startswith("ltmap: error: ") and "Traceback" not in r.output
    for w in words:
        assert w in r.output, r.output
    assert not out.exists()
