"""Plots that stay readable (issue 18): map_events.png with hundreds of events, map_3d.png that
shows the objects with sane axes and a truthful title, processing_latency.png not stretched by a
few slow first frames."""

from __future__ import annotations

import numpy as np
import pytest

from ltmap_cli.io.mapfile import GridMap
from ltmap_cli.viz import plots, render3d

R = 0.05


def room_grid(w=120, h=80) -> GridMap:
    data = np.zeros((h, w), dtype=np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    return GridMap(data, R, (0.0, 0.0, 0.0))


def random_events(n: int, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        c = rng.uniform([0.3, 0.3], [5.7, 3.7])
        s = rng.uniform(0.05, 0.4, 2)
        out.append({"id": k + 1, "kind": ("appear", "disappear")[k % 2], "extent_min": [*(c - s / 2), 0.0],
                    "extent_max": [*(c + s / 2), 0.5], "p_cells": int(rng.integers(0, 3))})  # fmt: skip
    return out


def label_boxes(fig, ax):
    """{label text: its box in pixels, with the padding of its round box}."""
    from matplotlib.transforms import Bbox

    fig.canvas.draw()  # as saved: the axes box after the equal aspect
    renderer = fig.canvas.get_renderer()
    out = {}
    for t in ax.texts:
        if t.get_bbox_patch() is None:
            continue
        e = t.get_window_extent(renderer)
        pad = 0.15 * t.get_fontsize() * fig.dpi / 72.0
        out[t.get_text()] = Bbox.from_extents(e.x0 - pad, e.y0 - pad, e.x1 + pad, e.y1 + pad)
    return out


@pytest.mark.parametrize("shape", [(120, 80), (60, 200)])
def test_hundreds_of_events_labels_only_p_changes_and_never_overlap(shape):
    g = room_grid(*shape)
    events = random_events(300)
    fig, ax = plots.new_figure(100, 100, legend=True)  # a figure whose shape is not the map's
    plots.plot_map_events(ax, g, events)
    boxes = label_boxes(fig, ax)
    changed = {str(e["id"]) for e in events if e["p_cells"] > 0}
    assert boxes and set(boxes) <= changed  # only events that changed P get an id
    assert len(boxes) >= 20  # as many as fit
    bb = list(boxes.values())
    for a in range(len(bb)):
        for b in range(a + 1, len(bb)):
            assert not bb[a].overlaps(bb[b]), (list(boxes)[a], list(boxes)[b])
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(f"ids: {len(boxes)} of the {len(changed)} events that changed P" in t for t in legend)
    # every event is drawn (a box each), labelled or not
    assert sum(1 for p in ax.patches if str(p.get_gid()).startswith("event ")) == 300


def test_map_view_is_the_occupied_part_of_a_large_grid():
    data = np.zeros((1000, 1000), dtype=np.int8)  # 50 x 50 m of free space (a laser's no-return beams)
    data[400:480, 300:420] = 0
    data[400, 300:420] = data[479, 300:420] = 100
    g = GridMap(data, R, (-25.0, -25.0, 0.0))
    x0, x1, y0, y1 = plots.map_view(g, [], robot_xy=np.array([[-7.0, -3.0]]))
    assert (x0, y0) == pytest.approx((-25 + 300 * R - 1.0 + R / 2, -25 + 400 * R - 1.0 + R / 2))
    assert (x1, y1) == pytest.approx((-25 + 419 * R + 1.0 + R / 2, -25 + 479 * R + 1.0 + R / 2))
    assert plots.map_view(GridMap(np.zeros((10, 10), np.int8), R, (0, 0, 0))) == (0.0, 0.5, 0.0, 0.5)


def test_processing_histogram_is_clipped_at_p99_and_says_so():
    rng = np.random.default_rng(1)
    scan = rng.lognormal(np.log(0.5), 0.3, 800)
    scan[:3] = [3000.0, 900.0, 400.0]  # the first frames: kernels loading
    tick = rng.lognormal(np.log(2.0), 0.3, 400)
    fig, ax = plots.new_plot_figure(9.0, 5.0)
    plots.plot_processing_hist(ax, {"/scan": scan, "tick": tick}, periods_ms={"/scan": 100.0, "tick": 200.0})
    p99 = max(np.percentile(scan, 99), np.percentile(tick, 99))
    clip = max(p99, 200.0)
    assert ax.get_xlim()[1] <= clip * 1.1 + 1e-9
    label = ax.get_xlabel()
    assert "clipped" in label and "3 frames up to 3000 ms" in label
    # the three are counted in the last bin, not dropped: the /scan outline's last step is 3 high
    outline = ax.patches[0].get_path().vertices  # histtype="step": (x, count) corners
    last = outline[np.isclose(outline[:, 0], ax.get_xlim()[1])]
    assert last[:, 1].max() == 3
    # no outliers: the axis is not clipped and says nothing
    fig, ax = plots.new_plot_figure(9.0, 5.0)
    plots.plot_processing_hist(ax, {"tick": np.array([10.0, 11.0, 12.0])}, periods_ms={"tick": 100.0})
    assert "clipped" not in ax.get_xlabel()


def test_3d_laser_only_one_height_has_sane_z_ticks_and_no_colour_bar():
    rng = np.random.default_rng(2)
    ij = np.unique(rng.integers(0, 100, (300, 2)), axis=0)
    centres = np.column_stack([(ij + 0.5) * R, np.full(len(ij), 0.275)])  # one layer at the laser
    fig = render3d.figure_3d(centres, None, R, width=640, height=480)
    ax = fig.axes[0]
    assert len(fig.axes) == 1  # no colour bar spanning nothing
    z0, z1 = ax.get_zlim()
    assert z0 == pytest.approx(0.0) and z1 >= 0.5  # from the floor
    ticks = [t for t in ax.get_zticks() if z0 - 1e-9 <= t <= z1 + 1e-9]
    assert 2 <= len(ticks) <= 6 and min(np.diff(ticks)) >= 0.1
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend == ["long-term voxels (z = 0.28 m)"]
    title = ax.get_title()
    assert "static" not in title and "long-term voxels" in title


def test_3d_static_walls_are_cut_and_the_title_says_so():
    wall = np.array([[x, 0.025, z] for x in np.arange(0.025, 3.0, R) for z in np.arange(0.025, 2.5, R)])
    table = np.array([[1.5 + dx, 1.0 + dy, 0.725] for dx in np.arange(0, 0.5, R) for dy in np.arange(0, 0.3, R)])
    c, v, s, what = render3d.cutaway(table, None, wall, R)
    assert len(c) == len(table) and s[:, 2].max() < 0.3 and what == "static walls (grey) cut at 0.3 m"
    fig = render3d.figure_3d(table, None, R, static_centers=wall, width=640, height=480)
    assert fig.axes[0].get_title().endswith("static walls (grey) cut at 0.3 m")
    # without a static layer, the front walls (low y, high x) are cut, the objects are not
    room = np.array([[x, 0.025, z] for x in np.arange(0.025, 3.0, R) for z in np.arange(0.025, 1.0, R)]
                    + [[x, 2.975, z] for x in np.arange(0.025, 3.0, R) for z in np.arange(0.025, 1.0, R)])  # fmt: skip
    allc = np.vstack([room, table])
    c, _, _, what = render3d.cutaway(allc, None, None, R)
    front = c[c[:, 1] < 0.5]
    back = c[c[:, 1] > 2.5]
    assert front[:, 2].max() < 0.3 and back[:, 2].max() > 0.9  # the back wall stays whole
    assert len(c[(c[:, 2] > 0.7) & (c[:, 1] > 0.5) & (c[:, 1] < 2.5)]) == len(table)
    assert what == "front walls cut at 0.3 m"
