"""Checking a node's input messages.

- :class:`BadInputWarner`: a throttled warning per topic for rejected input.
- :func:`pulse_width_command`: a ``pulse_width`` message to the recruitment
  command, with a hint for microseconds sent as seconds (the simulator and
  limb nodes).
"""
from __future__ import annotations

import time

from ..model import MuscleParams
from ..model.stimulus import command_from_pulse_width

#: [s] at most one bad-input warning per topic in this period.
BAD_INPUT_THROTTLE_S = 1.0
#: A pulse width this many times PW_max is not an FES pulse: it is rejected
#: with a hint, since it is most likely microseconds sent for seconds.
PULSE_WIDTH_UNIT_HINT_FACTOR = 100.0


class BadInputWarner:
    """A warning per topic, at most once per ``period_s``, counting the rest.

    rclpy's ``throttle_duration_sec`` throttles per call site, so one helper
    line would let one noisy topic hide another; this keys on the topic.

    :param logger: the node's logger
    :param period_s: [s] shortest interval between two warnings of one topic
    """

    def __init__(self, logger, period_s: float = BAD_INPUT_THROTTLE_S) -> None:
        self._logger = logger
        self._period_s = period_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        #: Rejected inputs per topic, logged or not (reported on /diagnostics).
        self.counts: dict[str, int] = {}

    @property
    def total(self) -> int:
        """Rejected inputs on every topic."""
        return sum(self.counts.values())

    def warn(self, topic: str, message: str) -> bool:
        """Count a rejected input on ``topic``; log ``message`` unless one was
        logged less than a period ago.

        :return: whether it was logged
        """
        self.counts[topic] = self.counts.get(topic, 0) + 1
        now = time.monotonic()
        last = self._last.get(topic)
        if last is not None and now - last < self._period_s:
            self._suppressed[topic] = self._suppressed.get(topic, 0) + 1
            return False
        skipped = self._suppressed.pop(topic, 0)
        suffix = f' ({skipped} more since the last warning)' if skipped else ''
        self._logger.warning(message + suffix)
        self._last[topic] = now
        return True


def pulse_width_command(pulse_width_s: float, params: MuscleParams, topic: str) -> float:
    """The command of a ``pulse_width`` message: the muscle's recruitment curve,
    and a width over :data:`PULSE_WIDTH_UNIT_HINT_FACTOR` x PW_max rejected
    with a hint, since it is most likely microseconds sent for seconds.

    :param pulse_width_s: [s] the message's pulse width
    :param params: the muscle's parameters (curve, PW_max)
    :param topic: the subscription's full topic name, for the error message
    :return: [-] recruitment command u
    :raises ValueError: naming the topic and the value
    """
    # Finite and non-negative first: only a finite width can be microseconds.
    u = command_from_pulse_width(pulse_width_s, params, topic)
    limit_s = PULSE_WIDTH_UNIT_HINT_FACTOR * params.pw_max_s
    if pulse_width_s > limit_s:
        raise ValueError(
            f'`{topic}` must be at most {PULSE_WIDTH_UNIT_HINT_FACTOR:g} x pw_max_s '
            f'({limit_s:g} s), got {pulse_width_s!r}. It looks like microseconds: '
            f'pulse_width is in seconds (REP 103), e.g. {pulse_width_s * 1e-6:g} for '
            f'{pulse_width_s:g} us')
    return u
