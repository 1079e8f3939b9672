"""The replay's plots (SPEC 6) and the 3D picture: each writes a real, non-blank PNG."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ltmap_cli.io.mapfile import GridMap
from ltmap_cli.viz import plots, render3d

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def check_png(path, min_bytes: int = 10_000, min_size=(300, 200), min_std: float = 5.0):
    data = Path(path).read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > min_bytes, len(data)
    with Image.open(path) as im:
        im.load()
        w, h = im.size
        px = np.asarray(im.convert("L"), dtype=float)
    assert w >= min_size[0] and h >= min_size[1], (w, h)
    assert w <= 6000 and h <= 6000, (w, h)
    assert px.std() > min_std, px.std()  # not a blank image
    return w, h


def grid_map(h=80, w=120, res=0.1, origin=(-2.0, -1.0, 0.0)):
    data = np.zeros((h, w), np.int8)
    data[:, 0] = data[:, -1] = data[0, :] = data[-1, :] = 100
    data[40:43, 20:90] = 100
    data[60:, 100:] = -1
    return GridMap(data=data, resolution=res, origin=origin)


def event(eid, kind, cx, cy, sx=0.6, sy=0.4):
    return {
        "id": eid,
        "kind": kind,
        "centroid": (cx, cy, 0.3),
        "extent_min": (cx - sx / 2, cy - sy / 2, 0.0),
        "extent_max": (cx + sx / 2, cy + sy / 2, 0.6),
    }


def history(n=120, t0=5.0, appear=True):
    t = np.linspace(0.0, 40.0, n)
    rise = np.clip((t - t0) / 4.0, 0, 1)
    slow = np.clip((t - t0) / 20.0, 0, 1)
    st, lt = (0.5 + 0.5 * rise, 0.5 + 0.5 * slow) if appear else (1 - 0.97 * rise, 1 - 0.97 * slow)
    return {
        "t": t,
        "st_mean": st,
        "lt_mean": lt,
        "st_min": np.clip(st - 0.1, 0, 1),
        "st_max": np.clip(st + 0.05, 0, 1),
        "lt_min": np.clip(lt - 0.05, 0, 1),
        "lt_max": np.clip(lt + 0.02, 0, 1),
        "marks": {"first seen": t0, "in P": t0 + 12.0},
    }


def save(fig, path):
    plots.save_png(fig, path)
    return path


def test_importing_plots_does_not_import_matplotlib():
    code = "import sys, ltmap_cli.viz.plots, ltmap_cli.viz.render3d; print('matplotlib' in sys.modules, 'open3d' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


def test_layer_history(tmp_path):
    h = history()
    fig, ax = plots.new_plot_figure()
    plots.plot_layer_history(
        ax,
        h["t"],
        h["st_mean"],
        h["lt_mean"],
        title="event 3",
        st_spread=(h["st_min"], h["st_max"]),
        lt_spread=(h["lt_min"], h["lt_max"]),
        marks={"first seen": 5.0, "in P": 17.0, "removed": 38.0, "close": 38.5},
    )
    assert ax.get_ylim() == (0.0, 1.05)
    assert ax.get_title() == "event 3"
    assert any(
        abs(line.get_ydata()[0] - 0.65) < 1e-12 for line in ax.get_lines() if line.get_linestyle() == "--"
    )
    check_png(save(fig, tmp_path / "h.png"))


@pytest.mark.parametrize("n", [0, 1, 2])
def test_layer_history_few_samples(tmp_path, n):
    t = np.arange(n, dtype=float)
    fig, ax = plots.new_plot_figure()
    plots.plot_layer_history(ax, t, np.full(n, 0.7), np.full(n, 0.5), title="few", marks={"in P": 3.0})
    check_png(save(fig, tmp_path / "h.png"))


def test_layer_history_length_mismatch():
    fig, ax = plots.new_plot_figure()
    with pytest.raises(ValueError):
        plots.plot_layer_history(ax, np.arange(3.0), np.zeros(2), np.zeros(3), title="bad")


def test_latency_boxes(tmp_path):
    rng = np.random.default_rng(0)
    lat = {"add": list(rng.gamma(4, 3, 9)), "remove": [7.5], "planner": []}
    fig, ax = plots.new_plot_figure()
    plots.plot_latency_boxes(ax, lat, targets={"st_rise_s": 2.0, "add": 20.0})
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert labels[0].startswith("add\nn = 9") and labels[1].startswith("remove\nn = 1")
    assert labels[2] == "planner\nn = 0"
    assert any(t.get_text() == "no events" for t in ax.texts)
    check_png(save(fig, tmp_path / "b.png"))


def test_latency_boxes_all_empty(tmp_path):
    fig, ax = plots.new_plot_figure()
    plots.plot_latency_boxes(ax, {"add": [], "remove": [], "planner": [float("nan")]})
    check_png(save(fig, tmp_path / "b.png"))


def test_processing_hist(tmp_path):
    rng = np.random.default_rng(1)
    per = {
        "/scan": rng.lognormal(1.4, 0.4, 500),
        "/points": rng.lognormal(3.7, 0.5, 200),
        "tick": np.zeros(0),
    }
    fig, ax = plots.new_plot_figure()
    plots.plot_processing_hist(ax, per, periods_ms={"/scan": 66.7, "/points": 33.3})
    assert ax.get_xscale() == "log"
    labels = ax.get_legend_handles_labels()[1]
    assert any("p50" in s and "p95" in s and "p99" in s and "% over period" in s for s in labels)
    assert any(s == "tick: no frames" for s in labels)
    x0, x1 = ax.get_xlim()
    assert x0 < 33.3 < x1 and x0 < 66.7 < x1
    check_png(save(fig, tmp_path / "p.png"))


def test_processing_hist_narrow_and_empty(tmp_path):
    fig, ax = plots.new_plot_figure()
    plots.plot_processing_hist(ax, {"tick": np.array([10.0, 11.0, 12.0, 10.5])}, periods_ms={"tick": 100.0})
    assert ax.get_xscale() == "linear"
    assert ax.get_xlim()[1] > 100.0
    check_png(save(fig, tmp_path / "p.png"))
    fig, ax = plots.new_plot_figure()
    plots.plot_processing_hist(ax, {})
    check_png(save(fig, tmp_path / "p0.png"))


def _event_boxes(ax):
    return {p.get_gid(): p for p in ax.patches if (p.get_gid() or "").startswith("event ")}


def test_map_events_boxes_in_place(tmp_path):
    g = grid_map()
    evs = [event(1, "appear", 2.0, 3.0, 0.6, 0.4), event(2, "disappear", 6.0, 1.0, 1.2, 0.8)]
    path = np.array([[-1.5, -0.5], [3.0, 1.0], [8.0, 5.0]])
    robot = np.array([[-1.5, -0.5], [0.0, 0.5], [1.0, 0.2]])
    fig, ax = plots.new_figure(g.width, g.height, legend=True)
    plots.plot_map_events(ax, g, evs, path_xy=path, robot_xy=robot)
    boxes = _event_boxes(ax)
    assert set(boxes) == {"event 1", "event 2"}
    b = boxes["event 1"]
    assert b.get_x() == pytest.approx(1.7) and b.get_y() == pytest.approx(2.8)
    assert b.get_width() == pytest.approx(0.6) and b.get_height() == pytest.approx(0.4)
    # the box's path in data coordinates covers exactly the event's xy extent
    ext = b.get_patch_transform().transform(b.get_path().vertices)
    assert ext.min(axis=0) == pytest.approx([1.7, 2.8]) and ext.max(axis=0) == pytest.approx([2.3, 3.2])
    # the appear box and the disappear box have different colours
    assert boxes["event 1"].get_edgecolor() != boxes["event 2"].get_edgecolor()
    # and the map extent covers the grid
    assert ax.get_xlim() == pytest.approx((-2.0, 10.0)) and ax.get_ylim() == pytest.approx((-1.0, 7.0))
    check_png(save(fig, tmp_path / "m.png"))


def test_map_events_degenerate_and_empty(tmp_path):
    g = grid_map()
    single = {
        "id": 7,
        "kind": "appear",
        "centroid": (1, 1, 0),
        "extent_min": (1, 1, 0),
        "extent_max": (1, 1, 0),
    }
    fig, ax = plots.new_figure(g.width, g.height, legend=True)
    plots.plot_map_events(ax, g, [single])
    b = _event_boxes(ax)["event 7"]
    assert b.get_width() == pytest.approx(g.resolution) and b.get_x() == pytest.approx(1 - g.resolution / 2)
    check_png(save(fig, tmp_path / "m1.png"))
    fig, ax = plots.new_figure(g.width, g.height, legend=True)
    plots.plot_map_events(ax, g, [])
    assert not _event_boxes(ax)
    assert "0 appeared, 0 disappeared" in ax.get_title()
    check_png(save(fig, tmp_path / "m0.png"))


def summary_inputs(n_events: int):
    evs = [
        event(i, "appear" if i % 2 else "disappear", 1.0 + i * 0.8, 2.0 + (i % 3)) for i in range(n_events)
    ]
    hist = {i: history(t0=3.0 + i, appear=bool(i % 2)) for i in range(n_events)}
    rng = np.random.default_rng(2)
    return dict(
        grid=grid_map(),
        events=evs,
        histories=hist,
        latencies={"add": list(rng.uniform(2, 9, n_events)), "remove": [], "planner": []},
        processing_ms={"/scan": rng.lognormal(1.5, 0.3, 300), "tick": rng.lognormal(2.5, 0.3, 100)},
        periods_ms={"/scan": 66.7, "tick": 100.0},
    )


@pytest.mark.parametrize("n_events", [0, 1, 14])
def test_write_summary_plots(tmp_path, n_events):
    out = plots.write_summary_plots(
        tmp_path / "plots",
        **summary_inputs(n_events),
        path_xy=np.array([[0.0, 0.0], [5.0, 5.0]]),
        robot_xy=np.array([[0.0, 0.0], [1.0, 1.0]]),
        targets={"st_rise_s": 2.0},
    )
    names = {"layer_history", "latency_boxes", "processing_latency", "map_events"}
    assert set(out) == names
    for name in names:
        assert out[name] == str(tmp_path / "plots" / f"{name}.png")
        check_png(out[name])
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == sorted(f"{n}.png" for n in names)
    if n_events == 14:  # twelve subplots at most, three per row: four rows
        with Image.open(out["layer_history"]) as im:
            assert im.size[1] > 4 * 300


def voxel_scene(res=0.1):
    def box(x0, x1, y0, y1, z0, z1):
        return np.mgrid[x0:x1:res, y0:y1:res, z0:z1:res].reshape(3, -1).T + res / 2

    static = np.vstack([box(0, 4, 0, 0.1, 0, 1.5), box(0, 0.1, 0, 3, 0, 1.5)])
    dyn = np.vstack([box(1, 1.5, 1, 1.6, 0, 0.8), box(2.5, 3.0, 2.0, 2.4, 0, 1.2), static[::5]])
    return dyn, static


def test_render_map_3d(tmp_path):
    dyn, static = voxel_scene()
    p = tmp_path / "map_3d.png"
    used = render3d.render_map_3d(
        p, dyn, None, 0.1, static_centers=static, title="test", width=640, height=480
    )
    assert used in ("open3d", "matplotlib")
    w, h = check_png(p)
    assert (w, h) == (640, 480)
    assert not list(tmp_path.glob(".*tmp*"))  # atomic write left no temporary file


def test_render_map_3d_matplotlib_merges_large_maps(tmp_path):
    dyn, static = voxel_scene(res=0.05)
    p = tmp_path / "m.png"
    used = render3d.render_map_3d(
        p, dyn, np.linspace(0, 1, len(dyn)), 0.05, static_centers=static, renderer="matplotlib",
        color_by="value", width=400, height=300, max_points=2000, max_faces=3000,
    )  # fmt: skip
    assert used == "matplotlib"
    check_png(p, min_bytes=5_000, min_size=(400, 300))


def test_render_map_3d_empty_and_single(tmp_path):
    for name, c in (("empty", np.zeros((0, 3))), ("one", np.array([[0.0, 0.0, 0.0]]))):
        p = tmp_path / f"{name}.png"
        used = render3d.render_map_3d(p, c, None, 0.1, renderer="matplotlib", width=400, height=300)
        assert used == "matplotlib"
        check_png(p, min_bytes=3_000, min_size=(400, 300))


def test_render_map_3d_bad_arguments(tmp_path):
    with pytest.raises(ValueError):
        render3d.render_map_3d(tmp_path / "x.png", np.zeros((1, 3)), None, 0.0)
    with pytest.raises(ValueError):
        render3d.render_map_3d(tmp_path / "x.png", np.zeros((1, 3)), None, 0.1, renderer="povray")
    assert not (tmp_path / "x.png").exists()


def test_open3d_probe_is_cached(monkeypatch):
    calls = []

    class FailingProbe:  # the child Python of the probe, which fails (no EGL)
        returncode = 1

        def communicate(self, timeout=None):
            return "", "no EGL"

    def fake_launch():
        calls.append(1)
        return FailingProbe()

    monkeypatch.setattr(render3d, "_probe_cache", None)
    monkeypatch.setattr(render3d, "_probe_proc", None)
    monkeypatch.setattr(render3d, "_launch_probe", fake_launch)
    assert render3d.open3d_offscreen_available() is False
    assert render3d.open3d_offscreen_available() is False
    assert len(calls) == 1


def test_open3d_failure_falls_back(tmp_path, monkeypatch):
    monkeypatch.setattr(render3d, "open3d_offscreen_available", lambda refresh=False: True)

    def boom(*a, **k):
        raise RuntimeError("Failed to load vulkan library!")

    monkeypatch.setattr(render3d, "_render_open3d", boom)
    p = tmp_path / "f.png"
    dyn, static = voxel_scene()
    assert (
        render3d.render_map_3d(p, dyn, None, 0.1, static_centers=static, width=400, height=300)
        == "matplotlib"
    )
    check_png(p, min_bytes=5_000, min_size=(400, 300))


def test_visible_faces_of_a_block():
    res = 0.1
    block = np.mgrid[0:3, 0:3, 0:3].reshape(3, -1).T * res + res / 2
    vox, dirs = render3d.visible_faces(block, res)
    assert len(vox) == 6 * 9  # the surface of a 3x3x3 block
    assert np.bincount(dirs, minlength=6).tolist() == [9] * 6


def test_event_titles_say_when_p_did_not_change():
    from ltmap_cli.viz.plots import _event_title

    e = {"kind": "disappear", "centroid": [3.06, 1.93, 0.28], "p_cells": 0}
    assert _event_title(e, 9) == "event 9: disappear at (3.1, 1.9) m (P unchanged)"
    assert _event_title(dict(e, p_cells=4), 9) == "event 9: disappear at (3.1, 1.9) m"


def test_map_events_fill_the_events_own_cells(tmp_path):
    """With event_cells, an L-shaped event fills its own cells (not its bounding box): one RGBA
    image over the map, opaque exactly at those cells, in the event's colour."""
    from matplotlib.colors import to_rgba as rgba
    from matplotlib.image import AxesImage

    g = grid_map()
    res = g.resolution
    corner = np.array([[2.0, 3.0], [2.0 + res, 3.0], [2.0 + 2 * res, 3.0], [2.0, 3.0 + res], [2.0, 3.0 + 2 * res]])
    ev = event(1, "appear", 2.0 + 1.5 * res, 3.0 + 1.5 * res, 3 * res, 3 * res)
    fig, ax = plots.new_figure(g.width, g.height, legend=True)
    plots.plot_map_events(ax, g, [ev], event_cells={1: corner})
    overlays = [im for im in ax.get_children() if isinstance(im, AxesImage) and im.get_array().ndim == 3
                and im.get_array().shape[2] == 4]  # fmt: skip
    (over,) = [im for im in overlays if np.asarray(im.get_array())[..., 3].any()]
    a = np.asarray(over.get_array())
    rows, cols = np.nonzero(a[..., 3] > 0)
    got = sorted(zip((cols * res + g.origin[0]).round(6).tolist(), (rows * res + g.origin[1]).round(6).tolist()))
    assert got == sorted(map(tuple, corner.round(6).tolist()))
    assert tuple(a[rows[0], cols[0]]) == pytest.approx(rgba(plots.EVENT_COLORS["appear"], 0.6))
    assert _event_boxes(ax)["event 1"].get_linewidth() < 1  # the box is only an outline now
    check_png(save(fig, tmp_path / "cells.png"))
