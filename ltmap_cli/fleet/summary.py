"""OUT/summary.csv and OUT/summary.png: per sweep point, site and day, what each day's
``report.json`` says (frames, speed, events, median add / remove latency, long-term voxels), with
one ``all`` row per site (its days together) and one per sweep point (its sites together)."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from ..io.atomic import write_text_atomic
from .graph import BatchPlan, DayTask
from .runner import DONE, FAILED, NOT_RUN, BatchResult

SUMMARY_CSV = "summary.csv"
SUMMARY_PNG = "summary.png"
ALL = "all"
COLUMNS = (
    "point",
    "site",
    "day",
    "status",
    "logs",
    "log_duration_s",
    "frames_used",
    "frames_skipped",
    "wall_time_s",
    "speed_vs_real_time",
    "events_appeared",
    "events_disappeared",
    "add_latency_median_s",
    "remove_latency_median_s",
    "long_term_voxels",
    "folder",
    "error",
)


def summary_rows(plan: BatchPlan, result: BatchResult) -> list[dict]:
    """One row per day, then per (point, site) an ``all`` row, and per point an ``all`` row."""
    state = {id(s.task): s for s in result.states}
    rows = []
    per_point: dict[str, list[tuple[dict, dict | None]]] = {}
    for point in plan.points:
        point_days = per_point.setdefault(point.name, [])
        for chain in (c for c in plan.chains if c.point.name == point.name):
            site_days = []
            for day in chain.days:
                st = state[id(day)]
                report = _report(day) if st.status not in (FAILED, NOT_RUN) else None
                row = _day_row(day, st.status, report, plan.manifest.path.parent.absolute())
                if st.status == FAILED:
                    row["error"] = st.result.get("error", "")
                elif st.status == NOT_RUN:
                    row["error"] = st.reason + _static_error(plan, result, day)
                rows.append(row)
                site_days.append((row, report))
            rows.append(_total_row(point.name, chain.site, site_days, last_lt=True))
            point_days += site_days
        rows.append(_total_row(point.name, ALL, point_days, last_lt=False))
    return rows


def write_summary(plan: BatchPlan, result: BatchResult, plot: bool = True) -> list[Path]:
    rows = summary_rows(plan, result)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: _cell(r.get(k)) for k in COLUMNS})
    written = [plan.out / SUMMARY_CSV]
    write_text_atomic(written[0], buf.getvalue())
    if plot:
        from ..viz.fleet import write_summary_png

        written.append(write_summary_png(plan.out / SUMMARY_PNG, rows))
    return written


def _report(day: DayTask) -> dict | None:
    try:
        return json.loads((day.out_dir / "report.json").read_text())
    except (OSError, ValueError):
        return None


def _day_row(day: DayTask, status: str, rep: dict | None, base: Path) -> dict:
    row = {
        "point": day.point,
        "site": day.site,
        "day": day.day,
        "status": status,
        "logs": " ".join(_rel(p, base) for p in day.logs),
        "folder": str(day.out_dir),
    }
    if rep is None:
        return row
    ev = rep.get("events") or {}
    row.update(
        {
            "log_duration_s": rep.get("log_duration_s"),
            "frames_used": sum((rep.get("frames_used") or {}).values()),
            "frames_skipped": sum((rep.get("frames_skipped") or {}).values()),
            "wall_time_s": rep.get("wall_time_s"),
            "speed_vs_real_time": rep.get("speed_vs_real_time"),
            "events_appeared": ev.get("appear"),
            "events_disappeared": ev.get("disappear"),
            "add_latency_median_s": (ev.get("add_latency_s") or {}).get("p50"),
            "remove_latency_median_s": (ev.get("remove_latency_s") or {}).get("p50"),
            "long_term_voxels": (rep.get("voxels") or {}).get("long_term_occupied"),
        }
    )
    return row


def _total_row(point: str, site: str, days: list[tuple[dict, dict | None]], last_lt: bool) -> dict:
    """Sums of the days; latencies: the median over all their events; long-term voxels: the last
    day's (a site's map at the end) or, over sites, the sum of their last days'."""
    statuses = [r["status"] for r, _ in days]
    bad = [s for s in statuses if s in (FAILED, NOT_RUN)]
    row = {
        "point": point,
        "site": site,
        "day": ALL,
        "status": f"{len(bad)} of {len(days)} not done" if bad else DONE,
    }
    reps = [(r, rep) for r, rep in days if rep is not None]
    if not reps:
        return row
    for k in (
        "log_duration_s",
        "frames_used",
        "frames_skipped",
        "wall_time_s",
        "events_appeared",
        "events_disappeared",
    ):
        vals = [r[k] for r, _ in reps if r.get(k) is not None]
        row[k] = round(sum(vals), 3) if vals else None
    if row.get("wall_time_s"):
        row["speed_vs_real_time"] = round(row["log_duration_s"] / row["wall_time_s"], 2)
    events = [e for _, rep in reps for e in ((rep.get("events") or {}).get("list") or [])]
    for kind, col in (("appear", "add_latency_median_s"), ("disappear", "remove_latency_median_s")):
        lat = [e["latency_s"] for e in events if e.get("kind") == kind and e.get("latency_s") is not None]
        row[col] = float(np.median(lat)) if lat else None
    if last_lt:
        row["long_term_voxels"] = reps[-1][0].get("long_term_voxels") if statuses[-1] not in bad else None
    else:
        finals: dict = {}
        for r, _ in reps:  # the last day of each (point, site) with a report
            finals[(r["point"], r["site"])] = r.get("long_term_voxels")
        row["long_term_voxels"] = sum(v for v in finals.values() if v is not None)
    return row


def _static_error(plan: BatchPlan, result: BatchResult, day: DayTask) -> str:
    st = plan.statics.get(day.site)
    if st is None:
        return ""
    s = next((x for x in result.states if x.task is st), None)
    return f": {s.result.get('error')}" if s is not None and s.status == FAILED else ""


def _rel(p: Path, base: Path) -> str:
    """A log as the manifest names it (relative to its folder when inside it)."""
    try:
        return str(p.relative_to(base))
    except ValueError:
        return str(p)


def _cell(v):
    if isinstance(v, float):
        return f"{v:.6g}"
    return "" if v is None else v
