"""Fixed steps against the steady clock, shared by the simulator and limb nodes.

- :class:`StepSchedule`: how many fixed steps are due at a clock reading.
- The ``rate_hz`` and ``real_time_factor`` parameters' defaults and ranges,
  and the limits of a tick's catch-up (:data:`MIN_TICK_PERIOD_S`,
  :data:`MAX_CATCH_UP_S`) with the /diagnostics levels that follow from them.
"""
from __future__ import annotations

import math

from ..timebase import NS_PER_S

#: [Hz] default ``rate_hz``: dt = 1 ms.
DEFAULT_RATE_HZ = 1000.0
#: [Hz] a step rate outside this range is a typo (period in place of rate).
RATE_HZ_RANGE = (1.0, 100_000.0)
#: [-] default ``real_time_factor``: simulated time runs with the steady clock.
DEFAULT_REAL_TIME_FACTOR = 1.0
#: [-] from 100x slower to 1000x faster than the wall clock.
REAL_TIME_FACTOR_RANGE = (0.01, 1000.0)

#: [s] the timer never ticks faster than this: at a higher step rate or a real
#: time factor > 1 each tick runs several steps (the simulator publishing every
#: n-th, see its DEFAULT_MAX_OUTPUT_RATE_HZ).
MIN_TICK_PERIOD_S = 0.001
#: [s] of clock time one tick may catch up at most, so that a long stall (a
#: suspended process) cannot freeze the node while it runs a huge backlog. It
#: also bounds a tick's burst of messages per output: 100 at 1 kHz (a
#: subscriber that must not lose any needs a queue at least that deep).
MAX_CATCH_UP_S = 0.1
#: /diagnostics: WARN when the steps run in the last period fall below this
#: fraction of rate_hz x real_time_factor (beyond one tick's worth of steps,
#: which the count may lag by when the report happens to fall between ticks).
RATE_WARN_FRACTION = 0.99
#: [s] /diagnostics: ERROR when more than this much clock time's worth of
#: steps is behind: more than one tick may catch up, so the node is not
#: keeping up (or has just come out of a stall that long).
ERROR_BEHIND_S = MAX_CATCH_UP_S
#: Slack, in steps, for the rounding of ``tick period x rate_hz x
#: real_time_factor`` to whole steps per tick (3000 Hz x 1 ms is 3.0000000000000004).
STEPS_PER_TICK_ROUNDING = 1e-9


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
