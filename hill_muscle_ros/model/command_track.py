"""A command track: time-stamped set points sent ahead, read back by time.

A sender that knows its commands in advance (a protocol player) stamps each
one with the simulated time at which it is to be reached and sends it early;
the receiver reads the track at its own step times. Transport latency then
no longer delays the command, as long as it arrives before its time. This is
the semantics of a trajectory (``trajectory_msgs/JointTrajectory``):

- the track is piecewise linear between its knots (``t_s``, ``value``) and
  holds the last knot's value after it;
- it starts from the value *applied* when it was last consumed: a single knot
  1 s ahead of the consumed time is a 1 s ramp from where the receiver is;
- :meth:`CommandTrack.consume` marks a time as applied: knots at or before it
  are pruned, and the applied value becomes the start of the next segment;
- a knot at or before the consumed time is *late*: it cannot act in the past,
  so the track continues from the consumed time as if it had arrived in time
  (on the line from the late knot to the next pending one, or holding its
  value if there is none), and :meth:`CommandTrack.add` returns how late it
  was so that the receiver can report it; a late knot older than one that
  already took effect is stale and changes nothing.

Values are MTU length changes dl_MT [m], validated like every length input
(:func:`~hill_muscle_ros.model.muscle.check_dl_mt`). Pure Python and NumPy.
"""
from __future__ import annotations

import math
from bisect import bisect_left, bisect_right

import numpy as np

from .muscle import check_dl_mt

#: Knots a track holds at most: 100 s of commands at 1 kHz. Far more than any
#: look-ahead needs; the bound keeps a runaway sender from exhausting memory.
MAX_KNOTS = 100_000


def check_time(t_s: float, name: str = 't_s') -> float:
    """Validate a time; raise ``ValueError`` naming it otherwise.

    :param t_s: [s] a simulated time
    :param name: what to call the value in the error message
    :return: [s] the time as a float
    """
    t = float(t_s)
    if not math.isfinite(t):
        raise ValueError(f'`{name}` must be finite, got {t_s!r}')
    return t


class CommandTrack:
    """Piecewise-linear dl_MT command keyed by simulated time.

    :param value: [m] the value applied at ``t_s`` (dl_MT), where the track starts
    :param t_s: [s] the time the track is consumed up to at the start
    :param name: what to call a value in error messages (e.g. the topic)
    :param max_knots: most pending knots held (:data:`MAX_KNOTS`)
    """

    def __init__(self, value: float = 0.0, t_s: float = 0.0, *, name: str = 'dl_mt_m',
                 max_knots: int = MAX_KNOTS) -> None:
        if not (isinstance(max_knots, int) and max_knots >= 1):
            raise ValueError(f'`max_knots` must be a positive integer, got {max_knots!r}')
        self._name = name
        self._max_knots = max_knots
        # Pending knots, strictly increasing in time and all after the
        # consumed time: two plain lists, searched with bisect.
        self._times: list[float] = []
        self._values: list[float] = []
        self.clear(t_s, value)

    def clear(self, t_s: float, value: float) -> None:
        """Drop every pending knot; the track holds ``value`` from ``t_s`` on.

        :param t_s: [s] the time the track is consumed up to from now on
        :param value: [m] the value applied at ``t_s`` (dl_MT)
        """
        t = check_time(t_s)
        v = check_dl_mt(value, self._name)
        self._times.clear()
        self._values.clear()
        self._consumed_s = t
        self._start_value = v
        # Time of the newest knot that took effect: an older late knot is stale.
        self._newest_applied_s = -math.inf

    def __len__(self) -> int:
        """The number of pending knots (after the consumed time)."""
        return len(self._times)

    @property
    def consumed_s(self) -> float:
        """[s] the time the track has been consumed up to."""
        return self._consumed_s

    @property
    def knots(self) -> tuple[np.ndarray, np.ndarray]:
        """[s], [m] the pending knots' times and values (copies)."""
        return np.array(self._times, dtype=float), np.array(self._values, dtype=float)

    def add(self, t_s: float, value: float) -> float | None:
        """Insert a knot: reach ``value`` at time ``t_s``.

        A knot at a time that already has one replaces it (the newest wins).

        :param t_s: [s] when the value is to be reached
        :param value: [m] dl_MT
        :return: ``None`` if the knot is pending; [s] how late it is (the
            consumed time minus ``t_s``, >= 0) if it is at or before the
            consumed time, in which case it acts from the consumed time on
            (unless a newer knot already took effect: then it is stale and
            changes nothing)
        :raises ValueError: naming the time or the value if either is invalid,
            or if the track already holds ``max_knots`` pending knots
        """
        t = check_time(t_s)
        v = check_dl_mt(value, self._name)
        if t <= self._consumed_s:
            if t >= self._newest_applied_s:
                self._newest_applied_s = t
                self._start_value = float(np.interp(
                    self._consumed_s, [t, *self._times[:1]], [v, *self._values[:1]]))
            return self._consumed_s - t
        i = bisect_left(self._times, t)
        if i < len(self._times) and self._times[i] == t:
            self._values[i] = v
            return None
        if len(self._times) >= self._max_knots:
            raise ValueError(f'cannot add `{self._name}` = {value!r} at t = {t_s!r} s: the '
                             f'track already holds {self._max_knots} pending knots '
                             '(max_knots); send fewer knots or consume it')
        self._times.insert(i, t)
        self._values.insert(i, v)
        return None

    def value_at(self, t_s: float | np.ndarray) -> float | np.ndarray:
        """The track's value at one time or an array of times.

        Linear from the consumed time's value through the pending knots,
        the last knot's value after it. Before the consumed time the past is
        not kept: the consumed time's value is returned.

        :param t_s: [s] time(s)
        :return: [m] dl_MT, a float or an array shaped like ``t_s``
        """
        t = np.asarray(t_s, dtype=float)
        # Only the knots up to the first one at or after the latest time asked
        # take part: the interpolation stays short however far ahead the
        # sender is.
        j = bisect_right(self._times, float(t.max())) + 1 if t.size else 0
        out = np.interp(t, [self._consumed_s, *self._times[:j]],
                        [self._start_value, *self._values[:j]])
        return float(out) if out.ndim == 0 else out

    def consume(self, t_s: float) -> float:
        """Mark the track as applied up to ``t_s``; return its value there.

        Knots at or before ``t_s`` are pruned; the value at ``t_s`` becomes
        the start of the next segment.

        :param t_s: [s] time applied up to, not before the consumed time
        :return: [m] the value at ``t_s``
        :raises ValueError: if ``t_s`` is not finite or before the consumed time
        """
        t = check_time(t_s)
        if t < self._consumed_s:
            raise ValueError(f'`t_s` must not be before the consumed time '
                             f'{self._consumed_s!r} s, got {t_s!r}')
        value = self.value_at(t)
        i = bisect_right(self._times, t)
        if i:
            self._newest_applied_s = self._times[i - 1]
            del self._times[:i]
            del self._values[:i]
        self._consumed_s = t
        self._start_value = value
        return value
