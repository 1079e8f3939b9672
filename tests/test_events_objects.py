"""Events that mean objects (issue 18): a group of LT transitions is an event when it is big
enough or changed P enough (the others counted, not silently dropped), and its latency columns
are consistent: ``latency_s`` lies within its per-cell min and max."""

from __future__ import annotations

import numpy as np
import pytest

from ltmap_cli.analysis.events import TickClock, find_events
from ltmap_cli.config import Config

CLOCK = TickClock(0.0, 0.2)
COORDS = np.zeros((1, 3), dtype=np.int32)


def _off(i, j, k):
    return (i << 6) | (j << 3) | k


def test_small_groups_that_leave_p_as_it_was_are_counted_not_reported():
    tr = np.array([
        # a 5-voxel column entering LT at ticks 80..84: an object (5 voxels, 1 cell)
        *[[1, 0, _off(0, 0, k), 80 + k, 5] for k in range(5)],
        # far from it (8 voxels away: another block of the key space), a single voxel flickering out
        # and in again, and a 2-voxel disappear under something that stays (no P change)
        [2, 0, _off(7, 7, 1), 120, 110],
        [1, 0, _off(7, 7, 1), 300, 200],
        [2, 0, _off(4, 7, 6), 150, 140], [2, 0, _off(4, 7, 7), 150, 140],
        # three voxels in a row at one height that empty three cells of P: kept for the P change
        *[[2, 0, _off(i, 4, 2), 400, 390] for i in range(3)],
    ])  # fmt: skip
    final = np.array([(4, 7), (4, 7), (7, 7)])  # what stays at the end: the 2-voxel column's others
    filtered = {}
    events, members = find_events(tr, COORDS, 0.05, CLOCK, link_m=0.05, min_voxels=4, min_p_cells=3,
                                  final_cols=final, filtered=filtered)  # fmt: skip
    assert [(e["kind"], e["voxels"], e["p_cells"]) for e in events] == [("appear", 5, 1), ("disappear", 3, 3)]
    assert filtered == {"appear": 1, "disappear": 2, "voxels": 4, "surface": 0}
    # with the defaults of find_events every group is an event
    assert len(find_events(tr, COORDS, 0.05, CLOCK, link_m=0.05, final_cols=final)[0]) == 5
    # min_p_cells 0: a P change alone does not make an event
    events0, _ = find_events(tr, COORDS, 0.05, CLOCK, link_m=0.05, min_voxels=4, min_p_cells=0, final_cols=final)
    assert [e["voxels"] for e in events0] == [5]


def test_latency_is_measured_on_what_p_shows():
    """The house sample's box: a voxel first seen free in a column that something else keeps
    occupied (it never changes P) must not start the event's latency: before, latency_s 4.8 s lay
    outside its own per-voxel min / max of 1.8 / 2.0 s."""
    tr = np.array([
        [2, 0, _off(0, 0, 3), 30, 10],  # seen free from tick 10; its column keeps another voxel
        [2, 0, _off(1, 0, 3), 40, 30],  # seen free from tick 30, its cell empties at tick 40
        [2, 0, _off(2, 0, 3), 45, 33],  # seen free from tick 33, its cell empties at tick 45
    ])  # fmt: skip
    final = np.array([(0, 0)])
    (e,) = find_events(tr, COORDS, 0.05, CLOCK, final_cols=final)[0]
    assert e["p_cells"] == 2
    assert e["t_start_s"] == pytest.approx(30 * 0.2)  # the first sight of what left P
    assert e["t_in_map_s"] == pytest.approx(41 * 0.2) and e["t_in_map_last_s"] == pytest.approx(46 * 0.2)
    assert e["latency_s"] == pytest.approx(11 * 0.2)
    assert (e["cell_latency_min_s"], e["cell_latency_max_s"]) == pytest.approx((11 * 0.2, 13 * 0.2))
    assert e["cell_latency_min_s"] <= e["latency_s"] <= e["cell_latency_max_s"]
    # per voxel, LT crossings: 21, 11, 13 ticks
    assert e["voxel_lt_latency_median_s"] == pytest.approx(13 * 0.2)


@pytest.mark.parametrize("seed", range(5))
def test_latency_always_within_cell_min_and_max(seed):
    rng = np.random.default_rng(seed)
    n = 60
    i, j, k = rng.integers(0, 4, n), rng.integers(0, 4, n), rng.integers(0, 8, n)
    since = rng.integers(0, 50, n)
    ticks = since + rng.integers(5, 40, n)
    tr = np.stack([np.full(n, 1), np.zeros(n, int), (i << 6) | (j << 3) | k, ticks, since], axis=1)
    _, uniq = np.unique(tr[:, 2], return_index=True)  # one transition per voxel
    tr = tr[uniq]
    final = np.stack([i, j], axis=1)[uniq][rng.random(len(uniq)) < 0.5]
    for e in find_events(tr, COORDS, 0.05, CLOCK, window_s=100.0, link_m=0.5, final_cols=final)[0]:
        if e["latency_s"] is not None:
            assert e["cell_latency_min_s"] - 1e-9 <= e["latency_s"] <= e["cell_latency_max_s"] + 1e-9, e


def test_settings_are_checked():
    cfg = Config()
    assert (cfg.replay.event_min_voxels, cfg.replay.event_min_p_cells) == (4, 3)
    cfg.replay.event_min_voxels = 0
    with pytest.raises(Exception, match="event_min_voxels"):
        cfg.validate()


def test_column_counts_equal_a_replay_of_the_transitions():
    from ltmap_cli.analysis.events import ColumnCounts

    rng = np.random.default_rng(4)
    n = 400
    cols = rng.integers(0, 6, (n, 2))
    ticks = rng.integers(0, 50, n)
    kind = rng.choice([1, 2], n)
    # a consistent history: start every column with 30 voxels, apply in tick order, end = final
    start = {(a, b): 30 for a in range(6) for b in range(6)}  # never below 0
    order = np.argsort(ticks, kind="stable")
    cur = dict(start)
    for r in order:
        c = tuple(cols[r])
        cur[c] += 1 if kind[r] == 1 else -1
    final_cols = np.array([c for c, v in cur.items() for _ in range(max(v, 0))])
    counts = ColumnCounts(kind, cols, ticks, final_cols)
    for t in (-1, 0, 7, 25, 49, 60):
        cur = dict(start)
        for r in order:
            if ticks[r] <= t:
                cur[tuple(cols[r])] += 1 if kind[r] == 1 else -1
        q = np.array(list(cur))
        got = counts.count(q, np.full(len(q), t))
        assert got.tolist() == [max(cur[tuple(c)], 0) for c in q], t
    assert counts.count(np.array([[40, 40]]), np.array([3])).tolist() == [0]  # a column never seen


def _strip(i0, i1, j):
    return [(i, j) for i in range(i0, i1)]


def test_a_wall_thinned_by_a_cell_is_surface_an_object_leaving_is_not():
    from ltmap_cli.analysis.events import ColumnCounts, surface_only

    wall = _strip(0, 20, 10)  # stays occupied all along (row j = 10)
    surface = _strip(4, 12, 9)  # the cells in front of it, leaving at tick 50
    box = [(i, j) for i in range(14, 18) for j in range(6, 10)]  # a box against the wall, leaving
    free_box = [(i, j) for i in range(3, 7) for j in range(1, 4)]  # a box in the open, leaving
    cols = np.array(surface + box + free_box)
    kind = np.full(len(cols), 2)
    ticks = np.concatenate([np.full(len(surface), 50), 60 + np.arange(len(box)) % 3, np.full(len(free_box), 70)])
    final = np.array(wall)
    counts = ColumnCounts(kind, cols, ticks, final)
    n_s, n_b = len(surface), len(box)
    assert surface_only(2, np.array(surface), ticks[:n_s], counts)
    assert not surface_only(2, np.array(box), ticks[n_s:n_s + n_b], counts)  # its middle frees too
    assert not surface_only(2, np.array(free_box), ticks[n_s + n_b:], counts)
    # the same wall given by the static map instead of LT
    counts_s = ColumnCounts(kind, cols, ticks, None)
    in_wall = np.array(wall)
    static = lambda c: (c[:, None, :] == in_wall[None]).all(axis=2).any(axis=1)  # noqa: E731
    assert surface_only(2, np.array(surface), ticks[:n_s], counts_s, static)
    assert not surface_only(2, np.array(surface), ticks[:n_s], counts_s)
    # appear: the surface cells coming back in front of the wall are surface; a box placed is not
    back = ColumnCounts(np.full(n_s, 1), np.array(surface), np.full(n_s, 80), np.array(wall + surface))
    assert surface_only(1, np.array(surface), np.full(n_s, 80), back)
    placed = ColumnCounts(np.full(len(free_box), 1), np.array(free_box), np.full(len(free_box), 5),
                          np.array(wall + free_box))  # fmt: skip
    assert not surface_only(1, np.array(free_box), np.full(len(free_box), 5), placed)


def _rows(items):
    """Transition rows and block coordinates for (kind, (i, j, k), tick, since) items."""
    keys = np.array([k for _, k, _, _ in items])
    blocks, inv = np.unique(keys // 8, axis=0, return_inverse=True)
    off = ((keys[:, 0] % 8) << 6) | ((keys[:, 1] % 8) << 3) | (keys[:, 2] % 8)
    rows = np.array([[kind, b, o, t, s_] for (kind, _, t, s_), b, o in zip(items, inv.ravel(), off)])
    return rows, blocks.astype(np.int32)


def test_find_events_drops_surface_groups_and_counts_them():
    items = [(2, (i, 9, 2), 50, 40) for i in range(4, 12)]  # in front of a wall at j = 10: leave
    items += [(2, (i, j, 2), 70, 60) for i in range(3, 7) for j in range(1, 4)]  # a box in the open
    rows, blocks = _rows(items)
    final = np.array([(i, 10) for i in range(0, 20)])  # the wall stays
    filtered = {}
    events, _ = find_events(rows, blocks, 0.05, CLOCK, link_m=0.05, min_voxels=4, min_p_cells=3,
                            final_cols=final, filtered=filtered, drop_surface=True)  # fmt: skip
    assert [e["voxels"] for e in events] == [12]
    assert filtered == {"appear": 0, "disappear": 1, "voxels": 8, "surface": 1}
    events, _ = find_events(rows, blocks, 0.05, CLOCK, link_m=0.05, min_voxels=4, min_p_cells=3,
                            final_cols=final)  # fmt: skip
    assert sorted(e["voxels"] for e in events) == [8, 12]
