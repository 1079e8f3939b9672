"""The depth outlier filter: flying pixels at depth jumps go, surfaces stay."""

import numpy as np

from ltmap_cli.pipeline.filters import depth_jump_mask, flying_pixel_mask

F, CX, CY = 100.0, 39.5, 29.5  # an 80 x 60 camera


def scene():
    """A wall at 3 m with a box face at 2 m in the middle; two mixed pixels on the box's edge."""
    d = np.full((60, 80), 3.0, dtype=np.float32)
    d[20:40, 30:50] = 2.0
    d[25, 30] = 2.5  # left edge of the box: halfway between box and wall
    d[33, 49] = 2.7  # right edge
    d[0, 0] = np.nan
    return d


def test_jump_mask_marks_both_sides_of_each_edge():
    m = depth_jump_mask(scene(), 0.1)
    assert m[30, 29] and m[30, 30] and m[19, 40] and m[20, 40]
    assert not m[10, 10] and not m[30, 40] and not m[0, 0]


def test_flying_pixels_go_and_the_surfaces_stay():
    d = scene()
    drop = flying_pixel_mask(d, F, F, CX, CY, radius=0.06, min_neighbors=3)
    assert drop[25, 30] and drop[33, 49]
    assert drop.sum() == 2  # nothing of the wall or the box face, edges included


def test_no_edges_no_work():
    d = np.full((60, 80), 3.0, dtype=np.float32)
    assert not flying_pixel_mask(d, F, F, CX, CY).any()


def test_replay_with_the_filter_drops_the_flying_voxels(tmp_path):
    """The same depth log replayed with and without --depth-outlier-filter: the two mixed pixels
    of each frame are dropped and counted, and the two voxels they alone occupied (the wall and
    the box face each hit by many pixels) are gone from O; nothing else changes."""
    import json

    from click.testing import CliRunner
    from logfactory import camera_info, image, tf, write_log

    from ltmap_cli.cli import cli

    s = 1_000_000_000
    mm = np.nan_to_num(scene() * 1000.0).round().astype(np.uint16)  # NaN -> 0: invalid
    msgs = [tf(s, [("map", "camera_optical")], static=True)]
    for i in range(3):
        t = s + i * 100_000_000
        msgs.append(camera_info("/cam/depth/camera_info", t, width=80, height=60, fx=F, fy=F, cx=CX, cy=CY))
        msgs.append(image("/cam/depth/image_raw", t + 1, mm))
    log = write_log(tmp_path / "depth.mcap", "mcap-ros2", msgs)

    def replay(out, *extra):
        args = ["replay", str(log), "-o", str(tmp_path / out), "--no-plots", "-q", *extra]
        res = CliRunner().invoke(cli, args, catch_exceptions=False)
        assert res.exit_code == 0, res.output
        return json.loads((tmp_path / out / "report.json").read_text())

    plain = replay("plain")
    filtered = replay("filtered", "--depth-outlier-filter", "--set", "replay.depth_outlier_radius=0.06")
    assert plain["depth_outlier_filter"] == {"enabled": False, "frames": 0, "pixels_dropped": 0}
    assert filtered["depth_outlier_filter"] == {"enabled": True, "frames": 3, "pixels_dropped": 6}
    assert plain["frames_used"] == filtered["frames_used"] == {"/cam/depth/image_raw": 3}
    assert plain["voxels"]["occupied_O"] - filtered["voxels"]["occupied_O"] == 2
