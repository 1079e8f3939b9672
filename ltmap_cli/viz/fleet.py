"""The picture of ``ltmap batch``'s summary (OUT/summary.png): per site and sweep point, over the
days, the long-term voxels, the events that appeared and disappeared, the median add / remove
latency and the replay speed. Each panel draws on an ``ax`` it is given."""

from __future__ import annotations

from pathlib import Path

from .plots import save_png

MAX_LEGEND = 12  # series named in the legend (a fleet of 100 sites draws them all, names 12)


def _series(rows: list[dict]) -> dict[str, list[dict]]:
    """(point, site) -> its day rows (the ``all`` rows left out), in day order."""
    out: dict[str, list[dict]] = {}
    for r in rows:
        if r.get("day") == "all" or r.get("site") == "all":
            continue
        name = r["site"] + (f" {r['point']}" if r.get("point") else "")
        out.setdefault(name, []).append(r)
    return out


def plot_days(ax, rows: list[dict], column: str, title: str, ylabel: str, second: str | None = None) -> None:
    """``column`` (and dashed ``second``) per day, one line per (site, point)."""
    series = _series(rows)
    for i, (name, days) in enumerate(series.items()):
        x = [r["day"] for r in days]
        y = [r.get(column) if r.get(column) is not None else float("nan") for r in days]
        (line,) = ax.plot(x, y, marker="o", label=name if i < MAX_LEGEND else None)
        if second is not None:
            y2 = [r.get(second) if r.get(second) is not None else float("nan") for r in days]
            ax.plot(x, y2, marker="s", linestyle="--", color=line.get_color())
    ax.set_title(title)
    ax.set_xlabel("day")
    ax.set_ylabel(ylabel)
    days = sorted({r["day"] for d in series.values() for r in d})
    if days:
        ax.set_xticks(days)
    ax.grid(True, alpha=0.3)


def write_summary_png(path: Path, rows: list[dict]) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 8.5), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2)
    plot_days(axes[0, 0], rows, "long_term_voxels", "long-term voxels at the end of the day", "voxels")
    plot_days(
        axes[0, 1],
        rows,
        "events_appeared",
        "events: appeared (solid), disappeared (dashed)",
        "events",
        second="events_disappeared",
    )
    plot_days(
        axes[1, 0],
        rows,
        "add_latency_median_s",
        "median latency: add (solid), remove (dashed)",
        "s",
        second="remove_latency_median_s",
    )
    plot_days(axes[1, 1], rows, "speed_vs_real_time", "replay speed", "x real time")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if handles:
        n = len(_series(rows))
        title = "site [sweep point]" + (f" (first {MAX_LEGEND} of {n})" if n > MAX_LEGEND else "")
        fig.legend(handles, labels, loc="outside right upper", title=title, fontsize="small")
    save_png(fig, path)
    return path
