"""The tick clock: ST/LT change on a fixed tick of log (header) time, whatever the sensor rates
(SPEC 2.2: every ``map.layers.tick`` seconds, default 0.2 s)."""

from __future__ import annotations

from collections.abc import Iterator

from ..analysis.events import TickClock

NS = 1_000_000_000


class Ticker:
    """Tick ends reached by frames stamped in order. The first frame's stamp starts tick 0; a
    frame stamped at or after a tick's end closes that tick (and any empty ticks before it)."""

    def __init__(self, tick_s: float):
        self.tick_s = tick_s
        self.tick_ns = int(round(tick_s * NS))
        self.t0_ns: int | None = None
        self.end_ns: int | None = None

    def advance(self, stamp_ns: int) -> Iterator[int]:
        """The end stamps (ns) of the ticks that ``stamp_ns`` closes, in order."""
        if self.end_ns is None:
            self.t0_ns = stamp_ns
            self.end_ns = stamp_ns + self.tick_ns
            return
        while stamp_ns >= self.end_ns:
            yield self.end_ns
            self.end_ns += self.tick_ns

    def since_start_s(self, stamp_ns: int) -> float:
        """Seconds from tick 0's start to ``stamp_ns``."""
        return (stamp_ns - (self.t0_ns or 0)) / NS

    def analysis_clock(self, log_start_ns: int) -> TickClock:
        """Tick index -> seconds since the log's first message (events, plots)."""
        t0 = (self.t0_ns - log_start_ns) / NS if self.t0_ns is not None else 0.0
        return TickClock(t0, self.tick_s)
