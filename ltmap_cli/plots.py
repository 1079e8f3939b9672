"""Plotting functions. Each draws on a matplotlib ``ax`` it is given (evo's style); the caller
makes the figure (``new_figure``) and saves it (``save_png``, atomic). Only the Agg canvas is
used (no pyplot, no GUI backend); matplotlib is imported inside the functions so that importing
this module is cheap.

Map images are drawn in world metres: ``imshow`` with the grid's extent, rotated by the origin's
yaw when it is not zero.
"""

from __future__ import annotations

import math

import numpy as np

# colours (RGB 0..255)
FREE_RGB = (247, 247, 247)
UNKNOWN_RGB = (180, 180, 180)
OCCUPIED_RGB = (20, 20, 20)
UNCHANGED_RGB = (110, 110, 110)
ADDED_RGB = (214, 39, 40)
REMOVED_RGB = (44, 160, 44)
ADDED_TOL_RGB = (244, 166, 166)
REMOVED_TOL_RGB = (166, 219, 160)
OCC_UNKNOWN_RGB = (148, 103, 189)
HALF_UNKNOWN_RGB = (212, 214, 232)
INFLATED_RGB = (253, 208, 162)


def new_figure(width_cells: int = 800, height_cells: int = 600, legend: bool = False):
    """A matplotlib Figure on an Agg canvas sized for a map of the given cells, and its axes.

    About one pixel per cell for large maps (capped at 20 in at 100 dpi), at least 6 in wide."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    aspect = height_cells / max(width_cells, 1)
    w_in = min(max(width_cells / 100.0, 6.0), 20.0)
    h_in = min(max(w_in * aspect, 4.0), 20.0)
    extra = 2.8 if legend else 0.0
    fig = Figure(figsize=(w_in + extra + 1.2, h_in + 1.0), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    return fig, ax


def save_png(fig, path) -> None:
    """Write ``fig`` as PNG to ``path`` atomically (temporary file, then rename)."""
    from .io.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")


def _nice_length(span: float) -> float:
    """A 1/2/5 x 10^k length near a fifth of ``span``."""
    if span <= 0:
        return 1.0
    target = span / 5.0
    k = math.floor(math.log10(target))
    for m in (5, 2, 1):
        if m * 10**k <= target:
            return m * 10**k
    return 10**k


def add_scale_bar(ax, length_m: float | None = None, loc: str = "lower right") -> float:
    """Draw a metre scale bar on ``ax`` (whose data units are metres); returns its length."""
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    x0, x1 = ax.get_xlim()
    length = length_m if length_m is not None else _nice_length(abs(x1 - x0))
    label = f"{length:g} m" if length >= 1 else f"{length * 100:g} cm"
    bar = AnchoredSizeBar(
        ax.transData,
        length,
        label,
        loc,
        pad=0.4,
        borderpad=0.6,
        sep=4,
        frameon=True,
        size_vertical=abs(ax.get_ylim()[1] - ax.get_ylim()[0]) / 150.0,
        color="black",
    )
    bar.patch.set_alpha(0.8)
    ax.add_artist(bar)
    return length


def draw_rgb(ax, rgb: np.ndarray, resolution: float, origin) -> None:
    """Draw an RGB image (H, W, 3) whose row 0 is the bottom row, in world metres."""
    from matplotlib.transforms import Affine2D

    h, w = rgb.shape[:2]
    ox, oy, yaw = (float(v) for v in origin)
    if yaw == 0.0:
        ax.imshow(
            rgb,
            origin="lower",
            extent=(ox, ox + w * resolution, oy, oy + h * resolution),
            interpolation="nearest",
        )
        return
    im = ax.imshow(
        rgb, origin="lower", extent=(0, w * resolution, 0, h * resolution), interpolation="nearest"
    )
    im.set_transform(Affine2D().rotate(yaw).translate(ox, oy) + ax.transData)
    c, s = math.cos(yaw), math.sin(yaw)
    cx = np.array([0, w, 0, w]) * resolution
    cy = np.array([0, 0, h, h]) * resolution
    xs, ys = ox + c * cx - s * cy, oy + s * cx + c * cy
    ax.set_xlim(xs.min(), xs.max())
    ax.set_ylim(ys.min(), ys.max())


def _metre_axes(ax) -> None:
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def occupancy_rgb(data: np.ndarray, occupied_min: int = 65) -> np.ndarray:
    """RGB of an occupancy grid: free light, unknown grey, occupied dark."""
    d = np.asarray(data)
    rgb = np.empty(d.shape + (3,), dtype=np.uint8)
    rgb[:] = FREE_RGB
    rgb[d < 0] = UNKNOWN_RGB
    rgb[d >= occupied_min] = OCCUPIED_RGB
    return rgb


def plot_map(ax, grid, title: str | None = None, scale_bar: bool = True) -> None:
    """Draw a GridMap (free light, unknown grey, occupied dark) in metres."""
    from .analysis import OCCUPIED_MIN

    draw_rgb(ax, occupancy_rgb(grid.data, OCCUPIED_MIN), grid.resolution, grid.origin)
    _metre_axes(ax)
    if title:
        ax.set_title(title)
    if scale_bar:
        add_scale_bar(ax)


def plot_diff(ax, result, title: str | None = None, names: tuple[str, str] = ("A", "B")) -> None:
    """Overlay of a ``DiffResult``: grey unchanged occupied, red added, green removed, light
    background where free (known in both), darker where unknown in both, pale blue-grey where
    unknown in one map only; light red / light green for changes
    within the tolerance, purple for occupied in one map and unknown in the other. With a
    legend and a metre scale bar."""
    from matplotlib.patches import Patch

    al = result.aligned
    a, b = al.a, al.b
    rgb = np.empty(a.shape + (3,), dtype=np.uint8)
    rgb[:] = UNKNOWN_RGB
    rgb[(a >= 0) & (b >= 0)] = FREE_RGB
    half = (a < 0) != (b < 0)
    rgb[half] = HALF_UNKNOWN_RGB
    occ_unknown = ((result.occupied_a & (b < 0)) | (result.occupied_b & (a < 0))) & ~result.added
    tol = f"{result.tolerance} cell{'' if result.tolerance == 1 else 's'}"
    layers = [
        (occ_unknown, OCC_UNKNOWN_RGB, "occupied in one map, unknown in the other"),
        (result.unchanged, UNCHANGED_RGB, "occupied in both (unchanged)"),
        (result.added_ignored, ADDED_TOL_RGB, f"added, within {tol} (ignored)"),
        (result.removed_ignored, REMOVED_TOL_RGB, f"removed, within {tol} (ignored)"),
        (result.added, ADDED_RGB, f"added (occupied in {names[1]} only)"),
        (result.removed, REMOVED_RGB, f"removed (occupied in {names[0]}, free in {names[1]})"),
    ]
    handles = [
        Patch(facecolor=np.array(FREE_RGB) / 255, edgecolor="0.5", label="free"),
        Patch(facecolor=np.array(UNKNOWN_RGB) / 255, edgecolor="0.5", label="unknown in both"),
    ]
    if half.any():
        handles.append(
            Patch(facecolor=np.array(HALF_UNKNOWN_RGB) / 255, edgecolor="0.5", label="unknown in one map")
        )
    always = {UNCHANGED_RGB, ADDED_RGB, REMOVED_RGB}
    for mask, colour, label in layers:
        rgb[mask] = colour
        if colour in always or mask.any():
            handles.append(Patch(facecolor=np.array(colour) / 255, edgecolor="0.5", label=label))
    draw_rgb(ax, rgb, al.resolution, al.origin)
    _metre_axes(ax)
    counts = result.counts()
    ax.set_title(
        title
        or f"{names[0]} -> {names[1]}: {counts['added']} added, {counts['removed']} removed, IoU {result.iou:.3f}"
    )
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small", frameon=False)
    add_scale_bar(ax)


def plot_path(
    ax,
    grid,
    path_xy: np.ndarray | None,
    start_xy=None,
    goal_xy=None,
    blocked: np.ndarray | None = None,
    title: str | None = None,
    label: str = "path",
    color: str = "tab:blue",
    draw_map: bool = True,
) -> None:
    """Draw a map (with the inflated zone of ``blocked`` in light orange when given), a path
    (world x, y, shape (K, 2)) and its start and goal. ``draw_map=False`` adds only the path,
    to overlay several paths on one map."""
    from .analysis import OCCUPIED_MIN

    if draw_map:
        rgb = occupancy_rgb(grid.data, OCCUPIED_MIN)
        if blocked is not None:
            d = np.asarray(grid.data)
            rgb[np.asarray(blocked) & (d >= 0) & (d < OCCUPIED_MIN)] = INFLATED_RGB
        draw_rgb(ax, rgb, grid.resolution, grid.origin)
        _metre_axes(ax)
    if path_xy is not None and len(path_xy):
        p = np.asarray(path_xy, dtype=float)
        ax.plot(p[:, 0], p[:, 1], "-", color=color, lw=2, label=label)
    if start_xy is not None:
        ax.plot([start_xy[0]], [start_xy[1]], "o", color="tab:green", ms=8, mec="black", label="start")
    if goal_xy is not None:
        ax.plot([goal_xy[0]], [goal_xy[1]], "*", color="tab:red", ms=13, mec="black", label="goal")
    if title:
        ax.set_title(title)
    if draw_map:
        from matplotlib.patches import Patch

        handles, _ = ax.get_legend_handles_labels()
        handles += [
            Patch(facecolor=np.array(OCCUPIED_RGB) / 255, label="occupied"),
            Patch(facecolor=np.array(UNKNOWN_RGB) / 255, label="unknown"),
        ]
        if blocked is not None:
            handles.append(Patch(facecolor=np.array(INFLATED_RGB) / 255, label="within robot radius"))
        ax.legend(
            handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small", frameon=False
        )
        add_scale_bar(ax)
