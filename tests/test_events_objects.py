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
    assert filtered == {"appear": 1, "disappear": 2, "voxels": 4}
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
