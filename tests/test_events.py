"""Change events and latencies (SPEC 6) on a log whose timeline is known exactly.

A pillar stands in the room for the first 20 s, then is gone for 12 s; the laser sees it the
whole time (one scan per 0.2 s tick). Defaults: st_rise_s 15 s, st_fall_s 1 s, lt_fall_s 3 s.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from logfactory import scan, tf, write_log, yaw_quat
from test_replay import MOUNT, PILLAR, ROBOT, T0, assert_one_line_error, beam_angles, cast, run

from ltmap_cli.analysis.events import TickClock, event_history, find_events


def pillar_log(path, present_s=20.0, absent_s=12.0, rate_hz=5.0):
    msgs = [tf(T0, [("base_link", "laser", MOUNT, (0, 0, 0, 1))], static=True)]
    x, y, yaw = ROBOT
    amin, inc, _ = beam_angles()
    with_pillar, _ = cast(True)
    without, _ = cast(False)
    n = int(round((present_s + absent_s) * rate_hz))
    for i in range(-1, n + 2):
        ns = T0 + int(round(i / rate_hz * 1e9))
        msgs.append(tf(ns, [("odom", "base_link", (x, y, 0.0), yaw_quat(yaw))]))
        if 0 <= i < n:
            r = with_pillar if i / rate_hz < present_s else without
            msgs.append(scan("/scan", ns, r, angle_min=amin, angle_increment=inc, range_min=0.05, range_max=10.0))
    return write_log(path, "mcap-ros2", msgs)


def in_pillar(e) -> bool:
    cx, cy, _ = e["centroid"]
    return PILLAR[0] - 0.1 <= cx <= PILLAR[2] + 0.1 and PILLAR[1] - 0.1 <= cy <= PILLAR[3] + 0.1


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("events")
    log = pillar_log(tmp / "pillar.mcap")
    out = tmp / "out"
    r = run(["replay", str(log), "-o", str(out), "-q"])
    assert r.exit_code == 0, r.output
    return out, json.loads((out / "report.json").read_text())


def test_the_pillar_appears_after_st_rise_s_and_disappears_within_lt_fall_s(replayed):
    out, report = replayed
    events = report["events"]["list"]
    pillar = [e for e in events if in_pillar(e)]
    kinds = sorted(e["kind"] for e in pillar)
    assert kinds == ["appear", "disappear"], pillar
    appear = next(e for e in pillar if e["kind"] == "appear")
    gone = next(e for e in pillar if e["kind"] == "disappear")
    # seen from its first tick: in P after st_rise_s, within [st_rise_s - tick, st_rise_s + 2 ticks]
    assert 15.0 - 0.2 <= appear["latency_s"] <= 15.0 + 0.4
    # the log starts with a tf 0.2 s before the first scan
    assert appear["t_start_s"] == pytest.approx(0.2, abs=1e-6)
    assert appear["t_in_map_s"] == pytest.approx(15.2, abs=1e-6)
    # seen free: ST falls 1 -> 0 in 5 ticks, LT starts falling in the 5th and is below 0.65 after
    # 6 decrements of 1/15: 10 ticks = 2.0 s from the first tick O says free; within lt_fall_s + 2 ticks
    assert gone["latency_s"] <= 3.0 + 0.4
    assert gone["latency_s"] == pytest.approx(2.0, abs=1e-6)
    # O turns free after 9 misses (3.5 / 0.405): the pillar, gone at 20.2 s, is seen free at 21.8 s
    assert gone["t_start_s"] == pytest.approx(21.8, abs=1e-6)
    assert appear["voxels"] >= 3 and gone["voxels"] >= 3


def test_the_other_events_are_walls_appearing_after_st_rise_s(replayed):
    _, report = replayed
    others = [e for e in report["events"]["list"] if not in_pillar(e)]
    assert others and all(e["kind"] == "appear" for e in others)
    for e in others:
        assert e["latency_s"] == pytest.approx(15.0, abs=1e-6)
        lo, hi = np.array(e["extent_min"]), np.array(e["extent_max"])
        on_wall = (np.abs(lo[:2]) >= 1.95) | (np.abs(hi[:2]) >= 1.95)
        assert on_wall.any(), e
    # the sparse laser (2 degrees between beams) samples the walls up to ~0.3 m apart at grazing
    # angles, more than event_link_m (0.15 m): the walls come as a dozen events, not one per voxel
    wall_voxels = sum(e["voxels"] for e in others)
    assert len(others) <= 12 < wall_voxels / 10


def test_events_csv_and_processing_latency_in_the_report(replayed):
    out, report = replayed
    rows = list(csv.DictReader((out / "events.csv").open()))
    assert len(rows) == report["events"]["count"]
    assert {r["kind"] for r in rows} == {"appear", "disappear"}
    assert all(float(r["latency_s"]) > 0 for r in rows)
    proc = report["processing_latency_ms"]
    assert proc["/scan"]["n"] == 160
    assert proc["/scan"]["frame_period_ms"] == pytest.approx(200.0)
    assert proc["/scan"]["p50"] < proc["/scan"]["frame_period_ms"]
    assert proc["/scan"]["keeps_up"] is True
    assert proc["tick"]["n"] > 150


def test_grouping_separates_space_and_time():
    # block 0: voxels (0,0,5), (1,0,5) at ticks 10, 11; (6,0,5) far away; (0,0,5) again at tick 200
    tr = np.array([
        [1, 0, (0 << 6) | (0 << 3) | 5, 10, 0],
        [1, 0, (1 << 6) | (0 << 3) | 5, 11, 1],
        [1, 0, (6 << 6) | (0 << 3) | 5, 10, 0],
        [1, 0, (0 << 6) | (0 << 3) | 5, 200, 120],
        [2, 0, (1 << 6) | (0 << 3) | 5, 30, 20],
    ])  # fmt: skip
    coords = np.zeros((1, 3), dtype=np.int32)
    events, members = find_events(tr, coords, 0.05, TickClock(0.0, 0.2), window_s=5.0, link_m=0.05)
    assert [(e["kind"], e["voxels"]) for e in events] == [("appear", 2), ("appear", 1), ("disappear", 1),
                                                         ("appear", 1)]  # fmt: skip
    first = events[0]
    assert first["latency_s"] == pytest.approx(11 * 0.2)  # median of (10-0+1) and (11-1+1) ticks
    assert first["extent_min"] == pytest.approx([0.0, 0.0, 0.25]) and first["extent_max"] == pytest.approx(
        [0.1, 0.05, 0.3])
    assert events[2]["latency_s"] == pytest.approx(11 * 0.2)
    assert first["cells"] == 2 and events[1]["cells"] == 1  # (0, 0) and (1, 0); (6, 0)
    assert set(members[first["id"]].tolist()) == {(0 << 6) | 5, (1 << 6) | 5}


def test_events_starting_together_are_numbered_by_place_not_by_storage_order():
    """Two pillars entering LT at the same tick: their events' ids follow their place (least
    voxel key), whatever order D stored their blocks and the tick buffer listed their voxels in
    (which depends on how a frame's updates were batched: lists or block masks)."""
    near, far = [1, 0, (2 << 6) | 5, 40, 10], [1, 1, (3 << 6) | 5, 40, 12]  # (kind, block, offset, tick, start)
    coords = np.array([[0, 0, 0], [5, 0, 0]], dtype=np.int32)  # block 0 at the origin, block 1 at x = 40 voxels
    runs = []
    for swap in (False, True):
        tr = np.array([far, near] if swap else [near, far])
        c = coords
        if swap:  # the blocks stored the other way round
            c = coords[::-1].copy()
            tr[:, 1] = 1 - tr[:, 1]
        events, _ = find_events(tr, c, 0.05, TickClock(0.0, 0.2))
        runs.append([(e["id"], e["kind"], round(e["centroid"][0], 3)) for e in events])
    assert runs[0] == runs[1] == [(1, "appear", 0.125), (2, "appear", 2.175)]


def test_event_latency_is_first_sight_to_first_in_map():
    """Issue 8's definition: from the first tick any voxel of the event was an obstacle to the
    first tick P shows any of them; the per-voxel median is kept beside it."""
    tr = np.array([
        [1, 0, (0 << 6) | 5, 20, 5],  # seen from tick 5, in LT at tick 20: 16 ticks
        [1, 0, (1 << 6) | 5, 12, 8],  # its neighbour, seen from tick 8, in LT at tick 12: 5 ticks
    ])  # fmt: skip
    events, _ = find_events(tr, np.zeros((1, 3), dtype=np.int32), 0.05, TickClock(1.0, 0.2))
    (e,) = events
    assert e["t_start_s"] == pytest.approx(1.0 + 5 * 0.2) and e["t_in_map_s"] == pytest.approx(1.0 + 13 * 0.2)
    assert e["latency_s"] == pytest.approx((13 - 5) * 0.2)
    # per changed cell (each voxel has its own column here): 16 and 5 ticks; latency_s between
    assert e["cell_latency_median_s"] == pytest.approx((16 + 5) / 2 * 0.2)
    assert (e["cell_latency_min_s"], e["cell_latency_max_s"]) == pytest.approx((5 * 0.2, 16 * 0.2))
    assert e["cell_latency_min_s"] <= e["latency_s"] <= e["cell_latency_max_s"]
    assert e["voxel_lt_latency_median_s"] == pytest.approx((16 + 5) / 2 * 0.2)


def _brute_labels(keys, ticks, window, link):
    """Every pair compared: connected components, labelled by their smallest index."""
    n = len(keys)
    close = (np.abs(keys[:, None, :] - keys[None, :, :]).max(axis=2) <= link) & (
        np.abs(ticks[:, None] - ticks[None, :]) <= window)
    label = np.arange(n)
    changed = True
    while changed:  # propagate the minimum label through the adjacency to a fixed point
        new = np.where(close, label[None, :], n).min(axis=1)
        changed = bool((new != label).any())
        label = new
    return label


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_grouping_equals_every_pair_compared(seed):
    """The bucketed, compiled grouping gives the components of the full pairwise relation, on
    random voxels around the origin (negative keys, buckets split by the floor) and chains."""
    from ltmap_cli.analysis.events import _group

    rng = np.random.default_rng(seed)
    keys = rng.integers(-25, 25, size=(400, 3))
    keys[:40] = np.stack([np.arange(40) * 2 - 40, np.zeros(40), np.zeros(40)], axis=1)  # a chain across 0
    ticks = rng.integers(0, 300, size=400)
    ticks[:40] = 5
    for window, link in ((25, 6), (3, 2), (0, 1)):
        got = _group(keys, ticks, window, link)
        assert got.tolist() == _brute_labels(keys, ticks, window, link).tolist()
    assert len(set(_group(keys, ticks, 25, 6)[:40].tolist())) == 1  # the chain is one group


def test_history_holds_values_between_records():
    hist_i = np.array([[0, 7], [0, 8], [5, 7], [10, 8]], dtype=np.int32)
    hist_v = np.array([[0.2, 0.0], [0.4, 0.0], [1.0, 1.0], [0.0, 0.5]], dtype=np.float32)
    h = event_history(hist_i, hist_v, np.array([7, 8]), TickClock(1.0, 0.2))
    assert h["t"] == pytest.approx([1.2, 2.2, 3.2])
    assert h["st_mean"] == pytest.approx([0.3, 0.7, 0.5])
    assert h["lt_max"] == pytest.approx([0.0, 1.0, 1.0])
    assert h["lt_min"] == pytest.approx([0.0, 0.0, 0.5])


def test_history_of_a_voxel_recorded_twice_in_a_tick_keeps_the_last_record():
    # voxel 7 recorded twice at tick 0 (0.9 then 0.1): the later record stands, as a tick's
    # rules leave it; voxel 9 is asked for but never recorded: 0 throughout
    hist_i = np.array([[0, 7], [0, 8], [0, 7], [3, 8], [3, 8]], dtype=np.int32)
    hist_v = np.array([[0.9, 0.0], [0.4, 0.2], [0.1, 0.0], [0.7, 0.6], [0.5, 0.3]], dtype=np.float32)
    h = event_history(hist_i, hist_v, np.array([9, 7, 8, 7]), TickClock(1.0, 0.2))
    assert h["t"] == pytest.approx([1.2, 1.8])
    assert h["st_mean"] == pytest.approx([(0.1 + 0.4) / 3, (0.1 + 0.5) / 3])
    assert h["st_max"] == pytest.approx([0.4, 0.5])
    assert h["lt_max"] == pytest.approx([0.2, 0.3])
    assert h["st_min"] == pytest.approx([0.0, 0.0])


def test_histories_of_several_events_share_voxels_and_carry_values_from_before_their_start():
    from ltmap_cli.analysis.events import event_histories

    # ticks 0, 2, 4 (end times 1.2, 1.6, 2.0 s at 0.2 s ticks from t0 = 1.0); voxel 5 in both events
    hist_i = np.array([[0, 5], [0, 6], [2, 9], [2, 5], [4, 6], [4, 9]], dtype=np.int32)
    hist_v = np.array([[0.5, 0.1], [0.9, 0.2], [0.3, 0.3], [0.7, 0.4], [0.1, 0.5], [0.2, 0.6]], dtype=np.float32)
    h = event_histories(hist_i, hist_v, {"a": np.array([6, 5]), "b": np.array([5, 9, 5])}, TickClock(1.0, 0.2),
                        {"a": 1.5, "b": None}, t_to_s=1.9)  # fmt: skip
    # a = {5, 6} from 1.5 s: tick 2 shows 5 at 0.7 (recorded then) and 6 at 0.9 (from tick 0, before the start)
    assert h["a"]["t"] == pytest.approx([1.6])
    assert h["a"]["st_mean"] == pytest.approx([0.8]) and h["a"]["lt_max"] == pytest.approx([0.4])
    # b = {5, 9} up to 1.9 s: ticks 0 and 2; tick 0 has no record of 9 yet (0)
    assert h["b"]["t"] == pytest.approx([1.2, 1.6])
    assert h["b"]["st_max"] == pytest.approx([0.5, 0.7]) and h["b"]["st_min"] == pytest.approx([0.0, 0.3])
    assert h["b"]["lt_mean"] == pytest.approx([0.05, 0.35])


def test_planner_latency_with_a_goal_behind_the_pillar(tmp_path):
    log = pillar_log(tmp_path / "pillar.mcap")
    out = tmp_path / "out"
    # the robot at (1.0, 0.5), the goal past the pillar: the straight path crosses the pillar
    r = run(["replay", str(log), "-o", str(out), "-q", "--plan-goal", "-1.8,-1.8", "--robot-radius", "0.1"],
            plots=True)
    assert r.exit_code == 0, r.output
    report = json.loads((out / "report.json").read_text())
    pillar = {e["kind"]: e for e in report["events"]["list"] if in_pillar(e)}
    # the path must go round the pillar the tick P shows it, and may cross its cells again the
    # tick P shows them free: planner latency = add / remove latency
    assert pillar["appear"]["planner_latency_s"] == pytest.approx(pillar["appear"]["latency_s"], abs=0.21)
    assert pillar["disappear"]["planner_latency_s"] == pytest.approx(pillar["disappear"]["latency_s"], abs=0.21)
    plan = report["events"]["plan"]
    assert plan["plans"] > 100 and plan["plans_by_outcome"] == {"path": plan["plans"]} and "warning" not in plan
    assert report["events"]["planner_latency_s"]["n"] >= 2
    rows = list(csv.DictReader((out / "events.csv").open()))
    assert any(r["planner_latency_s"] for r in rows)


def test_bad_plan_goal_is_one_line(tmp_path):
    r = run(["replay", "--dump-config", "--plan-goal", "3"])
    assert r.exit_code == 2 and "--plan-goal 3: expected X,Y" in r.output
    r = run(["replay", "--dump-config", "--plan-goal", "nan,1"])
    assert r.exit_code == 2 and "replay.plan_goal must hold finite numbers" in r.output


@pytest.mark.parametrize("goal", ["", " "])
def test_an_empty_plan_goal_is_refused_before_the_run(tmp_path, goal):
    # an empty value used to be taken as "no goal": exit 0 and a replay without the planner
    log = pillar_log(tmp_path / "pillar.mcap", present_s=1.0, absent_s=0.0)
    out = tmp_path / "out"
    r = run(["replay", str(log), "-o", str(out), "-q", "--plan-goal", goal])
    assert_one_line_error(r, f"--plan-goal {goal!r}: expected X,Y in metres")
    assert not out.exists()


def test_a_goal_off_the_map_is_said_not_silent(tmp_path):
    log = pillar_log(tmp_path / "pillar.mcap", present_s=2.0, absent_s=1.0)
    out = tmp_path / "out"
    r = run(["replay", str(log), "-o", str(out), "-q", "--plan-goal", "100,100"])
    assert r.exit_code == 0, r.output
    plan = json.loads((out / "report.json").read_text())["events"]["plan"]
    assert plan["plans_by_outcome"] == {"goal off the map": plan["plans"]} and plan["plans"] > 10
    assert plan["final_length_m"] is None
    assert "ltmap: warning: --plan-goal 100,100: no path at any of" in r.output
    assert "goal off the map" in plan["warning"]


def test_plots_of_the_replay_are_valid_pngs(tmp_path):
    from PIL import Image

    log = pillar_log(tmp_path / "pillar.mcap", present_s=17.0, absent_s=4.0)
    out = tmp_path / "out"
    r = run(["replay", str(log), "-o", str(out), "-q", "--plan-goal", "-1.8,-1.8"], plots=True)
    assert r.exit_code == 0, r.output
    names = {"layer_history", "latency_boxes", "processing_latency", "map_events", "map_3d"}
    assert {p.stem for p in (out / "plots").glob("*.png")} == names
    for name in names:
        path = out / "plots" / f"{name}.png"
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        img = np.asarray(Image.open(path).convert("L"), dtype=float)
        assert path.stat().st_size > 10_000 and min(img.shape) > 200
        assert img.std() > 5  # not a blank canvas
    report = json.loads((out / "report.json").read_text())
    assert set(report["outputs"]["plots"]) == names


def test_something_seen_for_less_than_st_rise_s_produces_no_event(tmp_path):
    # a person standing 5 s where the pillar is, then gone: ST rises to 1/3, never LT, no event
    log = pillar_log(tmp_path / "person.mcap", present_s=5.0, absent_s=20.0)
    out = tmp_path / "out"
    r = run(["replay", str(log), "-o", str(out), "-q"])
    assert r.exit_code == 0, r.output
    report = json.loads((out / "report.json").read_text())
    assert [e for e in report["events"]["list"] if in_pillar(e)] == []
    assert report["events"]["remove_latency_s"]["n"] == 0


def _off(i, j, k):
    return (i << 6) | (j << 3) | k


def test_p_changes_by_hand():
    """A transition changes P only when its column goes from no occupied band voxel to some
    (appear) or from some to none (disappear), and the static map does not fill the column."""
    from ltmap_cli.analysis.events import APPEAR, DISAPPEAR, p_changes

    rows = [  # (kind, i, j, tick)
        (APPEAR, 0, 0, 5), (APPEAR, 0, 0, 7), (DISAPPEAR, 0, 0, 10), (DISAPPEAR, 0, 0, 12),  # column A
        (APPEAR, 1, 0, 5), (DISAPPEAR, 1, 0, 9),  # column B: filled by the static map
        (APPEAR, 2, 0, 3), (DISAPPEAR, 2, 0, 8),  # column C: another voxel stays in LT throughout
        (APPEAR, 3, 0, 4), (APPEAR, 3, 0, 4),  # column D: two voxels enter in one tick
        (DISAPPEAR, 4, 0, 6), (APPEAR, 4, 0, 6),  # column E: one leaves as another enters, same tick
    ]  # fmt: skip
    kind = np.array([r[0] for r in rows])
    cols = np.array([(r[1], r[2]) for r in rows])
    ticks = np.array([r[3] for r in rows])
    final = np.array([(2, 0), (3, 0), (3, 0), (4, 0)])  # C's resident voxel, D's two, E's newcomer
    got = p_changes(kind, cols, ticks, final, static_cols=lambda c: c[:, 0] == 1)
    assert got.tolist() == [True, False, False, True, False, False, False, False, True, True, False, False]
    # without the final map, C's resident voxel is unknown: its column looks empty before tick 3
    got = p_changes(kind, cols, ticks, None)
    assert got[6] and got[7] and got[4] and got[5]


def test_event_that_never_changes_p_has_no_latency():
    """Table-leg voxels leaving LT under a table top that stays: LT changed, P did not."""
    tr = np.array([
        [1, 0, _off(0, 0, 5), 20, 5],  # the top, in LT at tick 20 (column (0, 0))
        [1, 0, _off(0, 0, 2), 21, 6],  # a leg voxel below it, in LT at tick 21
        [2, 0, _off(0, 0, 2), 60, 50],  # the leg voxel leaves at tick 60; the top stays
    ])  # fmt: skip
    final = np.array([(0, 0)])  # the top
    events, _ = find_events(tr, np.zeros((1, 3), dtype=np.int32), 0.05, TickClock(0.0, 0.2),
                            final_cols=final)  # fmt: skip
    appear, gone = events
    assert appear["t_in_map_s"] == pytest.approx(21 * 0.2) and appear["p_cells"] == 1
    assert appear["voxels"] == 2 and appear["cells"] == 1  # the top and the leg: one column
    assert gone["kind"] == "disappear" and gone["p_cells"] == 0
    assert gone["t_in_map_s"] is None and gone["latency_s"] is None
    assert gone["t_lt_s"] == pytest.approx(61 * 0.2)
    # the tick P changes, not the first LT crossing: a column emptied by its last voxel
    tr2 = np.array([
        [2, 0, _off(0, 0, 5), 30, 20],  # the top leaves first ...
        [2, 0, _off(0, 0, 2), 40, 35],  # ... the leg voxel ten ticks later: then the cell is free
    ])  # fmt: skip
    (e,) = find_events(tr2, np.zeros((1, 3), dtype=np.int32), 0.05, TickClock(0.0, 0.2))[0]
    assert e["t_lt_s"] == pytest.approx(31 * 0.2) and e["t_in_map_s"] == pytest.approx(41 * 0.2)
    assert e["latency_s"] == pytest.approx((41 - 20) * 0.2) and e["p_cells"] == 1


def test_planner_latency_only_while_the_event_changes_p():
    from ltmap_cli.analysis.plan_tracker import PlanRecord, PlanTracker

    ev = {"kind": "disappear", "t_start_s": 10.0, "t_in_map_s": 12.0, "t_in_map_last_s": 12.0,
          "extent_min": [1.0, 1.0, 0.0], "extent_max": [1.5, 1.5, 0.5], "planner_latency_s": None}
    around = np.array([[0.0, 0.0], [0.0, 3.0], [3.0, 3.0]])
    through = np.array([[0.0, 0.0], [1.2, 1.2], [3.0, 3.0]])
    t = PlanTracker(goal_xy=(3.0, 3.0))
    t.records = [PlanRecord(s, around, np.zeros((0, 2)), 6.0) for s in (11.0, 12.0, 12.2, 12.4)]
    t.records.append(PlanRecord(20.0, through, np.zeros((0, 2)), 4.3))  # the robot drove: later path
    late = dict(ev)
    t.attribute([late], 0.05)
    assert late["planner_latency_s"] is None  # 8 s after P showed it free: not this event's doing
    t.records[2] = PlanRecord(12.2, through, np.zeros((0, 2)), 4.3)  # the first plan after P changed
    prompt = dict(ev)
    t.attribute([prompt], 0.05)
    assert prompt["planner_latency_s"] == pytest.approx(2.2)
    never = dict(ev, t_in_map_s=None, t_in_map_last_s=None)
    t.attribute([never], 0.05)
    assert never["planner_latency_s"] is None


def test_histories_are_made_for_the_plotted_events_only(tmp_path):
    """The ST / LT histories feed only the layer-history plot, which draws the first
    MAX_HISTORY_EVENTS events: with plots they are made for those, without plots for none (on a
    long log they cost seconds at the end)."""
    from ltmap_cli.config import Config
    from ltmap_cli.pipeline.replay import Replay, ReplayRequest
    from ltmap_cli.viz.plots import MAX_HISTORY_EVENTS

    log = Path(__file__).resolve().parents[1] / "sample_logs" / "scenarios" / "01_static_object" / "log.mcap"
    made = {}
    for plots in (False, True):
        cfg = Config()
        cfg.replay.plots = plots
        run = Replay(cfg, ReplayRequest([log], tmp_path / str(plots)))
        run.run()
        made[plots] = (run.events.events, run.events.histories)
    events, histories = made[True]
    assert len(events) >= 2 and set(histories) == {e["id"] for e in events[:MAX_HISTORY_EVENTS]}
    assert all(len(h["t"]) for h in histories.values())
    assert made[False][1] == {} and [e["id"] for e in made[False][0]] == [e["id"] for e in events]
