"""Fixed steps against the steady clock: how many are due at a clock reading."""
from __future__ import annotations

import math

from ..timebase import NS_PER_S


class StepSchedule:
    """Whole steps due since a start instant, with no accumulated drift.

    The step count is always recomputed from the elapsed time,
    ``floor(elapsed * real_time_factor * rate_hz)``, never accumulated tick by
    tick, so simulated time cannot drift from the clock it follows.

    :param rate_hz: [Hz] step rate, 1 / dt
    :param real_time_factor: [-] simulated seconds per clock second
    :param start_ns: [ns] clock reading at simulated time 0
    """

    def __init__(self, rate_hz: float, real_time_factor: float, start_ns: int) -> None:
        self.steps_per_ns = rate_hz * real_time_factor / NS_PER_S
        self.start_ns = start_ns
        self.steps_done = 0
        self.late_ticks = 0
        self.ticks = 0
        #: [s] longest clock interval between two consecutive :meth:`due`
        #: calls: the longest time the node's tick did not run (0 before the
        #: second tick). Start-up before the first tick is not counted.
        self.max_tick_gap_s = 0.0
        #: [ns] clock reading at the end of that longest gap (``None`` before
        #: the second tick): to tell, afterwards, what else happened then.
        self.max_tick_gap_end_ns: int | None = None
        self._last_due_ns: int | None = None

    def target(self, now_ns: int) -> int:
        """Steps that should have been run by ``now_ns``."""
        return math.floor((now_ns - self.start_ns) * self.steps_per_ns)

    def due(self, now_ns: int) -> int:
        """Steps to run now; counts the tick, a late tick if more than one, and the gap."""
        n = max(0, self.target(now_ns) - self.steps_done)
        if self._last_due_ns is not None:
            gap_s = (now_ns - self._last_due_ns) / NS_PER_S
            if self.max_tick_gap_end_ns is None or gap_s > self.max_tick_gap_s:
                self.max_tick_gap_s = gap_s
                self.max_tick_gap_end_ns = now_ns
        self._last_due_ns = now_ns
        self.ticks += 1
        if n > 1:
            self.late_ticks += 1
        return n
