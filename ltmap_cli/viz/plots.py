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

from ..thresholds import OCCUPIED_MIN, OCCUPIED_THRESH

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


def save_png(fig, path, crop: bool = True) -> None:
    """Write ``fig`` as PNG to ``path`` atomically (temporary file, then rename), cropped to what
    it draws (``bbox_inches="tight"``, which draws the figure twice), or with ``crop=False`` as
    it is (a figure whose margins are set to fit it)."""
    from ..io.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight" if crop else None)


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


def occupancy_rgb(data: np.ndarray, occupied_min: int = OCCUPIED_MIN) -> np.ndarray:
    """RGB of an occupancy grid: free light, unknown grey, occupied dark."""
    d = np.asarray(data)
    rgb = np.empty(d.shape + (3,), dtype=np.uint8)
    rgb[:] = FREE_RGB
    rgb[d < 0] = UNKNOWN_RGB
    rgb[d >= occupied_min] = OCCUPIED_RGB
    return rgb


def plot_map(ax, grid, title: str | None = None, scale_bar: bool = True) -> None:
    """Draw a GridMap (free light, unknown grey, occupied dark) in metres."""
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


# ---------------------------------------------------------------------------------------------
# Plots of a replay (SPEC 6): layer history (the paper's Fig. 4), latency boxes (Fig. 5),
# processing time, the final map with its events, and ``write_summary_plots`` that writes them.
# Colours are Okabe & Ito's colour-blind-safe palette.

OI_ORANGE = "#E69F00"
OI_SKY = "#56B4E9"
OI_GREEN = "#009E73"
OI_YELLOW = "#F0E442"
OI_BLUE = "#0072B2"
OI_VERMILLION = "#D55E00"
OI_PURPLE = "#CC79A7"
OI_BLACK = "#000000"
OI_CYCLE = (OI_BLUE, OI_VERMILLION, OI_GREEN, OI_ORANGE, OI_PURPLE, OI_SKY, OI_BLACK, OI_YELLOW)

ST_COLOR = OI_BLUE
LT_COLOR = OI_VERMILLION
EVENT_COLORS = {"appear": OI_VERMILLION, "disappear": OI_BLUE}
LATENCY_COLORS = {"add": OI_VERMILLION, "remove": OI_BLUE, "planner": OI_GREEN}
PATH_COLOR = OI_GREEN
TRAJECTORY_COLOR = OI_PURPLE
MAX_HISTORY_EVENTS = 12


def new_plot_figure(
    width_in: float = 8.0, height_in: float = 5.0, nrows: int = 1, ncols: int = 1, layout: str | None = None
):
    """A Figure on an Agg canvas (no pyplot) with ``nrows x ncols`` axes; returns (fig, axes),
    axes a single Axes when 1 x 1, else a 2D array. ``layout``: matplotlib's figure layout
    engine (``"constrained"``), or None."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=100, layout=layout)
    FigureCanvasAgg(fig)
    if nrows == 1 and ncols == 1:
        return fig, fig.add_subplot(1, 1, 1)
    return fig, fig.subplots(nrows, ncols, squeeze=False)


def _finite(values) -> np.ndarray:
    a = np.asarray(values, dtype=float).ravel()
    return a[np.isfinite(a)]


def _fmt(v: float) -> str:
    """Three significant digits, no exponent for ordinary latencies."""
    if v == 0 or not math.isfinite(v):
        return f"{v:g}"
    if abs(v) >= 100:
        return f"{v:.0f}"
    return f"{v:.3g}"


def _no_data(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", color="0.4", style="italic")


def plot_layer_history(
    ax,
    times_s: np.ndarray,
    st: np.ndarray,
    lt: np.ndarray,
    *,
    title: str,
    st_spread: tuple[np.ndarray, np.ndarray] | None = None,
    lt_spread: tuple[np.ndarray, np.ndarray] | None = None,
    occupied_thresh: float = OCCUPIED_THRESH,
    marks: dict[str, float] | None = None,
    legend: bool = True,
) -> None:
    """The paper's Fig. 4 for one event: the ``ST`` and ``LT`` values of its voxels over log time
    (mean lines; ``*_spread`` = (min, max) arrays draw a band), the occupied threshold dashed,
    and a labelled vertical line per mark (``{"first seen": 3.2, "in P": 18.2}``, seconds).
    y in [0, 1.05]; x is the log's time in seconds (linear). NaN samples leave gaps."""
    t = np.asarray(times_s, dtype=float).ravel()
    series = [
        ("ST (short-term)", np.asarray(st, dtype=float).ravel(), st_spread, ST_COLOR, "-"),
        ("LT (long-term)", np.asarray(lt, dtype=float).ravel(), lt_spread, LT_COLOR, "-"),
    ]
    marker = "o" if len(t) < 3 else None
    for label, y, spread, colour, ls in series:
        if len(y) != len(t):
            raise ValueError(f"{label}: {len(y)} values for {len(t)} times")
        if spread is not None:
            lo, hi = (np.asarray(s, dtype=float).ravel() for s in spread)
            if len(lo) == len(t) and len(hi) == len(t) and len(t):
                ax.fill_between(
                    t, lo, hi, color=colour, alpha=0.18, lw=0, label=f"{label.split()[0]} min-max"
                )
        if len(t):
            ax.plot(t, y, ls, color=colour, lw=2, marker=marker, label=f"{label} mean")
    ax.axhline(
        occupied_thresh, color="0.25", ls="--", lw=1.2, label=f"occupied threshold {occupied_thresh:g}"
    )
    if not len(t):
        _no_data(ax, "no samples")
    xs = list(t[np.isfinite(t)])
    mark_items = sorted(
        ((float(v), k) for k, v in (marks or {}).items() if v is not None and math.isfinite(v))
    )
    xs += [v for v, _ in mark_items]
    if xs:
        x0, x1 = min(xs), max(xs)
        pad = 0.03 * (x1 - x0) if x1 > x0 else 1.0
        ax.set_xlim(x0 - pad, x1 + pad)
    if mark_items:
        from matplotlib.transforms import blended_transform_factory

        trans = blended_transform_factory(ax.transData, ax.transAxes)
        x0, x1 = ax.get_xlim()
        styles = [":", "-.", (0, (5, 2, 1, 2)), (0, (1, 3))]
        level, last_x = 0, None
        for i, (v, name) in enumerate(mark_items):
            ax.axvline(v, color="0.2", ls=styles[i % len(styles)], lw=1.2)
            # stagger the labels of marks that are close to each other
            level = level + 1 if last_x is not None and (v - last_x) < 0.06 * (x1 - x0) else 0
            last_x = v
            ax.text(
                v,
                0.97 - 0.33 * (level % 3),
                f" {name} {v:.1f} s",
                transform=trans,
                rotation=90,
                ha="right",
                va="top",
                fontsize="small",
                color="0.15",
                bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.75),
            )
    ax.set_ylim(0.0, 1.05)
    ax.set_xlabel("log time [s]")
    ax.set_ylabel("layer value")
    ax.set_title(title)
    ax.grid(True, color="0.9", lw=0.8)
    ax.set_axisbelow(True)
    if legend:
        ax.legend(loc="lower right", fontsize="small", framealpha=0.85)


def plot_latency_boxes(
    ax,
    latencies: dict[str, list[float]],
    *,
    targets: dict[str, float] | None = None,
    title: str = "Event latencies",
) -> None:
    """The paper's Fig. 5: a box plot per latency kind (``{"add": [...], "remove": [...],
    "planner": [...]}``, seconds) with the individual values overlaid (jittered), n and the
    median in the tick labels. A kind with no (finite) values is shown as "no events".
    ``targets``: a key naming a kind draws a dashed line across that box; any other key
    (e.g. ``st_rise_s``) a dashed line across the whole plot."""
    from matplotlib.transforms import blended_transform_factory

    names = list(latencies)
    trans = blended_transform_factory(ax.transData, ax.transAxes)
    rng = np.random.default_rng(0)
    tick_labels = []
    all_vals: list[float] = []
    for i, name in enumerate(names, start=1):
        v = _finite(latencies[name])
        colour = LATENCY_COLORS.get(name, OI_CYCLE[(i + 2) % len(OI_CYCLE)])
        if len(v) == 0:
            ax.text(
                i, 0.5, "no events", transform=trans, ha="center", va="center", color="0.4", style="italic"
            )
            tick_labels.append(f"{name}\nn = 0")
            continue
        all_vals += list(v)
        bp = ax.boxplot(
            [v],
            positions=[i],
            widths=0.5,
            showfliers=False,
            patch_artist=True,
            whis=(0, 100),
            medianprops=dict(color="black", lw=2),
        )
        for box in bp["boxes"]:
            box.set_facecolor(colour)
            box.set_alpha(0.3)
        jitter = rng.uniform(-0.13, 0.13, len(v)) if len(v) > 1 else np.zeros(1)
        ax.scatter(
            i + jitter, v, s=22, color=colour, edgecolors="black", linewidths=0.5, zorder=3, alpha=0.85
        )
        tick_labels.append(f"{name}\nn = {len(v)}, median {_fmt(float(np.median(v)))} s")
    for k, (name, value) in enumerate((targets or {}).items()):
        if value is None or not math.isfinite(value):
            continue
        style = ["--", "-.", ":"][k % 3]
        if name in names:
            i = names.index(name) + 1
            ax.plot(
                [i - 0.4, i + 0.4],
                [value, value],
                ls=style,
                color="0.2",
                lw=1.5,
                label=f"{name} target {_fmt(value)} s",
            )
        else:
            ax.axhline(value, ls=style, color="0.2", lw=1.2, label=f"{name} = {_fmt(value)} s")
        all_vals.append(float(value))
    ax.set_xticks(range(1, len(names) + 1))
    ax.set_xticklabels(tick_labels)
    ax.set_xlim(0.4, len(names) + 0.6)
    if all_vals:
        lo, hi = min(0.0, min(all_vals)), max(all_vals)
        ax.set_ylim(lo, hi * 1.08 if hi > 0 else 1.0)
    else:
        ax.set_ylim(0.0, 1.0)
    ax.set_ylabel("latency [s]")
    ax.set_title(title)
    ax.grid(True, axis="y", color="0.9", lw=0.8)
    ax.set_axisbelow(True)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize="small", framealpha=0.85)


def plot_processing_hist(
    ax,
    per_source_ms: dict[str, np.ndarray],
    *,
    periods_ms: dict[str, float] | None = None,
    title: str = "Processing time per frame (wall clock)",
    bins: int = 50,
) -> None:
    """Histogram of the wall-clock processing time of each frame, per source (sensor topic, or
    ``tick``), on shared bins; log-scaled x when the values span more than ~30x. A dashed line
    per source at its frame period (``periods_ms``): mass right of it is a frame that took longer
    than the sensor's period. p50/p95/p99 and the share over the period are in the legend.

    The x axis ends at the largest p99 of the sources (or the largest period, if larger): a few
    slow first frames (caches filling) would otherwise stretch it; frames beyond are counted in
    the last bin and the x label says how many and up to what time."""
    periods = {
        k: float(v) for k, v in (periods_ms or {}).items() if v is not None and math.isfinite(v) and v > 0
    }
    data = {name: _finite(v) for name, v in per_source_ms.items()}
    values = np.concatenate([v for v in data.values()] + [np.zeros(0)])
    if len(values) == 0:
        _no_data(ax, "no frames")
    clip = max((float(np.percentile(v, 99)) for v in data.values() if len(v)), default=None)
    beyond = 0
    if clip is not None and len(values):
        clip = max([clip] + list(periods.values()))
        beyond = int((values > clip).sum())
        top = float(values.max())
        values = np.minimum(values, clip)
    pos = values[values > 0]
    log = len(pos) > 0 and pos.max() / pos.min() > 30.0
    pers = [periods[k] for k in data if k in periods]
    span = list(values) + pers
    if log:
        lo, hi = min([float(pos.min())] + pers), max([float(pos.max())] + pers)
        edges = np.geomspace(lo / 1.1, hi * 1.1, bins + 1)
        ax.set_xscale("log")
    elif span:
        lo, hi = min(0.0, min(span)), max(span)
        edges = np.linspace(lo, hi * 1.05 if hi > 0 else 1.0, bins + 1)
    else:
        edges = np.linspace(0.0, 1.0, bins + 1)
    for i, (name, v) in enumerate(data.items()):
        colour = OI_CYCLE[i % len(OI_CYCLE)]
        if len(v) == 0:
            ax.plot([], [], color=colour, lw=2, label=f"{name}: no frames")
        else:
            p50, p95, p99 = np.percentile(v, [50, 95, 99])
            label = f"{name} (n = {len(v)}): p50 {_fmt(p50)}, p95 {_fmt(p95)}, p99 {_fmt(p99)} ms"
            if name in periods:
                label += f"; {100.0 * np.mean(v > periods[name]):.1f}% over period"
            vv = np.clip(v, edges[0], edges[-1])  # frames beyond the clip in the last bin
            ax.hist(vv, bins=edges, histtype="step", lw=2, color=colour, label=label)
            ax.hist(vv, bins=edges, histtype="stepfilled", color=colour, alpha=0.12)
        if name in periods:
            ax.axvline(
                periods[name],
                color=colour,
                ls="--",
                lw=1.5,
                label=f"{name} frame period {_fmt(periods[name])} ms",
            )
    ax.set_xlim(edges[0], edges[-1])
    xlabel = "processing time per frame [ms]" + (" (log scale)" if log else "")
    if beyond:
        xlabel += (f"\naxis clipped at the largest p99 or period ({_fmt(clip)} ms): {beyond} frame"
                   f"{'s' if beyond > 1 else ''} up to {_fmt(top)} ms counted in the last bin")  # fmt: skip
    ax.set_xlabel(xlabel)
    ax.set_ylabel("frames")
    ax.set_title(title)
    ax.grid(True, color="0.9", lw=0.8)
    ax.set_axisbelow(True)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.2 if beyond else -0.14), fontsize="small",
                  frameon=False, ncol=1)  # fmt: skip


def event_rectangle(event: dict, min_size: float = 0.0):
    """(x0, y0, width, height) of an event's xy extent, grown about its centre to ``min_size``."""
    (x0, y0), (x1, y1) = event["extent_min"][:2], event["extent_max"][:2]
    x0, x1 = sorted((float(x0), float(x1)))
    y0, y1 = sorted((float(y0), float(y1)))
    if x1 - x0 < min_size:
        c = 0.5 * (x0 + x1)
        x0, x1 = c - min_size / 2, c + min_size / 2
    if y1 - y0 < min_size:
        c = 0.5 * (y0 + y1)
        y0, y1 = c - min_size / 2, c + min_size / 2
    return x0, y0, x1 - x0, y1 - y0


def _paint_event_cells(ax, grid, events: list[dict], event_cells: dict) -> None:
    """Fill each event's cells in its kind's colour: one RGBA image over the map's extent."""
    from matplotlib.colors import to_rgba as _rgba

    from ..analysis import in_bounds, world_to_cell

    res = float(grid.resolution)
    ox, oy = float(grid.origin[0]), float(grid.origin[1])
    H, W = np.asarray(grid.data).shape
    over = np.zeros((H, W, 4), dtype=np.float32)
    for e in events:
        xy = event_cells.get(e.get("id"))
        if xy is None or not len(xy):
            continue
        centre = np.asarray(xy, dtype=float) + 0.5 * res  # lower-left corners -> centres
        r, c = world_to_cell(grid, centre[:, 0], centre[:, 1])
        ok = in_bounds(grid, r, c)
        over[r[ok], c[ok]] = _rgba(EVENT_COLORS.get(e.get("kind", "appear"), OI_PURPLE), 0.6)
    ax.imshow(over, origin="lower", extent=(ox, ox + W * res, oy, oy + H * res), interpolation="nearest",
              zorder=3)  # fmt: skip


def map_view(grid, events: list[dict] = (), robot_xy=None, path_xy=None, margin: float = 1.0):
    """(x0, x1, y0, y1): the part of ``grid`` worth showing with events, in metres: its occupied
    cells, the events, the robot's trajectory and the path, with ``margin`` around, within the
    grid (a laser's no-return beams can clear free space far beyond the rooms). The whole grid
    when there is nothing of these."""
    from ..analysis import occupied_centres

    ox, oy = float(grid.origin[0]), float(grid.origin[1])
    res = float(grid.resolution)
    full = (ox, ox + grid.width * res, oy, oy + grid.height * res)
    pts = []
    walls = occupied_centres(grid)
    if len(walls):
        pts.append(walls)
    for e in events:
        pts.append(np.array([e["extent_min"][:2], e["extent_max"][:2]], dtype=float))
    for xy in (robot_xy, path_xy):
        if xy is not None and len(xy):
            pts.append(np.asarray(xy, dtype=float).reshape(-1, 2))
    if not pts:
        return full
    p = np.concatenate(pts)
    p = p[np.isfinite(p).all(axis=1)]
    if not len(p):
        return full
    x0, y0 = p.min(axis=0) - margin
    x1, y1 = p.max(axis=0) + margin
    x0, x1 = max(x0, full[0]), min(x1, full[1])
    y0, y1 = max(y0, full[2]), min(y1, full[3])
    if x1 <= x0 or y1 <= y0:
        return full
    return (float(x0), float(x1), float(y0), float(y1))


def _label_size_px(ax, text: str) -> tuple[float, float]:
    """Width and height in pixels of an event label (small bold text in a padded box)."""
    from matplotlib.font_manager import FontProperties

    fs = FontProperties(size="small").get_size_in_points()
    dpi = ax.figure.dpi
    return ((0.72 * fs * len(text) + 0.9 * fs) * dpi / 72.0, (1.3 * fs + 0.7 * fs) * dpi / 72.0)


def _place_labels(ax, boxes: list[tuple[str, tuple[float, float, float, float]]]) -> list:
    """Positions for labels next to their boxes (x0, y0, w, h in data units) that overlap no
    label placed before them and stay inside the axes: [(text, (x, y) display anchor of the label's
    lower-left corner) or None when no place is free], in the order given (place the important
    ones first)."""
    ax.apply_aspect()  # the axes box as it will be drawn (equal aspect shrinks it)
    to_px = ax.transData.transform
    bb = ax.get_window_extent()
    placed: list[tuple[float, float, float, float]] = []
    out = []
    gap = 2.0
    for text, (x0, y0, w, h) in boxes:
        lw, lh = _label_size_px(ax, text)
        (px0, py0), (px1, py1) = to_px((x0, y0)), to_px((x0 + w, y0 + h))
        cands = [(px0, py1 + gap), (px1 - lw, py1 + gap), (px0, py0 - gap - lh), (px1 - lw, py0 - gap - lh),
                 (px1 + gap, (py0 + py1 - lh) / 2), (px0 - gap - lw, (py0 + py1 - lh) / 2)]  # fmt: skip
        where = None
        for cx, cy in cands:
            r = (cx, cy, cx + lw, cy + lh)
            if r[0] < bb.x0 or r[1] < bb.y0 or r[2] > bb.x1 or r[3] > bb.y1:
                continue
            if any(r[0] < q[2] and q[0] < r[2] and r[1] < q[3] and q[1] < r[3] for q in placed):
                continue
            where = (cx, cy)
            placed.append(r)
            break
        out.append((text, where))
    return out


def plot_map_events(
    ax,
    grid,
    events: list[dict],
    *,
    path_xy: np.ndarray | None = None,
    robot_xy: np.ndarray | None = None,
    title: str | None = None,
    labels: bool = True,
    event_cells: dict | None = None,
    view: tuple[float, float, float, float] | None = None,
) -> None:
    """The final 2D map (``plot_map``) with each event's xy extent as a box (vermillion: appeared,
    blue: disappeared), and optionally the planned path (green) and the robot's trajectory
    (purple). A box narrower than a cell is drawn one cell wide. Each box is a ``Rectangle``
    whose gid is ``"event <id>"``. With ``event_cells`` ({id: (N, 2) lower-left corners of its
    cells, in metres}) the event's own cells are filled instead of its whole box (an L-shaped
    wall is an L, not a rectangle), and the box is a thin outline.

    Readable with hundreds of events: only events that changed P (``p_cells`` > 0, or no
    ``p_cells`` given) get a label with their id, the ones that changed most cells first, each
    next to its box where it overlaps no other label (else none); the legend says how many are
    labelled. ``view`` (x0, x1, y0, y1) limits the axes (``map_view``: the occupied part)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Rectangle

    counts = {"appear": 0, "disappear": 0}
    for e in events:
        counts[e.get("kind", "appear")] = counts.get(e.get("kind", "appear"), 0) + 1
    if title is None:
        title = f"Final map: {counts['appear']} appeared, {counts['disappear']} disappeared"
    plot_map(ax, grid, title=title, scale_bar=False)
    if view is not None:
        ax.set_xlim(view[0], view[1])
        ax.set_ylim(view[2], view[3])
    if event_cells:
        _paint_event_cells(ax, grid, events, event_cells)
    rects = {}
    for e in events:
        kind = e.get("kind", "appear")
        colour = EVENT_COLORS.get(kind, OI_PURPLE)
        x0, y0, w, h = event_rectangle(e, min_size=float(grid.resolution))
        rects[id(e)] = (x0, y0, w, h)
        cells = event_cells is not None and e.get("id") in event_cells
        quiet = e.get("p_cells") == 0  # LT changed, P did not: a thin outline
        if not cells and not quiet:
            ax.add_patch(Rectangle((x0, y0), w, h, facecolor=colour, alpha=0.25, edgecolor="none", zorder=3))
        box = Rectangle(
            (x0, y0), w, h, fill=False, edgecolor=colour, lw=0.8 if cells or quiet else 2,
            ls="--" if cells or quiet else "-", alpha=0.6 if quiet else 1.0, zorder=4, gid=f"event {e.get('id')}",
        )
        ax.add_patch(box)
    changed = [e for e in events if e.get("p_cells") is None or e.get("p_cells") > 0]
    n_labelled = 0
    if labels and changed:
        order = sorted(changed, key=lambda e: (-(e.get("p_cells") or 0), str(e.get("id"))))
        places = _place_labels(ax, [(str(e.get("id")), rects[id(e)]) for e in order])
        to_data = ax.transData.inverted().transform
        for e, (text, where) in zip(order, places):
            if where is None:
                continue
            colour = EVENT_COLORS.get(e.get("kind", "appear"), OI_PURPLE)
            ax.annotate(
                text,
                tuple(to_data(where)),
                xytext=(1.5, 1.5),  # inside the box estimated by _label_size_px (its padding)
                textcoords="offset points",
                ha="left",
                va="bottom",
                fontsize="small",
                fontweight="bold",
                color=colour,
                zorder=5,
                bbox=dict(boxstyle="round,pad=0.15", fc="white", ec=colour, lw=0.8, alpha=0.85),
            )
            n_labelled += 1
    handles = []
    if robot_xy is not None and len(robot_xy):
        r = np.asarray(robot_xy, dtype=float)
        ax.plot(r[:, 0], r[:, 1], "-", color=TRAJECTORY_COLOR, lw=1.3, alpha=0.9, zorder=5)
        ax.plot([r[-1, 0]], [r[-1, 1]], "o", color=TRAJECTORY_COLOR, mec="black", ms=7, zorder=6)
        handles.append(
            Line2D(
                [],
                [],
                color=TRAJECTORY_COLOR,
                lw=1.3,
                marker="o",
                mec="black",
                markevery=[1],
                label="robot trajectory (o = end)",
            )
        )
    if path_xy is not None and len(path_xy):
        p = np.asarray(path_xy, dtype=float)
        ax.plot(p[:, 0], p[:, 1], "-", color=PATH_COLOR, lw=2.2, zorder=6)
        ax.plot([p[-1, 0]], [p[-1, 1]], "*", color=PATH_COLOR, mec="black", ms=13, zorder=7)
        handles.append(Line2D([], [], color=PATH_COLOR, lw=2.2, label="planned path (* = goal)"))
    handles = [
        Patch(
            facecolor=to_rgba(EVENT_COLORS["appear"], 0.35),
            edgecolor=EVENT_COLORS["appear"],
            lw=2,
            label=f"appeared ({counts['appear']})",
        ),
        Patch(
            facecolor=to_rgba(EVENT_COLORS["disappear"], 0.35),
            edgecolor=EVENT_COLORS["disappear"],
            lw=2,
            label=f"disappeared ({counts['disappear']})",
        ),
        *handles,
        Patch(facecolor=np.array(OCCUPIED_RGB) / 255, edgecolor="0.5", label="occupied"),
        Patch(facecolor=np.array(FREE_RGB) / 255, edgecolor="0.5", label="free"),
        Patch(facecolor=np.array(UNKNOWN_RGB) / 255, edgecolor="0.5", label="unknown"),
    ]
    if events and labels:
        note = f"ids: {n_labelled} of the {len(changed)} events that changed P"
        if len(changed) < len(events):
            note += f"\n({len(events) - len(changed)} that left P as it was: thin dashed boxes)"
        handles.append(Patch(facecolor="none", edgecolor="none", label=note))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small", frameon=False)
    add_scale_bar(ax)


def to_rgba(colour, alpha: float):
    from matplotlib.colors import to_rgba as _to_rgba

    return _to_rgba(colour, alpha)


def _event_title(event: dict | None, event_id) -> str:
    if not event:
        return f"event {event_id}"
    c = event.get("centroid")
    where = f" at ({c[0]:.1f}, {c[1]:.1f}) m" if c is not None else ""
    unseen = " (P unchanged)" if event.get("p_cells") == 0 else ""  # LT changed under something else
    return f"event {event_id}: {event.get('kind', '?')}{where}{unseen}"


def write_layer_history(
    path,
    events: list[dict],
    histories: dict,
    *,
    occupied_thresh: float = OCCUPIED_THRESH,
    max_events: int = MAX_HISTORY_EVENTS,
) -> None:
    """One PNG with a ``plot_layer_history`` subplot per event (three columns), for the first
    ``max_events`` events in the order of ``events`` that have a history (then any other
    histories, by id). Marks come from ``histories[id]["marks"]`` or ``event["marks"]``."""
    by_id = {e.get("id"): e for e in events}
    order = [e.get("id") for e in events if e.get("id") in histories]
    order += sorted((k for k in histories if k not in set(order)), key=str)
    shown = order[:max_events]
    n = len(shown)
    ncols = min(3, max(n, 1))
    nrows = max(1, math.ceil(n / ncols))
    width = max(5.4 * ncols, 8.0)
    height = 3.4 * nrows + 0.9
    fig, axes = new_plot_figure(width, height, nrows, ncols)
    # margins in inches, set once (a layout engine would measure every text at every draw: half
    # of this figure's time): the legend and heading on top, each axes' title above it, its
    # labels below and left
    top, bottom, left, right, row_gap, col_gap = 1.05, 0.5, 0.65, 0.15, 0.8, 0.75
    ax_h = (height - top - bottom - row_gap * (nrows - 1)) / nrows
    ax_w = (width - left - right - col_gap * (ncols - 1)) / ncols
    fig.subplots_adjust(left=left / width, right=1 - right / width, bottom=bottom / height, top=1 - top / height,
                        hspace=row_gap / ax_h, wspace=col_gap / ax_w)  # fmt: skip
    axes = np.atleast_1d(axes).ravel()
    if not n:
        plot_layer_history(
            axes[0], np.zeros(0), np.zeros(0), np.zeros(0), title="no events", occupied_thresh=occupied_thresh
        )
        axes[0].texts[0].set_text("no event was detected")
    for ax, eid in zip(axes, shown):
        h = histories[eid]
        ev = by_id.get(eid)

        def spread(layer, h=h):
            lo, hi = h.get(f"{layer}_min"), h.get(f"{layer}_max")
            return (lo, hi) if lo is not None and hi is not None else None

        marks = h.get("marks") or (ev or {}).get("marks")
        plot_layer_history(
            ax,
            h["t"],
            h["st_mean"],
            h["lt_mean"],
            title=_event_title(ev, eid),
            st_spread=spread("st"),
            lt_spread=spread("lt"),
            occupied_thresh=occupied_thresh,
            marks=marks,
            legend=False,
        )
    for ax in axes[n:]:
        if n:
            ax.set_axis_off()
    note = f" (first {n} of {len(order)} events)" if len(order) > n else ""
    heading = f"ST and LT values of each event's voxels over time{note}"
    if n:  # the heading is the legend's title (a suptitle would overlap an outside legend)
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(
            handles,
            labels,
            loc="upper center",
            bbox_to_anchor=(0.5, 1.0 - 0.03 / height),
            ncol=min(len(labels), 5 if width > 12 else 3),
            fontsize="small",
            frameon=False,
            title=heading,
            title_fontsize="large",
        )
    else:
        fig.suptitle(heading, fontsize="large")
    save_png(fig, path, crop=False)


def write_summary_plots(
    out_dir,
    *,
    grid,
    events: list[dict],
    histories: dict[int, dict],
    latencies: dict[str, list[float]],
    processing_ms: dict[str, np.ndarray],
    periods_ms: dict[str, float],
    path_xy=None,
    robot_xy=None,
    occupied_thresh: float = OCCUPIED_THRESH,
    targets=None,
    max_history_events: int = MAX_HISTORY_EVENTS,
    map3d: dict | None = None,
    event_cells: dict | None = None,
) -> dict[str, str]:
    """Write the replay's plots into ``out_dir`` and return ``{name: path}``:

    - ``layer_history.png``: one subplot per event (``write_layer_history``; at most
      ``max_history_events``, the title says when some are left out);
    - ``latency_boxes.png``, ``processing_latency.png``;
    - ``map_events.png`` (skipped when ``grid`` is None);
    - ``map_3d.png`` when ``map3d`` is given: keyword arguments of
      ``render3d.render_map_3d`` (``centers``, ``values``, ``resolution``, ...).
    Every file is written atomically."""
    from pathlib import Path

    from ..outputs.names import PLOT_FILES

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, str] = {}

    p = out / PLOT_FILES["layer_history"]
    write_layer_history(p, events, histories, occupied_thresh=occupied_thresh, max_events=max_history_events)
    written["layer_history"] = str(p)

    fig, ax = new_plot_figure(max(6.0, 2.6 * max(len(latencies), 1) + 2.0), 5.0)
    plot_latency_boxes(ax, latencies, targets=targets)
    p = out / PLOT_FILES["latency_boxes"]
    save_png(fig, p)
    written["latency_boxes"] = str(p)

    fig, ax = new_plot_figure(9.0, 5.0)
    plot_processing_hist(ax, processing_ms, periods_ms=periods_ms)
    p = out / PLOT_FILES["processing_latency"]
    save_png(fig, p)
    written["processing_latency"] = str(p)

    if grid is not None:
        view = map_view(grid, events, robot_xy=robot_xy, path_xy=path_xy)
        res = float(grid.resolution)
        fig, ax = new_figure(int((view[1] - view[0]) / res), int((view[3] - view[2]) / res), legend=True)
        plot_map_events(ax, grid, events, path_xy=path_xy, robot_xy=robot_xy, event_cells=event_cells, view=view)
        p = out / PLOT_FILES["map_events"]
        save_png(fig, p)
        written["map_events"] = str(p)

    if map3d is not None:
        from .render3d import render_map_3d

        p = out / PLOT_FILES["map_3d"]
        render_map_3d(p, **map3d)
        written["map_3d"] = str(p)
    return written
