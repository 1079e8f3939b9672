"""The ST / LT history of the events (issue 17: hours of RGB-D logs in bounded memory).

Its periodic samples (every observed voxel of P's band every ``history_every`` ticks) grow with
the log's length: 12 k rows a second of a room seen from one end, about 700 MB an hour. At
``EventLog.max_rows`` the older ones at every other sampling tick are dropped and the sampling
period doubles; transitions and forgetting are kept whole. Checked against the same frames with an
unbounded history: the map and the transitions bit for bit, the non-periodic rows all there in
order, the periodic rows a subset of the unbounded run's that holds every row at the final
period's ticks, and the buffer no bigger than it started.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_speed_quiet import _frames

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import EventLog, LayeredMap

ROWS0 = 1 << 14  # the bounded run's buffer: it starts (and must stay) this small


def _run(frames, bounded: bool) -> LayeredMap:
    cfg = MapConfig()
    cfg.layers.st_rise_s = 3.0  # voxels enter LT (and leave it): transitions are recorded
    cfg.layers.lt_fall_s = 10.0
    m = LayeredMap(cfg)
    if bounded:
        ev = EventLog(max_rows=ROWS0)
        ev.hist_i, ev.hist_v, ev.hist_p = ev.hist_i[:ROWS0].copy(), ev.hist_v[:ROWS0].copy(), ev.hist_p[:ROWS0].copy()
        m.events = ev
    for f, (origin, ends, kind) in enumerate(frames):
        m.integrate_rays(origin, ends, kind)
        if f % 2 == 1:
            m.end_tick()
    return m


def _rows(ev: EventLog, periodic: bool) -> np.ndarray:
    hi, hv = ev.history
    sel = (ev.hist_p[: len(hi)] == 1) == periodic
    return np.concatenate([hi[sel].astype(np.float64), hv[sel].astype(np.float64)], axis=1)


@pytest.mark.slow  # (end to end: the default tier stays under 5 minutes on a slow 2-core machine)
def test_history_stays_bounded_and_keeps_transitions_whole():
    frames = _frames(600, seed=11)
    full, small = _run(frames, bounded=False), _run(frames, bounded=True)
    a, b = full.events, small.events

    # the history does not feed back: map and transitions as with the unbounded history
    n = full.O.n_blocks
    assert np.array_equal(full.O.data["logodds"][:n], small.O.data["logodds"][:n])
    for ch in full.D.data:
        assert np.array_equal(full.D.data[ch][: full.D.n_blocks], small.D.data[ch][: small.D.n_blocks]), ch
    assert np.array_equal(a.transitions, b.transitions) and len(a.transitions) > 0

    assert len(a.history[0]) > 4 * ROWS0  # the unbounded history outgrew the bounded buffer
    assert b.thinned >= 2 and len(b.hist_i) == ROWS0 and len(b.history[0]) <= ROWS0
    assert a.thinned == 0

    # transitions and forgetting: every row, in order
    assert np.array_equal(_rows(a, False), _rows(b, False)) and len(_rows(a, False)) > 0
    # periodic samples: a subset of the unbounded run's, holding all those at the final period's ticks
    pa, pb = _rows(a, True), _rows(b, True)
    as_set = {tuple(r) for r in pa.tolist()}
    assert all(tuple(r) in as_set for r in pb.tolist())
    period = b.sample_every(small.history_every)
    assert period == small.history_every << b.thinned
    at_period = pa[pa[:, 0] % period == 0]
    bs_set = {tuple(r) for r in pb.tolist()}
    assert len(at_period) > 0 and all(tuple(r) in bs_set for r in at_period.tolist())
    # and sampling went on at the doubled period after each thinning: the last ticks' samples are there
    last_tick = int(pa[:, 0].max())
    assert last_tick % period != 0 or last_tick in set(pb[:, 0].astype(int).tolist())
    assert int(pb[:, 0].max()) >= last_tick - period
