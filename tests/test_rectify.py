"""Depth from a camera with lens distortion (CameraInfo ``d``): resampled to the pinhole image of
the same K before mapping (``io.rectify``). A wide camera with barrel distortion looks at a wall
3 m away whose edge is at x = 1.8 m, the background 5 m away; the recorded pixels are rendered
through the lens by inverting its model here (fixed-point iterations, as OpenCV's undistortPoints),
apart from ltmap's forward model."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from logfactory import FORMATS, SUFFIX, camera_info, image, tf, write_log

from ltmap_cli.cli import cli
from ltmap_cli.errors import LogReadError
from ltmap_cli.io import rectify

S = 1_000_000_000
W, H, F = 320, 240, 200.0
CX, CY = (W - 1) / 2, (H - 1) / 2
K1, K2 = -0.3, 0.1  # barrel, as a wide lens: about 9 % at the wall's edge


def recorded_wall(k1=K1, k2=K2) -> np.ndarray:
    """The 16UC1 image the lens records: each recorded pixel's ray, undistorted by iteration,
    meets the wall (z = 3 m) where x / z < 0.6, else the background (z = 5 m)."""
    ud, vd = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    xd, yd = (ud - CX) / F, (vd - CY) / F
    x, y = xd.copy(), yd.copy()
    for _ in range(50):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2
        x, y = xd / radial, yd / radial
    return np.where(x < 0.6, 3000, 5000).astype(np.uint16)


def _log(tmp_path, fmt, px, d, model="plumb_bob", name="log"):
    msgs = [tf(S // 2, [("map", "cam")], static=True)]
    for i in range(3):
        t = S + i * S // 10
        msgs.append(camera_info("/cam/depth/camera_info", t, width=W, height=H, fx=F, fy=F, cx=CX, cy=CY,
                                frame_id="cam", d=d, model=model))  # fmt: skip
        msgs.append(image("/cam/depth/image_raw", t + 1, px, frame_id="cam"))
    return write_log(tmp_path / (name + SUFFIX[fmt]), fmt, msgs)


def _wall_edge_voxel(out) -> int:
    from ltmap_cli.io.state import read_state

    a, _ = read_state(out / "snapshots" / "state_final.npz")
    occ = a["O_logodds"] > 0
    blocks = a["O_block_coords"].astype(np.int64)
    b, off = np.nonzero(occ)
    keys = blocks[b] * 8 + np.stack([off >> 6, (off >> 3) & 7, off & 7], axis=1)
    wall = keys[keys[:, 2] == 60]  # voxels whose centre is 3.025 m along the optical axis
    assert len(wall) > 100
    return int(wall[:, 0].max())


@pytest.mark.parametrize("fmt", ["mcap-ros2", "ros1"])
def test_a_distorted_depth_image_is_mapped_where_the_lens_saw_it(tmp_path, fmt):
    """With the CameraInfo's plumb_bob coefficients the wall's edge (x = 1.8 m: voxel 35, or 36
    from the nearest pixel's half-pixel rounding) is where it is; read as a pinhole image (the
    same pixels, d = 0) it lands about 0.17 m short (voxel 32): what ltmap did before."""
    px = recorded_wall()
    rep = {}
    for name, d in (("lens", (K1, K2, 0.0, 0.0, 0.0)), ("pinhole", (0.0,) * 5)):
        log = _log(tmp_path, fmt, px, d, name=name)
        out = tmp_path / f"o_{name}"
        r = CliRunner().invoke(cli, ["replay", str(log), "-o", str(out), "-q", "--no-plots", "--fixed-frame", "map"])
        assert r.exit_code == 0, r.output
        rep[name] = _wall_edge_voxel(out)
        assert json.loads((out / "report.json").read_text())["frames_used"] == {"/cam/depth/image_raw": 3}
    assert rep["lens"] in (35, 36) and rep["pinhole"] <= 33, rep


def test_the_lens_models_by_hand():
    x, y = np.array([0.5, -0.3, 0.0]), np.array([0.2, 0.4, 0.0])
    r2 = x * x + y * y
    pb = rectify.Distortion("plumb_bob", (0.1, -0.05, 0.01, 0.02, 0.003))
    xd, yd = rectify.distort(x, y, pb, "here")
    radial = 1 + 0.1 * r2 - 0.05 * r2**2 + 0.003 * r2**3
    assert np.allclose(xd, x * radial + 2 * 0.01 * x * y + 0.02 * (r2 + 2 * x * x))
    assert np.allclose(yd, y * radial + 0.01 * (r2 + 2 * y * y) + 2 * 0.02 * x * y)
    rp = rectify.Distortion("rational_polynomial", (0.1, -0.05, 0.01, 0.02, 0.003, 0.2, 0.01, 0.001))
    xr, _ = rectify.distort(x, y, rp, "here")
    den = 1 + 0.2 * r2 + 0.01 * r2**2 + 0.001 * r2**3
    assert np.allclose(xr, x * radial / den + 2 * 0.01 * x * y + 0.02 * (r2 + 2 * x * x))
    eq = rectify.Distortion("equidistant", (0.0, 0.0, 0.0, 0.0))
    xe, ye = rectify.distort(x, y, eq, "here")
    r = np.sqrt(r2)
    assert np.allclose(xe[:2], x[:2] * np.arctan(r[:2]) / r[:2]) and xe[2] == 0.0 and ye[2] == 0.0
    with pytest.raises(LogReadError, match="distortion model 'fov'"):
        rectify.distort(x, y, rectify.Distortion("fov", (0.5,)), "on /x")


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_carries_the_coefficients_and_zero_ones_change_nothing(tmp_path, fmt):
    """The distortion reaches the decoder from every log format (the fast CDR path too); all-zero
    coefficients leave the pixels as recorded (no resampling)."""
    from ltmap_cli.io.logs import open_logs

    px = recorded_wall()
    got = {}
    for name, d in (("lens", (K1, K2, 0.0, 0.0, 0.0)), ("pinhole", (0.0,) * 5)):
        log = _log(tmp_path, fmt, px, d, name=name)
        with open_logs(log) as logs:
            got[name] = [f.raw for _, _, f in logs.messages(logs.select(), fast=True) if hasattr(f, "raw")]
    assert len(got["lens"]) == 3 and all(np.array_equal(a, px) for a in got["pinhole"])
    rect = got["lens"][0]
    assert not np.array_equal(rect, px)
    row = rect[int(CY)]  # the centre row: the wall ends at the pixel of x / z = 0.6
    assert abs(int(np.argmax(row == 5000)) - (CX + 0.6 * F)) <= 2.0  # (nearest pixels: recorded, then resampled)
    assert (rect == 0).sum() == 0  # barrel: every pinhole pixel's ray is inside the recorded image


def test_info_says_the_lens_is_rectified(tmp_path):
    log = _log(tmp_path, "mcap-ros2", recorded_wall(), (K1, K2, 0.0, 0.0, 0.0))
    r = CliRunner().invoke(cli, ["info", str(log)])
    assert r.exit_code == 0, r.output
    row = next(ln for ln in r.stdout.splitlines() if ln.startswith("/cam/depth/image_raw "))
    assert row.endswith(f"(CameraInfo /cam/depth/camera_info), {W}x{H} fx {F:g} fy {F:g} cx {CX:g} cy {CY:g}, "
                        "lens plumb_bob rectified to pinhole"), row  # fmt: skip
    log = _log(tmp_path, "mcap-ros2", recorded_wall(), (0.5,), model="fov", name="fov")
    r = CliRunner().invoke(cli, ["info", str(log)])
    said = "CameraInfo for depth on /cam/depth/image_raw, message index 0 in " + str(log) + " has distortion " \
        "model 'fov' with non-zero coefficients"  # fmt: skip
    assert "/cam/depth/image_raw: replay would stop on its first image: " + said in r.stdout, r.stdout
    r = CliRunner().invoke(cli, ["replay", str(log), "-o", str(tmp_path / "o"), "-q", "--no-plots"])
    assert r.exit_code == 2 and said in r.stderr, r.output  # (the same line as replay's)


def test_the_map_in_row_blocks_and_a_hostile_coefficient_list(monkeypatch):
    """The resampling map computed a few rows at a time (its temporaries bounded) is the map
    computed at once; a CameraInfo with a million coefficients keeps the first 14."""
    dist = rectify.Distortion("plumb_bob", (K1, K2, 0.001, -0.002, 0.0))
    whole = rectify.source_index(W, H, F, F, CX, CY, dist, "here").copy()
    rectify._MAPS.clear()
    monkeypatch.setattr(rectify, "MAP_ROWS_PIXELS", 3 * W + 7)  # 3 rows a block, the last one short
    assert np.array_equal(rectify.source_index(W, H, F, F, CX, CY, dist, "here"), whole)

    class Info:
        d = np.full(1_000_000, 0.5)
        distortion_model = "plumb_bob"

    assert len(rectify.distortion(Info()).d) == rectify.MAX_COEFFS
